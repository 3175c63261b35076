#!/usr/bin/env bash
# Fast-mode Fitmap speed on 2 threads (issue 3 targets: bunny <= 5 s,
# gargoyle <= 4 s, a 350k-triangle mesh <= 40 s, peak memory <= 1 GB).
# The 350k mesh is spot.ply after three 1->4 midpoint splits (374,784
# triangles); bunny after one split (277,804) is timed too. One JSON line
# per run; wall time includes building the Embree scene, cpu_seconds / 2 is
# the wall time an unloaded 2-core machine would take.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DATA:-/work/shared/data}
export RAYON_NUM_THREADS=${RAYON_NUM_THREADS:-2}
cargo build --release --example fitmap_bench
B=target/release/examples/fitmap_bench
$B speed "$DATA/bunny.ply"
$B speed "$DATA/gargoyle.ply"
$B speed "$DATA/spot.ply" 3
$B speed "$DATA/bunny.ply" 1
