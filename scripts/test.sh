#!/usr/bin/env bash
# Runs flatport's whole test suite: unit tests, integration tests against independent oracles,
# property tests, CLI tests, benches compiled and run once, doc examples.
# Release mode: nalgebra code is ~100x slower unoptimised.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! command -v cargo >/dev/null 2>&1; then
    echo "error: cargo not found. Install Rust (https://rustup.rs), then run: scripts/test.sh" >&2
    exit 1
fi

cargo test --release --all-targets "$@"
cargo test --release --doc "$@"
