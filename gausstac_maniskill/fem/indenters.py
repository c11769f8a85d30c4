"""Rigid colliders as an elastic body sees them, in the body's frame (SI units).

An :class:`Indenter` is one collider: its signed distance φ [m] (negative inside) and outward
unit normal in its own frame, its pose [4, 4] (its frame in the body's) and its Coulomb
coefficient μ; the pose holds a stuck point's place on it. :class:`Indenters` is several at
once: each surface point meets the nearest (smallest φ), which owns its friction hold.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import ConfigError

__all__ = ["Indenter", "Indenters"]


@dataclass
class Indenter:
    """A rigid collider as a body sees it, for contact with friction (which needs the
    collider's frame to hold a stuck point's place on it).

    Attributes:
        local_sdf: ``local_sdf(q)`` for points q [k, 3] in the collider's own frame returns
            (φ [k] m, negative inside; outward unit normal [k, 3] in that frame).
        pose: [4, 4] the collider's frame in the body's frame [m].
        friction: Coulomb coefficient μ ≥ 0.
    """

    local_sdf: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    pose: np.ndarray
    friction: float = 0.0

    def __post_init__(self) -> None:
        self.pose = np.asarray(self.pose, float)
        if self.pose.shape != (4, 4):
            raise ConfigError(f"Indenter.pose has shape {self.pose.shape}, expected (4, 4)")
        if not np.isfinite(self.friction) or self.friction < 0:
            raise ConfigError(f"Indenter.friction={self.friction!r} must be a finite number >= 0")

    def to_local(self, x: np.ndarray) -> np.ndarray:
        return (x - self.pose[:3, 3]) @ self.pose[:3, :3]

    def to_body(self, q: np.ndarray) -> np.ndarray:
        return q @ self.pose[:3, :3].T + self.pose[:3, 3]

    def __call__(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        phi, n = self.local_sdf(self.to_local(x))
        return phi, n @ self.pose[:3, :3].T


class Indenters:
    """Several rigid colliders touching one body at once (a fingertip on an object that rests
    on a table). The contact conditions are read on their union: each surface point meets the
    one it is nearest to (smallest signed distance). Its friction hold is kept on its *owner*:
    the nearest where the solve starts (:meth:`assign`), the nearest at the end for the next
    solve (:meth:`reassign`; a hold moves to the new owner's frame where it changed).

    Args:
        indenters: ``{key: Indenter}``; the keys name the colliders (kept in results, so that
            a point's hold carries over from one solve to the next only on the same collider).

    Attributes:
        keys: the colliders' keys, in order; ``pose`` [C, 4, 4] their frames in the body's;
        ``mu`` [C] their friction coefficients; ``friction`` the largest; ``owner`` [S] int
        each point's collider (index into ``keys``), set by :meth:`assign`.
    """

    def __init__(self, indenters):
        if isinstance(indenters, Indenter):
            indenters = {None: indenters}
        if not len(indenters):
            raise ConfigError("Indenters: no collider")
        self.keys = tuple(indenters)
        self.items = [indenters[k] for k in self.keys]
        self.pose = np.stack([i.pose for i in self.items])
        self.mu = np.array([float(i.friction) for i in self.items])
        self.friction = float(self.mu.max())
        self.owner = None

    def _union(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(nearest collider [S] int, φ [S], normal [S, 3] body frame) of the points ``x`` [S, 3]."""
        phis, normals = zip(*(i(x) for i in self.items))
        k, rows = np.argmin(np.stack(phis), axis=0), np.arange(len(x))
        return k, np.stack(phis)[k, rows], np.stack(normals)[k, rows]

    def nearest(self, x: np.ndarray) -> np.ndarray:
        """[S] int: the collider nearest each of the points ``x`` [S, 3] (body frame)."""
        if len(self.items) == 1:
            return np.zeros(len(x), np.int64)
        return self._union(x)[0]

    def assign(self, x: np.ndarray) -> None:
        """Each of the points ``x`` [S, 3] (body frame) to the collider nearest it."""
        self.owner = self.nearest(x)

    def reassign(self, x: np.ndarray, local: np.ndarray) -> np.ndarray:
        """Each of the points ``x`` [S, 3] to the collider nearest it now; returns ``local``
        [S, 3] (points given in their old owner's frame, e.g. holds) in the new owner's."""
        body = self.to_body(local)
        self.owner = self.nearest(x)
        return self.to_local(body)

    def _groups(self):
        for c in range(len(self.items)):
            sel = np.flatnonzero(self.owner == c)
            if len(sel):
                yield c, sel

    def to_local(self, x: np.ndarray, pose: np.ndarray | None = None) -> np.ndarray:
        """Each point of ``x`` [S, 3] in its owner's frame (at ``pose`` [C, 4, 4], default: now)."""
        pose = self.pose if pose is None else pose
        if len(self.items) == 1:
            return Indenter(self.items[0].local_sdf, pose[0]).to_local(x)
        P = pose[self.owner]
        return np.einsum("si,sij->sj", x - P[:, :3, 3], P[:, :3, :3])

    def to_body(self, q: np.ndarray) -> np.ndarray:
        """Each point ``q`` [S, 3] given in its owner's frame, in the body frame."""
        if len(self.items) == 1:
            return self.items[0].to_body(q)
        P = self.pose[self.owner]
        return np.einsum("sij,sj->si", P[:, :3, :3], q) + P[:, :3, 3]

    def local_sdf(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """φ [S] and outward normal [S, 3] of each point ``q`` [S, 3] on its owner, in its frame."""
        if len(self.items) == 1:
            return self.items[0].local_sdf(q)
        phi, n = np.zeros(len(q)), np.zeros((len(q), 3))
        for c, sel in self._groups():
            phi[sel], n[sel] = self.items[c].local_sdf(q[sel])
        return phi, n

    def __call__(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """φ [S] and outward normal [S, 3] (body frame) of the points ``x`` [S, 3] on the
        colliders' union: each on the one nearest it (whatever its owner)."""
        if len(self.items) == 1:
            return self.items[0](x)
        return self._union(x)[1:]

    def point_friction(self) -> np.ndarray:
        """[S] each point's friction coefficient (its owner's)."""
        return self.mu[self.owner]
