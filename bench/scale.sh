#!/usr/bin/env bash
# Scale ladder (issues 16, 39): how `subdfit convert` grows with the input size.
#
#   bench/scale.sh [DATA_DIR] [OUT_DIR]      (env: LEVELS="1 2 3 10m", BASE=bunny,
#                                             EXTRA="bunny gargoyle", CONVERT_ARGS=...,
#                                             QF_PYTHON=..., QF_MAX=1200000, BIN=...)
#
# Makes a size ladder from $BASE.ply (bench/make_ladder.py: 1-to-4 midpoint
# subdivision LEVELS times, seeded normal noise of 0.05 of the mean edge, so
# bunny gives ~278k, 1.1M and 4.4M triangles; `10m` is level 2 split 1-to-9,
# 10.0M triangles), converts each rung and the $EXTRA shared meshes, and
# prints per mesh: triangles, wall and CPU seconds, peak memory, patches,
# irregular vertices, RMS L and D (‰ of the diagonal), unprojectable area,
# the three stages of most CPU (CPU s, and the process's peak MB at the
# stage's end), and the growth exponents log(t_i / t_{i-1}) / log(n_i /
# n_{i-1}) of CPU and wall time between rungs (and from the ~1M rung to
# the last, issue 39's "from 1M to 10M"). Needs numpy (the project's .venv
# has it). The ladder's meshes are kept in OUT_DIR and reused.
#
# On a shared, loaded machine wall time measures the load: compare CPU.
#
# Beside every mesh of at most QF_MAX triangles (default 1.2M: the shared
# meshes and rungs 1-2) it times QuadriFlow's layout alone
# (bench/quadriflow_time.py: pyquadriflow at subdfit's patch count, the mesh
# read before the clock starts) in the same run, and prints subdfit's CPU
# time over QuadriFlow's (and the wall ratio; issue 39's target: <= 0.5
# from 268k triangles on). QF_PYTHON is a Python with pyquadriflow and
# trimesh (the project's .venv, or bench/peers.sh's .venv-peers); without
# one the columns read "-".
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${1:-../shared/data}
OUT=${2:-target/scale}
LEVELS=${LEVELS-"1 2 3 10m"}
BASE=${BASE:-bunny}
EXTRA=${EXTRA-"bunny gargoyle"}
QF_MAX=${QF_MAX:-1200000}
QF_PYTHON=${QF_PYTHON:-}
common=$(git rev-parse --path-format=absolute --git-common-dir 2>/dev/null || echo .git)
if [ -z "$QF_PYTHON" ]; then
  # A worktree shares the main checkout's virtualenvs.
  for p in .venv-peers/bin/python "$common/../.venv-peers/bin/python" .venv/bin/python "$common/../.venv/bin/python"; do
    if [ -x "$p" ] && "$p" -c "import pyQuadriFlow, trimesh" 2>/dev/null; then QF_PYTHON=$p; break; fi
  done
fi
PY=python3
for p in .venv/bin/python "$common/../.venv/bin/python" python3; do
  if "$p" -c "import numpy" 2>/dev/null; then PY=$p; break; fi
done
"$PY" -c "import numpy" 2>/dev/null || { echo "bench/scale.sh: numpy not found (pip install numpy)"; exit 2; }
mkdir -p "$OUT"
[ -f "$DATA/$BASE.ply" ] || { echo "bench/scale.sh: $DATA/$BASE.ply not found (shared data absent)"; exit 2; }
if [ -z "${BIN:-}" ]; then
  cargo build --release --quiet --bin subdfit
  BIN=target/release/subdfit
fi

missing=""
for l in $LEVELS; do [ -f "$OUT/rung$l.ply" ] || missing="$missing $l"; done
if [ -n "$missing" ]; then
  # Every level asked for, so that the seeded noise of each rung is the same
  # whichever were missing.
  # shellcheck disable=SC2086
  "$PY" bench/make_ladder.py "$DATA/$BASE.ply" "$OUT" $LEVELS >/dev/null
