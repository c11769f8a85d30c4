#!/usr/bin/env bash
# One-shot set-up for a fresh machine (idempotent; `make setup` calls it).
#  1. a virtualenv in .venv
#  2. torch 2.13.0 (CPU wheel on disk) first, then `pip install -e .[test]`
#  3. a Vulkan driver for SAPIEN when the machine has no Vulkan device
#     (Mesa >= 25 lavapipe from bookworm-backports; see ARCHITECTURE.md "Set-up facts").
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
VENV=.venv
STAMP=$VENV/.gausstac-installed

if [ ! -x "$VENV/bin/python" ]; then
    echo "[setup] creating virtualenv $VENV"
    "$PY" -m venv "$VENV"
fi
if [ ! -f "$STAMP" ] || [ pyproject.toml -nt "$STAMP" ]; then
    echo "[setup] installing torch==2.13.0 and gausstac_maniskill[test] (about 2 minutes)"
    "$VENV/bin/python" -m pip install -q --upgrade pip
    "$VENV/bin/python" -m pip install -q "torch==2.13.0"
    "$VENV/bin/python" -m pip install -q -e ".[test]"
    touch "$STAMP"
fi

# --- Vulkan for SAPIEN -------------------------------------------------------
vulkan_ok() {
    "$VENV/bin/python" - <<'PYEOF' >/dev/null 2>&1
import sapien
sapien.render.RenderSystem()
PYEOF
}
if vulkan_ok; then
    echo "[setup] Vulkan device found (SAPIEN can render)"
else
    echo "[setup] no usable Vulkan device: installing Mesa lavapipe from bookworm-backports"
    if [ "$(id -u)" != "0" ]; then SUDO=sudo; else SUDO=""; fi
    if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
        echo "deb http://deb.debian.org/debian bookworm-backports main" | \
            $SUDO tee /etc/apt/sources.list.d/bookworm-backports.list >/dev/null
    fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq -t bookworm-backports \
        mesa-vulkan-drivers libvulkan1 >/dev/null
    if vulkan_ok; then
        echo "[setup] SAPIEN renders on the CPU (lavapipe)"
    else
        echo "[setup] WARNING: SAPIEN still finds no Vulkan device; SAPIEN-based tests will be skipped" >&2
    fi
fi
