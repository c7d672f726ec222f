#!/usr/bin/env bash
# check_links.sh ROOT: the link graph of the build has no circle, and the
# pure-logic layers link nothing they do not need.
#
# Configures ROOT into a scratch build with --graphviz (no compilation) and
# reads the target edges. Fails on: any cycle between targets (tsort), a
# backend reachable from hal_core, or a device/GLib library reachable from
# the synchronizer, the take format or the kernels.
set -euo pipefail
root=${1:?usage: check_links.sh ROOT}
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
cmake -S "$root" -B "$scratch" --graphviz="$scratch/deps.dot" -DF4D_FUZZ=OFF >/dev/null
# "a -> b" pairs of target names, from the edge comments
sed -n 's|.*// \(.*\) -> \(.*\)$|\1 \2|p' "$scratch/deps.dot" | sort -u > "$scratch/edges"
n=$(wc -l < "$scratch/edges")
(( n > 20 )) || { echo "links: only $n edges read from the graph"; exit 1; }

bad=0
if ! tsort "$scratch/edges" > /dev/null 2> "$scratch/tsort.err"; then
  echo "links: the target graph has a circle:"; sed 's/^/  /' "$scratch/tsort.err"
  bad=1
fi

# reach T: every target reachable from T
reach() {
  local -A seen=(); local todo=("$1") t
  while ((${#todo[@]})); do
    t=${todo[-1]}; unset 'todo[-1]'
    while read -r a b; do
      [[ "$a" == "$t" && -z "${seen[$b]:-}" ]] && { seen[$b]=1; todo+=("$b"); }
    done < "$scratch/edges"
  done
  printf '%s\n' "${!seen[@]}"
}
forbid() { # forbid TARGET PATTERN WHY
  local hits
  hits=$(reach "$1" | grep -E "$2" || true)
  if [[ -n "$hits" ]]; then
    echo "links: $1 reaches $(echo $hits) ($3)"; bad=1
  fi
}
forbid hal_core  '^hal_(sim|replay|aravis|gpiod|usb|libcamera|registry|take|board)$' "the interfaces link no backend"
forbid f4d_sync  'ARAVIS|GPIOD|GLIB|ZLIB|LIBUSB|LIBCAMERA|^hal_(sim|replay|aravis|gpiod|usb|libcamera|registry)$' "the synchronizer is pure logic"
forbid hal_take  'ARAVIS|GPIOD|LIBUSB|LIBCAMERA|^hal_(sim|replay|aravis|gpiod|usb|libcamera|registry)$' "the take format needs only zlib"
forbid fk        '^(hal_|f4d_)|PkgConfig' "kernels sit at the bottom"
for stage in f4d_sync f4d_capture f4d_gguf f4d_model f4d_preprocess f4d_foreground f4d_splat f4d_interp; do
  forbid "$stage" '^f4d_(scene|simscene)$' "no product stage links the synthetic world"
done
(( bad )) && exit 1
echo "links: $n target edges, no circle, layers link only downward"
