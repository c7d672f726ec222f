#!/usr/bin/env bash
# f4d-eval's cases on the tiny fixtures (random weights: only which columns are computed
# and why the others are n/a is checked, not their values) on small venue takes:
#   motion + fusion (tiny_f4d_seq)        every column a finite number;
#   motion, no fusion (tiny_f4d_seq with the fusion.* entries blanked out of the
#     safetensors header, converted here)  tlstd_fused null with its reason, the rest numbers;
#   no motion part (tiny_f4d)             novel time, motion EPE and TL-STD null, reason named;
#   a take of one key                     the same, reason "one key"; no crash;
#   a take without held-out cameras       novel view null, reason named, the rest numbers.
set -euo pipefail
scene=$1 eval=$2 convert=$3 fix=$4 gguf=$5
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$scene" venue --seed 300001 --frames 3 --size 42x28 --views 2 --eval 1 -o "$tmp/t3" > /dev/null
"$scene" venue --seed 300001 --frames 1 --size 42x28 --views 2 --eval 1 -o "$tmp/t1" > /dev/null
"$scene" venue --seed 300001 --frames 2 --size 42x28 --views 2 --eval 0 -o "$tmp/t0" > /dev/null
# same header length: each fusion entry (never the last one: names are sorted) becomes spaces
perl -e 'local $/; my $d = <STDIN>; my $n = unpack("Q<", substr($d, 0, 8)); my $h = substr($d, 8, $n);
         my $c = ($h =~ s/("fusion\.[^"]*":\{[^{}]*\},)/" " x length($1)/ge);
         die "no fusion entries\n" unless $c == 4; print substr($d, 0, 8), $h, substr($d, 8 + $n)' \
  < "$fix/tiny_f4d_seq/weights.safetensors" > "$tmp/nofusion.safetensors"
"$convert" "$tmp/nofusion.safetensors" "$tmp/nofusion.gguf" --config "$fix/tiny_f4d_seq/config.json" > /dev/null
fail=0
val() { sed -n "s/.*\"$2\": \([-0-9.e+]*\|null\)[,}].*/\1/p" "$1" | head -1; }
# check JSON KEY WANT(num|null)
check() {
  local v
  v=$(val "$1" "$2")
  case $3 in
    num) [[ $v =~ ^-?[0-9] ]] || { echo "$1: $2 is '$v', want a number"; fail=1; } ;;
    null) [ "$v" = null ] || { echo "$1: $2 is '$v', want null (n/a)"; fail=1; } ;;
  esac
}
timecols="novel_time_psnr novel_time_ssim motion_epe_m tlstd_unfused"
keycols="key_ms novel_view_psnr novel_view_ssim point_dist_m rot_err_deg trans_err_m"
run() { # NAME WEIGHTS TAKE
  "$eval" --take "$3" --weights "$2" --threads 1 --json "$tmp/$1.json" > "$tmp/$1.md"
}
run full "$gguf/tiny_f4d_seq_f32.gguf" "$tmp/t3"
for k in $keycols $timecols tlstd_fused; do check "$tmp/full.json" $k num; done
run nofusion "$tmp/nofusion.gguf" "$tmp/t3"
for k in $keycols $timecols; do check "$tmp/nofusion.json" $k num; done
check "$tmp/nofusion.json" tlstd_fused null
grep -q "TL-STD fused n/a: the weights have no fusion MLP" "$tmp/nofusion.md" || { echo "nofusion: no reason printed"; fail=1; }
run nomotion "$gguf/tiny_f4d_f32.gguf" "$tmp/t3"
for k in $keycols; do check "$tmp/nomotion.json" $k num; done
for k in $timecols tlstd_fused; do check "$tmp/nomotion.json" $k null; done
grep -q "n/a: the weights have no motion part" "$tmp/nomotion.md" || { echo "nomotion: no reason printed"; fail=1; }
run onekey "$gguf/tiny_f4d_seq_f32.gguf" "$tmp/t1"
for k in $keycols; do check "$tmp/onekey.json" $k num; done
for k in $timecols tlstd_fused; do check "$tmp/onekey.json" $k null; done
grep -q "n/a: the take has one key" "$tmp/onekey.md" || { echo "onekey: no reason printed"; fail=1; }
# the markdown says n/a exactly where the JSON has null (row of the one-key take: 5 of 12 cells)
nas=$(grep '^| f32 |' "$tmp/onekey.md" | grep -o 'n/a' | wc -l)
[ "$nas" = 5 ] || { echo "onekey: $nas n/a cells in the markdown row, want 5"; fail=1; }
run noeval "$gguf/tiny_f4d_seq_f32.gguf" "$tmp/t0"
for k in novel_view_psnr novel_view_ssim; do check "$tmp/noeval.json" $k null; done
for k in key_ms point_dist_m rot_err_deg trans_err_m $timecols tlstd_fused; do check "$tmp/noeval.json" $k num; done
grep -q "novel view n/a: the take has no held-out" "$tmp/noeval.md" || { echo "noeval: no reason printed"; fail=1; }
[ $fail = 0 ] && echo "f4d-eval: columns and n/a reasons as the weights and take allow"
exit $fail
