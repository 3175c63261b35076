#!/usr/bin/env bash
# Scale ladder (issue 16): how `subdfit convert` grows with the input size.
#
#   bench/scale.sh [DATA_DIR] [OUT_DIR]      (env: LEVELS="1 2 3 10m", BASE=bunny,
#                                             EXTRA="bunny gargoyle", CONVERT_ARGS=...,
#                                             QF_PYTHON=..., QF_MAX=1200000)
#
# Makes a size ladder from $BASE.ply (bench/make_ladder.py: 1-to-4 midpoint
# subdivision LEVELS times, seeded normal noise of 0.05 of the mean edge, so
# bunny gives ~278k, 1.1M and 4.4M triangles; `10m` is level 2 split 1-to-9,
# 10.0M triangles, ~11 GB for the conversion), converts each rung and the
# $EXTRA shared meshes, and prints per mesh: triangles, wall and CPU seconds,
# peak memory, patches, irregular vertices, RMS L and D (‰ of the diagonal),
# unprojectable area, the slowest stages, and the time growth exponent
# log(t_i / t_{i-1}) / log(n_i / n_{i-1}) between rungs. Needs numpy (pip).
#
# Beside every mesh of at most QF_MAX triangles (default 1.2M: the shared
# meshes and rungs 1-2) it times QuadriFlow's layout alone
# (bench/quadriflow_time.py: pyquadriflow at subdfit's patch count, the mesh
# read before the clock starts) in the same run, and prints subdfit's wall
# time over it (issue 39's target: <= 0.5 from 268k triangles on). QF_PYTHON
# is a Python with pyquadriflow and trimesh (bench/peers.sh makes
# .venv-peers); without one the columns read "-".
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${1:-../shared/data}
OUT=${2:-target/scale}
LEVELS=${LEVELS:-"1 2 3 10m"}
BASE=${BASE:-bunny}
EXTRA=${EXTRA:-"bunny gargoyle"}
QF_MAX=${QF_MAX:-1200000}
QF_PYTHON=${QF_PYTHON:-}
if [ -z "$QF_PYTHON" ]; then
  # A worktree shares the main checkout's virtualenvs.
  common=$(git rev-parse --path-format=absolute --git-common-dir 2>/dev/null || echo .git)
  for p in .venv-peers/bin/python "$common/../.venv-peers/bin/python" .venv/bin/python; do
    if [ -x "$p" ] && "$p" -c "import pyQuadriFlow, trimesh" 2>/dev/null; then QF_PYTHON=$p; break; fi
  done
fi
mkdir -p "$OUT"
[ -f "$DATA/$BASE.ply" ] || { echo "bench/scale.sh: $DATA/$BASE.ply not found (shared data absent)"; exit 2; }
python3 -c "import numpy" 2>/dev/null || pip install -q numpy
cargo build --release --quiet --bin subdfit
BIN=target/release/subdfit

# shellcheck disable=SC2086
python3 bench/make_ladder.py "$DATA/$BASE.ply" "$OUT" $LEVELS >/dev/null

run() { # name input
  local name=$1 input=$2 dir="$OUT/out_$1"
  /usr/bin/time -f "%e %U %S %M" -o "$OUT/$name.time" \
    "$BIN" convert "$input" -o "$dir" --quiet ${CONVERT_ARGS:-} || echo "$name: convert failed" >&2
  local qf="-"
  local tris faces
  tris=$(python3 -c "import json;print(json.load(open('$dir/report.json'))['input']['triangles'])")
  faces=$(python3 -c "import json;print(json.load(open('$dir/report.json'))['control']['faces'])")
  if [ -n "$QF_PYTHON" ] && [ "$tris" -le "$QF_MAX" ]; then
    qf=$("$QF_PYTHON" bench/quadriflow_time.py "$input" "$faces" | cut -d' ' -f1) || qf="-"
  fi
  python3 - "$name" "$dir/report.json" "$OUT/$name.time" "$qf" <<'PY'
import json, sys
name, rep, tim, qf = sys.argv[1:]
wall, user, sys_, kb = open(tim).read().split()[-4:]
r = json.load(open(rep))
st = sorted(r["stages"], key=lambda s: -s["seconds"])[:3]
qf_cols = f"{'-':>6s} {'-':>5s}" if qf == "-" else f"{float(qf):6.1f} {float(wall) / float(qf):5.2f}"
print(f"{name:10s} {r['input']['triangles']:>9d} {float(wall):8.1f} {float(user)+float(sys_):8.1f} "
      f"{int(kb)/1024:8.0f} {r['control']['faces']:>7d} {r['control']['irregular_vertices']:>5d} "
      f"{r['accuracy']['limit']['rms_permille']:7.3f} {r['accuracy']['displaced']['rms_permille']:7.3f} "
      f"{r['projectability']['unprojectable_area_percent']:7.3f} {qf_cols}  "
      + ", ".join(f"{s['stage']} {s['seconds']:.1f}" for s in st))
PY
}

echo "mesh        triangles   wall s    cpu s   peak MB patches irreg  RMS L‰  RMS D‰ unproj%   QF s ratio  slowest stages (s)"
for m in $EXTRA; do run "$m" "$DATA/$m.ply"; done
prev_n=""; prev_t=""; prev_l=""
for l in $LEVELS; do
  run "rung$l" "$OUT/rung$l.ply"
  read -r t _ < "$OUT/rung$l.time"
  n=$(python3 -c "import json;print(json.load(open('$OUT/out_rung$l/report.json'))['input']['triangles'])")
  if [ -n "$prev_n" ]; then
    python3 -c "import math,sys; t,pt,n,pn=map(float,sys.argv[1:5]); print(f'  growth exponent rung {sys.argv[5]}: {math.log(t/pt)/math.log(n/pn):.2f}')" "$t" "$prev_t" "$n" "$prev_n" "$prev_l -> $l"
  fi
  prev_n=$n; prev_t=$t; prev_l=$l
done
