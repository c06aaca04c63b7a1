#!/usr/bin/env bash
# Runs flatport's whole test suite: unit tests, integration tests against independent oracles,
# golden values, property tests, CLI tests, GPU-vs-CPU parity on Vulkan (lavapipe when there is
# no GPU), benches compiled and run once, doc examples (README.md and docs/*.md included), the
# Python package's tests, and the guides' commands (scripts/check-docs.sh). Release mode: nalgebra
# code is ~100x slower unoptimised.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! command -v cargo >/dev/null 2>&1; then
    echo "error: cargo not found. Install Rust (https://rustup.rs), then run: scripts/test.sh" >&2
    exit 1
fi

# A Vulkan loader and driver for the GPU tests: Mesa's lavapipe (software Vulkan) on Debian.
have_vulkan() {
    ldconfig -p 2>/dev/null | grep -q 'libvulkan\.so\.1' && ls /usr/share/vulkan/icd.d/*.json >/dev/null 2>&1
}
if ! have_vulkan; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "installing the Vulkan loader and Mesa's lavapipe driver (mesa-vulkan-drivers)..." >&2
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq
        apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
    else
        echo "error: no Vulkan driver. Install one, e.g. on Debian/Ubuntu:" >&2
        echo "  sudo apt-get install mesa-vulkan-drivers libvulkan1" >&2
        exit 1
    fi
fi
# The ffmpeg tool for the video tests of the frame reader (tests/frames.rs): without it they
# print a message and pass untested.
if ! command -v ffmpeg >/dev/null 2>&1 || ! command -v ffprobe >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "installing ffmpeg for the video tests..." >&2
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq
        apt-get install -y -qq ffmpeg >/dev/null
    else
        echo "warning: ffmpeg not found: the video tests will be skipped. Install it, e.g. on Debian/Ubuntu:" >&2
        echo "  sudo apt-get install ffmpeg" >&2
    fi
fi
# Chromium for the report pages (tests/report_page.rs opens every route's index.html in headless
# Chromium). Without it those tests say so and pass, except in CI (CI=true), where they fail.
have_chromium() {
    [ -n "${FLATPORT_CHROMIUM:-}" ] || command -v chromium >/dev/null 2>&1 \
        || command -v chromium-browser >/dev/null 2>&1 || command -v google-chrome >/dev/null 2>&1
}
if ! have_chromium; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "installing chromium for the report page tests..." >&2
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq
        apt-get install -y -qq chromium >/dev/null
    elif [ "${CI:-}" = true ]; then
        echo "error: Chromium not found (CI=true: the report page tests need it). Install it, e.g. on Debian/Ubuntu:" >&2
        echo "  sudo apt-get install chromium   (or set FLATPORT_CHROMIUM to the browser's path)" >&2
        exit 1
    else
        echo "warning: Chromium not found: the report pages will not be opened in a browser. Install it, e.g. on Debian/Ubuntu:" >&2
        echo "  sudo apt-get install chromium   (or set FLATPORT_CHROMIUM to the browser's path)" >&2
    fi
fi
# Mesa warns on headless machines unless this is set.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"

cargo test --release --all-targets "$@"
cargo test --release --doc "$@"
# The library without the optional features (no wgpu, no image crates, no clap): what an embedder
# who needs only the CPU geometry compiles (Cargo.toml's [features]).
cargo build --release --lib --no-default-features

# The Python package (python/, docs/python.md): built by maturin (`pip install ./python`) into a
# virtual environment under target/, sharing target/ with the builds above, then its pytest suite,
# which also compares with the CLI just built (target/release/flatport).
venv=target/python-venv
CARGO_TARGET_DIR="$PWD/target" FLATPORT_VENV="$venv" VIRTUAL_ENV= scripts/install-python.sh
# opencv-python-headless: OpenCV itself reads the exported FileStorage YAML.
"$venv/bin/python" -m pip install -q numpy pytest opencv-python-headless
# aquacal (PyPI): AquaCal's own loader and projection read `flatport export aquacal` and write what
# `flatport rig from-aquacal` reads (python/tests/test_aquacal.py). --no-deps: it pins
# opencv-python, which would clash with the headless OpenCV above (its cv2 calls are the same);
# the second line is the rest of what `import aquacal` needs. About 30 s on a fresh environment.
"$venv/bin/python" -m pip install -q --no-deps aquacal==2.1.0
"$venv/bin/python" -m pip install -q scipy natsort pyyaml pandas matplotlib tqdm requests
# plyfile reads the fused clouds of `stereo --fuse` back (python/tests/test_stereo.py).
"$venv/bin/python" -m pip install -q plyfile
FLATPORT_BIN="$PWD/target/release/flatport" "$venv/bin/python" -m pytest python/tests -q

# The commands of README.md and docs/*.md, run as written (shell and Python blocks; docs/testing.md).
FLATPORT_BIN="$PWD/target/release/flatport" FLATPORT_PYTHON="$PWD/$venv/bin/python" scripts/check-docs.sh
