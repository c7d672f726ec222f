#!/usr/bin/env bash
# The aarch64 (ARM boards) build and tests on a Debian 12 x86-64 machine:
# installs what is missing (Debian's cross compiler, qemu-user-static, and the
# arm64 cmocka / libpng / cJSON through dpkg multiarch), cross-configures
# build/aarch64 with tools/cmake/aarch64-linux-gnu.cmake restricted to
# kernels/ + firmware/gaussians/splat and their tests (F4D_KERNELS_SPLAT_ONLY),
# builds it (Release, warnings as errors) and runs ctest, every test binary
# under qemu-aarch64. The kernel tests compare the NEON kernels with the scalar
# references (speed means nothing under qemu; correctness does).
# Run as root (it installs packages); ~3 minutes on 2 cores, warm: ~2.
set -euo pipefail
cd "$(dirname "$0")/.."
jobs=$(nproc)

HOST_PKGS=(build-essential cmake pkg-config gcc-aarch64-linux-gnu libc6-dev-arm64-cross
           qemu-user-static)
ARM_PKGS=(libcmocka-dev:arm64 libpng-dev:arm64 libcjson-dev:arm64)

missing=()
for p in "${HOST_PKGS[@]}" "${ARM_PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "test-aarch64: installing ${missing[*]}"
  if [ "$(id -u)" -ne 0 ]; then
    echo "test-aarch64: need root to install packages" >&2
    exit 1
  fi
  dpkg --print-foreign-architectures | grep -qx arm64 || dpkg --add-architecture arm64
  # wait for another apt/dpkg run rather than fail on its lock
  lock=(-o DPkg::Lock::Timeout=600)
  apt-get "${lock[@]}" update -qq
  DEBIAN_FRONTEND=noninteractive apt-get "${lock[@]}" install -y -qq --no-install-recommends \
    "${missing[@]}" >/dev/null
fi

cmake -S . -B build/aarch64 -DCMAKE_TOOLCHAIN_FILE="$PWD/tools/cmake/aarch64-linux-gnu.cmake" \
      -DCMAKE_BUILD_TYPE=Release -DF4D_WERROR=ON -DF4D_KERNELS_SPLAT_ONLY=ON >/dev/null
cmake --build build/aarch64 -j "$jobs"
ctest --test-dir build/aarch64 --output-on-failure -j "$jobs" --timeout 900
