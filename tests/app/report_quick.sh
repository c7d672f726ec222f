#!/usr/bin/env bash
# app/report_quick: `forge4d report --quick` on a short venue take that f4d-scene
# generates from a test-split seed (2 views, 3 keys), then report_check on what it
# wrote (JSON fields, a non-dominated non-empty front, the goal line, PNGs that
# decode). The take carries its empty-venue plate (--background) for the foreground model. The checker is also run on broken copies, which it must refuse, and a
# missing take must fail with a clear message.
# Bad options (CPU clock with 2 threads, a grid without the baseline, motion off alone,
# an unknown axis value) must fail naming what is wrong.
#   report_quick.sh FORGE4D F4D-SCENE REPORT_CHECK WEIGHTS [SIZE] [--motion|-] [REPORT OPTIONS...]
set -euo pipefail
forge4d=$1 scene=$2 check=$3 weights=$4 size=${5:-112x112} motion=${6:-}
shift $(( $# < 6 ? $# : 6 ))
[ "$motion" = - ] && motion=
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
[ -s "$weights" ] || { echo "missing weights $weights"; exit 1; }
"$scene" venue --seed 300000 --frames 3 --views 2 --size "$size" --background -o "$tmp/take" > /dev/null

# no take / not a take: a clear error, not a crash
if "$forge4d" report --quick -o "$tmp/none" 2> "$tmp/err"; then echo "report without a take succeeded"; exit 1; fi
grep -q "no take given" "$tmp/err" || { echo "unclear error without a take:"; cat "$tmp/err"; exit 1; }
if "$forge4d" report --quick -o "$tmp/none" --take "$tmp/missing" 2> "$tmp/err"; then
  echo "report on a missing take succeeded"; exit 1
fi
grep -q "not a venue take" "$tmp/err" || { echo "unclear error for a missing take:"; cat "$tmp/err"; exit 1; }
refuse() { # refuse PATTERN OPTIONS...: the report must fail before running, naming the problem
  local want=$1; shift
  if "$forge4d" report --quick -o "$tmp/none" --take "$tmp/take" --weights "$weights" "$@" 2> "$tmp/err"; then
    echo "report $* succeeded"; exit 1
  fi
  grep -q -- "$want" "$tmp/err" || { echo "unclear error for $*:"; cat "$tmp/err"; exit 1; }
}
refuse "use --threads 1" --clock cpu --threads 2
refuse "must hold the baseline" --precision int8
refuse "must hold the baseline" --motion off
refuse 'unknown value "maybe"' --motion on,maybe
refuse 'unknown value "9/8"' --size 1,9/8

"$forge4d" report --quick -o "$tmp/out" --take "$tmp/take" --weights "$weights" "$@"
"$check" "$tmp/out" $motion
# the take has the empty-venue plate (--background): the foreground model learned from it
grep -q '"background_plate":[[:space:]]*true' "$tmp/out/report.json" ||
  { echo "the report did not use the take's background plate"; exit 1; }

# the checker must catch a wrong front, a broken plot and a missing figure
cp -r "$tmp/out" "$tmp/bad1"
flip_front() { # turn the first off-front point into a front point (or the reverse)
  if grep -q '"on_front":[[:space:]]*false' "$1"; then
    sed -i '0,/"on_front":[[:space:]]*false/s//"on_front": true/' "$1"
  else
    sed -i '0,/"on_front":[[:space:]]*true/s//"on_front": false/' "$1"
  fi
}
flip_front "$tmp/bad1/report.json"
if "$check" "$tmp/bad1" > /dev/null 2>&1; then echo "report_check accepted a wrong front"; exit 1; fi
cp -r "$tmp/out" "$tmp/bad2"
head -c 200 "$tmp/out/pareto.png" > "$tmp/bad2/pareto.png"
if "$check" "$tmp/bad2" > /dev/null 2>&1; then echo "report_check accepted a truncated PNG"; exit 1; fi
cp -r "$tmp/out" "$tmp/bad3"
sed -i '0,/"novel_view_psnr":[[:space:]]*[-0-9.e+]*/s//"novel_view_psnr": null/' "$tmp/bad3/report.json"
if "$check" "$tmp/bad3" > /dev/null 2>&1; then echo "report_check accepted a point without its PSNR"; exit 1; fi
echo "forge4d report --quick: outputs consistent; the checker refuses broken copies"
