#!/usr/bin/env bash
# How low can RMS M → D go at a sample budget? (issue 37; Fitmaps §4.1)
#
#   PY=/path/to/venv/bin/python bench/floor.sh [DATA_DIR] [OUT_DIR]
#
# For each mesh in $MESHES (default "gargoyle bunny"), bench/floor_remesh.py
# (pymeshlab, measurement only: `pip install pymeshlab` into the venv $PY)
# makes piecewise-linear surfaces with k × |V(M)| vertices, k = 1, 2 (qem,
# iso, qemsub1, qemsub2: see that script), then `examples/floor_fit` prints
# RMS M → surface (‰ of M's diagonal, M's 3-point quadrature, the figure of
# bench/density.sh's "M→ply") as made (vertices on M: interpolation) and
# after 4 Gauss–Newton rounds of least-squares offsets along the vertex
# normals (both directions), the freedom the displacement's offsets have.
#
# Measured 2026-12-05 (bench/results/floor-2026-12-05.txt), M → surface ‰,
# vertices on M / after least squares (bunny's qemsub meshes fall short of
# the budget: its holes' borders are kept, 0.90×/1.93× and 0.48×/1.52×):
#             qem 2×   iso 1×        iso 2×        qemsub1 2×    qemsub2 2×
#   gargoyle  0.0000   0.357/0.207   0.190/0.103   0.103/0.060   0.166/0.095
#   bunny     0.0000   0.107/0.065   0.059/0.036   0.038/0.024   0.076/0.048
# Issue 37's bar at 2×: gargoyle 0.07, bunny 0.08.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${1:-../shared/data}
OUT=${2:-target/floor}
PY=${PY:-python3}
MESHES=${MESHES:-"gargoyle bunny"}
mkdir -p "$OUT"
cargo build --release --quiet --example floor_fit
for m in $MESHES; do
  "$PY" bench/floor_remesh.py "$DATA/$m.ply" "$m" "$OUT"
  for f in "$OUT/$m"-*.ply; do
    target/release/examples/floor_fit "$DATA/$m.ply" "$f" 4 1
  done > "$OUT/$m-floor.jsonl"
done
python3 - "$OUT" $MESHES <<'PY'
import json, sys, os
out = sys.argv[1]
print(f"{'mesh':<10} {'surface':<14} {'vertices':>8} {'×|V|':>5} {'on M':>7} {'lsq':>7} {'lsq S→M':>8}")
for m in sys.argv[2:]:
    rows = {}
    for line in open(os.path.join(out, f"{m}-floor.jsonl")):
        r = json.loads(line)
        rows.setdefault(r["surface"], []).append(r)
    for s, rs in rows.items():
        tag = os.path.basename(s)[len(m) + 1:-4]
        a, b = rs[0], rs[-1]
        print(f"{m:<10} {tag:<14} {a['vertices']:>8} {a['vertices'] / a['m_vertices']:>5.2f} "
              f"{a['m_to_surface']:>7.4f} {b['m_to_surface']:>7.4f} {b['surface_to_m']:>8.4f}")
PY
