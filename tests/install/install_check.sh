#!/usr/bin/env bash
# install_check.sh CMAKE BUILD_DIR CC PKG_CONFIG USE_FK_C [EXTRA_CFLAGS]
# cmake --install into a fresh temporary prefix (removed on exit), then build
# USE_FK_C with `pkg-config --cflags --libs forge4d-kernels` only and run it.
# Also the appliance: forge4d.service, the default config, the boards.
set -euo pipefail
cmake=$1 build=$2 cc=$3 pkgconfig=$4 src=$5 extra=${6:-}
prefix=$(mktemp -d "${TMPDIR:-/tmp}/f4d_install_XXXXXX")
trap 'rm -rf "$prefix"' EXIT

"$cmake" --install "$build" --prefix "$prefix" >/dev/null

pcdir=$(dirname "$(find "$prefix" -name forge4d-kernels.pc -print -quit)")
[ -f "$pcdir/forge4d-kernels.pc" ] || { echo "forge4d-kernels.pc not installed under $prefix"; exit 1; }
case "$pcdir" in "$prefix"/lib/pkgconfig|"$prefix"/lib/*/pkgconfig) ;;
  *) echo "forge4d-kernels.pc installed in $pcdir, not <prefix>/lib/pkgconfig"; exit 1 ;; esac
for f in include/forge4d/f4d_status.h include/forge4d/fk_ctx.h include/forge4d/fk_ops.h \
         bin/forge4d bin/f4d-convert bin/f4d-infer bin/f4d-render bin/f4d-metrics bin/f4d-scene bin/f4d-eval \
         share/forge4d/forge4d_small.gguf share/forge4d/forge4d_small_int8.gguf; do
  [ -e "$prefix/$f" ] || { echo "missing after install: $f"; exit 1; }
done
# the appliance: unit, default config, the boards the config names
unit=$prefix/lib/systemd/system/forge4d.service conf=$prefix/etc/forge4d/forge4d.conf
for f in "$unit" "$conf" "$prefix/share/forge4d/board/sim-4cam.json" "$prefix/share/forge4d/board/sim-4cam-faulty.json"; do
  [ -f "$f" ] || { echo "missing after install: ${f#"$prefix"/}"; exit 1; }
done
grep -Eq '^ExecStart=/[^ ]*/forge4d run --config /[^ ]*/forge4d/forge4d\.conf' "$unit" ||
  { echo "forge4d.service: ExecStart does not run an absolute forge4d with the config"; exit 1; }
grep -Eq '^WantedBy=multi-user\.target' "$unit" || { echo "forge4d.service: no [Install] target"; exit 1; }
if command -v systemd-analyze >/dev/null 2>&1; then # the unit's syntax (not the paths: they are the build's prefix)
  sed "s|^ExecStart=[^ ]*|ExecStart=/bin/true|" "$unit" > "$prefix/forge4d.service"
  out=$(systemd-analyze verify "$prefix/forge4d.service" 2>&1) || { echo "systemd-analyze verify: $out"; exit 1; }
fi
# the installed config parses and runs (its board path points at the configured
# prefix, so the board comes from the install here)
"$prefix/bin/forge4d" run --config "$conf" --board "$prefix/share/forge4d/board/sim-4cam.json" --seconds 1 \
  --quiet --stats-json "$prefix/run.json" 2>"$prefix/run.log" || { cat "$prefix/run.log"; exit 1; }
grep -q '"sets_captured"' "$prefix/run.json" || { echo "installed forge4d run wrote no stats"; exit 1; }
find "$prefix" -name libfk.a | grep -q . || { echo "libfk.a not installed"; exit 1; }
# kernels/src/ is private
for h in fk_internal.h gemm.h pool.h attention.h; do
  if find "$prefix" -name "$h" | grep -q .; then echo "private header $h installed"; exit 1; fi
done

# only the prefix's .pc files: nothing from the build or source tree can leak in
export PKG_CONFIG_PATH=$pcdir
flags=$("$pkgconfig" --cflags --libs forge4d-kernels)
echo "pkg-config --cflags --libs forge4d-kernels: $flags"
for w in $flags; do # every -I/-L must lie in the prefix, not the build or source tree
  case "$w" in -I*|-L*) p=$(cd "${w:2}" 2>/dev/null && pwd) || { echo "$w: no such directory"; exit 1; }
    case "$p" in "$(cd "$prefix" && pwd)"/*) ;; *) echo "$w is outside the prefix $prefix"; exit 1 ;; esac ;;
  esac
done
# shellcheck disable=SC2086 # flags are words by design
"$cc" -std=c11 -Wall -Werror $extra "$src" $flags -o "$prefix/use_fk"
"$prefix/use_fk"
echo "install + pkg-config consumer ok"
