#!/usr/bin/env bash
# Runs every fuzz target (or those named after the seconds) for SECONDS each,
# with nightly and cargo-fuzz: `tests/fuzz/fuzz.sh 75 [target...]`, one target per core at a time.
# New inputs go to a scratch corpus (FUZZ_SCRATCH, default a temporary folder); the
# committed corpus/<target>/ is only read. Prints one line per target: total execs,
# execs/s, cov and ft of libFuzzer's last line, and whether it crashed (the input is
# then in tests/fuzz/artifacts/<target>/). Exit status 1 if any target crashed.
set -uo pipefail
cd "$(dirname "$0")/../.."
seconds=${1:-5}
shift || true
scratch=${FUZZ_SCRATCH:-$(mktemp -d)}
target_dir=${FUZZ_TARGET_DIR:-target/fuzz}
fuzz=(cargo +nightly fuzz)
common=(--fuzz-dir tests/fuzz --features libfuzzer --sanitizer none --target-dir "$target_dir")
# FUZZ_DEV=1: the targets built unoptimized (`cargo fuzz --dev`), which builds in a
# fraction of the release build's time: for a smoke run of a few seconds per target,
# where executions per second matter less than the build (CI). Campaigns use release.
if [ "${FUZZ_DEV:-0}" = 1 ]; then common+=(--dev); fi
if [ $# -gt 0 ]; then
  targets=("$@")
else
  mapfile -t targets < <("${fuzz[@]}" list --fuzz-dir tests/fuzz)
fi
mkdir -p "$scratch"
if ! "${fuzz[@]}" build "${common[@]}" >"$scratch/build.log" 2>&1; then
  cat "$scratch/build.log"
  exit 1
fi
# Targets run side by side, one per core (FUZZ_JOBS to change it): each is single-threaded.
jobs=${FUZZ_JOBS:-$(nproc 2>/dev/null || echo 1)}
run_one() { # target: runs it and writes its result line to $scratch/$t.result
  local t=$1 log="$scratch/$1.log" rc execs rate last cov ft result
  mkdir -p "$scratch/$t"
  "${fuzz[@]}" run "$t" "${common[@]}" "$scratch/$t" "tests/fuzz/corpus/$t" -- \
    -max_total_time="$seconds" -print_final_stats=1 -timeout=10 -rss_limit_mb=2048 >"$log" 2>&1
  rc=$?
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
  last=$(grep -E '^#[0-9]+' "$log" | tail -1)
  cov=$(sed -n 's/.* cov: \([0-9]*\).*/\1/p' <<<"$last")
  ft=$(sed -n 's/.* ft: \([0-9]*\).*/\1/p' <<<"$last")
  result=ok
  [ $rc -ne 0 ] && result="CRASH (exit $rc; log $log)"
  printf '%-16s %12s %9s %7s %8s  %s\n' "$t" "${execs:-?}" "${rate:-?}" "${cov:-?}" "${ft:-?}" "$result" >"$scratch/$t.result"
}
for t in "${targets[@]}"; do
  while [ "$(jobs -rp | wc -l)" -ge "$jobs" ]; do wait -n || true; done
  run_one "$t" &
done
wait
failed=0
printf '%-16s %12s %9s %7s %8s  %s\n' target execs execs/s cov ft result
for t in "${targets[@]}"; do
  cat "$scratch/$t.result"
  grep -q CRASH "$scratch/$t.result" && failed=1
done
exit $failed
