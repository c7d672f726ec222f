#!/usr/bin/env bash
# The main job on the simulated board: installs what is missing, builds, then
# records a take from the simulated 4-camera rig (board/sim-4cam.json), checks
# it, and writes a contact sheet of one synchronized set.
# Outputs land in out/ (override with OUT=DIR); extra arguments go to
# `forge4d record` (e.g. --seconds 5, --board board/sim-4cam-faulty.json).
set -euo pipefail
cd "$(dirname "$0")/.."
tools/setup-debian.sh
cmake -S . -B build/release -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build/release -j "$(nproc)"

out=${OUT:-out}
rm -rf "$out/take"
mkdir -p "$out"
build/release/firmware/app/forge4d record --board board/sim-4cam.json --frames 60 \
  -o "$out/take" --stats-json "$out/stats.json" --sheet "$out/contact-sheet.png" "$@"
build/release/firmware/app/forge4d verify "$out/take"
echo "main: take in $out/take, stats in $out/stats.json, contact sheet $out/contact-sheet.png"
