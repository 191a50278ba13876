#!/usr/bin/env bash
# Fuzzes every input reader (and a tiny registration) with cargo-fuzz / libFuzzer for a bounded time.
#
#   scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]     (default 60 s, all targets)
#
# Needs the nightly toolchain and cargo-fuzz (`cargo install cargo-fuzz`). One process per target, one after
# the other (the machine is shared). Seeds are read from fuzz/corpus/<target> (kept small, in git); what the
# fuzzer finds goes to fuzz/work/<target> (not in git), crashes to fuzz/artifacts/<target>. Prints the number
# of executions per target; exits 1 if any target crashed, leaked, timed out or ran out of memory.
set -uo pipefail
secs=${1:-60}
shift || true
cd "$(dirname "$0")/.."
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    targets=(ply pcd xyz npy depth_png pose_csv intrinsics_json cell_manifest matrix rosbag register_tiny)
fi
cargo +nightly fuzz build --fuzz-dir fuzz || exit 1
failed=()
printf '%-16s %12s %s\n' target executions result
for t in "${targets[@]}"; do
    mkdir -p "fuzz/work/$t"
    log="fuzz/work/$t.log"
    cargo +nightly fuzz run --fuzz-dir fuzz "$t" "fuzz/work/$t" "fuzz/corpus/$t" -- \
        -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 >"$log" 2>&1
    rc=$?
    execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
    [ -n "$execs" ] || execs=$(grep -o '^#[0-9]*' "$log" | tail -1 | tr -d '#')
    if [ $rc -eq 0 ]; then res=ok; else res="FAILED (exit $rc, see $log)"; failed+=("$t"); fi
    printf '%-16s %12s %s\n' "$t" "${execs:-?}" "$res"
done
if [ ${#failed[@]} -gt 0 ]; then
    echo "failed: ${failed[*]}" >&2
    exit 1
fi
