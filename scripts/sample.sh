#!/usr/bin/env bash
# The main job on bundled samples: installs what is missing, builds, then
# inspects the bundled mesh and cross-checks the two limit evaluators on a
# bundled control mesh. (Becomes `subdfit convert` once the pipeline lands.)
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/install-deps.sh
if [ -f "$HOME/.cargo/env" ]; then . "$HOME/.cargo/env"; fi
cargo build --release
./target/release/subdfit info data/spot.ply
for control in data/samples/*.obj; do
  echo "== diff-limit $control"
  ./target/release/subdfit diff-limit "$control"
done
