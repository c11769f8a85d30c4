"""Launching a Taichi kernel thousands of times a second with less Python in between.

Each ``@ti.kernel`` call derives the key of its compiled variant from all its arguments (Taichi 1.7
visits every ndarray of every argpack), and that look-up is the only place Taichi checks each ndarray
against its declared type. The key depends only on the ``ti.template()`` values and the ndarrays'
types, so :class:`CachedKernel` remembers it per tuple of template values together with the very
ndarrays and argpacks it was checked on (weak references: a rebuilt array, e.g. when the grid grows,
is a new object), and launches that variant directly, filling a fresh launch context from a plan
made once (``CachedKernel._plan``). New template values, new arrays or a Taichi reset take the
ordinary call, which compiles and checks. A context is never reused: a launch rewrites the arrays'
entries in place. It relies on Taichi 1.7 kernel internals (pinned in ``pyproject.toml``) and falls
back to the ordinary call where they are missing. ``GAUSSTAC_KERNEL_CACHE=0`` (:data:`ENABLED`)
turns it off; ``GAUSSTAC_KERNEL_ARGS=taichi`` (:data:`LEAN_ARGS`) lets Taichi set the arguments.
The ``ND*`` names are the ndarray argument types the kernels of both pad solvers share.
"""
from __future__ import annotations

import functools
import weakref

import taichi as ti
from taichi._lib import core as _ti_core
from taichi.lang import impl, runtime_ops
from taichi.lang.argpack import ArgPackType
from taichi.lang.util import cook_dtype
from taichi.types import primitive_types
from taichi.types.annotations import template
from taichi.types.ndarray_type import NdarrayType
from taichi.types.utils import is_signed

from . import environment

__all__ = ["CachedKernel", "cached_kernel", "ENABLED", "NDI", "NDI2", "NDF", "NDF2", "NDV", "NDM"]

# ndarray argument types shared by the kernels of every module
NDI = ti.types.ndarray(dtype=ti.i32, ndim=1)  #: int32 [N]
NDI2 = ti.types.ndarray(dtype=ti.i32, ndim=2)  #: int32 [N, M]
NDF = ti.types.ndarray(dtype=ti.f32, ndim=1)  #: float32 [N]
NDF2 = ti.types.ndarray(dtype=ti.f32, ndim=2)  #: float32 [N, M]
NDV = ti.types.ndarray(dtype=ti.math.vec3, ndim=1)  #: float32 3-vectors [N, 3]
NDM = ti.types.ndarray(dtype=ti.math.mat3, ndim=1)  #: float32 3x3 matrices [N, 3, 3]

_LCB = _ti_core.KernelLaunchContext  # Taichi's launch context builder (set_arg_* methods)

_MEMBERS = ("arguments", "compiled_kernels", "ensure_compiled", "launch_kernel")
#: False: every CachedKernel takes Taichi's ordinary call (``GAUSSTAC_KERNEL_CACHE=0``)
ENABLED = environment.read("GAUSSTAC_KERNEL_CACHE") != "0"
#: False: the fast path sets the arguments through Taichi's own ``launch_kernel`` (``GAUSSTAC_KERNEL_ARGS=taichi``)
LEAN_ARGS = environment.read("GAUSSTAC_KERNEL_ARGS") != "taichi"


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
        # argument index -> its slot in the launch context (templates take none)
        self._slot = {i: n for n, i in enumerate(i for i in range(len(primal.arguments)) if i not in self._templates)}
        # the scalars, set on every launch: (argument index, slot, the context's setter, the cast it takes)
        self._scalars = tuple((i, (self._slot[i],)) + _scalar_setter(a.annotation)
                              for i, a in enumerate(primal.arguments) if id(a.annotation) in primitive_types.type_ids)
        # template values -> [weak references to the arrays and packs checked with them, compiled variant's
        # key, plan of their launch-context slots (made on the first fast launch)]
        self._keys: dict[tuple, list] = {}

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
            self._keys[values] = [tuple(weakref.ref(args[i]) for i in self._arrays), primal.ensure_compiled(*args),
                                  None]
            return out
        impl.get_runtime().materialize()  # as every kernel call does: fields defined since then
        if seen[2] is None:
            seen[2] = self._plan(args)
        if not LEAN_ARGS or seen[2] is False:
            return primal.launch_kernel(compiled, *args)
        # a launch context takes the arrays' addresses afresh each time (the launch rewrites them in
        # place), but from the plan: no type dispatch per argument as in Taichi's launch_kernel
        ctx = compiled.make_launch_context()
        for setter, idx, obj in seen[2]:
            setter(ctx, idx, obj)
        for i, slot, setter, cast in self._scalars:
            setter(ctx, slot, cast(args[i]))
        prog = impl.get_runtime().prog
        prog.launch_kernel(prog.compile_kernel(prog.config(), prog.get_device_caps(), compiled), ctx)
        ret_types = primal.return_type
        if ret_types is None and not primal.has_print:
            return None
        runtime_ops.sync()
        if ret_types is None:
            return None
        ret = [primal.construct_kernel_ret(ctx, t, (k,)) for k, t in enumerate(ret_types)]
        return ret[0] if len(ret) == 1 else ret

    def _plan(self, args) -> list | bool:
        """How to put ``args``' arrays and packs into a launch context, as Taichi 1.7's
        ``Kernel.launch_kernel`` lays them out: one slot per non-template argument in order (an
        argpack's own slot holds its buffer, with its nested packs under it), then the ndarrays
        found inside argpacks, in the order met, in slots after the last argument. Rows
        (setter, slot, C++ object); scalars are set on each launch. False where an array has a
        gradient (Taichi's launch sets those)."""
        plan, inside = [], []
        for i, a in enumerate(self._primal.arguments):
            ann, v = a.annotation, args[i]
            if isinstance(ann, ArgPackType):
                _plan_pack(plan, (self._slot[i],), ann, v, inside)
            elif isinstance(ann, NdarrayType):
                plan.append((_LCB.set_arg_ndarray, (self._slot[i],), v))
        plan += [(_LCB.set_arg_ndarray, (len(self._slot) + k,), arr) for k, arr in enumerate(inside)]
        if any(setter is _LCB.set_arg_ndarray and arr.grad is not None for setter, _, arr in plan):
            return False
        return [(setter, idx, arr.arr if setter is _LCB.set_arg_ndarray else arr) for setter, idx, arr in plan]


def _plan_pack(plan, idx, ann, pack, inside):
    j = 0
    for name, member in ann.members.items():
        if isinstance(member, ArgPackType):
            _plan_pack(plan, idx + (j,), member, pack[name], inside)
            j += 1
        elif isinstance(member, NdarrayType):
            inside.append(pack[name])  # no slot inside the pack
        else:
            j += 1  # scalars and matrices live in the pack's own buffer
    plan.append((_LCB.set_arg_argpack, idx, pack._ArgPack__argpack))


def _scalar_setter(ann) -> tuple:
    """(the launch context's setter, the Python cast it takes) for a scalar argument of type ``ann``."""
    if id(ann) in primitive_types.real_type_ids:
        return _LCB.set_arg_float, float
    return (_LCB.set_arg_int if is_signed(cook_dtype(ann)) else _LCB.set_arg_uint), int


def cached_kernel(kernel) -> CachedKernel:
    """Decorator form of :class:`CachedKernel` (under ``@ti.kernel``)."""
    return CachedKernel(kernel)
