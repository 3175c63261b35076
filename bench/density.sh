#!/usr/bin/env bash
# RMS D against the displacement samples, uniform and per-patch (issue 37;
# Fitmaps §4, Table 1).
#
#   bench/density.sh [DATA_DIR] [OUT_DIR]
#
# For each mesh in $MESHES (default "bunny gargoyle spot homer
# cheburashka") at each τ
# in $TAUS (default "0.01"), converts once with `--max-error inf` (or
# reuses OUT_DIR/MESH-τ/control.obj), then evaluates the same control mesh
# at multiples $MULTS (default "1 2") of M's vertex count: on the uniform
# grid (R = round((R₀ − 1)·√m) + 1, `displace::auto_resolution`;
# `--displacement-allocation uniform`) and per patch under a budget of
# m × M's vertices (`--displacement-samples`, the default allocation,
# `displace::allocate_resolutions`), least-squares offsets both. Printed:
# the samples (each shared sample once), report.json's D on its own mesh
# (both directions), and RMS M → displaced.ply (the host's reconstruction,
# bilinear or the cubic B-spline per $RECONS, default both, as an
# independent harness measures), ‰ of the diagonal.
# Then the floor: M resampled at its own density with every vertex on M
# (`report::resampling_floor`), measured as report.json does.
#
# Measured (τ = 1 %, `--max-error inf`, RMS M → displaced.ply, ‰ of the
# diagonal; "samples" = each shared sample once; the whole output in
# bench/results/density-2026-12-05.txt):
#              uniform 1×  adaptive 1×  uniform 2×  adaptive 2×
#   bunny        0.194       0.098        0.188       0.074
#   gargoyle     0.421       0.226        0.213       0.136
#   spot         0.640       0.380        0.417       0.283
#   homer        0.397       0.207        0.212       0.181
#   cheburashka  0.453       0.179        0.229       0.115
# With `--displacement-reconstruction bspline` (2026-12-05, session 6; RMS M →
# displaced.ply, adaptive 1× / 2×): bunny 0.080 / 0.060, gargoyle 0.199 /
# 0.113, spot 0.328 / 0.250, homer 0.179 / 0.113, cheburashka 0.154 / 0.100
# (docs/status.md, "Adaptive displacement").
# The uniform grid's R is rounded, so its samples run −11 to +23 % off the
# adaptive budget's (spot 1×: 3458 against 2924). The "s" column is the
# wall time of the whole evaluation (limit and displaced sides), on a
# shared machine: compare CPU seconds for the stage's cost.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${1:-../shared/data}
OUT=${2:-target/density}
MESHES=${MESHES:-"bunny gargoyle spot homer cheburashka"}
TAUS=${TAUS:-"0.01"}
MULTS=${MULTS:-"1 2"}
# Reconstructions measured (`--displacement-reconstruction`): each at every
# multiple and allocation.
export RECONS=${RECONS:-"bilinear bspline"}
mkdir -p "$OUT"
cargo build --release --quiet --bin subdfit --example density --example resample_floor

for m in $MESHES; do
  mesh="$DATA/$m.ply"
  [ -f "$mesh" ] || { echo "skip $m: $mesh not found" >&2; continue; }
  for tau in $TAUS; do
    dir="$OUT/$m-$tau"
    [ -f "$dir/control.obj" ] || target/release/subdfit convert "$mesh" -o "$dir" --tolerance "$tau" --max-error inf --quiet
    target/release/examples/density "$mesh" "$dir/control.obj" $MULTS > "$OUT/$m-$tau.jsonl"
  done
  for reach in 0.5 0.25; do
    target/release/examples/resample_floor "$mesh" "$reach" 1
  done > "$OUT/$m-floor.jsonl"
done

python3 - "$OUT" $MESHES <<'PY'
import json, sys, os
out = sys.argv[1]
print(f"{'mesh':<10} {'τ':>5} {'×':>4} {'allocation':<9} {'recon':<8} {'R max':>5} {'samples':>8} {'D→M':>7} {'M→D':>7} {'M→ply':>7} {'s':>6}  resolutions")
for m in sys.argv[2:]:
    for f in sorted(os.listdir(out)):
        if not (f.startswith(m + "-") and f.endswith(".jsonl")) or "floor" in f:
            continue
        tau = f[len(m) + 1:-6]
        for line in open(os.path.join(out, f)):
            r = json.loads(line)
            hist = " ".join(f"{k}:{v}" for k, v in sorted((r.get("histogram") or {}).items(), key=lambda kv: int(kv[0])))
            print(f"{m:<10} {float(tau)*100:>4g}% {r['multiple']:>4g} {r['allocation']:<9} {r.get('reconstruction', 'bilinear'):<8} {r['res']:>5} {r['samples']:>8} "
                  f"{r['d_s2m']:>7.3f} {r['d_m2s']:>7.3f} {r['m_to_displaced_ply']:>7.3f} {r['seconds']:>6.2f}  {hist}")
    fl = os.path.join(out, f"{m}-floor.jsonl")
    if os.path.exists(fl):
        for line in open(fl):
            r = json.loads(line)
            a = r["floor"]
            print(f"{m:<10} floor (M resampled at its own {r['vertices']} vertices, reach {r['reach']}): "
                  f"D→M {a['surface_to_mesh']['rms_permille']:.3f}  M→D {a['mesh_to_surface']['rms_permille']:.3f}  "
                  f"max {a['rms_permille']:.3f}")
PY
