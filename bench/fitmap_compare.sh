#!/usr/bin/env bash
# Fast vs exact Fitmap on shared meshes (issue 3: Spearman ρ of F_S >= 0.95,
# F_M on the same radius step for >= 90 % of vertices, never more than one
# step apart). The exact mode is quadratic: these meshes take minutes each
# on 2 cores; set FITMAP_EXACT_CACHE=DIR to keep the exact results there
# (per mesh, seed and τ) and compare variants of the fast mode against them.
# FITMAP_CERTIFY=1 compares the fast mode with FitmapOptions::certify.
# `target/release/examples/fitmap_bench diag MESH...` lists the vertices
# more than one step apart with the exact flipped fraction at every radius.
# Usage: bench/fitmap_compare.sh [MESH...]
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DATA:-/work/shared/data}
if [ $# -eq 0 ]; then
  set -- "$DATA/spot.ply" "$DATA/homer.ply" "$DATA/fandisk.ply"
fi
cargo build --release --example fitmap_bench
exec target/release/examples/fitmap_bench compare "$@"
