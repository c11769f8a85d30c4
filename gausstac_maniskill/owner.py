"""A part's reference back to the object that owns it (:class:`Owner`), held weakly.

A co-simulator owns its pad solvers and its splat scene, and each of them reads the
co-simulator back. With strong references both ways every co-simulator is a reference cycle,
which only Python's cyclic collector frees; an env rebuilds its co-simulators at every reset, so
their arrays would pile up between the collector's passes (megabytes per reset).
"""
from __future__ import annotations

import weakref

from .errors import GaussTacError

__all__ = ["Owner"]


class Owner:
    """A descriptor for a part's attribute that names its owner: set as usual
    (``self.scene = scene``), stored as a weak reference (a strong one for objects that allow
    none), read back as the owner itself, and a :class:`GaussTacError` once the owner is gone."""

    def __set_name__(self, cls, name: str) -> None:
        self.name, self.slot = name, f"_{name}_ref"

    def __get__(self, obj, cls=None):
        if obj is None:
            return self
        target = obj.__dict__[self.slot]()
        if target is None:
            raise GaussTacError(f"{type(obj).__name__}.{self.name}: the object that owned it was deleted "
                                f"(a {type(obj).__name__} lives as long as its owner)")
        return target

    def __set__(self, obj, value) -> None:
        try:
            ref = weakref.ref(value)
        except TypeError:  # no weak references to it (__slots__ without __weakref__, a builtin)
            def ref():
                return value
        obj.__dict__[self.slot] = ref
