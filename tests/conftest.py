"""Test-wide set-up: Taichi runs on the CPU (CI has no GPU), once per session, unless
``GAUSSTAC_TEST_ARCH=cuda`` asks for the CUDA backend (the GPU checks); tests that
need SAPIEN (ManiSkill envs, SAPIEN cameras) skip with the reason where it finds no Vulkan
device: mark them ``@pytest.mark.sapien`` (or a fixture takes ``sapien_vulkan``)."""
import functools
import os
import subprocess
import sys

import pytest

from gausstac_maniskill import backend, environment

_PROBE = "import sapien\nsapien.render.RenderSystem()\n"


@functools.lru_cache(maxsize=None)
def sapien_vulkan_device() -> tuple[bool, str]:
    """``(True, "")`` if SAPIEN can create its render system (it needs a Vulkan device even
    with ``render_backend='none'``), else ``(False, reason)``. Probed once per session, in a
    child process so that a failing Vulkan driver cannot disturb the tests' SAPIEN."""
    try:
        out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        return False, "SAPIEN's render system did not start within 120 s (Vulkan driver hangs)"
    if out.returncode == 0:
        return True, ""
    lines = [ln.strip() for ln in (out.stderr or out.stdout).splitlines() if ln.strip()]
    why = lines[-1] if lines else f"exit status {out.returncode}"
    return False, (f"SAPIEN finds no usable Vulkan device ({why}); `make setup` installs a CPU Vulkan "
                   "driver (Mesa lavapipe) where the distribution has one recent enough")


def _skip_without_vulkan() -> None:
    ok, reason = sapien_vulkan_device()
    if not ok:
        pytest.skip(reason)


@pytest.fixture(scope="session")
def sapien_vulkan() -> bool:
    """Skips the requesting test (or fixture) when SAPIEN has no Vulkan device."""
    _skip_without_vulkan()
    return True


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    if item.get_closest_marker("sapien") is not None:  # before any fixture (e.g. a module's env) is made
        _skip_without_vulkan()


@pytest.fixture(scope="session", autouse=True)
def compliance_cache(tmp_path_factory):
    """GaussTac's disk cache (the equilibrium pads' compliances, mesh SDFs, rigid cores) in a
    directory of this run's own: no test reads what an earlier run (or the user) left in ``~/.cache``. The run's pytest-xdist workers share
    it (their temporary folders' common parent; the cache writes each file atomically), so a
    pad shape's compliance is computed once per run, not once per worker."""
    old = os.environ.get("GAUSSTAC_CACHE")
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder = shared / "gausstac-cache"
    folder.mkdir(exist_ok=True)
    os.environ["GAUSSTAC_CACHE"] = str(folder)
    yield
    if old is None:
        os.environ.pop("GAUSSTAC_CACHE", None)
    else:
        os.environ["GAUSSTAC_CACHE"] = old


@pytest.fixture(scope="session", autouse=True)
def taichi_backend():
    backend.init(environment.read("GAUSSTAC_TEST_ARCH"))
    yield
