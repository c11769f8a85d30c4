"""The single ti.init: arch names, CUDA asked for on a machine without it, compile switches."""
import os
import subprocess
import sys

import pytest

from gausstac_maniskill import backend
from gausstac_maniskill.errors import GaussTacError  # noqa: F401  (import check)


def test_unknown_arch_is_refused():
    with pytest.raises(backend.BackendError, match="vulkan"):
        backend.init("vulkan")


def test_cannot_switch_arch_after_init():
    assert backend.current_arch() == "cpu"
    assert backend.init("auto") == "cpu"
    if backend.current_arch() == "cpu":
        with pytest.raises(backend.BackendError, match="already initialised"):
            backend.init("cuda")


def test_cuda_request_on_cpu_machine_gives_clear_error():
    code = ("from gausstac_maniskill import backend\n"
            "try:\n    backend.init('cuda')\n    print('CUDA-OK')\n"
            "except backend.BackendError as e:\n    print('ERR', e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    if "CUDA-OK" in out.stdout:
        pytest.skip("this machine has CUDA")
    assert "ERR backend arch='cuda' was requested but no working CUDA device" in out.stdout, out.stdout + out.stderr
    assert "Traceback" not in out.stderr


@pytest.mark.parametrize("fast", ["", "1"])
def test_compile_switches_reach_taichi(fast):
    """Guards the wiring of backend._compile_options (not physics): Taichi's CFG pass is off,
    ``GAUSSTAC_FAST_COMPILE=1`` drops its whole-kernel CSE (opt_level 0), and the offline
    cache may grow to 1 GiB. Checked in a child process: Taichi starts once per process."""
    code = ("import taichi as ti\nfrom gausstac_maniskill import backend\nbackend.init('cpu')\n"
            "c = ti.lang.impl.current_cfg()\n"
            "print(c.cfg_optimization, c.opt_level, c.offline_cache_max_size_of_files)\n")
    env = {**os.environ, "GAUSSTAC_FAST_COMPILE": fast}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert out.stdout.split()[-3:] == ["False", "0" if fast else "1", str(1 << 30)], out.stdout + out.stderr
