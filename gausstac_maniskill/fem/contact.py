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
from .hex import VoxelBody, dissection_order, neo_hookean_forces, stiffness, trilinear

__all__ = ["QuasiStaticBody", "ContactResult", "solve_lcp"]

_BLAS = None


def _one_blas_thread():
    """Context: BLAS on one thread. The dense algebra here is small (a few hundred unknowns);
    OpenBLAS's threads only contend with Taichi's workers for the cores (measured 2× slower)."""
    global _BLAS
    from threadpoolctl import ThreadpoolController

    if _BLAS is None:
        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")


#: Points whose compliance columns are solved together (one multi-right-hand-side solve).
COLUMN_BATCH = 32
#: Iterates the finite-strain fixed point mixes (Anderson acceleration).
ANDERSON_DEPTH = 15


class _Anderson:
    """Anderson acceleration of a fixed point u = T(u) (Walker & Ni 2011, "type II"): the next
    iterate is the combination of the last ``depth`` values of T whose residual combination
    T(u) − u is least in the least-squares sense. A plain iteration overshoots where the
    material has stiffened beyond the factored stiffness (compressed, near-incompressible
    silicone); the mixing damps that."""

    def __init__(self, depth: int):
        self.depth, self.dr, self.dt, self.last = depth, [], [], None

    def next(self, u: np.ndarray, t: np.ndarray) -> np.ndarray:
        r, t = (t - u).ravel(), t.ravel()
        if self.last is not None:
            self.dr.append(r - self.last[0])
            self.dt.append(t - self.last[1])
            del self.dr[:-self.depth], self.dt[:-self.depth]
        self.last = (r, t)
        if not self.dr:
            return t.reshape(u.shape)
        R = np.stack(self.dr, axis=1)
        gamma = np.linalg.lstsq(R, r, rcond=None)[0]
        return (t - np.stack(self.dt, axis=1) @ gamma).reshape(u.shape)


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
    A[np.diag_indices(len(b))] += 1e-12 * np.trace(A) / len(b)
    L = cholesky(A, lower=True, check_finite=False)
    lam, _ = nnls(L.T, -solve_triangular(L, b, lower=True, check_finite=False), maxiter=50 * len(b))
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
        nodes: [V, 3] displacement [m] of every node (``"neo_hookean"`` bodies; None for
            linear ones, whose :meth:`QuasiStaticBody.nodal_displacement` gives it on demand).
        residual: |f_int − f_contact| / |f_contact| at the end (0 for linear bodies).
    """

    force: np.ndarray
    displacement: np.ndarray
    gap: np.ndarray
    iterations: int
    candidates: int
    nodes: np.ndarray | None = None
    residual: float = 0.0

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
        model: ``"linear"`` (small strain, the default) or ``"neo_hookean"`` (finite strain:
            :func:`~.hex.neo_hookean_forces`, solved by fixed-point iterations on the linear
            stiffness's factor, each with the contact solved exactly; see :meth:`solve`).
    """

    def __init__(self, body: VoxelBody, E: float, nu: float, fixed, points, point_elements, name: str = "body",
                 model: str = "linear"):
        import scipy.sparse.linalg as sla

        if model not in ("linear", "neo_hookean"):
            raise ConfigError(f"{name}: model={model!r} must be 'linear' or 'neo_hookean'")
        self.body, self.E, self.nu, self.name, self.model = body, float(E), float(nu), name, model
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
        self._K = K
        self._free = free
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

    def _normal_compliance(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """[m, m] normal compliance A_sd = n_s · W_sd n_d [m/N] among surface ``points`` [m] with unit
        ``normals`` [m, 3]."""
        self._ensure_columns(points)
        cols = np.stack([self._columns[int(p)][points] @ n for p, n in zip(points, normals)], axis=1)  # [s, d, 3]
        return np.einsum("sdi,si->sd", cols, normals)

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
              margin: float | None = None, tol: float | None = None, max_iterations: int = 60,
              warm: ContactResult | None = None) -> ContactResult:
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
            warm: the last step's result, to start from (``"neo_hookean"`` bodies).

        A ``"neo_hookean"`` body is always read at its displaced surface (finite strain), and
        solved by fixed-point iterations on the linear stiffness K: with the nonlinear
        remainder r(u) = f_int(u) − K u of the last iterate as a load, each iteration solves
        the linear contact problem exactly, u ← K⁻¹(Nᵀf − r(u)). It converges where K⁻¹ f_int
        is a contraction: the pad's strains of tens of per cent are.
        """
        if geometry not in ("rest", "deformed"):
            raise ConfigError(f"{self.name}: geometry={geometry!r} must be 'rest' or 'deformed'")
        margin = self.body.size if margin is None else float(margin)
        tol = 1e-4 * self.body.size if tol is None else float(tol)
        with _one_blas_thread():
            if self.model == "neo_hookean":
                return self._solve_finite_strain(sdf, margin, tol, max_iterations, warm)
            return self._solve_linear(sdf, geometry, margin, tol, max_iterations)

    def _solve_linear(self, sdf, geometry, margin, tol, max_iterations) -> ContactResult:
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
            nc = n[idx]
            lam = solve_lcp(self._normal_compliance(idx, nc), phi[idx])
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

    # ------------------------------------------------------------------ finite strain
    def _interp(self, u_nodes: np.ndarray) -> np.ndarray:
        """[S, 3] displacement of the surface points from node displacements [V, 3]."""
        return np.einsum("sa,sai->si", self._weights, u_nodes[self.body.element_nodes[self.point_elements]])

    def _solve_nodes(self, load: np.ndarray) -> np.ndarray:
        """[V, 3] node displacements K⁻¹ load for a nodal load [V, 3] (fixed ones read 0)."""
        x = self._lu.solve(load.ravel()[self._free])
        u = np.zeros(self.body.num_dofs)
        u[self._free] = x
        return u.reshape(-1, 3)

    def _solve_finite_strain(self, sdf, margin, tol, max_iterations, warm) -> ContactResult:
        body = self.body
        u = np.zeros((len(body.nodes), 3)) if warm is None or warm.nodes is None else warm.nodes.copy()
        taken = np.zeros(self.num_points, bool)
        if warm is not None:
            taken |= np.abs(warm.force).sum(1) > 0
        f = np.zeros((0, 3))
        idx = np.zeros(0, np.int64)
        mix = _Anderson(ANDERSON_DEPTH)
        for it in range(1, max_iterations + 1):
            us = self._interp(u)
            phi, n = sdf(self.points + us)
            try:
                remainder = neo_hookean_forces(body, u, self.E, self.nu) - (self._K @ u.ravel()).reshape(-1, 3)
            except FloatingPointError as err:
                raise SimulationError(f"{self.name}: {err} at iteration {it}; the press is too deep for "
                                      "the pad, or the step too large") from None
            u_load = self._solve_nodes(-remainder)
            b = phi + np.einsum("si,si->s", n, self._interp(u_load) - us)  # gap with no contact force
            taken |= b < margin
            idx = np.flatnonzero(taken)
            f = np.zeros((0, 3))
            u_new = u_load
            if len(idx):
                nc = n[idx]
                lam = solve_lcp(self._normal_compliance(idx, nc), b[idx])
                f = lam[:, None] * nc
                u_new = u_load + self.nodal_displacement(idx, f)
            moved = float(np.abs(u_new - u).max())
            if moved < tol:
                u = u_new
                break
            u = mix.next(u, u_new)
        else:
            raise SimulationError(f"{self.name}: finite-strain contact did not converge in {max_iterations} "
                                  f"iterations (last motion {moved:.3g} m)")
        force = np.zeros((self.num_points, 3))
        force[idx] = f
        us = self._interp(u)
        load = np.zeros((len(body.nodes), 3))
        if len(idx):
            rows = body.element_nodes[self.point_elements[idx]]
            np.add.at(load, rows.ravel(), (self._weights[idx][:, :, None] * f[:, None, :]).reshape(-1, 3))
        fint = neo_hookean_forces(body, u, self.E, self.nu)
        free = ~self.fixed
        residual = float(np.linalg.norm((fint - load)[free]) / max(np.linalg.norm(load[free]), 1e-30))
        return ContactResult(force, us, sdf(self.points + us)[0], it, len(idx), u, residual)
