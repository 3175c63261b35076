#!/usr/bin/env bash
# Runs `subdfit info` on every OFF and STL file of the hostile-input corpus
# under valgrind (memcheck) and fails on any memory error, whether the file
# is read or refused: a reader must never touch uninitialised memory (the
# OpenMesh OFF reader did, so the same file gave different messages from run
# to run). OBJ and PLY can be added with READERS_ALL=1.
#
# Usage: scripts/valgrind-readers.sh [path/to/subdfit]
# (default: target/release/subdfit; build it with `cargo build --release`).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${1:-target/release/subdfit}
corpus=tests/data/hostile
[[ -x $bin ]] || { echo "no binary at $bin; run cargo build --release" >&2; exit 2; }
command -v valgrind >/dev/null || { echo "valgrind not found" >&2; exit 2; }

pattern='*.off *.stl'
[[ ${READERS_ALL:-0} == 1 ]] && pattern='*.off *.stl *.obj *.ply'
failed=0
count=0
log=$(mktemp)
trap 'rm -f "$log"' EXIT
for f in $(cd "$corpus" && eval "ls $pattern"); do
    count=$((count + 1))
    # Exit 99 is valgrind's (an error found); 0 and 2 are subdfit's own
    # (read, refused). --errors-for-leak-kinds=definite: a leak of ours is a
    # bug too, the C++ libraries' one-off static allocations are not.
    set +e
    valgrind --quiet --error-exitcode=99 --leak-check=full \
        --errors-for-leak-kinds=definite --log-file="$log" \
        "$bin" info "$corpus/$f" >/dev/null 2>&1
    rc=$?
    set -e
    if [[ $rc == 99 || -s $log ]]; then
        echo "FAIL $f (exit $rc)"
        cat "$log"
        failed=$((failed + 1))
    elif [[ $rc != 0 && $rc != 2 ]]; then
        echo "FAIL $f: subdfit exited with $rc"
        failed=$((failed + 1))
    else
        echo "ok   $f (exit $rc)"
    fi
done
echo "$count files, $failed with valgrind errors"
[[ $failed == 0 ]]
