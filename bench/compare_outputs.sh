#!/usr/bin/env bash
# Byte-for-byte check that a refactor kept `subdfit convert`'s outputs:
# converts every shared mesh (organic), fandisk/block/joint (mechanical) and
# spot/fandisk (auto) with BIN, then compares each output folder with the
# reference one. report.json is compared after removing what varies run to
# run (timings, CPU time, memory, the input's path); every other file must be
# identical byte for byte.
#
#   bench/compare_outputs.sh record  [BIN] [REF_DIR]   # write the references
#   bench/compare_outputs.sh compare [BIN] [REF_DIR] [NEW_DIR]
#
# Defaults: BIN=target/release/subdfit, REF_DIR=/work/ref-house,
# NEW_DIR=/tmp/compare-outputs. Exit 0 when everything matches.
set -u
verb=${1:-compare}
bin=${2:-target/release/subdfit}
ref=${3:-/work/ref-house}
new=${4:-/tmp/compare-outputs}
data=${DATA:-/work/shared/data}

runs=()
for m in "$data"/*.ply; do runs+=("$(basename "$m" .ply):organic"); done
for n in fandisk block joint; do runs+=("$n:mechanical"); done
for n in spot fandisk; do runs+=("$n:auto"); done
# The layout proxy M' (none of the shared meshes is above --proxy auto's
# bound): bunny's layout on a 20 000-triangle decimation.
runs+=("bunny:organic:--proxy 20000")

case "$verb" in
record) out=$ref ;;
compare) out=$new ;;
*) echo "usage: $0 record|compare [BIN] [REF_DIR] [NEW_DIR]" >&2; exit 2 ;;
esac
mkdir -p "$out"

# report.json without the fields that differ between two runs of the same
# build: every timing (`seconds`, `cpu_seconds`, `seconds_*`), peak memory
# (`*_mib`), the input's path (`mesh`).
strip() {
  jq -S 'walk(if type == "object" then with_entries(select(.key | test("seconds|_mib$") | not)) | del(.mesh) else . end)' "$1"
}

fail=0
for r in "${runs[@]}"; do
  IFS=: read -r name mode extra <<<"$r"
  dir="$out/$name-$mode${extra:+-proxy}"
  # shellcheck disable=SC2086 # $extra: more flags, split on purpose
  if ! "$bin" convert "$data/$name.ply" -o "$dir" --mode "$mode" $extra --quiet >"$dir.log" 2>&1; then
    echo "FAIL $(basename "$dir"): convert failed (see $dir.log)"; fail=1; continue
  fi
  [ "$verb" = record ] && { echo "recorded $(basename "$dir")"; continue; }
  refdir="$ref/$(basename "$dir")"
  before=$fail; fail=0
  for f in "$refdir"/*; do
    b=$(basename "$f")
    if [ "$b" = report.json ]; then
      if ! diff <(strip "$f") <(strip "$dir/$b") >/dev/null; then
        echo "DIFF $(basename "$dir")/$b"; fail=1
      fi
    elif ! cmp -s "$f" "$dir/$b"; then
      echo "DIFF $(basename "$dir")/$b"; fail=1
    fi
  done
  more=$(comm -13 <(ls "$refdir") <(ls "$dir"))
  [ -n "$more" ] && { echo "EXTRA $(basename "$dir"): $more"; fail=1; }
  [ $fail = 0 ] && echo "same $(basename "$dir") ($(ls "$dir" | wc -l) files)"
  [ $before = 1 ] && fail=1
done
[ "$verb" = compare ] && { [ $fail = 0 ] && echo "ALL IDENTICAL" || echo "DIFFERENCES FOUND"; }
exit $fail
