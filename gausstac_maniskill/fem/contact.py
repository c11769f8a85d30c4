"""Frictionless contact of a linear elastic body with a rigid collider, at equilibrium.

The body (:mod:`.hex`) is held by its fixed degrees of freedom and touched only at its
surface points. A force f_d at point d moves point s by W_sd f_d, where W = N K⁻¹ Nᵀ is the
body's compliance at its surface points (N: trilinear interpolation, K: the stiffness with
the fixed degrees of freedom removed). The contact problem is then one on the points near
the collider (Signorini's conditions, linearised at the present surface):

    λ ≥ 0,   g = φ + Σ_d (n_s · W_sd n_d) λ_d ≥ 0,   λ · g = 0,

with φ the collider's signed distance at each point, n its outward normal there and λ the
normal force. It is solved exactly (:func:`solve_lcp`), the surface moved, φ and n read
again, until the surface stops moving. K is factored once; W's column for a point is
computed by three solves the first time the point comes near a collider, and kept, so a
press or a slide costs solves only for the points it reaches.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import ConfigError, SimulationError
from .hex import VoxelBody, dissection_order, stiffness, trilinear

__all__ = ["QuasiStaticBody", "ContactResult", "solve_lcp"]

#: Points whose compliance columns are solved together (one multi-right-hand-side solve).
COLUMN_BATCH = 32


def solve_lcp(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """λ ≥ 0 with Aλ + b ≥ 0 and λ · (Aλ + b) = 0, for a symmetric positive definite ``A``
    [m, m]: the minimiser of ½ λᵀAλ + bᵀλ over λ ≥ 0, solved as the non-negative least
    squares problem min |Lᵀλ + L⁻¹b| (A = LLᵀ) by Lawson and Hanson's active-set method
    (finite, exact up to rounding)."""
    from scipy.linalg import cholesky, solve_triangular
    from scipy.optimize import nnls

    b = np.asarray(b, float)
    if not len(b):
        return np.zeros(0)
    A = 0.5 * (A + A.T)
    L = cholesky(A + 1e-12 * np.trace(A) / len(b) * np.eye(len(b)), lower=True)
    lam, _ = nnls(L.T, -solve_triangular(L, b, lower=True), maxiter=50 * len(b))
    return lam


@dataclass
class ContactResult:
    """Equilibrium under one collider (body frame, SI units).

    Attributes:
        force: [S, 3] force [N] the collider exerts on the body at each surface point.
        displacement: [S, 3] displacement [m] of each surface point.
        gap: [S] signed distance [m] from each displaced point to the collider.
        iterations: outer iterations (surface moved, φ and n read again).
        candidates: points taken into the complementarity problem.
    """

    force: np.ndarray
    displacement: np.ndarray
    gap: np.ndarray
    iterations: int
    candidates: int

    @property
    def total_force(self) -> np.ndarray:
        """[3] resultant force [N] on the body."""
        return self.force.sum(0)


class QuasiStaticBody:
    """A linear elastic :class:`VoxelBody` held by its fixed degrees of freedom, touched at
    surface points, solved at equilibrium (no inertia, no time step).

    Args:
        body: the elements.
        E: Young's modulus [Pa]; nu: Poisson's ratio, in (−1, 0.5).
        fixed: [V, 3] bool (or [V] for all three), the degrees of freedom held at zero
            displacement (a bond to a rigid base or link, a symmetry plane).
        points: [S, 3] rest positions [m] of the surface points contact may act on.
        point_elements: [S] element each point is interpolated from.
        name: label for error messages.
    """

    def __init__(self, body: VoxelBody, E: float, nu: float, fixed, points, point_elements, name: str = "body"):
        import scipy.sparse.linalg as sla

        self.body, self.E, self.nu, self.name = body, float(E), float(nu), name
        fixed = np.asarray(fixed, bool)
        if fixed.ndim == 1:
            fixed = np.repeat(fixed[:, None], 3, axis=1)
        if fixed.shape != (len(body.nodes), 3):
            raise ConfigError(f"{name}: fixed has shape {fixed.shape}, expected ({len(body.nodes)}, 3)")
        self.fixed = fixed
        dofs = (dissection_order(body.nodes)[:, None] * 3 + np.arange(3)).ravel()
        free = dofs[~fixed.ravel()[dofs]]  # unknowns, in elimination order
        if not fixed.any():
            raise ConfigError(f"{name}: no fixed degree of freedom; the body would float (singular stiffness)")
        K = stiffness(body, E, nu)
        self.num_free = len(free)
        # row of each degree of freedom in a solution vector padded with a zero row for the fixed ones
        self._row = np.full(body.num_dofs, len(free), np.int64)
        self._row[free] = np.arange(len(free))
        # K is symmetric positive definite: no pivoting, so the nested-dissection order stands
        self._lu = sla.splu(K[free][:, free].tocsc(), permc_spec="NATURAL",
                            options=dict(SymmetricMode=True, DiagPivotThresh=0.0))
        self.points = np.asarray(points, float).reshape(-1, 3)
        self.point_elements = np.asarray(point_elements, np.int64)
        nodes, self._weights = trilinear(body, self.points, self.point_elements)
        self._point_rows = self._row[nodes[:, :, None] * 3 + np.arange(3)]  # [S, 8, 3]
        self._columns: dict[int, np.ndarray] = {}

    @property
    def num_points(self) -> int:
        return len(self.points)

    @property
    def columns_solved(self) -> int:
        """Surface points whose compliance column has been computed so far."""
        return len(self._columns)

    # ------------------------------------------------------------------ linear algebra
    def _load(self, points: np.ndarray, forces: np.ndarray) -> np.ndarray:
        """[num_free, k] nodal load vectors of k sets of point forces: ``forces`` [k, m, 3] at ``points`` [m]."""
        k = len(forces)
        rhs = np.zeros((self.num_free + 1, k))
        rows = self._point_rows[points]  # [m, 8, 3]
        contrib = self._weights[points][None, :, :, None] * forces[:, :, None, :]  # [k, m, 8, 3]
        for j in range(k):
            np.add.at(rhs[:, j], rows.ravel(), contrib[j].ravel())
        return rhs[:-1]

    def _at_points(self, u: np.ndarray) -> np.ndarray:
        """Displacements [S, 3, k] of every surface point from nodal solutions ``u`` [num_free, k]."""
        padded = np.vstack([u, np.zeros((1, u.shape[1]))])
        return np.einsum("sa,saik->sik", self._weights, padded[self._point_rows])

    def _ensure_columns(self, points) -> None:
        need = [int(p) for p in points if int(p) not in self._columns]
        for start in range(0, len(need), COLUMN_BATCH):
            chunk = np.array(need[start:start + COLUMN_BATCH])
            unit = np.zeros((3 * len(chunk), len(chunk), 3))
            for c in range(len(chunk)):
                unit[3 * c:3 * c + 3, c, :] = np.eye(3)
            u = self._lu.solve(self._load(chunk, unit))
            disp = self._at_points(u)  # [S, 3, 3m]
            for c, p in enumerate(chunk):
                self._columns[int(p)] = np.ascontiguousarray(disp[:, :, 3 * c:3 * c + 3])  # [S, 3 (u), 3 (f)]

    def displacement_of(self, points, forces) -> np.ndarray:
        """[S, 3] displacement [m] of every surface point under ``forces`` [m, 3] [N] at ``points`` [m]
        (from the kept compliance columns)."""
        self._ensure_columns(points)
        u = np.zeros((self.num_points, 3))
        for p, f in zip(points, forces):
            u += self._columns[int(p)] @ f
        return u

    def nodal_displacement(self, points, forces) -> np.ndarray:
        """[V, 3] displacement [m] of every node under ``forces`` [m, 3] [N] at surface ``points`` [m]
        (one solve)."""
        forces = np.asarray(forces, float).reshape(1, -1, 3)
        u = self._lu.solve(self._load(np.asarray(points, np.int64), forces))[:, 0]
        return np.append(u, 0.0)[self._row].reshape(-1, 3)

    # ------------------------------------------------------------------ contact
    def solve(self, sdf: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], geometry: str = "rest",
              margin: float | None = None, tol: float | None = None, max_iterations: int = 20) -> ContactResult:
        """Equilibrium of the body pressed by one rigid collider.

        Args:
            sdf: ``sdf(x)`` for body-frame points x [S, 3] (every surface point, in order)
                returns (φ [S] m, negative inside the collider; outward unit normal [S, 3]).
            geometry: where the contact conditions are read. ``"rest"`` (default): φ and n
                at the rest surface, the gap linear in the displacement, g = φ(X) + n(X)·u:
                small-displacement contact, consistent with the linear body and with the
                published layer and Hertz solutions (:mod:`~gausstac_maniskill.bench.thinlayer`).
                ``"deformed"``: φ and n read again at the displaced surface X + u until it
                stops moving (the surface's lateral motion under a curved indenter counts;
                on the thin layer at δ = 0.1·h it lowers the force by 3–7 %).
            margin: points with φ below it enter the problem [m] (default: one element).
            tol: convergence of the surface's motion and of the largest penetration [m]
                (default 1e-4 of an element).
            max_iterations: outer iterations before :class:`SimulationError`.
        """
        if geometry not in ("rest", "deformed"):
            raise ConfigError(f"{self.name}: geometry={geometry!r} must be 'rest' or 'deformed'")
        margin = self.body.size if margin is None else float(margin)
        tol = 1e-4 * self.body.size if tol is None else float(tol)
        u = np.zeros((self.num_points, 3))
        taken = np.zeros(self.num_points, bool)
        phi, n = sdf(self.points)
        for it in range(1, max_iterations + 1):
            if geometry == "deformed" and it > 1:
                phi, n = sdf(self.points + u)
                phi = phi - np.einsum("si,si->s", n, u)  # g = φ(x) + n·(u_new − u) = phi + n·u_new
            gap_now = phi + np.einsum("si,si->s", n, u)
            taken |= gap_now < (margin if it == 1 else tol)
            idx = np.flatnonzero(taken)
            if not len(idx):
                return ContactResult(np.zeros_like(u), u, gap_now, it, 0)
            self._ensure_columns(idx)
            Wc = np.stack([self._columns[int(p)][idx] for p in idx], axis=2)  # [m (s), 3, m (d), 3]
            nc = n[idx]
            lam = solve_lcp(np.einsum("si,sidj,dj->sd", nc, Wc, nc), phi[idx])
            f = lam[:, None] * nc
            u_new = self.displacement_of(idx, f)
            moved = float(np.abs(u_new - u).max())
            u = u_new
            gap = phi + np.einsum("si,si->s", n, u)  # linearised at this iteration's surface
            if geometry == "deformed":
                gap = sdf(self.points + u)[0]
            if (geometry == "rest" or moved < tol) and gap.min() > -tol:
                force = np.zeros_like(u)
                force[idx] = f
                return ContactResult(force, u, gap, it, len(idx))
        raise SimulationError(f"{self.name}: contact did not converge in {max_iterations} iterations "
                              f"(last surface motion {moved:.3g} m, deepest penetration {-gap.min():.3g} m)")
