#!/usr/bin/env bash
# Peer layouts fitted the same way (issue 17; Fitmaps §4.1's protocol):
# for each mesh and τ, `subdfit convert` gives its patch count P; then
# QuadriFlow and Instant Meshes make layouts of ≈ P patches (±5 %, two
# tries), `subdfit fit` fits them and the same metrics measure them.
#
#   bench/peers.sh [DATA_DIR] [OUT_DIR]        (MESHES, TAUS to override)
#
# Prints one row per (mesh, τ, tool): patches, irregular vertices, RMS L and
# D (‰ of the diagonal), unprojectable area (%), topology kept, seconds.
# Installs pyquadriflow, pyinstantmeshes and trimesh into .venv-peers
# (PyPI) the first time. subdfit's rows use the paper's protocol (τ alone,
# `--max-error inf`), so the counts are the layouts' own; `subdfit-field` is
# the experimental `--layout field` at its natural size (FIELD=0 skips it).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${1:-../shared/data}
OUT=${2:-target/bench-peers}
MESHES=${MESHES:-"bunny gargoyle homer spot cheburashka"}
TAUS=${TAUS:-"0.01 0.1"}
BIN=${SUBDFIT_BIN:-target/release/subdfit}
[ -x "$BIN" ] || cargo build --release --quiet
if [ ! -x .venv-peers/bin/python ]; then
  python3 -m venv .venv-peers
  .venv-peers/bin/pip install --quiet pyquadriflow pyinstantmeshes trimesh numpy
fi
mkdir -p "$OUT"
printf '%-12s %-5s %-15s %7s %5s %7s %7s %7s %5s %s\n' mesh tau tool patches irr "L‰" "D‰" "unpr%" topo "seconds / error"
for m in $MESHES; do
  mesh="$DATA/$m.ply"
  [ -f "$mesh" ] || { echo "skip $m: $mesh not found" >&2; continue; }
  for tau in $TAUS; do
    dir="$OUT/$m-$tau"
    s=$(date +%s.%N)
    "$BIN" convert "$mesh" -o "$dir/subdfit" --tolerance "$tau" --max-error inf --mode organic --quiet
    secs=$(echo "$(date +%s.%N) - $s" | bc)
    read -r P irr L D U < <(python3 -c "
import json; r=json.load(open('$dir/subdfit/report.json'))
print(r['control']['faces'], r['control']['irregular_vertices'], round(r['accuracy']['limit']['rms_permille'],3),
      round(r['accuracy']['displaced']['rms_permille'],3), round(r['projectability']['unprojectable_area_percent'],3))")
    printf '%-12s %-5s %-15s %7s %5s %7s %7s %7s %5s %.1f\n' "$m" "$tau" subdfit "$P" "$irr" "$L" "$D" "$U" yes "$secs"
    # The field-aligned layout (--layout field, issue 40) under the same
    # protocol, at its own natural size.
    if [ "${FIELD:-1}" = 1 ]; then
      s=$(date +%s.%N)
      if "$BIN" convert "$mesh" -o "$dir/subdfit-field" --tolerance "$tau" --max-error inf --mode organic --layout field --quiet; then
        secs=$(echo "$(date +%s.%N) - $s" | bc)
        read -r Pf irrf Lf Df Uf < <(python3 -c "
import json; r=json.load(open('$dir/subdfit-field/report.json'))
print(r['control']['faces'], r['control']['irregular_vertices'], round(r['accuracy']['limit']['rms_permille'],3),
      round(r['accuracy']['displaced']['rms_permille'],3), round(r['projectability']['unprojectable_area_percent'],3))")
        printf '%-12s %-5s %-15s %7s %5s %7s %7s %7s %5s %.1f\n' "$m" "$tau" subdfit-field "$Pf" "$irrf" "$Lf" "$Df" "$Uf" yes "$secs"
      else
        printf '%-12s %-5s %-15s %s\n' "$m" "$tau" subdfit-field "convert --layout field failed"
      fi
    fi
    .venv-peers/bin/python bench/peers.py "$mesh" "$P" "$dir" "$BIN" | python3 -c "
import json, sys
for line in sys.stdin:
    r = json.loads(line)
    if 'error' in r and 'rms_l' not in r:
        print('%-12s %-5s %-15s %7s %5s %7s %7s %7s %5s %s' % ('$m', '$tau', r['tool'], r.get('patches', '-'), '-', '-', '-', '-', '-', r['error'][:80]))
    else:
        print('%-12s %-5s %-15s %7d %5d %7.3f %7.3f %7.3f %5s %.1f + %.1f' % ('$m', '$tau', r['tool'], r['patches'], r['irregular'], r['rms_l'], r['rms_d'], r['unprojectable'], 'yes' if r['topology_kept'] else 'no', r['layout_seconds'], r['fit_seconds']))
"
  done
done
