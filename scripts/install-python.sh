#!/usr/bin/env bash
# Installs the Python package `flatport` (python/, docs/python.md) into a virtual environment:
# the one that is active ($VIRTUAL_ENV), else $FLATPORT_VENV, else ./.venv (created). It runs
# `pip install ./python`, which builds the crate with maturin (Rust needed, as for the CLI).
# Debian's own Python refuses packages outside a virtual environment (PEP 668), and a fresh Debian
# may lack python3 or its venv module: as root this installs python3 and python3-venv through apt,
# otherwise it says what to install.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! command -v python3 >/dev/null 2>&1 || ! python3 -c 'import venv, ensurepip' >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "installing python3 and python3-venv..." >&2
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq
        apt-get install -y -qq python3 python3-venv >/dev/null
    else
        echo "error: the Python package needs Python 3.9 or newer with venv. On Debian/Ubuntu: sudo apt-get install python3 python3-venv" >&2
        exit 1
    fi
fi
if ! command -v cargo >/dev/null 2>&1; then
    echo "error: cargo not found. Install Rust (https://rustup.rs): maturin builds the package from the crate" >&2
    exit 1
fi

venv="${VIRTUAL_ENV:-${FLATPORT_VENV:-.venv}}"
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
echo "building and installing flatport into $venv (the first build takes a few minutes)..." >&2
"$venv/bin/python" -m pip install -q --upgrade pip
"$venv/bin/python" -m pip install -q --force-reinstall ./python
"$venv/bin/python" -c 'import flatport; print("flatport", flatport.__version__, "installed in", flatport.__file__)'
[ -n "${VIRTUAL_ENV:-}" ] || echo "use it: . $venv/bin/activate  (then: python -c 'import flatport')" >&2
