#!/usr/bin/env bash
# Runs one libFuzzer harness for a bounded time and prints one summary line (docs/TESTING.md).
#   run_fuzzer.sh NAME EXE SECONDS MAX_LEN WORK SEED_DIR...
# $DEIF_FUZZ_SECONDS overrides SECONDS. New inputs go to WORK/corpus (started afresh), never
# into the seed folders; a crash, a hang or a sanitizer report leaves WORK/artifacts/<kind>-<sha1>
# and fails the test.
set -uo pipefail
name="$1" exe="$2" seconds="${DEIF_FUZZ_SECONDS:-$3}" max_len="$4" work="$5"
shift 5
rm -rf "$work/corpus" "$work/artifacts"
mkdir -p "$work/corpus" "$work/artifacts"
seeds=()
for dir in "$@"; do [ -d "$dir" ] && seeds+=("$dir"); done

"$exe" \
  -max_total_time="$seconds" -max_len="$max_len" -timeout=10 -rss_limit_mb=2048 \
  -malloc_limit_mb=1024 -print_final_stats=1 -artifact_prefix="$work/artifacts/" \
  "$work/corpus" "${seeds[@]}" >"$work/fuzz.log" 2>&1
status=$?

stat() { sed -n "s/^stat::$1: *//p" "$work/fuzz.log" | tail -1; }
runs="$(stat number_of_executed_units)"
rate="$(stat average_exec_per_sec)"
rss="$(stat peak_rss_mb)"
corpus="$(find "$work/corpus" -type f | wc -l)"
artifacts="$(find "$work/artifacts" -type f | wc -l)"
echo "fuzz $name: ${runs:-?} executions in ${seconds} s (${rate:-?} exec/s), ${corpus} new inputs," \
     "peak RSS ${rss:-?} MB, ${artifacts} crashes/hangs/reports"
if [ "$status" -ne 0 ] || [ "$artifacts" -ne 0 ]; then
  tail -n 60 "$work/fuzz.log"
  for a in "$work"/artifacts/*; do
    [ -f "$a" ] || continue
    echo "fuzz $name: failing input $a; reproduce with: $exe $a"
    echo "fuzz $name: after the fix keep it as a regression input: cp $a tests/fuzz/corpus/$name/"
  done
  exit 1
fi
