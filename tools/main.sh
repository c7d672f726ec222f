#!/usr/bin/env bash
# The main job on the simulated board. Installs what is missing, builds, runs.
# Until the capture pipeline lands this is the kernel self-check and
# speed-vs-error table on the model's shapes (quick mode).
set -euo pipefail
cd "$(dirname "$0")/.."
tools/setup-debian.sh
cmake -S . -B build/release -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build/release -j "$(nproc)"
exec build/release/tools/f4d-bench/f4d-bench kernels --quick "$@"
