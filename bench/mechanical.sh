#!/usr/bin/env bash
# Mechanical mode end to end (issue 6: fandisk <= 1 s on 2 cores).
# Usage: bench/mechanical.sh  (from the repository root; needs hyperfine)
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --bin subdfit
bin=target/release/subdfit
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
meshes=(data/fandisk.ply)
data=${SUBDFIT_DATA:-/work/shared/data}
for extra in block joint; do
    if [[ -f $data/$extra.ply ]]; then
        meshes+=("$data/$extra.ply")
    else
        echo "skipping $extra.ply: $data/$extra.ply not found" >&2
    fi
done
for m in "${meshes[@]}"; do
    name=$(basename "$m" .ply)
    hyperfine --warmup 1 --runs 5 \
        --prepare "rm -rf $out/$name" \
        "$bin convert $m --mode mechanical --quiet -o $out/$name"
done
