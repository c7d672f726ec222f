#!/usr/bin/env bash
# display_cli.sh F4D_DISPLAY F4D_SCENE F4D_CODEC F4D_RENDER F4D_METRICS DIR:
# f4d-display headless on a stream file: PNG frames, the JSON summary, a rig
# camera whose first frame equals f4d-render of the decoded key (CPU path:
# identical; GLES: PSNR floor), a join in the middle of the file, and errors.
set -euo pipefail
disp=$1 scenebin=$2 codec=$3 render=$4 metrics=$5 dir=$6
rm -rf "$dir" && mkdir -p "$dir"
"$scenebin" --preset walk --frames 5 --views 2 --size 160x120 --gaussians 8000 -o "$dir/scene" >/dev/null
"$codec" encode "$dir"/scene/t*/gaussians.ply -o "$dir/s.f4ds" --quality medium --key-rate 30 --intra-every 2 >/dev/null
"$codec" decode "$dir/s.f4ds" -o "$dir/k0.ply" --frame 0 >/dev/null
"$render" --ply "$dir/k0.ply" --rig "$dir/scene/rig.json" --camera 0 -o "$dir/ref0.png" >/dev/null
status=0
"$disp" --headless --png-dir "$dir/cpu" --rig "$dir/scene/rig.json" --camera 0 --no-status --renderer cpu \
  --fps 60 "$dir/s.f4ds" > "$dir/cpu.json" || status=$?
[ $status -eq 77 ] && { echo "[  SKIP    ] no surfaceless EGL display"; exit 77; }
[ $status -eq 0 ] || { echo "f4d-display failed ($status)"; cat "$dir/cpu.json"; exit 1; }
cat "$dir/cpu.json"
# 5 keys at 30 Hz shown at 60 fps: 4/30 s of stream, 9 refreshes
grep -q '"frames": 9,' "$dir/cpu.json"
grep -q '"keys": 5,' "$dir/cpu.json"
grep -q '"renderer": "cpu"' "$dir/cpu.json"
[ "$(ls "$dir/cpu" | wc -l)" -eq 9 ]
"$metrics" "$dir/ref0.png" "$dir/cpu/frame_000000.png" | tee "$dir/m_cpu.txt"
grep -q "psnr=inf" "$dir/m_cpu.txt"
"$disp" --headless --png-dir "$dir/gles" --rig "$dir/scene/rig.json" --camera cam0 --no-status --renderer gles \
  --frames 2 "$dir/s.f4ds" > "$dir/gles.json"
"$metrics" "$dir/ref0.png" "$dir/gles/frame_000000.png" | tee "$dir/m_gles.txt"
awk -F'[= ]' '{ if ($2 + 0 < 45) { print "GLES PSNR " $2 " below 45 dB"; exit 1 } }' "$dir/m_gles.txt"
# a join 100 bytes into the first key: it is skipped, the display starts at the next intra (key 2)
off=$(( 32 + 12 + 100 ))
"$disp" --headless --offset $off --no-status --fps 30 --size 96x64 "$dir/s.f4ds" > "$dir/join.json"
cat "$dir/join.json"
grep -q '"keys": 3,' "$dir/join.json"
grep -q '"frames": 3,' "$dir/join.json"
# orbit camera with the status line, --seconds limits the refreshes
"$disp" --headless --png-dir "$dir/orbit" --size 128x96 --seconds 0.05 --fps 60 "$dir/s.f4ds" > "$dir/orbit.json"
grep -q '"frames": 3,' "$dir/orbit.json"
# --ready-fd: one byte on the descriptor once set up, then closed (the
# reader below sees the byte and the end of the pipe)
"$disp" --headless --no-status --frames 1 --size 96x64 --ready-fd 5 "$dir/s.f4ds" 5> "$dir/ready.txt" > /dev/null
[ "$(cat "$dir/ready.txt")" = "1" ] || { echo "--ready-fd: no byte"; exit 1; }
# errors name what is wrong
if "$disp" --ready-fd 9 "$dir/s.f4ds" 9>&- 2> "$dir/e6.txt"; then echo "a closed --ready-fd accepted"; exit 1; fi
grep -q "ready-fd 9: not an open descriptor" "$dir/e6.txt"
if "$disp" --ready-fd 1.5 "$dir/s.f4ds" 2> "$dir/e7.txt"; then echo "--ready-fd 1.5 accepted"; exit 1; fi
grep -q "whole number" "$dir/e7.txt"
if "$disp" --headless "$dir/missing.f4ds" 2> "$dir/e1.txt"; then echo "missing input accepted"; exit 1; fi
grep -q "missing.f4ds" "$dir/e1.txt"
if "$disp" --camera 3 "$dir/s.f4ds" 2> "$dir/e2.txt"; then echo "--camera without a rig accepted"; exit 1; fi
grep -q "rig" "$dir/e2.txt"
if "$disp" --renderer vulkan "$dir/s.f4ds" 2> "$dir/e3.txt"; then echo "bad renderer accepted"; exit 1; fi
grep -q "vulkan" "$dir/e3.txt"
# KMS is built but there is no DRM device here: the error names the device
if "$disp" --kms --kms-device "$dir/no-card" "$dir/s.f4ds" 2> "$dir/e5.txt"; then echo "KMS without a device"; exit 1; fi
grep -q "no-card" "$dir/e5.txt"
head -c 20 "$dir/s.f4ds" > "$dir/cut.f4ds"
if "$disp" --headless "$dir/cut.f4ds" > /dev/null 2> "$dir/e4.txt"; then echo "a stream without keys was shown"; exit 1; fi
grep -q "no key frame" "$dir/e4.txt"
echo "display_cli: ok"
