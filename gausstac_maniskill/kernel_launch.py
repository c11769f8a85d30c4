"""Launching a Taichi kernel thousands of times a second with less Python in between.

Every call of a ``@ti.kernel`` first derives the key of its compiled variant from all of its
arguments: Taichi 1.7 visits every ndarray of every argpack and builds its type. The MPM
substep's two kernels (``prepare`` and ``advance``) take about 80 ndarrays between them, and
on the 2-core CPU machine that look-up took a third of the Python time of a substep
(cProfile of GraspSqueezeSponge at ``mpm_dx = 3e-3``, where a substep's Python time equals
its kernels' time).

That key depends only on the values of the kernel's ``ti.template()`` arguments and on the
types of its ndarrays (direct, or members of argpacks). The look-up is also the only place
where Taichi checks each ndarray against its declared type (building an argpack checks
nothing). :class:`CachedKernel` therefore remembers the key for each tuple of template values
together with the very ndarrays and argpacks it was checked on (weak references: an array or a
pack that is rebuilt, e.g. when the grid grows, is a new object), and launches that compiled
variant directly while the same objects come back. The first call with new template values or
new arrays, and any call after Taichi was reset, takes the ordinary path, which compiles and
checks.

``mpm/kernels.py`` applies it to the kernels of every substep and every step. It uses three
members of Taichi's kernel object (``compiled_kernels``, ``ensure_compiled``,
``launch_kernel``), present throughout Taichi 1.7 (pinned in ``pyproject.toml``); where they
are missing it falls back to the ordinary call, as it does everywhere with
``GAUSSTAC_KERNEL_CACHE=0`` (or :data:`ENABLED` set False: the A/B of ``BENCHMARKS.md``).
"""
from __future__ import annotations

import functools
import os
import weakref

from taichi.lang import impl
from taichi.lang.argpack import ArgPackType
from taichi.types import primitive_types
from taichi.types.annotations import template
from taichi.types.ndarray_type import NdarrayType

__all__ = ["CachedKernel", "cached_kernel", "ENABLED"]

_MEMBERS = ("arguments", "compiled_kernels", "ensure_compiled", "launch_kernel")
#: False: every CachedKernel takes Taichi's ordinary call (``GAUSSTAC_KERNEL_CACHE=0``)
ENABLED = os.environ.get("GAUSSTAC_KERNEL_CACHE", "1") != "0"


class CachedKernel:
    """``kernel`` (a ``@ti.kernel`` function), called the same way, without re-deriving its
    compiled variant's key on every call. Only for kernels whose arguments are scalars,
    argpacks, ndarrays declared with their dtype and ndim, and ``ti.template()`` values
    (checked here)."""

    def __init__(self, kernel):
        self.kernel = kernel
        functools.update_wrapper(self, kernel)
        primal = getattr(kernel, "_primal", None)
        if primal is None or not all(hasattr(primal, m) for m in _MEMBERS):
            self._primal = None  # another Taichi: the ordinary call only
            return
        self._primal = primal
        self._templates = tuple(i for i, a in enumerate(primal.arguments) if isinstance(a.annotation, template))
        for a in primal.arguments:
            ann = a.annotation
            typed = isinstance(ann, NdarrayType) and ann.dtype is not None and ann.ndim is not None
            if not (typed or isinstance(ann, (template, ArgPackType)) or id(ann) in primitive_types.type_ids):
                raise TypeError(f"CachedKernel({kernel.__name__}): argument {a.name!r} is a "
                                f"{type(ann).__name__} without a fixed type; only scalars, argpacks, "
                                "ndarrays of a declared dtype and ndim, and templates have a key fixed by "
                                "their declaration")
        self._arrays = tuple(i for i, a in enumerate(primal.arguments)
                             if isinstance(a.annotation, (ArgPackType, NdarrayType)))
        # template values -> (weak references to the arrays and packs checked with them, compiled variant's key)
        self._keys: dict[tuple, tuple] = {}

    def __call__(self, *args):
        primal = self._primal
        if primal is None or not ENABLED:
            return self.kernel(*args)
        values = tuple(args[i] for i in self._templates)
        seen = self._keys.get(values)
        compiled = None
        if seen is not None and all(ref() is args[i] for ref, i in zip(seen[0], self._arrays)):
            compiled = primal.compiled_kernels.get(seen[1])  # None once Taichi was reset
        if compiled is None:  # the ordinary call: compiles if need be, checks every ndarray
            out = self.kernel(*args)
            self._keys[values] = (tuple(weakref.ref(args[i]) for i in self._arrays), primal.ensure_compiled(*args))
            return out
        impl.get_runtime().materialize()  # as every kernel call does: fields defined since then
        return primal.launch_kernel(compiled, *args)


def cached_kernel(kernel) -> CachedKernel:
    """Decorator form of :class:`CachedKernel` (under ``@ti.kernel``)."""
    return CachedKernel(kernel)
