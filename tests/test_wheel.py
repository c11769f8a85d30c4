"""The built wheel: it ships every module and asset of the source tree, and a task steps from it
installed in a scratch folder, run from outside the source tree."""
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAPPED = ("agents", "tasks", "assets")  # top-level folders installed inside the package
ASSET_SUFFIXES = {".ply", ".json", ".obj", ".stl", ".glb", ".urdf", ".png"}
SKIP = shutil.ignore_patterns(".venv", ".git", "out", "build", "*.egg-info", "__pycache__", ".pytest_cache", "tests")


def expected_files() -> set[str]:
    """The paths the wheel must hold: every .py of the package and of the mapped folders, and the assets."""
    files = {p.relative_to(ROOT).as_posix() for p in (ROOT / "gausstac_maniskill").rglob("*.py")}
    for folder in MAPPED:
        for p in (ROOT / folder).rglob("*"):
            if p.suffix == ".py" or (folder == "assets" and p.suffix in ASSET_SUFFIXES and p.parent != ROOT / folder):
                files.add(f"gausstac_maniskill/{p.relative_to(ROOT).as_posix()}")
    return {f for f in files if "__pycache__" not in f}


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel built from a copy of the source tree, with the virtualenv's setuptools."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=SKIP)
    out = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                          "-w", str(tmp / "dist"), str(src)], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr
    (whl,) = (tmp / "dist").glob("gausstac_maniskill-*.whl")
    return whl


def test_wheel_ships_every_module_and_asset(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = sorted(expected_files() - names)
    assert not missing, f"the wheel lacks {len(missing)} files, e.g. {missing[:5]}"
    assert "gausstac_maniskill/fem/__init__.py" in names  # the default pad solver


@pytest.mark.sapien
def test_installed_wheel_runs_a_task_step_outside_the_source_tree(wheel, tmp_path):
    site = tmp_path / "site"
    out = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site), str(wheel)],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    code = (
        "import gymnasium as gym, torch, gausstac_maniskill as g\n"
        f"assert g.__file__.startswith({str(site)!r}), g.__file__\n"
        "env = gym.make('GaussTac-PressCube-v1', sim_backend='physx_cpu', obs_mode='state_dict')\n"
        "env.reset(seed=0)\n"
        "obs, reward, *_ = env.step(torch.zeros(env.action_space.shape))\n"
        "print(tuple(obs['tactile']['index']['force'].shape), bool(torch.isfinite(reward).all()))\n")
    env = {**os.environ, "PYTHONPATH": str(site)}
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.split("\n")[-2] == "(1, 16, 16) True", run.stdout
