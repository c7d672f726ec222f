#!/usr/bin/env bash
# Runs tools/train's Python tests (raster forward vs firmware, gradient check, the
# training smoke test). Exit 77 (skipped) when Debian's torch / numpy are absent.
set -euo pipefail
src=$1 scene=$2 render=$3 convert=$4
py=/usr/bin/python3
if ! [ -x "$py" ] || ! "$py" -c 'import torch, numpy' 2>/dev/null; then
  echo "[  SKIP    ] python3-torch / python3-numpy not installed (tools/train/README.md)"
  exit 77
fi
export F4D_SCENE_BIN=$scene F4D_RENDER_BIN=$render F4D_CONVERT_BIN=$convert OMP_NUM_THREADS=1
exec "$py" -m unittest discover -s "$src/tools/train/tests" -v
