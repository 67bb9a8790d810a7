#!/usr/bin/env bash
# Revisit's whole check, the same for a person and for CI (.ci/run calls it):
# set-up, formatting, lints, every test, docs.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cargo fmt --all --check
cargo clippy --workspace --all-targets --locked -- -D warnings
cargo test --workspace --locked
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --locked --quiet
