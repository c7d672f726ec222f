#!/usr/bin/env bash
# f4d-eval on key 0 of test take 300000 (regenerated exactly by f4d-scene venue from its
# seed) with the shipped weights reproduces the committed table
# (firmware/infer/weights/eval_take300000_{f32,int8}.json) within noise: ISA paths
# differ in rounding only. Timing (key_ms) is not compared.
set -euo pipefail
scene=$1 eval=$2 wdir=$3
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$scene" venue --seed 300000 --frames 1 -o "$tmp/t" > /dev/null
num() { sed -n "s/.*\"$2\": \([-0-9.e+]*\).*/\1/p" "$1"; }
fail=0
for p in f32 int8; do
  w=$wdir/forge4d_small.gguf
  [ $p = int8 ] && w=$wdir/forge4d_small_int8.gguf
  want=$wdir/eval_take300000_$p.json
  [ -s "$w" ] && [ -s "$want" ] || { echo "missing $w or $want"; exit 1; }
  "$eval" --take "$tmp/t" --weights "$w" --precision $p --keys 1 --threads 2 --json "$tmp/$p.json"
  # key: absolute tolerance
  for kv in novel_view_psnr:0.05 novel_view_ssim:0.002 point_dist_m:0.002 rot_err_deg:0.05 trans_err_m:0.002; do
    k=${kv%%:*} tol=${kv#*:}
    a=$(num "$tmp/$p.json" $k) b=$(num "$want" $k)
    if ! awk -v a="$a" -v b="$b" -v t="$tol" 'BEGIN { d = a - b; if (d < 0) d = -d; exit !(a != "" && b != "" && d <= t) }'; then
      echo "$p $k: got '$a', committed '$b' (tolerance $tol)"
      fail=1
    fi
  done
done
[ $fail = 0 ] && echo "f4d-eval reproduces the committed table"
exit $fail
