#!/usr/bin/env bash
# Times `subdfit render` at 1024x768 on 2 cores (issue 8 target: a
# 100k-triangle mesh in <= 2 s). Meshes: a generated bumpy torus of exactly
# 100,000 triangles, the Stanford bunny (69k), and, when a `convert` output
# folder is given, its patches picture (limit tessellation ~300k triangles).
# Wall time includes reading the mesh, building the ray caster and writing
# the PNG. Usage: bench/render.sh [DATA_DIR] [CONVERT_OUTPUT_DIR]
set -euo pipefail
data=${1:-$(dirname "$0")/../../shared/data}
outdir=${2:-}
cargo build --release --bin subdfit >/dev/null
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
python3 - "$tmp/torus100k.obj" <<'PY'
import math, sys
n, m = 250, 200  # 2 n m = 100,000 triangles
with open(sys.argv[1], "w") as f:
    for i in range(n):
        a = 2 * math.pi * i / n
        for j in range(m):
            b = 2 * math.pi * j / m
            r = 0.35 * (1 + 0.08 * math.sin(7 * a) * math.sin(5 * b))
            ring = 1 + r * math.cos(b)
            f.write(f"v {ring*math.cos(a):.6f} {r*math.sin(b):.6f} {ring*math.sin(a):.6f}\n")
    idx = lambda i, j: (i % n) * m + (j % m) + 1
    for i in range(n):
        for j in range(m):
            f.write(f"f {idx(i,j)} {idx(i+1,j)} {idx(i+1,j+1)}\n")
            f.write(f"f {idx(i,j)} {idx(i+1,j+1)} {idx(i,j+1)}\n")
PY
run() {
  local label=$1; shift
  echo "== $label"
  for rays in embree rust; do
    /usr/bin/time -f "  $rays: wall %e s, peak %M KB" taskset -c 0,1 \
      target/release/subdfit render "$@" --size 1024x768 --rays "$rays" --quiet -o "$tmp/out.png"
  done
}
run "torus 100k triangles, input, iso" "$tmp/torus100k.obj" --view iso
run "torus 100k triangles, input, auto view" "$tmp/torus100k.obj" --view auto
run "bunny 69k triangles, input, front" "$data/bunny.ply" --view front
if [ -n "$outdir" ]; then
  run "$outdir patches, front" "$outdir" --what patches --view front
fi
