"""An elastic body's equilibrium under rigid colliders (:class:`QuasiStaticBody`; SI units).

The body (:mod:`.hex`) is held by its fixed degrees of freedom and touched only at its
surface points. A force f_d at point d moves point s by W_sd f_d, where W = N K⁻¹ Nᵀ is the
body's compliance at its surface points (N: trilinear interpolation, K: the linear stiffness
with the fixed degrees of freedom removed). Each outer iteration reads the colliders (an sdf,
or :mod:`.indenters`) at the surface and solves the contact problem on the points near them
(:mod:`.signorini`: frictionless, or with Coulomb friction). A finite-strain body repeats that
inside fixed-point iterations on K (:meth:`QuasiStaticBody.solve`). K is factored once, when a
solve first needs it; W's column for a point is computed by three solves the first time the
point comes near a collider, and kept, so a press or a slide costs solves only for the points
it reaches (or all of W at once, :mod:`.compliance`).
"""
from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import ConfigError, SimulationError, SimulationWarning
from .hex import VoxelBody, dissection_order, neo_hookean_remainder, stiffness, strain_points, trilinear
from .indenters import Indenter, Indenters
from .signorini import _block, _xyz_rows, solve_frictional, solve_lcp, tangent_bases

__all__ = ["QuasiStaticBody", "ContactResult"]


def _one_blas_thread():
    """Context: BLAS on one thread. The dense algebra here is small (a few hundred unknowns);
    OpenBLAS's threads only contend with Taichi's workers for the cores and slow it down."""
    from ..backend import blas_threads

    return blas_threads(1)


#: Points whose compliance columns are solved together (one multi-right-hand-side solve).
COLUMN_BATCH = 32
#: Iterates the finite-strain fixed point mixes (Anderson acceleration).
ANDERSON_DEPTH = 15
#: the finite-strain iterations' mixing, tried in turn where the last failed: undamped first
#: (enough for whole cubes); 0.5 carries the sphere's 1 mm press on cut cells of 0.5 mm (which
#: inverts undamped). Where the cut cubes' finite strain stalls or creeps to ``max_iterations``,
#: damping does not cure it (the plate's slide): the step falls back at once
#: (:meth:`QuasiStaticBody.solve`, ``cut_cells_linear``), and the fallback damps on a stall as
#: on an inversion
DAMPED_MIXING = (1.0, 0.5, 0.25)
#: finite-strain iterations without halving the smallest surface motion so far, after which the
#: fixed point counts as stalled, while that motion is still above 100 tolerances (converging
#: steps creep for longer below that, toward the tolerance; the stalled plate slide hovers at
#: 5e-5 m, 1000 tolerances). A stalled mixing then
#: fails in about this many iterations instead of running to ``max_iterations``
STALL_ITERATIONS = 100
#: the finite-strain iterations' relative tolerance (:meth:`QuasiStaticBody.solve`'s ``rtol``)
FINITE_RTOL = 5e-4


class _Diverged(Exception):
    """The finite-strain iterations diverged (an element inverted, or no convergence)."""


class _Stalled(_Diverged):
    """The finite-strain iterations stopped contracting (:data:`STALL_ITERATIONS`), or crept
    to ``max_iterations``."""


class _Anderson:
    """Anderson acceleration of a fixed point u = T(u) (Walker & Ni 2011, "type II", with
    mixing ``beta``): the next iterate is u + β r less the combination of the last ``depth``
    steps whose residual combination r = T(u) − u is least in the least-squares sense
    (β = 1: the combination of the last values of T). A plain iteration overshoots where the
    material has stiffened beyond the factored stiffness (compressed, near-incompressible
    silicone); the mixing damps that, and β < 1 damps it further."""

    def __init__(self, depth: int, beta: float = 1.0):
        self.depth, self.beta, self.dr, self.du, self.last = depth, beta, [], [], None

    def next(self, u: np.ndarray, t: np.ndarray) -> np.ndarray:
        x, r = u.ravel(), (t - u).ravel()
        if self.last is not None:
            self.dr.append(r - self.last[0])
            self.du.append(x - self.last[1])
            del self.dr[:-self.depth], self.du[:-self.depth]
        self.last = (r, x.copy())
        step = x + self.beta * r
        if not self.dr:
            return step.reshape(u.shape)
        R = np.stack(self.dr, axis=1)
        gamma = np.linalg.lstsq(R, r, rcond=None)[0]
        return (step - (np.stack(self.du, axis=1) + self.beta * R) @ gamma).reshape(u.shape)


