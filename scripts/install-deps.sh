#!/usr/bin/env bash
# Installs what subdfit needs on Debian 12, idempotently: the C++ stack the
# build links against, and a Rust toolchain when none is on the PATH.
# Run as root (or with sudo available).
set -euo pipefail

# chromium: the headless browser that tests/render.rs opens report.html in.
PKGS=(cmake g++ make pkg-config libosd-dev libembree-dev libeigen3-dev libopenmesh-dev chromium)
SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi

missing=()
for p in "${PKGS[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "install-deps: installing ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}"
fi

if ! command -v cargo >/dev/null 2>&1; then
  if [ -x "$HOME/.cargo/bin/cargo" ]; then
    echo "install-deps: cargo is in ~/.cargo/bin; add it to PATH"
  else
    echo "install-deps: installing a Rust toolchain with rustup"
    if ! command -v curl >/dev/null 2>&1; then
      DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq curl ca-certificates
    fi
    curl -sSf https://sh.rustup.rs | sh -s -- -y --profile minimal -c clippy,rustfmt
  fi
fi

# Pixar's USD Python bindings, to check that control.usda loads (tests).
if command -v python3 >/dev/null 2>&1 && ! python3 -c "import pxr" >/dev/null 2>&1; then
  echo "install-deps: installing usd-core (Pixar USD) with pip"
  python3 -m pip install --quiet --disable-pip-version-check usd-core
fi
