#!/usr/bin/env bash
# One-shot set-up for a fresh machine (idempotent; `make setup` calls it).
#  1. a virtualenv in .venv
#  2. torch 2.13.0 (CPU wheel on disk) first, then `pip install -e .[test,ray]`
#  3. a Vulkan driver for SAPIEN when the machine has no usable Vulkan device
#     (scripts/vulkan.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
VENV=.venv
STAMP=$VENV/.gausstac-installed
# pip: no version nag, no "running as root" warning; -qq hides progress and warnings (the
# build backend's notices included) but still prints errors, with the failing build's output
export PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_ROOT_USER_ACTION=ignore
PIP=("$VENV/bin/python" -m pip install -qq)

if [ ! -x "$VENV/bin/python" ]; then
    echo "[setup] creating virtualenv $VENV"
    "$PY" -m venv "$VENV"
fi
if [ ! -f "$STAMP" ] || [ pyproject.toml -nt "$STAMP" ] || [ setup.py -nt "$STAMP" ]; then
    echo "[setup] installing torch==2.13.0 and gausstac_maniskill[test,ray] (about 2 minutes on a fresh machine)"
    "${PIP[@]}" --upgrade pip
    "${PIP[@]}" "torch==2.13.0"
    "${PIP[@]}" -e ".[test,ray]"
    touch "$STAMP"
fi

exec bash scripts/vulkan.sh "$VENV/bin/python"
