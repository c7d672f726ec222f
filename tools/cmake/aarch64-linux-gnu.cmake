# tools/cmake/aarch64-linux-gnu.cmake - cross build for the ARM boards
# (Cortex-A76/A78, AArch64) on a Debian 12 x86-64 machine, with Debian's cross
# compiler (gcc-aarch64-linux-gnu) and Debian's multiarch arm64 libraries
# (dpkg --add-architecture arm64; libcmocka-dev:arm64, libpng-dev:arm64,
# libcjson-dev:arm64). ctest runs the test binaries under qemu-user.
#
#   cmake -S . -B build/aarch64 -DCMAKE_TOOLCHAIN_FILE=tools/cmake/aarch64-linux-gnu.cmake \
#         -DF4D_KERNELS_SPLAT_ONLY=ON
#
# tools/test-aarch64.sh installs all of it, configures, builds and runs ctest.
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)

# Libraries and headers: the cross libc in /usr/aarch64-linux-gnu, the arm64
# multiarch packages in /usr/lib/aarch64-linux-gnu and /usr/include (both on
# the cross compiler's default search paths). Programs come from the host.
set(CMAKE_FIND_ROOT_PATH /usr/aarch64-linux-gnu)
set(CMAKE_LIBRARY_ARCHITECTURE aarch64-linux-gnu)
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY BOTH)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE BOTH)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE BOTH)

# pkg-config answers for arm64: only the multiarch .pc files.
set(ENV{PKG_CONFIG_LIBDIR} "/usr/lib/aarch64-linux-gnu/pkgconfig:/usr/share/pkgconfig")
set(ENV{PKG_CONFIG_PATH} "")

# Tests run under qemu-user (qemu-user-static or qemu-user) with the cross
# libc as the guest root (-L). LD_LIBRARY_PATH=/lib (inside that root) keeps
# libc.so.6 next to the cross ld.so: otherwise ld.so takes the host's
# /etc/ld.so.cache, which lists the multiarch libc6:arm64 that cmocka pulled
# in, a different Debian build of glibc whose private ABI differs from the
# cross ld.so's (pthread_create then spins forever). libcmocka, libpng and
# libcjson are found through that cache in /usr/lib/aarch64-linux-gnu.
# qemu's default CPU model ("max") has the dot product, so the sdot path runs;
# tests/kernels adds runs on a Cortex-A72 (ARMv8.0: NEON, no dot product) for
# the int8 fallback.
find_program(F4D_QEMU_AARCH64 NAMES qemu-aarch64-static qemu-aarch64)
if(F4D_QEMU_AARCH64)
  set(CMAKE_CROSSCOMPILING_EMULATOR
      "${F4D_QEMU_AARCH64};-L;/usr/aarch64-linux-gnu;-E;LD_LIBRARY_PATH=/lib")
  set(F4D_EMULATOR_NO_DOTPROD
      "${F4D_QEMU_AARCH64};-cpu;cortex-a72;-L;/usr/aarch64-linux-gnu;-E;LD_LIBRARY_PATH=/lib")
endif()
