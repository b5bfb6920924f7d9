#!/usr/bin/env bash
# Set up chpf in ./.venv on a fresh machine: system GL libraries for headless rendering,
# then the package with its training (which pulls in [render]) and dev extras at this machine's
# pinned versions.
set -euo pipefail
cd "$(dirname "$0")"
if ! ldconfig -p | grep -q 'libEGL.so.1'; then
    if command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        apt-get update -qq
        apt-get install -y -qq libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 >/dev/null
    else
        echo "warning: install libegl1 libegl-mesa0 libgl1-mesa-dri (or libosmesa6) for headless rendering" >&2
    fi
fi
[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -c constraints.txt -e '.[train,dev]'
echo "chpf is set up in .venv"
