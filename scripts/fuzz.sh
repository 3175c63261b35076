#!/usr/bin/env bash
# Fuzzes the pure-Rust mesh readers: scripts/fuzz.sh [SECONDS] [TARGET...]
#
# Targets (fuzz/fuzz_targets/): obj ply off stl (default: all four), each run
# for SECONDS (default 1800, the 30 minutes per target that issue 22 asks)
# one after the other, in one libFuzzer process at a time, under `nice -n 19`.
# Prints per target: executions, exec/s, coverage (cov/ft of libFuzzer's last
# status line) and crashes found (new files in fuzz/artifacts/TARGET/).
# Exits 1 if any target found a crash; the input is in fuzz/artifacts/TARGET/,
# replay it with `RUSTC_BOOTSTRAP=1 cargo fuzz run TARGET FILE` in fuzz/.
#
# Environment: FUZZ_MAX_LEN (default 16384, the largest input tried; the
# big seeds data/*.ply are cut to it), FUZZ_SANITIZER (default address;
# `none` for a plain libFuzzer build), FUZZ_LOG_DIR (default fuzz/logs).
#
# Toolchain: the machine has stable Rust only; cargo-fuzz needs nightly flags
# (-Zsanitizer, -Cpasses=sancov-module ...), so everything runs with
# RUSTC_BOOTSTRAP=1. AddressSanitizer builds and links on stable 1.95 that
# way (the runtime ships with the stable std); the std itself is not
# instrumented (no -Zbuild-std), the crate's code is. If a toolchain cannot
# link ASan, use FUZZ_SANITIZER=none: libFuzzer's coverage instrumentation,
# its malloc/RSS limits and Rust's bounds and overflow checks (cargo-fuzz
# turns on debug assertions) still catch panics, overflows and huge
# allocations. The C++ side of the crate (build.rs -> CMake) is built as for
# a normal build (not instrumented); it is linked but never run by the
# targets. The first build takes ~10 minutes (the C++ side included).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
FUZZ="$ROOT/fuzz"
DURATION="${1:-1800}"
[ $# -gt 0 ] && shift
TARGETS=("$@")
[ ${#TARGETS[@]} -eq 0 ] && TARGETS=(obj ply off stl)
MAX_LEN="${FUZZ_MAX_LEN:-16384}"
LOGS="${FUZZ_LOG_DIR:-$FUZZ/logs}"
SAN="${FUZZ_SANITIZER:-address}"
export RUSTC_BOOTSTRAP=1

case "$DURATION" in
    '' | *[!0-9]*) echo "usage: $0 [SECONDS] [obj|ply|off|stl ...]" >&2; exit 2 ;;
esac
for t in "${TARGETS[@]}"; do
    [ -f "$FUZZ/fuzz_targets/$t.rs" ] || { echo "unknown target '$t' (obj ply off stl)" >&2; exit 2; }
done

if ! cargo fuzz --version >/dev/null 2>&1; then
    echo "installing cargo-fuzz" >&2
    nice -n 19 cargo install cargo-fuzz --locked
fi

cd "$FUZZ"
echo "building ${TARGETS[*]} (sanitizer $SAN)" >&2
for t in "${TARGETS[@]}"; do
    nice -n 19 cargo fuzz build -s "$SAN" "$t"
done

# Seeds: the hostile corpus and the sample meshes of the format, copied into
# the (git-ignored) working corpus fuzz/corpus/TARGET, which libFuzzer grows.
seed() {
    local t="$1" dir="$FUZZ/corpus/$1" f
    mkdir -p "$dir"
    for f in "$ROOT"/tests/data/hostile/*."$t" "$ROOT"/data/*."$t" "$ROOT"/data/samples/*."$t"; do
        [ -f "$f" ] && cp -n "$f" "$dir/"
    done
    return 0
}

mkdir -p "$LOGS"
summary=()
status=0
for t in "${TARGETS[@]}"; do
    seed "$t"
    art="$FUZZ/artifacts/$t"
    mkdir -p "$art"
    before=$(find "$art" -type f | wc -l)
    log="$LOGS/$t.log"
    echo "fuzzing $t for ${DURATION}s (log: $log)" >&2
    # One process (no -jobs/-workers: libFuzzer's default is a single
    # in-process fuzzer, the same as -jobs=1 -workers=1 without the extra
    # supervising process and fuzz-0.log indirection).
    set +e
    nice -n 19 cargo fuzz run -s "$SAN" "$t" "corpus/$t" -- \
        -max_total_time="$DURATION" -max_len="$MAX_LEN" -timeout=10 \
        -rss_limit_mb=2048 -print_final_stats=1 >"$log" 2>&1
    rc=$?
    set -e
    after=$(find "$art" -type f | wc -l)
    crashes=$((after - before))
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
    rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -1)
    cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | awk '{print $2}')
    ft=$(grep -o 'ft: [0-9]*' "$log" | tail -1 | awk '{print $2}')
    corp=$(grep -o 'corp: [0-9]*/[0-9a-zA-Z]*' "$log" | tail -1 | awk '{print $2}')
    line=$(printf '%-4s execs %-10s exec/s %-7s cov %-6s ft %-6s corpus %-10s crashes %s' \
        "$t" "${execs:-?}" "${rate:-?}" "${cov:-?}" "${ft:-?}" "${corp:-?}" "$crashes")
    if [ "$rc" -ne 0 ] || [ "$crashes" -ne 0 ]; then
        status=1
        line="$line  (exit $rc; see $log and $art)"
    fi
    echo "$line"
    summary+=("$line")
done

echo
echo "== fuzz summary (${DURATION}s per target) =="
printf '%s\n' "${summary[@]}"
exit "$status"
