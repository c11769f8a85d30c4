"""The single ti.init: arch names, and CUDA asked for on a machine without it."""
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
