#!/usr/bin/env bash
# infer_forge4d.sh F4D_INFER F4D_RENDER GGUF_DIR FIXTURE_DIR OUT: f4d-infer
# --forge4d on the tiny fixtures. Checks per key time that every file exists,
# parses (the PLY and cameras.json through f4d-render, the .npy headers) and
# has the right counts (S * H * W Gaussians, [S,H,W,3] motions, S cameras);
# the --at frames; PNG sets; and that bad arguments are refused by name.
set -euo pipefail
infer=$1 render=$2 gg=$3 fix=$4 out=$5
rm -rf "$out" && mkdir -p "$out"
fail() { echo "infer_forge4d: $*"; exit 1; }

# npy_shape FILE: the shape tuple of a .npy header, e.g. "(2, 42, 70, 3)"
export LC_ALL=C
npy_shape() { head -c 128 "$1" | grep -ao "'shape': ([^)]*)" | head -1 | cut -c 10-; }
ply_count() { head -c 400 "$1" | grep -ao 'element vertex [0-9]*' | head -1 | cut -d' ' -f3; }

# check_key DIR S H W: one key time's files
check_key() {
  local d=$1 S=$2 H=$3 W=$4 n=$(($2 * $3 * $4))
  for f in gaussians.ply cameras.json extrinsic.npy intrinsic.npy gauge.npy; do
    [ -s "$d/$f" ] || fail "$d/$f is missing"
  done
  [ "$(ply_count "$d/gaussians.ply")" = "$n" ] || fail "$d/gaussians.ply: $(ply_count "$d/gaussians.ply") Gaussians, want $n"
  head -c 600 "$d/gaussians.ply" | grep -aq "property float rot_3" || fail "$d/gaussians.ply: not the INRIA layout"
  [ "$(npy_shape "$d/extrinsic.npy")" = "($S, 3, 4)" ] || fail "$d/extrinsic.npy: shape $(npy_shape "$d/extrinsic.npy")"
  [ "$(npy_shape "$d/intrinsic.npy")" = "($S, 3, 3)" ] || fail "$d/intrinsic.npy: shape $(npy_shape "$d/intrinsic.npy")"
  [ "$(npy_shape "$d/gauge.npy")" = "(1,)" ] || fail "$d/gauge.npy: shape $(npy_shape "$d/gauge.npy")"
  [ "$(grep -o '"world_to_camera"' "$d/cameras.json" | wc -l)" = "$S" ] || fail "$d/cameras.json: not $S cameras"
  for f in motion_bwd.npy motion_fwd.npy; do
    if [ -e "$d/$f" ]; then
      [ "$(npy_shape "$d/$f")" = "($S, $H, $W, 3)" ] || fail "$d/$f: shape $(npy_shape "$d/$f")"
    fi
  done
  # both files parse: render the key from its own camera 0 (and the last one)
  "$render" --ply "$d/gaussians.ply" --rig "$d/cameras.json" --camera 0 -o "$d/view0.png" >/dev/null
  "$render" --ply "$d/gaussians.ply" --rig "$d/cameras.json" --camera $((S - 1)) -o "$d/view_last.png" >/dev/null
  [ -s "$d/view0.png" ] || fail "$d: no render"
}

# 1. raw sets, 3 key times, two frames in between (tiny_f4d: no motion part)
x=$fix/tiny_f4d/s2/input.npy
"$infer" --forge4d --weights "$gg/tiny_f4d_f32.gguf" --raw-input "$x" --raw-input "$x" --raw-input "$x" \
  --at 0.5 --at 1.75 --out "$out/raw" | tee "$out/raw.log"
for t in 0 1 2; do check_key "$out/raw/t000$t" 2 42 70; done
[ ! -e "$out/raw/t0003" ] || fail "a fourth key time from three sets"
for a in 0.500 1.750; do
  [ "$(ply_count "$out/raw/at_$a/gaussians.ply")" = 5880 ] || fail "at_$a: wrong count"
  "$render" --ply "$out/raw/at_$a/gaussians.ply" --rig "$out/raw/t0001/cameras.json" --camera 0 -o "$out/at$a.png" >/dev/null