@dataclass
class ContactResult:
    """Equilibrium under rigid colliders (body frame, SI units).

    Attributes:
        force: [S, 3] force [N] the collider exerts on the body at each surface point.
        displacement: [S, 3] displacement [m] of each surface point.
        gap: [S] signed distance [m] from each displaced point to the collider.
        iterations: outer iterations (surface moved, φ and n read again).
        candidates: points taken into the complementarity problem.
        nodes: [V, 3] displacement [m] of every node (``"neo_hookean"`` bodies; None for
            linear ones, whose :meth:`QuasiStaticBody.nodal_displacement` gives it on demand).
        residual: |f_int − f_contact| / |f_contact| at the end (0 for linear bodies).
        state: [S] int, 0 open, 1 stuck, 2 slipping (friction; 1 wherever a frictionless
            point carries force).
        anchors: [S, 3] where each stuck or slipping point holds on its collider, in the
            collider's frame [m] (NaN where open; frictional contact only).
        pose: [C, 4, 4] the colliders' poses in the body frame (frictional contact only).
        owner: [S] int, each point's collider (index into ``keys``, and ``pose``; solves with
            an :class:`Indenter` or :class:`Indenters` only).
        keys: the colliders' keys (:class:`Indenters`; ``(None,)`` for one :class:`Indenter`).
        cut_cells_linear: the finite-strain solve of this step failed with the cut cubes finite
            and was solved with them linear, the whole cubes alone finite (a
            :class:`~gausstac_maniskill.errors.SimulationWarning` says so; :meth:`QuasiStaticBody.solve`).
        load: [S, 3] force [N] at each surface point that is not a rigid collider's, given to
            the solve (``load=``: a soft object's push, :meth:`QuasiStaticBody.solve`); None: none.
            :attr:`force` holds the colliders' alone.
    """

    force: np.ndarray
    displacement: np.ndarray
    gap: np.ndarray
    iterations: int
    candidates: int
    nodes: np.ndarray | None = None
    residual: float = 0.0
    state: np.ndarray | None = None
    anchors: np.ndarray | None = None
    pose: np.ndarray | None = None
    owner: np.ndarray | None = None
    keys: tuple = (None,)
    cut_cells_linear: bool = False
    load: np.ndarray | None = None

    @property
    def surface_force(self) -> np.ndarray:
        """[S, 3] every force [N] on each surface point: the colliders' plus the given load."""
        return self.force if self.load is None else self.force + self.load

    @property
    def total_force(self) -> np.ndarray:
        """[3] resultant force [N] on the body (colliders and load)."""
        return self.surface_force.sum(0)


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
        point_sources: [S] what each point stands for, for its owner's bookkeeping (a pad: the
            soft particle whose surface it is; default: ``point_elements``).
    """

    def __init__(self, body: VoxelBody, E: float, nu: float, fixed, points, point_elements, name: str = "body",
                 model: str = "linear", point_sources=None):
        if model not in ("linear", "neo_hookean"):
            raise ConfigError(f"{name}: model={model!r} must be 'linear' or 'neo_hookean'")
        self._args = (body, E, nu, fixed, points, point_elements, name, model, point_sources)  # (pickling)
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
        self._factor = None  # K's sparse LU, computed on first use (:attr:`_lu`)
        self.points = np.asarray(points, float).reshape(-1, 3)
        self.point_elements = np.asarray(point_elements, np.int64)
        self.point_sources = self.point_elements if point_sources is None else np.asarray(point_sources, np.int64)
        nodes, self._weights = trilinear(body, self.points, self.point_elements)
        self._point_rows = self._row[nodes[:, :, None] * 3 + np.arange(3)]  # [S, 8, 3]
        self._columns: dict[int, np.ndarray] = {}  # point -> its compliance column [S, 3, 3], as solved
        self._compliance: np.ndarray | None = None  # [3S, 3S] all of W, once computed (precompute_compliance)
        # the finite-strain remainder's integration points, built on first use: {cut_cells: points}
        self._strain_points: dict[bool, object] = {}
        #: what other modules compute once from this body and keep with it (e.g. :class:`~.maps.PadMaps`)
        self.derived: dict = {}

    def __reduce__(self):
        """Pickled as its description; unpickling assembles and factors it again (the factor
        itself cannot be pickled)."""
        return (type(self), self._args)

    @property
    def _lu(self):
        """K's sparse LU on the free degrees of freedom (SuperLU), factored the first time a
        solve needs it (about 0.5 GB for the index pad at 0.5 mm elements). The compliance and
        the maps' response do not need it
        (:meth:`inverse_between`): a linear pad that only presses and reads its maps never factors."""
        if self._factor is None:
            import scipy.sparse.linalg as sla

            free = self._free
            # K is symmetric positive definite: no pivoting, so the nested-dissection order stands
            self._factor = sla.splu(self._K[free][:, free].tocsc(), permc_spec="NATURAL",
                                    options=dict(SymmetricMode=True, DiagPivotThresh=0.0))
        return self._factor

    @property
    def factored(self) -> bool:
        """Whether K's factor has been computed in this process."""
        return self._factor is not None

    @property
    def num_points(self) -> int:
        return len(self.points)

    @property
    def has_compliance(self) -> bool:
        """Whether the compliance among all surface points is at hand (:meth:`precompute_compliance`)."""
        return self._compliance is not None

    @property
    def columns_solved(self) -> int:
        """Surface points whose compliance column has been computed so far (all of them after
        :meth:`precompute_compliance`)."""
        return self.num_points if self._compliance is not None else len(self._columns)

    def precompute_compliance(self, progress: bool = True, cache: bool = True, readouts=()) -> None:
        """Compute (or load from the disk cache) the compliance among all surface points now,
        so that contact solves need no sparse solve for it: :func:`~.compliance.surface_compliance`
        (float32, 36 S² bytes; ``cache``: kept in and read from the disk cache).
        ``readouts``: readouts [R, 3V] whose responses will be asked for, computed in the same sweep
        where the compliance is computed (see there)."""
        from .compliance import surface_compliance

        if self._compliance is None:
            self._compliance = surface_compliance(self, progress=progress, cache=cache, readouts=readouts)
            self._columns = {}

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

    def point_loads(self, points) -> "scipy.sparse.csc_matrix":
        """[num_free, 3k] nodal load vectors (sparse) of a unit force [N] at each of surface
        ``points`` [k] along each axis, columns ordered (point, axis)."""
        import scipy.sparse as sp

        points = np.asarray(points, np.int64)
        k = len(points)
        rows = np.broadcast_to(self._point_rows[points][:, :, :, None], (k, 8, 3, 3))  # [d, a, i (row axis), j]
        cols = np.broadcast_to((3 * np.arange(k))[:, None, None, None] + np.arange(3)[None, None, None, :], (k, 8, 3, 3))
        vals = np.broadcast_to(self._weights[points][:, :, None, None] * np.eye(3)[None, None], (k, 8, 3, 3))
        keep = (vals != 0.0) & (rows < self.num_free)
        return sp.csc_matrix((vals[keep], (rows[keep], cols[keep])), shape=(self.num_free, 3 * k))

    def surface_response(self, loads) -> np.ndarray:
        """[C, S, 3] displacement [m] of every surface point under each of C nodal load vectors
        ``loads`` [num_free, C] (dense or sparse; N): one multi-right-hand-side solve."""
        loads = loads.toarray() if hasattr(loads, "toarray") else np.asarray(loads, float)
        return self._at_points(self._lu.solve(loads)).transpose(2, 0, 1)

    def inverse_between(self, P, Q=None, bar=None, dtype=np.float64) -> np.ndarray:
        """Pᵀ K⁻¹ Q [p, q] (of ``dtype``) for load sets ``P`` [num_free, p] and ``Q`` [num_free, q] (sparse;
        None: P, the result then symmetric) on the free degrees of freedom (as :meth:`point_loads`
        and :meth:`dofs_to_free` give them): all their solves at once, by the stiffness's Cholesky
        factor taken lattice plane by lattice plane (:mod:`.plane_cholesky`, dense BLAS 3 on every
        core; SuperLU's factor is not needed). ``bar``: a tqdm bar advanced once per plane."""
        from .plane_cholesky import inverse_between

        return inverse_between(self._free_stiffness(), self._planes, P, Q, bar=bar, name=self.name, dtype=dtype)

    def inverse_products(self, loads: list, pairs: list, bar=None, dtype=np.float64) -> list[np.ndarray]:
        """[Pᵢᵀ K⁻¹ Pⱼ for (i, j) in ``pairs``] of load sets ``loads`` [num_free, pᵢ] (sparse), as
        :meth:`inverse_between` computes one, all in one sweep: the factor and each load set's
        forward substitution once (:func:`~.plane_cholesky.inverse_products`)."""
        from .plane_cholesky import inverse_products

        return inverse_products(self._free_stiffness(), self._planes, loads, pairs, bar=bar, name=self.name,
                                dtype=dtype)

    def _free_stiffness(self):
        """The stiffness on the free degrees of freedom (sparse [num_free, num_free])."""
        free = self._free
        return self._K[free][:, free]

    @functools.cached_property
    def _planes(self) -> np.ndarray:
        """[num_free] the lattice plane of each free degree of freedom (:func:`~.plane_cholesky.lattice_planes`)."""
        from .plane_cholesky import lattice_planes

        return lattice_planes(self.body.nodes[self._free // 3])[0]

    @property
    def num_planes(self) -> int:
        """Lattice planes :meth:`inverse_between` works through (its progress bar's total)."""
        return int(self._planes.max()) + 1

    def dofs_to_free(self, A) -> "scipy.sparse.csc_matrix":
        """[num_free, R]: the transpose of a readout ``A`` [R, 3V] (sparse; node-major degrees
        of freedom) restricted to the free ones, as load vectors (:meth:`surface_response`). By
        Maxwell–Betti (K symmetric) their responses are the readouts' responses to point forces."""
        import scipy.sparse as sp

        A = sp.csc_matrix(A)
        if A.shape[1] != self.body.num_dofs:
            raise ConfigError(f"{self.name}: a readout of shape {A.shape} does not act on {self.body.num_dofs} dofs")
        return A[:, self._free].T.tocsc()  # free degrees of freedom, in elimination order

    def solve_columns(self, points) -> np.ndarray:
        """[k, S, 3, 3] compliance columns of surface ``points`` [k]: entry [d, s, i, j] is the
        displacement [m] of surface point s along axis i under a unit force [N] at ``points[d]``
        along axis j (three solves per point)."""
        points = np.asarray(points, np.int64)
        disp = self.surface_response(self.point_loads(points))  # [3k (d, j), S, 3 (i)]
        return disp.reshape(len(points), 3, self.num_points, 3).transpose(0, 2, 3, 1)

    def _ensure_columns(self, points) -> None:
        if self._compliance is not None:
            return
        need = [int(p) for p in points if int(p) not in self._columns]
        for start in range(0, len(need), COLUMN_BATCH):
            chunk = need[start:start + COLUMN_BATCH]
            for p, col in zip(chunk, self.solve_columns(chunk)):
                self._columns[p] = np.ascontiguousarray(col)

    def compliance_among(self, points) -> np.ndarray:
        """[m, 3, m, 3] compliance W [m/N] among surface ``points`` [m]: entry [s, i, d, j] is the
        displacement of ``points[s]`` along i under a unit force at ``points[d]`` along j."""
        points = np.asarray(points, np.int64)
        m = len(points)
        if self._compliance is not None:
            rows = _xyz_rows(points)
            return _block(self._compliance, rows, rows).astype(np.float64).reshape(m, 3, m, 3)
        self._ensure_columns(points)
        return np.stack([self._columns[int(p)][points] for p in points], axis=2)

    def _normal_compliance(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """[m, m] normal compliance A_sd = n_s · W_sd n_d [m/N] among surface ``points`` [m] with unit
        ``normals`` [m, 3]."""
        return np.einsum("si,sidj,dj->sd", normals, self.compliance_among(points), normals, optimize=True)

    def displacement_of(self, points, forces) -> np.ndarray:
        """[S, 3] displacement [m] of every surface point under ``forces`` [m, 3] [N] at ``points`` [m]
        (from the compliance: all of it, or the kept columns)."""
        points = np.asarray(points, np.int64)
        forces = np.asarray(forces, float).reshape(-1, 3)
        if self._compliance is not None:  # W is symmetric: the rows of the loaded points
            rows = _xyz_rows(points)
            return (forces.ravel().astype(np.float32) @ self._compliance[rows]).astype(np.float64).reshape(-1, 3)
        self._ensure_columns(points)
        u = np.zeros((self.num_points, 3))
        for p, f in zip(points, forces):
            u += self._columns[int(p)] @ f
        return u

    def internal_forces(self, u: np.ndarray, cut_cells: bool = True) -> np.ndarray:
        """[V, 3] internal nodal forces [N] of the body displaced by ``u`` [V, 3] [m], under its
        own model (linear: K u; neo-Hookean: :func:`~.hex.neo_hookean_forces`, as K u plus
        :func:`~.hex.neo_hookean_remainder` with the stiffness assembled here; ``cut_cells=False``:
        the cut cubes linear, as a step solved with ``cut_cells_linear``).

        Raises:
            FloatingPointError: a neo-Hookean element is inverted.
        """
        linear = (self._K @ u.ravel()).reshape(-1, 3)
        if self.model == "linear":
            return linear
        return linear + self._remainder(u, cut_cells)

    def _points(self, cut_cells: bool):
        """The finite-strain remainder's integration points (built once each): with the cut cubes
        at least :data:`~.hex.CUT_FINITE_SHARE` full, or (``cut_cells=False``) the whole cubes alone."""
        if cut_cells not in self._strain_points:
            self._strain_points[cut_cells] = strain_points(self.body, None if cut_cells else math.inf)
        return self._strain_points[cut_cells]

    def _remainder(self, u: np.ndarray, cut_cells: bool = True) -> np.ndarray:
        """[V, 3] :func:`~.hex.neo_hookean_remainder` [N] of node displacements ``u`` [V, 3] [m]."""
        return neo_hookean_remainder(self.body, u, self.E, self.nu, self._points(cut_cells))

    def nodal_displacement(self, points, forces) -> np.ndarray:
        """[V, 3] displacement [m] of every node under ``forces`` [m, 3] [N] at surface ``points`` [m]
        (one solve)."""
        forces = np.asarray(forces, float).reshape(1, -1, 3)
        u = self._lu.solve(self._load(np.asarray(points, np.int64), forces))[:, 0]
        return np.append(u, 0.0)[self._row].reshape(-1, 3)

    # ------------------------------------------------------------------ contact
    def solve(self, sdf: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | Indenter | Indenters,
              geometry: str = "rest", margin: float | None = None, tol: float | None = None,
              max_iterations: int = 60, warm: ContactResult | None = None,
              rtol: float = FINITE_RTOL, load: np.ndarray | None = None) -> ContactResult:
        """Equilibrium of the body pressed by rigid colliders.

        Args:
            sdf: ``sdf(x)`` for body-frame points x [S, 3] (every surface point, in order)
                returns (φ [S] m, negative inside the collider; outward unit normal [S, 3]);
                frictionless. An :class:`Indenter` with ``friction`` > 0 adds Coulomb
                friction (:func:`solve_frictional`): a point holds its place on the collider
                from one solve to the next (pass the last result as ``warm``); a point that
                comes into contact holds where it lands: the foot on the collider's surface of
                where it was at the last solve, carried by the collider's motion from then
                (``warm.pose``), or of where it rests if there is none. :class:`Indenters`:
                several colliders at once, read on their union (each point against the
                nearest); a point's hold carries over only on the same collider.
            geometry: where the contact conditions are read. ``"rest"`` (default): φ and n
                at the rest surface, the gap linear in the displacement, g = φ(X) + n(X)·u:
                small-displacement contact, consistent with the linear body and with the
                published layer and Hertz solutions (:mod:`~gausstac_maniskill.reference`).
                ``"deformed"``: φ and n read again at the displaced surface X + u until it
                stops moving (the surface's lateral motion under a curved indenter counts;
                on the thin layer at δ = 0.1·h it lowers the force by 3–7 %).
            margin: points with φ below it enter the problem [m] (default: one element).
            tol: convergence of the surface's motion and of the largest penetration [m]
                (default 1e-4 of an element).
            rtol: ``"neo_hookean"`` bodies: the iterations also stop where the surface's motion
                per iteration is below ``rtol`` times its largest displacement (absolute and
                relative tolerances, as nonlinear solvers take them: a deep press converges
                to its own scale, a light touch still to ``tol``).
            max_iterations: outer iterations before :class:`SimulationError`.
            warm: the last step's result: the state to start from (``"neo_hookean"`` bodies) and
                the points' holds on the collider (friction).
            load: [S, 3] forces [N] on the surface points besides the colliders' (a soft
                object's push, given), added to theirs by superposition (``"linear"`` bodies
                only); kept in :attr:`ContactResult.load`.

        A ``"neo_hookean"`` body is always read at its displaced surface (finite strain), and
        solved by fixed-point iterations on the linear stiffness K: with the nonlinear
        remainder r(u) = f_int(u) − K u of the last iterate as a load, each iteration solves
        the linear contact problem exactly, u ← K⁻¹(Nᵀf − r(u)). It converges where K⁻¹ f_int
        is a contraction: the pad's strains of tens of per cent are. Where an element inverts,
        it starts again from ``warm`` with the mixing damped (:data:`DAMPED_MIXING`). Where it
        stalls (or creeps to ``max_iterations``), or inverts at every mixing, a body of cut
        cells solves the step again with the cut cubes linear, the whole cubes alone finite
        (at every mixing); the result says so
        (``cut_cells_linear``), and a :class:`~gausstac_maniskill.errors.SimulationWarning`
        gives the reason. On the index pad the plate's 2 mm slide needs it from 4/3 mm on and
        reads within 0.2 % (Fn) and 0.1 % (Ft) of the cut cubes linear throughout; the sphere,
        whose contact lies on the curved cut surface, reads 4.3 % higher with them linear, and
        slides whose different steps fall back read up to 1.2 % apart. The next step tries the
        cut cubes finite again.
        """
        if geometry not in ("rest", "deformed"):
            raise ConfigError(f"{self.name}: geometry={geometry!r} must be 'rest' or 'deformed'")
        margin = self.body.size if margin is None else float(margin)
        tol = 1e-4 * self.body.size if tol is None else float(tol)
        if load is not None:
            load = np.asarray(load, float)
            if self.model != "linear":
                raise ConfigError(f"{self.name}: a given load (load=) needs the linear model, this body is {self.model!r}")
            if load.shape != (self.num_points, 3):
                raise ConfigError(f"{self.name}: load has shape {load.shape}, expected ({self.num_points}, 3)")
        if isinstance(sdf, (Indenter, Indenters)):
            sdf = Indenters(sdf) if isinstance(sdf, Indenter) else sdf
            sdf.assign(self.points if warm is None else self.points + warm.displacement)
        elif getattr(sdf, "friction", 0.0) > 0:
            raise ConfigError(f"{self.name}: friction needs an Indenter (its frame holds the stuck points)")
        friction = _Friction(self, sdf, warm, tol) if getattr(sdf, "friction", 0.0) > 0 else None
        with _one_blas_thread():
            if self.model == "neo_hookean":
                res = self._solve_finite_strain(sdf, margin, tol, max_iterations, warm, friction, rtol)
            else:
                res = self._solve_linear(sdf, geometry, margin, tol, max_iterations, friction, warm, load)
        if friction is not None:
            friction.finish(res)
        else:
            res.state = (np.abs(res.force).sum(1) > 0).astype(np.int64)
            if isinstance(sdf, Indenters):
                res.owner, res.keys = sdf.nearest(self.points + res.displacement), sdf.keys
        return res

    def _contact_forces(self, idx, n, gap0, offset, friction) -> np.ndarray:
        """[m, 3] forces on points ``idx`` with normals ``n`` [m, 3], gap ``gap0`` + n·(W f) and,
        with ``friction``, position offset from their holds ``offset`` [m, 3] + W f."""
        if friction is None:
            return solve_lcp(self._normal_compliance(idx, n), gap0)[:, None] * n
        W = self.compliance_among(idx)  # [m (s), 3, m (d), 3]
        f0 = None
        last_idx, last_force = friction.last
        if len(last_idx):  # the last iteration's (or step's) forces: near this solution
            f0 = np.zeros((len(idx), 3))
            common, here, there = np.intersect1d(idx, last_idx, assume_unique=True, return_indices=True)
            f0[here] = last_force[there]
        f, friction.state = solve_frictional(W, n, gap0, np.einsum("pai,pi->pa", tangent_bases(n), offset),
                                             friction.mu[idx], friction.tol, f0=f0)
        friction.idx, friction.last = idx, (idx, f)
        return f

    def loaded(self, load: np.ndarray) -> np.ndarray:
        """[S, 3] displacement [m] of the surface points under ``load`` [S, 3] [N] at them (linear)."""
        idx = np.flatnonzero(np.abs(load).sum(1) > 0)
        return self.displacement_of(idx, load[idx]) if len(idx) else np.zeros((self.num_points, 3))

    def _solve_linear(self, sdf, geometry, margin, tol, max_iterations, friction=None, warm=None,
                      load=None) -> ContactResult:
        # a given load moves the surface by u_load = W load; the colliders' forces add to it
        u_load = np.zeros((self.num_points, 3)) if load is None else self.loaded(load)
        u = u_load.copy()
        taken = np.zeros(self.num_points, bool)
        if geometry == "deformed" and warm is not None and warm.displacement.shape == u.shape:
            # read first where the last step left the surface, its loaded points in the problem:
            # one pass where nothing moved since
            u = warm.displacement.copy()
            taken |= np.abs(warm.force).sum(1) > 0
        for it in range(1, max_iterations + 1):
            if it == 1 or geometry == "deformed":
                phi, n = sdf(self.points + u)
                phi = phi - np.einsum("si,si->s", n, u)  # g = φ(x) + n·(u_new − u) = phi + n·u_new
            gap_now = phi + np.einsum("si,si->s", n, u)
            taken |= gap_now < (margin if it == 1 else tol)
            idx = np.flatnonzero(taken)
            gap_load = phi + np.einsum("si,si->s", n, u_load)  # the gap with no collider force
            if not len(idx):
                return ContactResult(np.zeros_like(u), u_load, gap_load, it, 0, load=load)
            nc = n[idx]
            offset = None if friction is None else self.points[idx] + u_load[idx] - friction.hold[idx]
            f = self._contact_forces(idx, nc, gap_load[idx], offset, friction)
            u_new = u_load + self.displacement_of(idx, f)
            moved = float(np.abs(u_new - u).max())
            u = u_new
            gap = phi + np.einsum("si,si->s", n, u)  # linearised at this iteration's surface
            if geometry == "deformed":
                gap = sdf(self.points + u)[0]
            if (geometry == "rest" or moved < tol) and gap.min() > -tol:
                force = np.zeros_like(u)
                force[idx] = f
                return ContactResult(force, u, gap, it, len(idx), load=load)
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

    def _solve_finite_strain(self, sdf, margin, tol, max_iterations, warm, friction=None, rtol=0.0) -> ContactResult:
        """The finite-strain solve, by fixed-point iterations preconditioned with the factored
        linear stiffness; where an element inverts (a step that compresses thin cut cells far
        beyond the linear stiffness) they start again from ``warm`` with the mixing damped
        (:data:`DAMPED_MIXING`); where they stall (:data:`STALL_ITERATIONS`) or invert at every
        mixing, the same again with the cut cubes linear (:meth:`solve`), which damps the
        mixing on a stall too (the last resort)."""
        reasons = {True: [], False: []}
        # the cut cubes linear only where that changes the law (a body of cut cells)
        rules = (True, False) if (self._points(True).rule != self._points(False).rule).any() else (True,)
        for cut_cells in rules:
            for beta in DAMPED_MIXING:
                try:
                    res = self._finite_strain_iterations(sdf, margin, tol, max_iterations, warm, friction, beta,
                                                         cut_cells, rtol)
                except _Diverged as err:
                    reasons[cut_cells].append(f"mixing {beta:g}: {err.args[0]}")
                    if isinstance(err, _Stalled) and cut_cells is not rules[-1]:
                        break  # straight to the fallback; the last resort damps on a stall too
                    continue
                if not cut_cells:
                    warnings.warn(SimulationWarning(
                        f"{self.name}: the finite-strain solve failed with the cut cubes finite "
                        f"({'; '.join(reasons[True])}); this step is solved with them linear, the whole cubes alone "
                        f"finite (ContactResult.cut_cells_linear). Where the contact lies on the pad's curved surface, "
                        f"that law reads higher (+4.3 % on the 5 mm sphere at 1 mm); a slide whose steps fall back reads "
                        f"up to 1.2 % apart from one whose other steps do"))
                return res
        tried = "; ".join(reasons[True]) + ("; with the cut cubes linear: " + "; ".join(reasons[False])
                                            if len(rules) > 1 else "")
        raise SimulationError(f"{self.name}: the finite-strain solve failed ({tried}). "
                              "The press may be too deep for the pad or the step too large. "
                              "fem_model='linear' (small strain) and pad_solver='mpm' solve such steps")

    def _finite_strain_iterations(self, sdf, margin, tol, max_iterations, warm, friction, beta,
                                  cut_cells=True, rtol=0.0) -> ContactResult:
        body = self.body
        u = np.zeros((len(body.nodes), 3)) if warm is None or warm.nodes is None else warm.nodes.copy()
        taken = np.zeros(self.num_points, bool)
        if warm is not None:
            taken |= np.abs(warm.force).sum(1) > 0
        f = np.zeros((0, 3))
        idx = np.zeros(0, np.int64)
        mix = _Anderson(ANDERSON_DEPTH, beta)
        mark, mark_it = math.inf, 0  # the smallest motion yet, at its last halving, and when
        for it in range(1, max_iterations + 1):
            us = self._interp(u)
            phi, n = sdf(self.points + us)
            try:
                remainder = self._remainder(u, cut_cells)  # internal forces less K u
            except FloatingPointError as err:
                raise _Diverged(f"{err} at iteration {it}") from None
            u_load = self._solve_nodes(-remainder)
            us_load = self._interp(u_load)
            b = phi + np.einsum("si,si->s", n, us_load - us)  # gap with no contact force
            taken |= b < margin
            idx = np.flatnonzero(taken)
            f = np.zeros((0, 3))
            u_new = u_load
            if len(idx):
                nc = n[idx]
                offset = None
                if friction is not None:
                    offset = (self.points + us_load - friction.hold)[idx]
                f = self._contact_forces(idx, nc, b[idx], offset, friction)
                u_new = u_load + self.nodal_displacement(idx, f)
            # the surface's motion, as in the linear solve: a node of a nearly empty cut cube,
            # held by 1e-4 of the material's stiffness, wanders by millimetres and would hold
            # up the nodes' maximum long after the surface has stopped
            us_new = self._interp(u_new)
            moved = float(np.abs(us_new - us).max())
            if moved < max(tol, rtol * float(np.abs(us_new).max())):
                u = u_new
                break
            if moved < 0.5 * mark:
                mark, mark_it = moved, it
            elif it - mark_it >= STALL_ITERATIONS and mark > 100.0 * tol:
                raise _Stalled(f"finite-strain contact stalled: the surface's largest motion per iteration has not halved in "
                                f"{STALL_ITERATIONS} iterations ({moved:.3g} m at iteration {it}, tolerance {tol:.3g} m)")
            u = mix.next(u, u_new)
        else:  # a creep below the stall detector's 100 tolerances: a smaller mixing does not cure it
            raise _Stalled(f"finite-strain contact did not converge in {max_iterations} iterations "
                           f"(last motion {moved:.3g} m)")
        force = np.zeros((self.num_points, 3))
        force[idx] = f
        us = us_new  # the converged surface (u is u_new)
        load = self._load(idx, f[None])[:, 0]  # free degrees of freedom, in elimination order
        fint = self.internal_forces(u, cut_cells).ravel()[self._free]
        residual = float(np.linalg.norm(fint - load) / max(np.linalg.norm(load), 1e-30))
        return ContactResult(force, us, sdf(self.points + us)[0], it, len(idx), u, residual,
                             cut_cells_linear=not cut_cells)


class _Friction:
    """The holds of one frictional solve: where each surface point holds on its collider
    (body frame), and, once solved, the points' states and their new holds."""

    def __init__(self, body: QuasiStaticBody, colliders: Indenters, warm: ContactResult | None, tol: float):
        self.colliders, self.tol = colliders, tol
        self.mu = colliders.point_friction()  # [S]
        held = warm is not None and warm.pose is not None
        if held:  # where each point was, carried by its collider's motion from then (none for a collider new to it)
            then = colliders.pose.copy()
            for c, key in enumerate(colliders.keys):
                if key in warm.keys:
                    then[c] = warm.pose[warm.keys.index(key)]
            local = colliders.to_local(body.points + warm.displacement, then)
        else:
            local = colliders.to_local(body.points)
        phi, n = colliders.local_sdf(local)
        local = local - phi[:, None] * n  # a point that comes into contact holds where it lands: its foot on the surface
        if held:  # a stuck point keeps its hold, on the same collider
            now = np.array([colliders.keys.index(k) if k in colliders.keys else -1 for k in warm.keys])
            keep = (warm.state == 1) & (now[warm.owner] == colliders.owner)
            local[keep] = warm.anchors[keep]
        self.rest = body.points
        self.local = local
        self.hold = colliders.to_body(local)
        self.idx = np.zeros(0, np.int64)  # the points of this solve's last contact problem, and their states
        self.state = np.zeros(0, np.int64)
        # (points, forces [m, 3]) the next contact problem starts from (solve_frictional's f0): the
        # last step's loaded points, then the last outer iteration's
        self.last = (np.zeros(0, np.int64), np.zeros((0, 3)))
        if held:
            loaded = np.flatnonzero(np.abs(warm.force).sum(1) > 0)
            self.last = (loaded, warm.force[loaded])

    def finish(self, res: ContactResult) -> None:
        """Store the states and the new holds in ``res``: a stuck point keeps its hold, a
        slipping one holds where it ended, an open one none."""
        S = len(res.gap)
        state = np.zeros(S, np.int64)
        state[self.idx] = self.state
        anchors = np.full((S, 3), np.nan)
        stuck, sliding = state == 1, state == 2
        if len(self.colliders.items) > 1:  # each point's owner for the next solve: the nearest now
            self.local = self.colliders.reassign(self.rest + res.displacement, self.local)
        anchors[stuck] = self.local[stuck]
        anchors[sliding] = self.colliders.to_local(self.rest + res.displacement)[sliding]
        res.state, res.anchors, res.pose = state, anchors, self.colliders.pose.copy()
        res.owner, res.keys = self.colliders.owner.copy(), self.colliders.keys
