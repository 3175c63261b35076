#!/usr/bin/env bash
# Times `subdfit simplify` on the paper's meshes on 2 cores (issue 4
# acceptance: bunny <= 10 s, gargoyle <= 8 s for the simplification, peak
# memory <= 1 GB), at tau = 1 % and 10 %. Prints faces, irregular vertices,
# collapses/s, the simplification's seconds, the adaptivity figure
# (Spearman rank correlation of patch radius with 1/F_S over the final
# patches) and /usr/bin/time's wall time and peak RSS.
#
# The Fitmap (minutes on bunny) is computed once per mesh and tau and cached
# under target/fitmaps (hidden option --fitmap-cache), so the second run
# times the simplification alone; delete the cache to time the whole
# pipeline. With FIT=1 each control mesh also goes through the global fit
# (`subdfit fit`, §3.5) and the report's patch count, irregular vertices
# and RMS L (‰ of the diagonal, Table 1's "L") are printed: the guard and
# the M-fitmap test must keep the surface on M while the counts drop.
# On a loaded machine read the "user" CPU seconds, not the wall time.
# "final_blockers" counts, per test, the final patches one of whose
# collapses that test refused in the last sweep (what stops each patch at
# the natural end). S_FITMAP=x sets the S-fitmap test's κ = x·κ₀
# (hidden option --s-fitmap; default 1.55, 0 turns it off; see
# `SimplifyOptions::s_fitmap_scale` for the measured trade-off).
# Adaptivity (issue 4: "patches visibly smaller where F_S is large"):
# adaptivity_spearman = Spearman(patch radius, 1/F_S) over the final
# patches, radius_ratio_fs_quartiles = mean radius of the top F_S quartile
# over the bottom one (below 1: adapts), sd_log_fs_* = spread of ln F_S
# over the patches and over M's vertices.
# The cache is keyed by vertex count and tau only: delete target/fitmaps
# after any change to the Fitmap code (F_S's fit changed 2026-11-22).
# Usage: [FIT=1] [S_FITMAP=x] bench/simplify.sh [DATA_DIR]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
data=${1:-$root/../shared/data}
cargo build --release --bin subdfit >/dev/null
out=$(mktemp -d)
mkdir -p "$root/target/fitmaps"
for mesh in bunny gargoyle; do
  for tau in 0.01 0.10; do
    echo "== $mesh tau=$tau"
    /usr/bin/time -f "wall %e s, user %U s, peak %M KB" taskset -c 0,1 \
      "$root/target/release/subdfit" simplify "$data/$mesh.ply" -o "$out/$mesh-$tau.obj" \
      --tolerance "$tau" --json --fitmap-cache "$root/target/fitmaps/$mesh-$tau.bin" \
      ${S_FITMAP:+--s-fitmap "$S_FITMAP"} |
      python3 -c '
import json, sys
j = json.load(sys.stdin); s = j["stats"]
for k in ("faces", "irregular_vertices", "collapses", "stopped_at", "seconds_fitmap",
          "seconds_simplify", "collapses_per_second"):
    print(f"  {k}: {j[k]}")
for k in ("adaptivity_spearman", "radius_ratio_fs_quartiles", "sd_log_fs_patches",
          "sd_log_fs_vertices", "spearman_radius_fm", "median_radius_over_fm",
          "refused_m_fitmap", "refused_s_fitmap", "s_fitmap_kappa", "refused_guard_distance",
          "refused_guard_normal", "sweeps", "final_blockers"):
    print(f"    {k}: {s[k]}")'
    if [ "${FIT:-0}" = 1 ]; then
      "$root/target/release/subdfit" fit "$data/$mesh.ply" "$out/$mesh-$tau.obj" \
        -o "$out/fit-$mesh-$tau" 2>&1 | grep -E 'patches.*RMS L'
      rm -rf "$out/fit-$mesh-$tau"
    fi
  done
done