done
grep -q "nearest key" "$out/raw.log" || fail "no motion part: interpolation must say it takes the nearest key"
[ ! -e "$out/raw/t0001/motion_bwd.npy" ] || fail "motion written without a motion part"

# 2. PNG sets through the preprocessing (2 views, --size 56 -> 56 x 42 crop)
p=$fix/prep
"$infer" --forge4d --weights "$gg/tiny_f4d_f16.gguf" --precision f16 --size 56 \
  --set "$p/rgb_40x30.png" "$p/rgb_30x50.png" --set "$p/rgb_30x50.png" "$p/rgb_40x30.png" \
  --at 0.25 --out "$out/png" > "$out/png.log"
n0=$(ply_count "$out/png/t0000/gaussians.ply")
(( n0 % 2 == 0 && n0 > 0 )) || fail "png: $n0 Gaussians"
check_key "$out/png/t0000" 2 $((n0 / 2 / 56)) 56
check_key "$out/png/t0001" 2 $((n0 / 2 / 56)) 56
[ -s "$out/png/at_0.250/gaussians.ply" ] || fail "png: no frame at 0.25"

# 3. with the motion part (tiny_f4d_seq: state, motion, fusion; 4 key times):
#    motions on the right keys, the frame between keys fused
"$infer" --help 2>&1 | grep -q -- --forge4d || fail "usage does not name --forge4d"
{
  s=$fix/tiny_f4d_seq
  "$infer" --forge4d --weights "$gg/tiny_f4d_seq_f32.gguf" --raw-input "$s/t0/input.npy" --raw-input "$s/t1/input.npy" \
    --raw-input "$s/t2/input.npy" --raw-input "$s/t3/input.npy" --at 1.5 --out "$out/seq" | tee "$out/seq.log"
  sh=$(npy_shape "$s/t0/input.npy"); S=$(echo "$sh" | tr -d '( )' | cut -d, -f1)
  H=$(echo "$sh" | tr -d '( )' | cut -d, -f3); W=$(echo "$sh" | tr -d '( )' | cut -d, -f4)
  for t in 0 1 2 3; do check_key "$out/seq/t000$t" "$S" "$H" "$W"; done
  [ ! -e "$out/seq/t0000/motion_bwd.npy" ] && [ -s "$out/seq/t0000/motion_fwd.npy" ] || fail "seq: t0 motions"
  [ -s "$out/seq/t0003/motion_bwd.npy" ] && [ ! -e "$out/seq/t0003/motion_fwd.npy" ] || fail "seq: t3 motions"
  [ -s "$out/seq/t0001/motion_bwd.npy" ] && [ -s "$out/seq/t0001/motion_fwd.npy" ] || fail "seq: t1 motions"
  grep -q "at 1.500 (fused)" "$out/seq.log" || fail "seq: the frame at 1.5 is not fused"
  [ -s "$out/seq/at_1.500/gaussians.ply" ] || fail "seq: no frame at 1.5"
}

# 4. bad arguments name what is wrong
if "$infer" --forge4d --weights "$gg/tiny_f4d_f32.gguf" --raw-input "$x" --raw-input "$x" --at 3 \
     --out "$out/bad" 2> "$out/err1.txt"; then fail "--at 3 of 2 key times accepted"; fi
grep -q "outside the key times" "$out/err1.txt" || fail "no message for --at: $(cat "$out/err1.txt")"
if "$infer" --weights "$gg/tiny_f4d_f32.gguf" --set "$p/rgb_40x30.png" --out "$out/bad" 2> "$out/err2.txt"; then
  fail "--set without --forge4d accepted"; fi
grep -q "need --forge4d" "$out/err2.txt" || fail "no message for --set: $(cat "$out/err2.txt")"
if "$infer" --forge4d --weights "$gg/tiny_f32.gguf" --raw-input "$fix/tiny/s3/input.npy" --out "$out/bad" \
     2> "$out/err3.txt"; then fail "a plain VGGT file accepted"; fi
grep -q "gaussian_head" "$out/err3.txt" || fail "no message for plain VGGT: $(cat "$out/err3.txt")"
echo "infer_forge4d: ok"
