#!/usr/bin/env bash
# Fitmaps Table 1 on the shared organic meshes (issue 5, item 4).
#
#   bench/table1.sh [DATA_DIR] [OUT_DIR]
#
# For each organic mesh and each τ in $TAUS (default "0.01 0.1", i.e. 1 %
# and 10 %), runs `subdfit convert MESH -o OUT --tolerance τ --max-error inf`
# (the paper's protocol: τ alone sets the result; the default 5‰ RMS bound
# would add patches to the 10 % rows) under
# /usr/bin/time and prints the table in the paper's layout: patches □K,
# irregular vertices, unprojectable area (%), RMS error of the limit (L) and
# displaced (D) surfaces in ‰ of the bounding-box diagonal (D also split by
# direction, and D → M over the part of D whose samples projected onto M,
# which leaves out the surface beyond M's boundary or over its holes) — plus wall
# seconds, user CPU seconds (the figure to compare on a shared machine, where
# wall time grows with the load) and peak memory, and the paper's figures
# where it has them.
#
# Until `convert` exists, each mesh is run through `subdfit fit` from the
# interpolating quad control mesh of §3.2 (examples/quad_control.rs): the
# same fit/displacement/metrics path, but no simplification, so □K is about
# half M's triangle count and the τ columns repeat ("fit-only" rows).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${1:-../shared/data}
OUT=${2:-target/table1}
TAUS=${TAUS:-"0.01 0.1"}
MESHES=${MESHES:-"bunny gargoyle homer spot cheburashka"}
mkdir -p "$OUT"

cargo build --release --quiet --bin subdfit --example quad_control
BIN=target/release/subdfit
HAVE_CONVERT=0
if "$BIN" convert --help >/dev/null 2>&1; then HAVE_CONVERT=1; fi

timed() { # timed LOG cmd...: runs cmd, wall seconds, peak RSS (KiB) and user CPU seconds into LOG
  local log=$1; shift
  /usr/bin/time -f "%e %M %U" -o "$log" "$@"
}

rows=()
for m in $MESHES; do
  mesh="$DATA/$m.ply"
  [ -f "$mesh" ] || { echo "skip $m: $mesh not found" >&2; continue; }
  for tau in $TAUS; do
    dir="$OUT/$m-$tau"
    rm -rf "$dir"
    if [ "$HAVE_CONVERT" = 1 ]; then
      timed "$OUT/$m-$tau.time" "$BIN" convert "$mesh" -o "$dir" --tolerance "$tau" --max-error inf --quiet
      mode="convert"
    else
      ctrl="$OUT/$m-quad.obj"
      [ -f "$ctrl" ] || target/release/examples/quad_control "$mesh" "$ctrl" 2>/dev/null
      timed "$OUT/$m-$tau.time" "$BIN" fit "$mesh" "$ctrl" -o "$dir" --quiet --no-fitmap
      mode="fit-only"
    fi
    rows+=("$m $tau $mode $dir $(cat "$OUT/$m-$tau.time")")
  done
done

python3 - "${rows[@]}" <<'PY'
import json, sys
# Table 1 of the paper (□K, irregular, unprojectable %, RMS L, RMS D).
paper = {
    ("bunny", "0.01"): (506, 216, 0.1, 3.41, 0.08),
    ("bunny", "0.1"): (218, 72, None, 8.48, 0.14),
    ("gargoyle", "0.01"): (1096, 345, 0.0, 2.36, 0.07),
    ("gargoyle", "0.1"): (493, 182, 0.4, 4.50, 0.15),
}
hdr = f"{'Mesh (Δ)':<18} {'τ':>5} {'□K':>7} {'Irreg.':>7} {'Unp.%':>6} {'L ‰':>7} {'D ‰':>7} {'D s→M':>7} {'D M→s':>7} {'D over M':>8} {'s':>7} {'cpu s':>7} {'MB':>7}  mode      paper (□K irr unp L D)"
print(hdr)
print("-" * len(hdr))
for row in sys.argv[1:]:
    m, tau, mode, d, secs, kib, cpu = row.split()
    r = json.load(open(f"{d}/report.json"))
    tris = r["input"].get("triangles", 0)
    name = f"{m} ({tris/1000:.0f}k)"
    p = paper.get((m, tau))
    dis = r["accuracy"]["displaced"]
    # D → M over the displaced triangles whose samples all projected (the
    # part of D that lies over M; see report::DisplacedBreakdown).
    bd = r["accuracy"].get("displaced_breakdown")
    over_m = f"{bd['surface_to_mesh_projected']['rms_permille']:.3f}" if bd else "-"
    ptxt = " ".join("-" if x is None else str(x) for x in p) if p else ""
    print(f"{name:<18} {float(tau)*100:>4g}% {r['control']['faces']:>7} "
          f"{r['control']['irregular_vertices']:>7} "
          f"{r['projectability']['unprojectable_area_percent']:>6.2f} "
          f"{r['accuracy']['limit']['rms_permille']:>7.3f} "
          f"{r['accuracy']['displaced']['rms_permille']:>7.3f} "
          f"{dis['surface_to_mesh']['rms_permille']:>7.3f} "
          f"{dis['mesh_to_surface']['rms_permille']:>7.3f} "
          f"{over_m:>8} "
          f"{float(secs):>7.2f} {float(cpu):>7.2f} {int(kib)/1024:>7.0f}  {mode:<9} {ptxt}")
PY
