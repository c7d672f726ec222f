#!/usr/bin/env bash
# The whole test suite: installs what is missing, builds twice (optimised with
# warnings as errors, and AddressSanitizer + UndefinedBehaviorSanitizer), runs
# ctest on both, runs the aarch64 cross build of kernels + splat under qemu-user
# (tools/test-aarch64.sh), then prints what passed, failed and was SKIPPED (with why).
#
# A skipped test is never a pass. Under CI (CI set, as CI runners do) a skip
# fails the run unless the test carries the ctest label machine-dependent
# (tests/common f4d_add_test MACHINE_DEPENDENT): it skips only for what the
# machine is and nothing can change (a CPU without the ISA, no GPIO chip).
# Everything else CI can run (root, network namespaces, ../shared beside the
# repository) it must run.
set -euo pipefail
cd "$(dirname "$0")/.."
t0=$SECONDS
tools/setup-debian.sh
jobs=$(nproc)
ci=false
case "${CI:-}" in ''|0|false|False|FALSE|no) ;; *) ci=true ;; esac

failed_runs=0
summary=()
ci_bad=()

# run_ctest <label> <build dir> [ctest args...]
run_ctest() {
  local what=$1 dir=$2
  shift 2
  local log="$dir/ctest-output.log" rc=0 allowed
  # the tests allowed to skip under CI: labelled machine-dependent (asked
  # before the run: ctest -N would overwrite the run's Testing/Temporary/LastTest.log)
  allowed=$(ctest --test-dir "$dir" -N -L '^machine-dependent$' "$@" | sed -n 's/^ *Test *#[0-9]*: //p')
  ctest --test-dir "$dir" --output-on-failure -j "$jobs" "$@" 2>&1 | tee "$log" || rc=$?
  [ "$rc" -eq 0 ] || failed_runs=$((failed_runs + 1))

  local total failed skipped
  total=$(sed -n 's/.* tests failed out of \([0-9]*\).*/\1/p' "$log" | tail -1)
  failed=$(sed -n 's/.*tests passed, \([0-9]*\) tests* failed out of.*/\1/p' "$log" | tail -1)
  mapfile -t skipped < <(sed -n 's/^[[:space:]]*[0-9][0-9]* - \(.*\) (Skipped)$/\1/p' "$log")
  local nskip=${#skipped[@]}
  summary+=("$what: $(( ${total:-0} - ${failed:-0} - nskip )) passed, ${failed:-?} failed, $nskip skipped (of ${total:-?}), ctest exit $rc")

  [ "$nskip" -gt 0 ] || return 0
  local t why kind
  for t in "${skipped[@]}"; do
    # the test's own reason: its "[  SKIP    ]" lines in ctest's full log
    why=$(awk -v t="$t" '
        /^[0-9]+\/[0-9]+ Testing: / { on = ($3 == t) }
        on && /\[  SKIP    \]/ && !/case\(s\) skipped \(exit/ { sub(/^.*\[  SKIP    \] /, ""); print; n++ }
        END { if (!n) print "(no reason printed)" }' "$dir/Testing/Temporary/LastTest.log" | head -3 | paste -sd'|')
    if grep -qxF -- "$t" <<<"$allowed"; then kind="machine-dependent"; else kind="NOT machine-dependent"; ci_bad+=("$what: $t"); fi
    summary+=("    SKIPPED $t [$kind]: $why")
  done
}

cmake -S . -B build/release -DCMAKE_BUILD_TYPE=Release -DF4D_WERROR=ON >/dev/null
cmake --build build/release -j "$jobs"
run_ctest "release" build/release --timeout 600

cmake -S . -B build/asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DF4D_SANITIZE=ON \
      -DF4D_WERROR=ON -DF4D_BENCH_OPENBLAS=OFF >/dev/null
cmake --build build/asan -j "$jobs"
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 \
  run_ctest "asan+ubsan" build/asan --timeout 900 -LE no-asan

# The ARM boards: kernels + splat cross-built for aarch64, their tests under qemu-user.
arm_rc=0
bash tools/test-aarch64.sh 2>&1 | tee build/aarch64-test.log || arm_rc=$?
arm_line=$(sed -n 's/.*\(tests passed, [0-9]* tests* failed out of [0-9]*\).*/\1/p' build/aarch64-test.log | tail -1)
summary+=("aarch64 (qemu-user): ${arm_line:-no ctest summary}, exit $arm_rc")
[ "$arm_rc" -eq 0 ] || failed_runs=$((failed_runs + 1))

echo
echo "==== tools/test.sh summary ($((SECONDS - t0)) s wall, CI=$ci) ===="
printf '%s\n' "${summary[@]}"
rc=0
if [ "$failed_runs" -gt 0 ]; then
  echo "FAILED: $failed_runs ctest run(s) had failures (see above)"
  rc=1
fi
if [ ${#ci_bad[@]} -gt 0 ]; then
  if $ci; then
    echo "FAILED (CI): these tests were skipped, but CI can run them (not labelled machine-dependent):"
    printf '    %s\n' "${ci_bad[@]}"
    rc=1
  else
    echo "note: under CI these skips would fail the run: ${ci_bad[*]}"
  fi
fi
[ "$rc" -ne 0 ] || echo "OK"
exit "$rc"
