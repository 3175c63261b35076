#!/usr/bin/env bash
# Peer layouts fitted the same way (issue 17; Fitmaps §4.1's protocol):
# for each mesh and τ, `subdfit convert` gives its patch count P; then
# QuadriFlow and Instant Meshes make layouts of ≈ P patches (±5 %, two
# tries), `subdfit fit` fits them and the same metrics measure them.
#
#   bench/peers.sh [DATA_DIR] [OUT_DIR]        (MESHES, TAUS to override)
#
# Prints one row per (mesh, τ, tool): patches, irregular vertices, RMS L and
# D (‰ of the diagonal), unprojectable area (%), topology kept, the layout
# stage's seconds and the whole run's (wall, CPU; for a peer: its layout
# with retries, then `subdfit fit`). Installs pyquadriflow, pyinstantmeshes
# and trimesh into .venv-peers (PyPI) the first time. subdfit's rows use
# the paper's protocol (τ alone, `--max-error inf`), so the counts are the
# layouts' own: `subdfit-greedy` (the default layout; the peers aim at its
# count) and `subdfit-field` (`--layout field`, issue 40; FIELD=0 skips it).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${1:-../shared/data}
OUT=${2:-target/bench-peers}
MESHES=${MESHES:-"bunny gargoyle homer spot cheburashka"}
TAUS=${TAUS:-"0.01 0.1"}
BIN=${SUBDFIT_BIN:-target/release/subdfit}
[ -x "$BIN" ] || cargo build --release --quiet
# The peers' Python: PEERS_PYTHON, else .venv-peers (a link to another
# checkout's is fine), made the first time.
PY=${PEERS_PYTHON:-.venv-peers/bin/python}
if ! "$PY" -c "import pyQuadriFlow, pyinstantmeshes, trimesh" 2>/dev/null; then
  python3 -m venv .venv-peers
  .venv-peers/bin/pip install --quiet pyquadriflow pyinstantmeshes trimesh numpy
  PY=.venv-peers/bin/python
fi
mkdir -p "$OUT"
# One row from a subdfit report.json: patches, irregular, RMS L, RMS D,
# unprojectable %, topology kept (V − E + F and whether there is a
# boundary, as bench/peers.py checks the peers), layout seconds (the
# layout stage alone: greedy `simplify`, field `field layout` plus its
# `--max-error` refinement passes).
row() {
  python3 - "$1" <<'PY'
import json, sys
r = json.load(open(sys.argv[1] + "/report.json"))
c, i = r["control"], r["input"]
kept = c["vertices"] - c["edges"] + c["faces"] == i["euler_characteristic"] and \
    (c["boundary_vertices"] > 0) == (i["boundary_loops"] > 0)
lay = sum(s["seconds"] for s in r["stages"]
          if s["stage"] in ("simplify", "field layout", "field refinement"))
print(c["faces"], c["irregular_vertices"], round(r["accuracy"]["limit"]["rms_permille"], 3),
      round(r["accuracy"]["displaced"]["rms_permille"], 3),
      round(r["projectability"]["unprojectable_area_percent"], 3), "yes" if kept else "no",
      round(lay, 1))
PY
}
FMT='%-12s %-5s %-15s %7s %5s %7s %7s %7s %5s %s\n'
printf "$FMT" mesh tau tool patches irr "L‰" "D‰" "unpr%" topo "layout s / total s (wall, CPU) or error"
for m in $MESHES; do
  mesh="$DATA/$m.ply"
  [ -f "$mesh" ] || { echo "skip $m: $mesh not found" >&2; continue; }
  for tau in $TAUS; do
    dir="$OUT/$m-$tau"
    # Both layouts of subdfit (the greedy default and `--layout field`,
    # issue 40) under the paper's protocol, at their natural sizes; the
    # greedy one's count P is what the peers aim at.
    P=
    for layout in greedy field; do
      [ "$layout" = field ] && [ "${FIELD:-1}" != 1 ] && continue
      out="$dir/subdfit-$layout"
      if /usr/bin/time -f "%e %U %S" -o "$dir.time" "$BIN" convert "$mesh" -o "$out" --tolerance "$tau" \
          --max-error inf --mode organic --layout "$layout" --quiet 2>"$dir.err"; then
        read -r wall user sys < "$dir.time"
        read -r p irr L D U topo lay < <(row "$out")
        printf "$FMT" "$m" "$tau" "subdfit-$layout" "$p" "$irr" "$L" "$D" "$U" "$topo" \
          "$lay / $wall, $(echo "$user + $sys" | bc)"
        [ -n "$P" ] || P=$p
      else
        printf "$FMT" "$m" "$tau" "subdfit-$layout" - - - - - - "convert failed: $(tail -n 1 "$dir.err")"
      fi
    done
    [ -n "$P" ] || continue
    "$PY" bench/peers.py "$mesh" "$P" "$dir" "$BIN" | python3 -c "
import json, sys
fmt = '%-12s %-5s %-15s %7s %5s %7s %7s %7s %5s %s'
for line in sys.stdin:
    r = json.loads(line)
    if 'error' in r and 'rms_l' not in r:
        print(fmt % ('$m', '$tau', r['tool'], r.get('patches', '-'), '-', '-', '-', '-', '-', r['error'][:80]))
    else:
        print(fmt % ('$m', '$tau', r['tool'], r['patches'], r['irregular'], '%.3f' % r['rms_l'], '%.3f' % r['rms_d'],
                     '%.3f' % r['unprojectable'], 'yes' if r['topology_kept'] else 'no',
                     '%.1f / + fit %.1f' % (r['layout_seconds'], r['fit_seconds'])))
"
  done
done
