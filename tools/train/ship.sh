#!/usr/bin/env bash
# ship.sh - the latest checkpoint -> firmware/infer/weights: f32 and int8 GGUF (the
# stage-1 model), the stream modules (safetensors), config, recipe, loss curves, and
# the evaluation table of the C runtime (f4d-eval) on the test split.
#   bash tools/train/ship.sh [BUILD_DIR]        (run from the repository root)
set -euo pipefail
build=${1:-build}
dst=firmware/infer/weights
exp=tools/train/export
py=/usr/bin/python3
"$py" tools/train/train.py --export "$exp"
"$build/tools/f4d-convert/f4d-convert" "$exp/forge4d_small.safetensors" "$dst/forge4d_small.gguf" \
  --config "$exp/config.json" --type f32 > "$exp/convert_f32.log"
"$build/tools/f4d-convert/f4d-convert" "$exp/forge4d_small.safetensors" "$dst/forge4d_small_int8.gguf" \
  --config "$exp/config.json" --type int8 > "$exp/convert_int8.log"
tail -1 "$exp/convert_int8.log"
cp "$exp/config.json" "$dst/config.json"
[ -f "$exp/forge4d_small_stream.safetensors" ] && cp "$exp/forge4d_small_stream.safetensors" "$dst/"
"$py" tools/train/plot_losses.py -o "$dst/loss_curves.png"
# the committed regression table: key 0 of test take 300000 (f4d-scene venue --seed 300000 --frames 1)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$build/tools/f4d-scene/f4d-scene" venue --seed 300000 --frames 1 -o "$tmp/t" > /dev/null
for p in f32 int8; do
  "$build/tools/f4d-eval/f4d-eval" --take "$tmp/t" --precision $p --keys 1 --threads 1 \
    --json "$dst/eval_take300000_$p.json" > /dev/null
done
F4D_WEIGHTS= "$build/tools/f4d-eval/f4d-eval" --take "$tmp/t" --precision all --keys 1 --threads 1 \
  | grep -v '| f16 |' | tee "$dst/eval_take300000.md"
# the whole test split (every key), one row per precision, averaged over takes
for d in tools/train/data/test/*; do
  for p in f32 int8; do
    "$build/tools/f4d-eval/f4d-eval" --take "$d" --precision $p --threads 1 --json "$tmp/$(basename "$d")_$p.json" > /dev/null
  done
done
"$py" - "$tmp" "$dst/eval_test_split.json" <<'PY'
import glob, json, math, sys
tmp, out = sys.argv[1], sys.argv[2]
rows = []
for p in ("f32", "int8"):
    rs = [json.load(open(f))["rows"][0] for f in sorted(glob.glob(f"{tmp}/3*_{p}.json"))]
    avg = {"precision": p, "takes": len(rs)}
    for k in rs[0]:
        if k == "precision":
            continue
        v = [r[k] for r in rs if r[k] is not None]
        avg[k] = sum(v) / len(v) if v else None
    rows.append(avg)
json.dump({"rows": rows}, open(out, "w"), indent=1)
for r in rows:
    print(r)
PY
ls -la "$dst"
