#!/usr/bin/env bash
# check_layers.sh ROOT: the house's one direction, checked from the sources.
#
# Ranks, low to high: kernels; hal/core; hal/take, hal/board; the backends;
# hal/registry; the stages in data-path order (capture: sync, then capture;
# infer: gguf/npy/preprocess, then model; gaussians: splat, then interp,
# then sequence (which runs the model and interp);
# stream: codec, then transport; display), the synthetic world beside them; firmware/app; tools.
#
# Every quoted #include in kernels/, hal/, firmware/ and tools/ is resolved to
# the header it names (by file name: headers are unique across the tree) and
# both files get a layer rank. A file may include only headers of a lower
# rank, or of its own module folder. The synthetic world (firmware/synth) is
# reachable only from firmware/app, tools/ and tests/. Exit 1 with one line
# per violation, 0 when the tree is clean.
set -euo pipefail
root=${1:?usage: check_layers.sh ROOT}
cd "$root"

# rank <path>: prints "rank module" for a source path (module = the folder
# that owns the file; a file may always include headers of its own module).
rank() {
  case "$1" in
    kernels/*)              echo "0 kernels" ;;
    hal/core/*)             echo "10 hal/core" ;;
    hal/take/*|hal/board/*) echo "20 ${1%/*}" ;;
    hal/registry/*)         echo "40 hal/registry" ;;
    hal/*/*)                m=${1#hal/}; echo "30 hal/${m%%/*}" ;;
    firmware/capture/sync/*)        echo "50 firmware/capture/sync" ;;
    firmware/capture/*)             m=${1#firmware/capture/}; echo "51 firmware/capture/${m%%/*}" ;;
    firmware/infer/model/*)         echo "61 firmware/infer/model" ;;
    firmware/infer/*)               m=${1#firmware/infer/};   echo "60 firmware/infer/${m%%/*}" ;;
    firmware/gaussians/splat/*)     echo "70 firmware/gaussians/splat" ;;
    firmware/gaussians/sequence/*)  echo "72 firmware/gaussians/sequence" ;;
    firmware/gaussians/*)           m=${1#firmware/gaussians/}; echo "71 firmware/gaussians/${m%%/*}" ;;
    firmware/stream/codec/*)        echo "80 firmware/stream/codec" ;;
    firmware/stream/*)              m=${1#firmware/stream/};  echo "81 firmware/stream/${m%%/*}" ;;
    firmware/display/*)             m=${1#firmware/display/}; echo "90 firmware/display/${m%%/*}" ;;
    firmware/synth/scene/*)         echo "75 firmware/synth/scene" ;;
    firmware/synth/*)               m=${1#firmware/synth/};   echo "76 firmware/synth/${m%%/*}" ;;
    firmware/app/*)         echo "100 firmware/app" ;;
    tools/*)                m=${1#tools/}; echo "110 tools/${m%%/*}" ;;
    *)                      echo "999 other" ;;
  esac
}

# header name -> path (first one found; a duplicate name is itself an error)
declare -A where
bad=0
while IFS= read -r h; do
  b=${h##*/}
  if [[ -n "${where[$b]:-}" ]]; then
    echo "layers: header name $b is used twice: ${where[$b]} and $h"
    bad=1
  fi
  where[$b]=$h
done < <(find kernels hal firmware tools -name '*.h' | sort)

checked=0
while IFS= read -r f; do
  read -r fr fm < <(rank "$f")
  while IFS= read -r inc; do
    p=${where[$inc]:-}
    [[ -z "$p" ]] && continue          # a system or generated header
    read -r ir im < <(rank "$p")
    checked=$((checked + 1))
    [[ "$im" == "$fm" ]] && continue   # inside one module
    if [[ "$im" == firmware/synth/* && "$fm" != firmware/synth/* && $fr -lt 100 ]]; then
      echo "layers: $f includes $p: the synthetic world is for app, tools and tests only"
      bad=1
    elif (( ir >= fr )); then
      echo "layers: $f ($fm) includes $p ($im): includes must run down the layers"
      bad=1
    fi
  done < <(sed -n 's/^[[:space:]]*#[[:space:]]*include[[:space:]]*"\([^"]*\)".*/\1/p' "$f" | sed 's|.*/||')
done < <(find kernels hal firmware tools \( -name '*.c' -o -name '*.h' -o -name '*.cpp' \) | sort)

if (( bad )); then
  exit 1
fi
echo "layers: $checked includes checked, all run down the layers"
