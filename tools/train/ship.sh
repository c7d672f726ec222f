#!/usr/bin/env bash
# ship.sh - the latest checkpoint -> firmware/infer/weights: ONE GGUF with every module the
# checkpoint has (VGGT + Gaussian / scale heads and, from stage 2 on, state, motion, motion
# head and fusion MLP: train.py --export writes them into one safetensors, f4d-convert knows
# every name) in f32 and int8, the config, the loss curves, and the evaluation tables of the
# C runtime (f4d-eval, every column: novel view / time, motion EPE, point distance, cameras,
# TL-STD fused / unfused, time per key) on
#   - the committed short test take: test seed 300000 with 3 keys, regenerated from its seed
#     (eval_take300000_{f32,int8}.json, eval_take300000.md; tests/model/eval_table.sh
#     compares against them), and
#   - the whole test split (every take, every key; eval_test_split.json: mean over takes).
# The stage-2/3 modules no longer ship as a separate forge4d_small_stream.safetensors.
#
#   bash tools/train/ship.sh [BUILD_DIR] [--ckpt-dir DIR] [--data DIR] [--tables-only]
#                                                   (from the repository root)
#     BUILD_DIR      a Release build with f4d-convert, f4d-scene and f4d-eval (default: build)
#     --ckpt-dir DIR train.py's checkpoints and loss logs (default: tools/train/checkpoints)
#     --data DIR     the takes of tools/train/gen_data.py; the test split is DIR/test/*
#                    (default: tools/train/data)
#     --tables-only  no export or conversion: only the tables, from the GGUFs already in
#                    firmware/infer/weights
# Time per key (key_ms) is measured with one thread; f4d-eval's JSON records the load average.
set -euo pipefail
build=build data=tools/train/data tables_only=0 ckpt=tools/train/checkpoints
while [ $# -gt 0 ]; do
  case $1 in
    --data) data=$2; shift 2 ;;
    --ckpt-dir) ckpt=$2; shift 2 ;;
    --tables-only) tables_only=1; shift ;;
    -*) echo "ship.sh: unknown option $1" >&2; exit 2 ;;
    *) build=$1; shift ;;
  esac
done
dst=firmware/infer/weights
exp=tools/train/export
py=/usr/bin/python3
eval_bin=$build/tools/f4d-eval/f4d-eval
for b in "$build/tools/f4d-convert/f4d-convert" "$build/tools/f4d-scene/f4d-scene" "$eval_bin"; do
  [ -x "$b" ] || { echo "ship.sh: $b is missing (cmake --build $build --target f4d-convert f4d-scene f4d-eval)" >&2; exit 1; }
done
if [ $tables_only = 0 ]; then
  "$py" tools/train/train.py --ckpt-dir "$ckpt" --export "$exp"
  for t in f32 int8; do
    out=$dst/forge4d_small.gguf
    [ $t = int8 ] && out=$dst/forge4d_small_int8.gguf
    "$build/tools/f4d-convert/f4d-convert" "$exp/forge4d_small.safetensors" "$out" \
      --config "$exp/config.json" --type $t > "$exp/convert_$t.log"
    grep '^config:' "$exp/convert_$t.log"   # the groups the GGUF holds
  done
  tail -1 "$exp/convert_int8.log"
  cp "$exp/config.json" "$dst/config.json"
  "$py" tools/train/plot_losses.py --ckpt-dir "$ckpt" -o "$dst/loss_curves.png"
fi
# the committed regression table: test take 300000, 3 keys (f4d-scene venue --seed 300000 --frames 3)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$build/tools/f4d-scene/f4d-scene" venue --seed 300000 --frames 3 -o "$tmp/t" > /dev/null
# explicit --weights: f4d-eval's default prefers an installed copy over the tree's new files
wf32=$dst/forge4d_small.gguf wint8=$dst/forge4d_small_int8.gguf
for p in f32 int8; do
  w=$wf32
  [ $p = int8 ] && w=$wint8
  "$eval_bin" --take "$tmp/t" --weights "$w" --precision $p --threads 1 \
    --json "$dst/eval_take300000_$p.json" > "$tmp/t_$p.md"
done
# one markdown table: the f32 run's header, both rows, the paper row and notes of both
{ sed -n '1,3p' "$tmp/t_f32.md"; sed -n '3p' "$tmp/t_int8.md"; sed -n '4,$p' "$tmp/t_f32.md"
  sed -n '7,$p' "$tmp/t_int8.md"; } | tee "$dst/eval_take300000.md"
# the whole test split (every key), one row per precision, averaged over takes
takes=("$data"/test/*/)
[ -d "${takes[0]}" ] || { echo "ship.sh: no test takes in $data/test (tools/train/gen_data.py --out $data)" >&2; exit 1; }
for d in "${takes[@]}"; do
  for p in f32 int8; do
    w=$wf32
    [ $p = int8 ] && w=$wint8
    "$eval_bin" --take "$d" --weights "$w" --precision $p --threads 1 \
      --json "$tmp/split_$(basename "$d")_$p.json" > /dev/null
  done
done
"$py" - "$tmp" "$dst/eval_test_split.json" <<'PY'
import glob, json, sys
tmp, out = sys.argv[1], sys.argv[2]
rows, extra = [], []
for p in ("f32", "int8"):
    docs = [json.load(open(f)) for f in sorted(glob.glob(f"{tmp}/split_*_{p}.json"))]
    rs = [d["rows"][0] for d in docs]
    avg = {"precision": p, "takes": len(rs)}
    for k in rs[0]:
        if k == "precision":
            continue
        v = [r[k] for r in rs if r[k] is not None]
        avg[k] = sum(v) / len(v) if v else None   # n/a where no take has it
        if v and len(v) < len(rs):
            avg[k + "_takes"] = len(v)
    la = [d.get("load_average") for d in docs if d.get("load_average") is not None]
    avg["load_average"] = sum(la) / len(la) if la else None
    rows.append(avg)
    # the context columns (f4d-eval's "extra": EPE over all valid pixels, of zero motion, ...)
    ex = [d["extra"][0] for d in docs if d.get("extra")]
    e = {"precision": p}
    for k in (ex[0] if ex else {}):
        v = [x[k] for x in ex if isinstance(x.get(k), (int, float))]
        if k not in ("precision", "na"):
            e[k] = sum(v) / len(v) if v else None
    e["na"] = sorted({s for x in ex for s in x.get("na", [])})
    extra.append(e)
json.dump({"rows": rows, "extra": extra}, open(out, "w"), indent=1)
for r in rows:
    print(r)
PY
ls -la "$dst"
