#!/usr/bin/env bash
# The main job on a bundled sample: installs what is missing, builds, then
# converts data/spot.ply into a fitted Catmull-Clark surface with
# displacement (out/spot/), and cross-checks the two limit evaluators on the
# bundled control meshes.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/install-deps.sh
if [ -f "$HOME/.cargo/env" ]; then . "$HOME/.cargo/env"; fi
cargo build --release
./target/release/subdfit info data/spot.ply
./target/release/subdfit convert data/spot.ply -o out/spot --report
echo "== results in out/spot: report.html (open it in a browser), control.obj (+ control.usda), limit.ply, displaced.ply, displacement.exr, fitmap.ply, report.json"
for control in data/samples/*.obj; do
  echo "== diff-limit $control"
  ./target/release/subdfit diff-limit "$control"
done
