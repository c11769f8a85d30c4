"""The one place that initialises Taichi.

``init("cpu" | "cuda" | "auto")`` picks the compute backend once per process.
``auto`` means CUDA when a CUDA device works, otherwise the CPU; never Vulkan or
Metal by accident (``ti.init(arch=ti.gpu)`` silently picks Vulkan on a machine
without CUDA, which is why we never pass ``ti.gpu``).

The architecture can also be chosen with the environment variable
``GAUSSTAC_ARCH`` (same values), which ``ensure_init()`` reads (every variable read here:
:mod:`~gausstac_maniskill.environment`).

Compile time. Taichi compiles each variant of a kernel on its first launch and keeps it in
its offline cache (``~/.cache/taichi``), so only a machine's first run pays. Two of Taichi's
whole-kernel passes cost most of that on our substep kernel: its CFG optimisation (store
forwarding and dead stores across the kernel) and its whole-kernel common subexpression
elimination (``opt_level >= 1``). The CFG pass is off here, which costs the compiled steps
nothing measurable. ``GAUSSTAC_COMPILE`` chooses another build: ``fast`` also sets
``opt_level=0`` (``make test`` and ``make demo`` use it: a far shorter first step, slightly
slower steps after it) and ``taichi`` keeps Taichi's own defaults. Builds differ by float
rounding only. ``bench compile`` measures each build's first step and step time.
"""
from __future__ import annotations

import atexit
import os
import threading
from typing import Callable

import taichi as ti

from . import environment
from .cpu_pinning import pin_taichi_workers, thread_ids

__all__ = ["BackendError", "init", "ensure_init", "current_arch", "torch_device", "is_initialized", "before_shutdown",
           "cpu_share", "cpu_threads"]

_VALID = ("cpu", "cuda", "auto")
_BUILDS = ("", "fast", "taichi")  # GAUSSTAC_COMPILE: the product build, make test's, Taichi's defaults
_lock = threading.Lock()
_arch: str | None = None
_before_shutdown: list[Callable[[], None]] = []


def before_shutdown(fn: Callable[[], None]) -> Callable[[], None]:
    """Register ``fn`` to run at interpreter exit just before Taichi is shut down (free what
    holds Taichi objects there); usable as a decorator."""
    _before_shutdown.append(fn)
    return fn


def _shutdown() -> None:
    """Shut Taichi down explicitly at exit. Taichi writes its offline kernel cache
    (``~/.cache/taichi``) when its program is destroyed, which the interpreter's teardown
    does not do in a process that built a ManiSkill env: every such process recompiled the
    MPM kernels (measured: 67 s for the one-field substep, 70 s more for the two-field one
    on the 2-core CPU machine, instead of loading them in a few seconds)."""
    for fn in _before_shutdown:
        fn()
    if _arch is not None:
        ti.reset()


class BackendError(RuntimeError):
    """Raised when the requested compute backend cannot be used."""


def _taichi_arch_name() -> str:
    arch = ti.lang.impl.current_cfg().arch
    return "cuda" if arch == ti.cuda else ("cpu" if arch in (ti.x64, ti.arm64) else str(arch))


def _profiler_on() -> bool:
    """``GAUSSTAC_KERNEL_PROFILER=1`` turns Taichi's kernel profiler on (``bench kernels``)."""
    return environment.read("GAUSSTAC_KERNEL_PROFILER") == "1"


def _compile_options() -> dict:
    """Taichi compiler settings of every ``ti.init`` here (module docstring, "Compile time").

    The offline cache may hold 1 GiB: Taichi's 100 MB default evicts a quarter of its
    entries at exit once full, and the test suite's variants alone take 34 MB per build."""
    build = environment.read("GAUSSTAC_COMPILE")
    if build not in _BUILDS:
        raise BackendError(f"GAUSSTAC_COMPILE={build!r} is not one of {_BUILDS} (unset: the product build)")
    opts = dict(offline_cache=True, offline_cache_max_size_of_files=1 << 30, kernel_profiler=_profiler_on())
    if build != "taichi":
        opts["cfg_optimization"] = False
    if build == "fast":
        opts["opt_level"] = 0
    return opts


