#!/usr/bin/env bash
# Times `subdfit simplify` on the paper's meshes on 2 cores (issue 4
# acceptance: bunny <= 10 s, gargoyle <= 8 s, peak memory <= 1 GB), at
# tau = 1 % and 10 %. Prints the JSON summary's counts and stage timings and
# /usr/bin/time's wall time and peak RSS. Usage: bench/simplify.sh [DATA_DIR]
set -euo pipefail
data=${1:-$(dirname "$0")/../../shared/data}
cargo build --release --bin subdfit >/dev/null
out=$(mktemp -d)
for mesh in bunny gargoyle; do
  for tau in 0.01 0.10; do
    echo "== $mesh tau=$tau"
    /usr/bin/time -f "wall %e s, peak %M KB" taskset -c 0,1 \
      target/release/subdfit simplify "$data/$mesh.ply" -o "$out/$mesh-$tau.obj" \
      --tolerance "$tau" --json |
      grep -E '^  "(faces|irregular_vertices|collapses|rotations|doublets|stopped_at|seconds_[a-z]+|collapses_per_second)"'
  done
done
