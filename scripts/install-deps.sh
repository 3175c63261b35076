#!/usr/bin/env bash
# Installs what subdfit needs on Debian 12, idempotently: the C++ stack the
# build links against, and a Rust toolchain when none is on the PATH.
# Run as root (or with sudo available).
set -euo pipefail

# chromium: the headless browser that tests/render.rs opens report.html in.
# python3-venv: the Python package is built and tested in .venv (Debian's
# own python3 is externally managed, PEP 668).
PKGS=(cmake g++ make pkg-config libosd-dev libembree-dev libeigen3-dev libopenmesh-dev chromium python3-venv)
# Blender (not installed here) runs Debian's system Python, which needs
# NumPy for subdfit: added when Blender is present.
if command -v blender >/dev/null 2>&1; then PKGS+=(python3-numpy); fi
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

# The Python package's build and test tools, in the repository's .venv.
VENV="$(cd "$(dirname "$0")/.." && pwd)/.venv"
if [ ! -x "$VENV/bin/python" ]; then
  echo "install-deps: creating $VENV"
  python3 -m venv "$VENV"
fi
if ! [ -x "$VENV/bin/maturin" ] || ! "$VENV/bin/python" -c "import numpy, pytest, dask.distributed" >/dev/null 2>&1; then
  echo "install-deps: installing maturin, numpy, pytest, dask[distributed] into .venv"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check \
    "maturin>=1.5,<2" numpy pytest "dask[distributed]"
fi
