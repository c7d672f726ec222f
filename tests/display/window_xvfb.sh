#!/usr/bin/env bash
# window_xvfb.sh F4D_DISPLAY F4D_SCENE F4D_CODEC F4D_RENDER F4D_METRICS DIR:
# f4d-display in a real X11 window (EGL on the X11 platform) under Xvfb, on a
# display number Xvfb picks itself (-displayfd). Each refresh is read back from
# the window's back buffer before the swap (glReadPixels, written as PNG by
# f4d-display) and the first is compared with f4d-render of the decoded key:
# CPU path identical, GLES path above the PSNR floor; keys sent with xdotool
# move the free camera. Exit 77 only when Xvfb cannot start. -noreset: by
# default an X server resets when its last client leaves, and a client that
# connects during the reset is refused ("cannot open the X display"), which
# happened between two of the runs below.
set -euo pipefail
disp=$1 scenebin=$2 codec=$3 render=$4 metrics=$5 dir=$6
rm -rf "$dir" && mkdir -p "$dir"
command -v Xvfb >/dev/null || { echo "[  SKIP    ] Xvfb is not installed (Debian package xvfb)"; exit 77; }
command -v xdotool >/dev/null || { echo "xdotool is not installed (Debian package xdotool)"; exit 1; }
Xvfb -displayfd 3 -screen 0 640x480x24 -nolisten tcp -noreset 3> "$dir/displayno" 2> "$dir/xvfb.log" &
xpid=$!
trap 'kill $xpid 2>/dev/null || true; wait $xpid 2>/dev/null || true' EXIT
for _ in $(seq 600); do # a hang bound (60 s), not a speed limit
  [ -s "$dir/displayno" ] && break
  kill -0 $xpid 2>/dev/null || break
  sleep 0.1
done
if ! [ -s "$dir/displayno" ]; then echo "[  SKIP    ] Xvfb did not start:"; cat "$dir/xvfb.log"; exit 77; fi
export DISPLAY=":$(head -n1 "$dir/displayno")"
echo "Xvfb on $DISPLAY"
"$scenebin" --preset wave --frames 3 --views 2 --size 200x150 --gaussians 8000 -o "$dir/scene" >/dev/null
"$codec" encode "$dir"/scene/t*/gaussians.ply -o "$dir/s.f4ds" --quality high --key-rate 30 >/dev/null
"$codec" decode "$dir/s.f4ds" -o "$dir/k0.ply" --frame 0 >/dev/null
"$render" --ply "$dir/k0.ply" --rig "$dir/scene/rig.json" --camera 1 -o "$dir/ref0.png" >/dev/null
for r in cpu gles; do
  "$disp" --window --png-dir "$dir/$r" --rig "$dir/scene/rig.json" --camera 1 --no-status --renderer $r --no-realtime \
    --frames 3 "$dir/s.f4ds" > "$dir/$r.json"
  cat "$dir/$r.json"
  grep -q '"frames": 3,' "$dir/$r.json"
  "$metrics" "$dir/ref0.png" "$dir/$r/frame_000000.png" | tee "$dir/m_$r.txt"
done
grep -q "psnr=inf" "$dir/m_cpu.txt"
awk -F'[= ]' '{ if ($2 + 0 < 45) { print "GLES PSNR " $2 " below 45 dB"; exit 1 } }' "$dir/m_gles.txt"
# the status line is drawn in the window too (paced: the wall clock drives the stream time)
"$disp" --window --png-dir "$dir/status" --rig "$dir/scene/rig.json" --camera 1 --renderer cpu --frames 2 \
  "$dir/s.f4ds" > /dev/null
"$metrics" "$dir/ref0.png" "$dir/status/frame_000000.png" | tee "$dir/m_status.txt"
if grep -q "psnr=inf" "$dir/m_status.txt"; then echo "the status line is missing"; exit 1; fi
# the free camera: W (forward) and Left (turn) sent to the window while it
# plays 8 s of stream in real time move the view; the same run without input
# ends on exactly f4d-render's picture of the last key (--interp nearest).
# The keys must reach the window before the stream's end: 8 s (keys 4 s
# apart) rather than 2 s leave a loaded machine, where the sanitized display
# takes seconds to open its window, time to do so.
"$codec" encode "$dir"/scene/t*/gaussians.ply -o "$dir/slow.f4ds" --quality high --key-rate 0.25 >/dev/null
"$codec" decode "$dir/slow.f4ds" -o "$dir/k2.ply" --frame 2 >/dev/null
"$render" --ply "$dir/k2.ply" --rig "$dir/scene/rig.json" --camera 1 -o "$dir/ref2.png" >/dev/null
for run in still moved; do
  "$disp" --window --png-dir "$dir/$run" --rig "$dir/scene/rig.json" --camera 1 --no-status --renderer cpu \
    --interp nearest --fps 10 --realtime "$dir/slow.f4ds" > "$dir/$run.json" &
  dpid=$!
  if [ $run = moved ]; then
    wid=""
    for _ in $(seq 600); do
      wid=$(xdotool search --name '^f4d-display$' 2>/dev/null | head -n1 || true)
      [ -n "$wid" ] && break
      sleep 0.1
    done
    [ -n "$wid" ] || { echo "the f4d-display window did not appear"; kill $dpid; exit 1; }
    sleep 0.5
    for _ in 1 2 3 4 5 6; do xdotool key --window "$wid" w Left 2>/dev/null; done
  fi
  wait $dpid
  last=$(ls "$dir/$run" | tail -n1)
  "$metrics" "$dir/ref2.png" "$dir/$run/$last" | tee "$dir/m_$run.txt"
done
grep -q "psnr=inf" "$dir/m_still.txt"
awk -F'[= ]' '{ if ($2 + 0 > 30) { print "the keys did not move the camera (PSNR " $2 ")"; exit 1 } }' "$dir/m_moved.txt"
echo "window_xvfb: ok"
