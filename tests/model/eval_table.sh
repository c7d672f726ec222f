#!/usr/bin/env bash
# f4d-eval on test take 300000 (3 keys, regenerated exactly by f4d-scene venue from its
# seed: the committed short test take) with the shipped weights reproduces the committed
# table (firmware/infer/weights/eval_take300000_{f32,int8}.json) within noise: ISA paths
# differ in rounding only. Every column but the timing (key_ms): a column the committed
# table has as null (n/a: weights without motion / fusion) must be null here too, and a
# number must be a number within its tolerance. tools/train/ship.sh writes the tables.
set -euo pipefail
scene=$1 eval=$2 wdir=$3
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$scene" venue --seed 300000 --frames 3 -o "$tmp/t" > /dev/null
# the rows' value of a key (a number or null), first row only
num() { sed -n "s/^{\"rows\": \[{[^]]*\"$2\": \([-0-9.e+]*\|null\)[,}].*/\1/p" "$1"; }
fail=0
for p in f32 int8; do
  w=$wdir/forge4d_small.gguf
  [ $p = int8 ] && w=$wdir/forge4d_small_int8.gguf
  want=$wdir/eval_take300000_$p.json
  [ -s "$w" ] && [ -s "$want" ] || { echo "missing $w or $want"; exit 1; }
  "$eval" --take "$tmp/t" --weights "$w" --precision $p --threads 2 --json "$tmp/$p.json"
  # key: absolute tolerance
  for kv in novel_view_psnr:0.05 novel_view_ssim:0.002 novel_time_psnr:0.05 novel_time_ssim:0.002 \
            motion_epe_m:0.0005 point_dist_m:0.002 rot_err_deg:0.05 trans_err_m:0.002 \
            tlstd_fused:0.001 tlstd_unfused:0.001; do
    k=${kv%%:*} tol=${kv#*:}
    a=$(num "$tmp/$p.json" $k) b=$(num "$want" $k)
    if [ -z "$b" ]; then
      echo "$p $k: absent from the committed $want (regenerate it: tools/train/ship.sh --tables-only)"
      fail=1
    elif [ "$a" = null ] || [ "$b" = null ]; then
      [ "$a" = "$b" ] || { echo "$p $k: got '$a', committed '$b' (n/a must match)"; fail=1; }
    elif ! awk -v a="$a" -v b="$b" -v t="$tol" 'BEGIN { d = a - b; if (d < 0) d = -d; exit !(a != "" && d <= t) }'; then
      echo "$p $k: got '$a', committed '$b' (tolerance $tol)"
      fail=1
    fi
  done
done
[ $fail = 0 ] && echo "f4d-eval reproduces the committed table"
exit $fail
