#!/usr/bin/env bash
# Installs the Debian 12 packages the build, the tests and the benchmarks need,
# skipping the ones already present (so a warm machine pays nothing).
set -euo pipefail

PKGS=(
  build-essential cmake pkg-config git
  libcmocka-dev libcjson-dev libpng-dev
  libopenblas-dev
)
# Extra package lists that modules add as they land (one name per line, '#' comments).
here=$(cd "$(dirname "$0")" && pwd)
for list in "$here"/deps/*.txt; do
  [ -e "$list" ] || continue
  while read -r p _; do
    case "$p" in ''|'#'*) continue ;; esac
    PKGS+=("$p")
  done < "$list"
done

missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}"
  if [ "$(id -u)" -ne 0 ]; then
    echo "setup: need root to install packages" >&2
    exit 1
  fi
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
