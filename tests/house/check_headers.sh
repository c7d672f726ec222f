#!/usr/bin/env bash
# check_headers.sh ROOT: every header of the tree opens with its comment and
# then its include guard: no definition, declaration or include may stand
# before `#ifndef GUARD` / `#define GUARD` (a macro defined there escapes the
# guard and is redefined on every inclusion). Exit 1 naming each offender.
set -euo pipefail
root=${1:?usage: check_headers.sh ROOT}
cd "$root"
bad=0 n=0
while IFS= read -r h; do
  n=$((n + 1))
  # first line of code after leading comments and blank lines
  first=$(awk '
    BEGIN { c = 0 }
    {
      line = $0
      while (1) {
        if (c) { i = index(line, "*/"); if (!i) { line = ""; break } line = substr(line, i + 2); c = 0 }
        sub(/^[ \t]+/, "", line)
        if (substr(line, 1, 2) == "/*") { line = substr(line, 3); c = 1; continue }
        if (substr(line, 1, 2) == "//") line = ""
        break
      }
      if (line != "") { print line; exit }
    }' "$h")
  case "$first" in
    "#ifndef "*|"#pragma once"*) ;;
    *) echo "headers: $h: '$first' stands before the include guard"; bad=1 ;;
  esac
done < <(find kernels hal firmware tools tests -name '*.h' -not -path '*/fixtures/*' | sort)
(( bad )) && exit 1
echo "headers: $n headers, each opens with its include guard"
