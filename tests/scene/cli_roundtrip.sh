#!/usr/bin/env bash
# f4d-scene -> f4d-render -> f4d-metrics: re-rendering the written PLY with the
# written rig reproduces the written image (PLY stores log-scale and logit
# opacity, so the match is near, not bit-exact), and the tools reject bad input.
set -euo pipefail
scene=$1 render=$2 metrics=$3
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
"$scene" --preset throw --frames 2 --views 2 --size 96x80 --seed 3 -o "$dir/s" >/dev/null
for f in scene.json rig.json t0001/gaussians.ply t0001/cam1.png t0001/cam1_depth.npy t0001/cam1_flow.npy \
         t0001/cam1_motion_bwd.npy t0001/cam1_motion_fwd.npy t0001/motion_fwd.npy; do
  [ -s "$dir/s/$f" ] || { echo "missing $f"; exit 1; }
done
"$render" --ply "$dir/s/t0001/gaussians.ply" --rig "$dir/s/rig.json" --camera cam1 -o "$dir/r.png" \
  --background 0.55,0.65,0.78 --depth "$dir/d.npy" >/dev/null
out=$("$metrics" --json "$dir/s/t0001/cam1.png" "$dir/r.png")
echo "$out"
psnr=$(printf '%s' "$out" | sed -n 's/.*"psnr": \([^,]*\),.*/\1/p')
ssim=$(printf '%s' "$out" | sed -n 's/.*"ssim": \([0-9.]*\).*/\1/p')
awk -v p="$psnr" -v s="$ssim" 'BEGIN { if (!((p == "null" || p + 0 > 45) && s + 0 > 0.995)) exit 1 }' \
  || { echo "re-render differs: $out"; exit 1; }
text=$("$metrics" "$dir/s/t0000/cam0.png" "$dir/s/t0001/cam0.png")
case "$text" in psnr=*" ssim="*) ;; *) echo "bad text output: $text"; exit 1 ;; esac
if "$scene" --preset dance --frames 1 -o "$dir/x" 2>"$dir/err"; then exit 1; fi
grep -q "unknown preset 'dance'" "$dir/err"
if "$scene" --preset walk --frames 1 --size 99 -o "$dir/x" 2>"$dir/err"; then exit 1; fi
grep -q "must be WxH" "$dir/err"
if "$render" --ply "$dir/s/t0001/gaussians.ply" --rig "$dir/s/rig.json" --camera cam9 -o "$dir/r.png" 2>"$dir/err"; then exit 1; fi
grep -q "no camera named 'cam9'" "$dir/err"
# venue takes: every array present, deterministic by seed, the PLY re-renders to the first view
"$scene" venue --seed 7 --frames 2 --size 56x42 --ply -o "$dir/v" >/dev/null
"$scene" venue --seed 7 --frames 2 --size 56x42 -o "$dir/v2" >/dev/null
for f in rgb depth alpha motion_bwd motion_fwd eval_rgb eval_depth eval_alpha mid_rgb; do
  [ -s "$dir/v/$f.npy" ] || { echo "venue: missing $f.npy"; exit 1; }
  cmp -s "$dir/v/$f.npy" "$dir/v2/$f.npy" || { echo "venue: $f.npy differs between runs"; exit 1; }
done
grep -q '"people": \[{"preset"' "$dir/v/take.json" || { echo "venue: bad take.json"; exit 1; }
if "$scene" venue --seed 7 --views 9 -o "$dir/x" 2>"$dir/err"; then exit 1; fi
grep -q "must be an integer in 2..6" "$dir/err"
echo "cli round trip ok"