fi

run() { # name input
  local name=$1 input=$2 dir="$OUT/out_$1"
  /usr/bin/time -f "%e %U %S %M" -o "$OUT/$name.time" \
    "$BIN" convert "$input" -o "$dir" --quiet ${CONVERT_ARGS:-} || echo "$name: convert failed" >&2
  local qf="- -"
  local tris faces
  tris=$(python3 -c "import json;print(json.load(open('$dir/report.json'))['input']['triangles'])")
  faces=$(python3 -c "import json;print(json.load(open('$dir/report.json'))['control']['faces'])")
  if [ -n "$QF_PYTHON" ] && [ "$tris" -le "$QF_MAX" ]; then
    qf=$("$QF_PYTHON" bench/quadriflow_time.py "$input" "$faces" | cut -d' ' -f1,2) || qf="- -"
  fi
  python3 - "$name" "$dir/report.json" "$OUT/$name.time" $qf <<'PY'
import json, sys
name, rep, tim, qf_wall, qf_cpu = sys.argv[1:]
wall, user, sys_, kb = open(tim).read().split()[-4:]
cpu = float(user) + float(sys_)
r = json.load(open(rep))
st = sorted(r["stages"], key=lambda s: -s.get("cpu_seconds", 0))[:3]
if qf_cpu == "-":
    qf_cols = f"{'-':>6s} {'-':>6s} {'-':>5s} {'-':>5s}"
else:
    qw, qc = float(qf_wall), float(qf_cpu)
    qf_cols = f"{qw:6.1f} {qc:6.1f} {cpu / qc:5.2f} {float(wall) / qw:5.2f}"
print(f"{name:10s} {r['input']['triangles']:>9d} {float(wall):8.1f} {cpu:8.1f} "
      f"{int(kb)/1024:8.0f} {r['control']['faces']:>7d} {r['control']['irregular_vertices']:>5d} "
      f"{r['accuracy']['limit']['rms_permille']:7.3f} {r['accuracy']['displaced']['rms_permille']:7.3f} "
      f"{r['projectability']['unprojectable_area_percent']:7.3f} {qf_cols}  "
      + ", ".join(f"{s['stage']} {s.get('cpu_seconds', 0):.1f}/{s.get('peak_memory_mib') or 0:.0f}" for s in st))
PY
}

exponent() { # label wall cpu n prev_wall prev_cpu prev_n
  python3 -c "
import math, sys
w, c, n, pw, pc, pn = map(float, sys.argv[2:8])
k = math.log(n / pn)
print(f'  growth exponent {sys.argv[1]}: CPU {math.log(c / pc) / k:.2f}, wall {math.log(w / pw) / k:.2f}')" "$@"
}

echo "mesh        triangles   wall s    cpu s   peak MB patches irreg  RMS L‰  RMS D‰ unproj%  QF s QF cpu cpu/QF wall/QF  most CPU: stage cpu s/peak MB"
for m in $EXTRA; do run "$m" "$DATA/$m.ply"; done
prev=""; first=""
for l in $LEVELS; do
  run "rung$l" "$OUT/rung$l.ply"
  read -r w u s _ < "$OUT/rung$l.time"
  n=$(python3 -c "import json;print(json.load(open('$OUT/out_rung$l/report.json'))['input']['triangles'])")
  c=$(python3 -c "print($u + $s)")
  # shellcheck disable=SC2086
  [ -n "$prev" ] && exponent "rung ${prev%% *} -> $l" "$w" "$c" "$n" ${prev#* }
  # The first rung of about a million triangles or more: issue 39's "from 1M".
  if [ -z "$first" ] && [ "$n" -ge 1000000 ]; then first="$l $w $c $n"; fi
  prev="$l $w $c $n"
done
if [ -n "$first" ] && [ "${first%% *}" != "${prev%% *}" ]; then
  # shellcheck disable=SC2086
  exponent "rung ${first%% *} -> ${prev%% *}" ${prev#* } ${first#* }
fi
