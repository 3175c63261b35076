#!/usr/bin/env bash
# The whole test suite: installs what is missing, then builds and runs every
# test (unit, integration, differential, doc), then clippy and rustfmt checks.
set -euo pipefail
cd "$(dirname "$0")/.."
./scripts/install-deps.sh
# rustup installs into ~/.cargo/bin, which a fresh shell may not have on PATH.
if [ -f "$HOME/.cargo/env" ]; then . "$HOME/.cargo/env"; fi
# install-deps.sh installed chromium, so the report.html browser test must
# run, not skip.
export SUBDFIT_REQUIRE_CHROMIUM=1
# A clean clone never reuses the incremental cache; on CI it is only 1-2 GB
# of disk written for nothing.
if [ -n "${CI:-}" ]; then export CARGO_INCREMENTAL=0; fi
cargo test --all-targets
cargo test --doc
cargo clippy --all-targets -- -D warnings
cargo fmt --all --check

# The Python package (python/): a wheel of the test profile, so it reuses the
# library built above, installed into .venv, then its pytest suite (which
# compares its outputs with the CLI's target/debug/subdfit).
export PYO3_PYTHON="$PWD/.venv/bin/python"
cargo clippy -p subdfit-python --all-targets -- -D warnings
(cd python && ../.venv/bin/maturin build --profile dev --strip -i ../.venv/bin/python -o ../target/wheels)
.venv/bin/python -m pip install --quiet --disable-pip-version-check --force-reinstall --no-deps \
  target/wheels/subdfit-0.1.0-cp311-abi3-linux_x86_64.whl
SUBDFIT_CLI="$PWD/target/debug/subdfit" .venv/bin/python -m pytest python/tests -q -rs
