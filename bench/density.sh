#!/usr/bin/env bash
# What limits RMS D (issue 5; Fitmaps §4, Table 1): D against the
# displacement density, and against an idealised floor.
#
#   bench/density.sh [DATA_DIR] [OUT_DIR]
#
# For each mesh in $MESHES (default "gargoyle bunny") at each τ in $TAUS
# (default "0.01"), converts once (or reuses OUT_DIR/MESH-τ/control.obj),
# then evaluates the same control mesh at multiples $MULTS (default
# "1 2 4 9 16") of the paper's density (total samples ≈ M's vertex count,
# `displace::auto_resolution`), with φ's hit offsets (D interpolates M at
# the samples) and with least-squares offsets (`displace::refine_offsets`,
# the default), both directions of D measured as report.json does. Then
# the floor: M resampled at its own density with every vertex on M
# (`report::resampling_floor`: vertices slid within their half rings,
# REACH 0.5, and within a quarter ring, 0.25), measured the same way — the
# best an interpolating resampling with M's own well-shaped triangles does.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${1:-../shared/data}
OUT=${2:-target/density}
MESHES=${MESHES:-"gargoyle bunny"}
TAUS=${TAUS:-"0.01"}
MULTS=${MULTS:-"1 2 4 9 16"}
mkdir -p "$OUT"
cargo build --release --quiet --bin subdfit --example density --example resample_floor

for m in $MESHES; do
  mesh="$DATA/$m.ply"
  [ -f "$mesh" ] || { echo "skip $m: $mesh not found" >&2; continue; }
  for tau in $TAUS; do
    dir="$OUT/$m-$tau"
    [ -f "$dir/control.obj" ] || target/release/subdfit convert "$mesh" -o "$dir" --tolerance "$tau" --quiet
    target/release/examples/density "$mesh" "$dir/control.obj" $MULTS > "$OUT/$m-$tau.jsonl"
  done
  for reach in 0.5 0.25; do
    target/release/examples/resample_floor "$mesh" "$reach" 1
  done > "$OUT/$m-floor.jsonl"
done

python3 - "$OUT" $MESHES <<'PY'
import json, sys, os
out = sys.argv[1]
print(f"{'mesh':<10} {'τ':>5} {'×':>4} {'R':>3} {'samples':>8} {'offsets':>7} {'D→M':>7} {'M→D':>7} {'D':>7} {'s':>6}")
for m in sys.argv[2:]:
    for f in sorted(os.listdir(out)):
        if not (f.startswith(m + "-") and f.endswith(".jsonl")) or "floor" in f:
            continue
        tau = f[len(m) + 1:-6]
        for line in open(os.path.join(out, f)):
            r = json.loads(line)
            print(f"{m:<10} {float(tau)*100:>4g}% {r['multiple']:>4g} {r['res']:>3} {r['samples']:>8} "
                  f"{r['offsets']:>7} {r['d_s2m']:>7.3f} {r['d_m2s']:>7.3f} {r['d_rms']:>7.3f} {r['seconds']:>6.2f}")
    fl = os.path.join(out, f"{m}-floor.jsonl")
    if os.path.exists(fl):
        for line in open(fl):
            r = json.loads(line)
            a = r["floor"]
            print(f"{m:<10} floor (M resampled at its own {r['vertices']} vertices, reach {r['reach']}): "
                  f"D→M {a['surface_to_mesh']['rms_permille']:.3f}  M→D {a['mesh_to_surface']['rms_permille']:.3f}  "
                  f"max {a['rms_permille']:.3f}")
PY
