"""Every environment variable GaussTac reads, read here and nowhere else.

The variables, their defaults (the value read where one is not set) and what they do
(:data:`VARIABLES`; the table below is made from it):

{table}

:func:`read` returns a variable's value at the time of the call (so a test may change
``os.environ`` while running), its default where it is not set; a name missing from
:data:`VARIABLES` is refused, so that every variable read is listed. Values are interpreted
by the module that uses them. :func:`write` and :func:`write_default` set a variable for this
process and the processes it starts; :func:`child_environ` is a child process's environment
with some variables set.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Mapping

__all__ = ["Variable", "VARIABLES", "read", "write", "write_default", "child_environ"]


@dataclass(frozen=True)
class Variable:
    """One environment variable: its ``name``, the value read where it is not set, what it does."""

    name: str
    default: str
    meaning: str


#: Every environment variable read by the package (and by the test suite), by name.
VARIABLES: Mapping[str, Variable] = {v.name: v for v in (
    Variable("GAUSSTAC_ARCH", "auto",
             "Taichi arch of backend.ensure_init and of the command lines' --arch: cpu, cuda or auto "
             "(CUDA where it works, else the CPU)."),
    Variable("GAUSSTAC_COMPILE", "",
             "Taichi build (backend): empty the product build (CFG pass off), fast also opt_level=0, "
             "taichi Taichi's own defaults."),
    Variable("GAUSSTAC_CPU_THREADS", "0",
             "Threads of Taichi's CPU pool and of BLAS between kernels; 0: every CPU of the affinity set. "
             "Process collection sets it for its workers (collect)."),
    Variable("GAUSSTAC_CPU_PIN", "1",
             "0 leaves Taichi's CPU workers unpinned (cpu_pinning); anything else pins one per core."),
    Variable("GAUSSTAC_KERNEL_PROFILER", "",
             "1 turns Taichi's kernel profiler on (bench kernels sets it)."),
    Variable("GAUSSTAC_KERNEL_CACHE", "1",
             "0: every kernel_launch.CachedKernel takes Taichi's ordinary call (read at import)."),
    Variable("GAUSSTAC_KERNEL_ARGS", "lean",
             "taichi: the cached launch sets its arguments through Taichi's own launch_kernel "
             "(read at import)."),
    Variable("GAUSSTAC_SCATTER", "",
             "How the MPM scatters particles to the grid: atomic or slabs; empty: atomic on CUDA, "
             "slabs on the CPU."),
    Variable("GAUSSTAC_CACHE", "",
             "Root folder of the disk cache (cache); off (or 0): no cache is written; empty: "
             "$XDG_CACHE_HOME/gausstac_maniskill."),
    Variable("XDG_CACHE_HOME", "",
             "The user's cache folder (freedesktop.org); empty: ~/.cache."),
    Variable("GAUSSTAC_TEST_ARCH", "cpu",
             "Taichi arch of the test suite (tests/conftest.py): cpu or cuda."),
    Variable("DISPLAY", "",
             "The X11 display; with neither it nor WAYLAND_DISPLAY set, Linux has no window for "
             "render_mode='human' (the tasks refuse it)."),
    Variable("WAYLAND_DISPLAY", "",
             "The Wayland display (see DISPLAY)."),
)}


def _known(name: str) -> Variable:
    try:
        return VARIABLES[name]
    except KeyError:
        raise KeyError(f"{name!r} is not an environment variable of gausstac_maniskill.environment.VARIABLES "
                       f"({', '.join(VARIABLES)}): add it there") from None


def read(name: str) -> str:
    """The value of environment variable ``name`` now, or its default where it is not set."""
    return os.environ.get(name, _known(name).default)


def write(name: str, value: str) -> None:
    """Set ``name`` to ``value`` for this process and the processes it starts."""
    _known(name)
    os.environ[name] = value


def write_default(name: str, value: str) -> str:
    """Set ``name`` to ``value`` where it is not set yet; its value afterwards."""
    _known(name)
    return os.environ.setdefault(name, value)


def child_environ(**values: str) -> dict[str, str]:
    """This process's environment with ``values`` (``NAME=value``, any variable, Taichi's
    too) set: the ``env`` of a child process."""
    return {**os.environ, **values}


def _table() -> str:
    """:data:`VARIABLES` as a reStructuredText table (the module docstring's)."""
    rows = [(f"``{v.name}``", f"``{v.default}``" if v.default else "(empty)", v.meaning) for v in VARIABLES.values()]
    widths = [max(len(r[i]) for r in rows + [("Variable", "Default", "Meaning")]) for i in range(3)]
    rule = "  ".join("=" * w for w in widths)
    line = lambda r: "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip()  # noqa: E731
    return "\n".join([rule, line(("Variable", "Default", "Meaning")), rule, *map(line, rows), rule])


__doc__ = __doc__.replace("{table}", _table())