def _try_cuda(seed: int, debug: bool, opts: dict) -> bool:
    """Initialise Taichi on CUDA; return False (and reset) if CUDA does not work.

    ``enable_fallback=False``: without CUDA, ``ti.init`` raises before it starts (and
    prints "[Taichi] Starting on arch=...") instead of starting on the CPU, which we would
    reset and start again: one start-up line per process."""
    try:
        ti.init(arch=ti.cuda, default_fp=ti.f32, random_seed=seed, debug=debug,
                log_level=ti.ERROR, enable_fallback=False, **opts)
    except Exception:  # noqa: BLE001 - any CUDA failure means "no CUDA here"
        ti.reset()
        return False
    if _taichi_arch_name() != "cuda":
        ti.reset()
        return False
    return True


def init(arch: str = "auto", *, seed: int = 0, debug: bool = False) -> str:
    """Initialise Taichi once for this process and return the arch in use.

    Args:
        arch: ``"cpu"``, ``"cuda"`` or ``"auto"`` (CUDA if it works, else CPU).
        seed: Taichi's random seed (``ti.random``), for reproducible runs.
        debug: Taichi debug mode (bounds checks; slow).

    Returns:
        ``"cpu"`` or ``"cuda"``.

    Raises:
        BackendError: ``arch`` is not one of the three names; ``"cuda"`` was asked
            for on a machine where CUDA does not work; or Taichi was already
            initialised on a different arch (re-initialising would silently
            destroy every existing Taichi field).
    """
    global _arch
    if not isinstance(arch, str) or arch.lower() not in _VALID:
        raise BackendError(f"backend arch={arch!r} is not one of {_VALID}")
    arch = arch.lower()
    with _lock:
        if _arch is not None:
            if arch in ("auto", _arch):
                return _arch
            raise BackendError(
                f"Taichi is already initialised on {_arch!r}; cannot switch to {arch!r} "
                "in the same process (it would destroy all simulation state). "
                "Choose the arch once, before creating any simulator.")
        opts = _compile_options()  # before any start: a bad GAUSSTAC_COMPILE is named, not taken for "no CUDA"
        if arch in ("cuda", "auto"):
            if _try_cuda(seed, debug, opts):
                _arch = "cuda"
                return _arch
            if arch == "cuda":
                raise BackendError(
                    "backend arch='cuda' was requested but no working CUDA device was "
                    "found (Taichi could not start its CUDA backend). Use arch='cpu' or "
                    "arch='auto', or set GAUSSTAC_ARCH=cpu.")
        cpu_threads = cpu_share()
        kwargs = dict(arch=ti.cpu, default_fp=ti.f32, random_seed=seed, debug=debug,
                      log_level=ti.WARN, **opts)
        if cpu_threads:
            kwargs["cpu_max_num_threads"] = cpu_threads
        before = thread_ids()
        ti.init(**kwargs)
        _arch = "cpu"
        pin_taichi_workers(before, ti.lang.impl.current_cfg().cpu_max_num_threads)
        return _arch


atexit.register(_shutdown)  # at import: it then runs after whatever registers later (LIFO)


def cpu_share() -> int | None:
    """This process's share of the CPU in threads, ``GAUSSTAC_CPU_THREADS`` (a collection worker
    sets it: :mod:`~gausstac_maniskill.collect`); None where not set."""
    return int(environment.read("GAUSSTAC_CPU_THREADS")) or None


def cpu_threads() -> int:
    """Threads this process's host work may run on at once (BLAS's, between Taichi kernels):
    :func:`cpu_share` where set, else every CPU of its affinity set."""
    share = cpu_share()
    if share:
        return share
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


_BLAS = None


def blas_threads(n: int):
    """Context: BLAS (OpenBLAS, MKL) on ``n`` threads inside it (threadpoolctl, with one
    controller for the process: entering costs microseconds, a fresh ``threadpool_limits``
    re-reads the loaded libraries each time)."""
    global _BLAS
    if _BLAS is None:
        import scipy.linalg  # noqa: F401 (SciPy's own BLAS loaded first, so that the controller sees it)
        from threadpoolctl import ThreadpoolController

        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=int(n), user_api="blas")


def ensure_init() -> str:
    """Initialise with ``$GAUSSTAC_ARCH`` (default ``auto``) unless already done."""
    if _arch is not None:
        return _arch
    return init(environment.read("GAUSSTAC_ARCH"))


def current_arch() -> str | None:
    """The arch chosen by :func:`init`, or ``None`` before initialisation."""
    return _arch


def torch_device() -> str:
    """The torch device of the Taichi arch in use (``"cuda"`` or ``"cpu"``; initialises Taichi
    with :func:`ensure_init` if needed): where kernels that write torch tensors put them."""
    return "cuda" if ensure_init() == "cuda" else "cpu"


def is_initialized() -> bool:
    """Whether :func:`init` has run in this process."""
    return _arch is not None
