#!/usr/bin/env bash
# Optional: installs Debian's Blender (3.4 on Debian 12, large) and runs the
# Blender add-on test (tests/blender.rs). Not part of install-deps.sh / CI.
set -euo pipefail
cd "$(dirname "$0")/.."
SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
if ! command -v blender >/dev/null 2>&1; then
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq blender
fi
if [ -f "$HOME/.cargo/env" ]; then . "$HOME/.cargo/env"; fi
cargo test --release --test blender -- --nocapture
