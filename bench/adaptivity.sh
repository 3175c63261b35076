#!/usr/bin/env bash
# The field layout's adaptivity on the bunny and the gargoyle (issue 40):
# Spearman's ρ of patch radius against 1/F_S at τ = 1 %, ≥ 0.6
# (tests/field_adaptivity.rs, ignored by default because each Fitmap takes
# ~30 s). Needs ../shared/data.
set -euo pipefail
cd "$(dirname "$0")/.."
exec nice -n 5 cargo test --release --test field_adaptivity -- --ignored --nocapture
