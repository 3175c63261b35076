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
if [[ -f $data/block.ply ]]; then
    meshes+=("$data/block.ply")
else
    echo "skipping block.ply: $data/block.ply not found" >&2
fi
for m in "${meshes[@]}"; do
    name=$(basename "$m" .ply)
    hyperfine --warmup 1 --runs 5 \
        --prepare "rm -rf $out/$name" \
        "$bin convert $m --mode mechanical --quiet -o $out/$name"
done
