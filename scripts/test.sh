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
cargo test --all-targets
cargo test --doc
cargo clippy --all-targets -- -D warnings
cargo fmt --check
