#!/usr/bin/env bash
# Packs what the lent GPU machine lacks (it has Python 3.12, torch, numpy, scipy, pytest, no
# internet) into .whl/site312.tar.xz, under the 64 MiB a device call may carry:
# Taichi (its C API dropped), mujoco, trimesh, rtree, plyfile, gymnasium, ..., and in place of
# mani_skill only its Allegro assets behind a stand-in __init__ (the real package imports
# SAPIEN, which does not fit beside Taichi). Nothing here runs ManiSkill or SAPIEN on the GPU.
# Then, from the device tool: run `bash scripts/gpu_check.sh` with carry [".whl"].
set -euo pipefail
cd "$(dirname "$0")/.."
site=$(mktemp -d)/site312
plat=(--python-version 3.12 --implementation cp --only-binary=:all: --platform any)
for p in manylinux1 manylinux2014 manylinux_2_17 manylinux_2_24 manylinux_2_27 manylinux_2_28 manylinux_2_31 \
         manylinux_2_34 manylinux_2_35; do plat+=(--platform "${p}_x86_64"); done
python3 -m pip install -q --no-deps --target "$site" "${plat[@]}" \
    taichi==1.7.4 dill mani_skill==3.0.1 mujoco==4.0.0 mujoco-core==4.0.0 trimesh rtree plyfile \
    pytorch-msssim gymnasium Farama-Notifications transforms3d dacite threadpoolctl
keep=$(mktemp -d)
cp -r "$site/mani_skill/assets/robots/allegro" "$keep/"
rm -rf "$site/mani_skill" "$site/taichi/_lib/c_api" "$site/taichi/examples" \
       "$site/mujoco/testdata" "$site/mujoco/usd" "$site/mujoco/sysid" "$site"/mujoco/*_test.py
mkdir -p "$site/mani_skill/assets/robots"
mv "$keep/allegro" "$site/mani_skill/assets/robots/"
cat > "$site/mani_skill/__init__.py" <<'PY'
# Device-only stand-in for mani_skill: the asset paths gausstac_maniskill.urdf reads.
from pathlib import Path
__version__ = "3.0.1"
PACKAGE_DIR = Path(__file__).parent.resolve()
PACKAGE_ASSET_DIR = PACKAGE_DIR / "assets"
PY
mkdir -p .whl
tar -C "$(dirname "$site")" -cf - site312 | xz -6 -T2 > .whl/site312.tar.xz
ls -l .whl/site312.tar.xz
