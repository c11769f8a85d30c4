"""The single ti.init: arch names, CUDA asked for on a machine without it, compile switches."""
import ast
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


@pytest.mark.parametrize("build, cfg, opt", [("", "False", "1"), ("fast", "False", "0"),
                                             ("taichi", "True", "1"), ("bogus", None, None)])
def test_compile_builds_reach_taichi(build, cfg, opt):
    """Guards the wiring of backend._compile_options (not physics): the product build turns
    Taichi's CFG pass off, ``GAUSSTAC_COMPILE=fast`` also its whole-kernel CSE (opt_level 0),
    ``taichi`` keeps Taichi's defaults, another value is refused by name; the offline cache
    may grow to 1 GiB. In a child process: Taichi starts once per process."""
    code = ("import taichi as ti\nfrom gausstac_maniskill import backend\n"
            "try:\n    backend.init('cpu')\nexcept backend.BackendError as e:\n    print('ERR', e)\n    raise SystemExit\n"
            "c = ti.lang.impl.current_cfg()\n"
            "print(c.cfg_optimization, c.opt_level, c.offline_cache_max_size_of_files)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "GAUSSTAC_COMPILE": build})
    if cfg is None:
        assert "ERR GAUSSTAC_COMPILE='bogus' is not one of" in out.stdout, out.stdout + out.stderr
    else:
        assert out.stdout.split()[-3:] == [cfg, opt, str(1 << 30)], out.stdout + out.stderr


_CORES = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1


@pytest.mark.skipif(_CORES < 2, reason="pinning needs a process that may use 2 or more cores")
@pytest.mark.parametrize("threads, pin, pinned", [(_CORES, "", True), (_CORES, "0", False), (1, "", False)])
def test_cpu_pool_workers_pinned_one_per_core(threads, pin, pinned):
    """Guards the wiring of cpu_pinning (not physics; the speed it buys is in BENCHMARKS.md): a
    pool with one worker per core has its workers pinned to distinct cores, all of them;
    ``GAUSSTAC_CPU_PIN=0`` or a smaller pool (process collection) leaves every thread free."""
    code = ("import os\nfrom gausstac_maniskill import backend\nbackend.init('cpu')\n"
            "print(sorted(tuple(sorted(os.sched_getaffinity(int(t)))) for t in os.listdir('/proc/self/task')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "GAUSSTAC_CPU_THREADS": str(threads), "GAUSSTAC_CPU_PIN": pin})
    masks = ast.literal_eval(out.stdout.strip().splitlines()[-1])
    single = sorted(m for m in masks if len(m) == 1)
    if pinned:
        assert single == sorted((c,) for c in os.sched_getaffinity(0)), out.stdout + out.stderr
    else:
        assert single == [], out.stdout + out.stderr
