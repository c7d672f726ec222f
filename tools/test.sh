#!/usr/bin/env bash
# The whole test suite: installs what is missing, builds twice (optimised with
# warnings as errors, and AddressSanitizer + UndefinedBehaviorSanitizer), runs ctest on both.
set -euo pipefail
cd "$(dirname "$0")/.."
tools/setup-debian.sh
jobs=$(nproc)

cmake -S . -B build/release -DCMAKE_BUILD_TYPE=Release -DF4D_WERROR=ON >/dev/null
cmake --build build/release -j "$jobs"
ctest --test-dir build/release --output-on-failure -j "$jobs" --timeout 600

cmake -S . -B build/asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DF4D_SANITIZE=ON \
      -DF4D_WERROR=ON -DF4D_BENCH_OPENBLAS=OFF >/dev/null
cmake --build build/asan -j "$jobs"
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 \
  ctest --test-dir build/asan --output-on-failure -j "$jobs" --timeout 900 -LE no-asan
