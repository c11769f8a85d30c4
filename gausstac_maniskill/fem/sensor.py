"""One pad solved at equilibrium on a moving link, read as the MPM's pads are read.

:class:`EquilibriumPad` holds a pad's quasi-static body (:func:`~.pad.pad_body`, built the
first time the pad touches something), the last contact solution (the warm state: where
stuck points hold, the finite-strain iterate) and turns it into what the tactile maps, the
wrenches and the renderer read from a pad: each particle's world position, deformation
gradient, Cauchy stress and contact force.

The body has one cube element per soft particle, centred on it, so a particle's
displacement is the mean of its element's eight nodes and its stress the element's at its
centre (:func:`~.hex.centre_state`). A surface point (on the link mesh, ``depth`` along
``normal`` from its particle) passes its contact force to its particle. Kinematic particles
ride with the link. Units: SI; "link frame" is the pad's link's frame, "world" the scene's.
"""
from __future__ import annotations

import copy
import functools
import hashlib
import time
from collections import OrderedDict
from typing import Mapping, Sequence

import numpy as np

from ..errors import ConfigError
from .compliance import estimated_bytes
from .contact import ContactResult
from .hex import centre_state, voxel_body
from .pad import collider_indenter, pad_body, pad_lattice

__all__ = ["EquilibriumPad", "PRECOMPUTE_BYTES", "forget_bodies"]

#: Largest compliance [bytes] an :class:`EquilibriumPad` computes in full by default (the index
#: pad at the default dx = 1 mm: 1994 surface points, 143 MB; at dx = 0.75 mm, 452 MB: solved
#: point by point instead).
PRECOMPUTE_BYTES = 256 * 2 ** 20
#: Bodies kept in this process (the most recently used), by pad geometry, material and model: a
#: scene rebuilt at every reset (a task's) finds its pads' factors and compliances again instead
#: of assembling them anew (3 s per pad at the default resolution). Each holds its factor
#: (~0.5 GB at the default resolution) and compliance (143 MB) while kept: the four pads of a
#: hand at the default resolution, about 3 GB. :func:`forget_bodies` lets them go.
BODY_CACHE = 4
_BODIES: OrderedDict = OrderedDict()


def forget_bodies() -> None:
    """Drop the bodies kept in this process (their memory returns once no pad uses them)."""
    _BODIES.clear()


def _body_key(pad, model: str) -> str:
    """Digest of what a pad's body is built from: its particles (rest positions, bond, surface,
    depth and normal of the contact surface), spacing, material and the model."""
    h = hashlib.sha256()
    for a in (pad.rest, pad.kinematic, pad.surface, pad.depth, pad.normal):
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    mat = pad.spec.material
    h.update(repr((pad.spacing, mat.E, mat.nu, model)).encode())
    return h.hexdigest()


class EquilibriumPad:
    """A :class:`~gausstac_maniskill.tactile.pad.Pad` solved at equilibrium against one rigid
    collider at a time (no inertia, no time step: what a pad on a link is at control rates).

    Args:
        pad: the pad (rest geometry in the link frame, particles on a lattice).
        model: ``"linear"`` (small strain; one factored solve per new contact point, then
            dense algebra on the contact points) or ``"neo_hookean"`` (finite strain, fixed-point
            iterations on the linear factor: accurate at the pad's tens of per cent strain,
            seconds per step at 0.5 mm elements). See :class:`~.contact.QuasiStaticBody`.
        geometry: where a ``"linear"`` body reads the contact conditions, ``"deformed"``
            (default: at the displaced surface, as the MPM does) or ``"rest"``.
        precompute: compute the body's compliance among all its surface points when the body
            is built (:meth:`~.contact.QuasiStaticBody.precompute_compliance`: 40 s on the
            2-core VM for the index pad at the default resolution, the first time on a machine,
            then read from the disk cache in 0.1 s), so that a press or a slide costs no sparse
            solve; or (False) solve each point's column when it first comes into contact.
            Default (None): precompute when that compliance takes at most
            :data:`PRECOMPUTE_BYTES` of memory.
    """

    def __init__(self, pad, model: str = "linear", geometry: str = "deformed", precompute: bool | None = None):
        if model not in ("linear", "neo_hookean"):
            raise ConfigError(f"EquilibriumPad({pad.name!r}): model={model!r} must be 'linear' or 'neo_hookean'")
        if geometry not in ("rest", "deformed"):
            raise ConfigError(f"EquilibriumPad({pad.name!r}): geometry={geometry!r} must be 'rest' or 'deformed'")
        self.pad, self.model, self.geometry, self.precompute = pad, model, geometry, precompute
        self.soft = np.flatnonzero(~pad.kinematic)  # pad particle of each element
        self._body = None
        self._source: EquilibriumPad | None = None  # the pad whose body this one uses (share_body)
        self.result: ContactResult | None = None  # the last solve; None: at rest, nothing touches
        self.holder = None  # key of the collider ``result`` holds on
        self.solve_time = 0.0  # wall time [s] of the last solve (and of building the body, the first time)
        self._cache, self._cache_of = {}, object()  # what _derived() computed, and from which result
        self._pose = None  # the collider's frame in the link frame at the last solve [4, 4]
        #: outer iterations of a solve before it gives up (the finite-strain fixed point takes up to ~200)
        self.max_iterations = 60 if model == "linear" else 400
        #: [m] points this close to the collider enter a solve's first iteration; the others join
        #: when they would penetrate. 0: only those touching already (the same equilibrium for
        #: fewer compliance columns: 122 instead of 178 over the sphere's press and slide, 542
        #: instead of 752 for the plate's, than with one element, the body's default)
        self.margin = 0.0

    def share_body(self, other: "EquilibriumPad") -> None:
        """Use ``other``'s body (the same pad in another env of a batch): one factor and one
        compliance for all envs. The body is immutable once built; each pad keeps its own state."""
        if other.shape != self.shape or other.model != self.model:
            raise ConfigError(f"EquilibriumPad({self.pad.name!r}).share_body: the other pad differs "
                              f"(points, nodes {other.shape} vs {self.shape}; model {other.model!r} vs {self.model!r})")
        self._source = other

    @property
    def body(self):
        """The pad's :class:`~.contact.QuasiStaticBody`, assembled and factored on first use
        (and its compliance computed or loaded, see ``precompute``)."""
        if self._source is not None:
            return self._source.body
        if self._body is None:
            key = _body_key(self.pad, self.model)
            body = _BODIES.pop(key, None)
            if body is None:
                body = pad_body(self.pad, model=self.model)
            _BODIES[key] = body  # the most recent last
            while len(_BODIES) > BODY_CACHE:
                _BODIES.popitem(last=False)
            precompute = self.precompute
            if precompute is None:
                precompute = estimated_bytes(body.num_points) <= PRECOMPUTE_BYTES
            if precompute:
                body.precompute_compliance()
            self._body = body
        return self._body

    @property
    def point_particles(self) -> np.ndarray:
        """[S] the pad particle of each of the body's surface points."""
        return self.soft[self.body.point_elements]

    # ------------------------------------------------------------------ solving
    def solve(self, collider, link_pose: np.ndarray, key=None) -> ContactResult:
        """Equilibrium with ``collider`` (an MPM :class:`~gausstac_maniskill.mpm.colliders.Collider`
        at its world pose, its friction coefficient) and the link at world pose ``link_pose``
        [4, 4]. ``key`` names the collider: the last solution warms the next one (and keeps the
        friction holds) only while it is the same collider."""
        t0 = time.perf_counter()
        indenter = collider_indenter(collider, link_pose)
        warm = self.result if self.result is not None and key == self.holder else None
        if warm is not None and self._relative_motion(indenter.pose) <= self.hold_tolerance:
            # the collider has not moved relative to the link: the equilibrium (and with friction
            # every hold: a zero increment slips nowhere) is the last one, to the solver's tolerance
            self.solve_time = time.perf_counter() - t0
            return self.result
        self.result = self.body.solve(indenter, geometry=self.geometry, warm=warm, max_iterations=self.max_iterations,
                                      margin=self.margin)
        self.holder, self._pose = key, indenter.pose
        self.solve_time = time.perf_counter() - t0
        return self.result

    @property
    def hold_tolerance(self) -> float:
        """[m] the contact solve's tolerance (:meth:`QuasiStaticBody.solve`'s default, 1e-4 of an
        element): a collider that moved less than this relative to the link, at every surface
        point of the pad, leaves the last equilibrium standing."""
        return 1e-4 * self.pad.spacing

    def _relative_motion(self, pose: np.ndarray) -> float:
        """[m] how far the collider's motion since the last solve (``pose``: its frame in the link
        frame now) moves the pad's surface points, at most (inf without a last solve)."""
        if self._pose is None:
            return float("inf")
        D = pose @ np.linalg.inv(self._pose)
        p = self.body.points
        return float(np.abs(p @ (D[:3, :3] - np.eye(3)).T + D[:3, 3]).max())

    def release(self) -> None:
        """Nothing touches the pad: the unloaded equilibrium is the rest shape, exactly."""
        self.result, self.holder, self._pose, self.solve_time = None, None, None, 0.0

    @functools.cached_property
    def shape(self) -> tuple[int, int]:
        """(S, V): the body's surface points and nodes, from the pad alone (no assembly)."""
        origin, ijk = pad_lattice(self.pad)
        nodes = voxel_body(ijk[self.soft], origin, self.pad.spacing).nodes
        return int(self.pad.surface[self.soft].sum()), len(nodes)

    def flat_state(self, holders: Sequence[str]) -> dict[str, np.ndarray]:
        """:meth:`state` as a flat dict of fixed-shape arrays (S, V from :attr:`shape`), so that
        the states of identical scenes stack; the holder is stored as its index in ``holders``
        (the names a holder may have), −1 for none."""
        S, V = self.shape
        r = self.result
        out = {"solved": np.array([r is not None]), "force": np.zeros((S, 3)), "displacement": np.zeros((S, 3)),
               "gap": np.zeros(S), "contact_state": np.zeros(S, np.int64), "anchors": np.full((S, 3), np.nan),
               "result_pose": np.eye(4), "has_result_pose": np.array([False]), "nodes": np.zeros((V, 3)),
               "has_nodes": np.array([False]), "counts": np.zeros(2, np.int64), "residual": np.zeros(1),
               "holder": np.array([-1 if self.holder is None else list(holders).index(self.holder)]),
               "pose": np.eye(4) if self._pose is None else self._pose.copy(),
               "has_pose": np.array([self._pose is not None])}
        if r is not None:
            out.update(force=r.force.copy(), displacement=r.displacement.copy(), gap=r.gap.copy(),
                       counts=np.array([r.iterations, r.candidates], np.int64), residual=np.array([r.residual]))
            if r.state is not None:
                out["contact_state"] = r.state.copy()
            if r.anchors is not None:
                out["anchors"] = r.anchors.copy()
            if r.pose is not None:
                out["result_pose"], out["has_result_pose"] = r.pose.copy(), np.array([True])
            if r.nodes is not None:
                out["nodes"], out["has_nodes"] = r.nodes.copy(), np.array([True])
        return out

    def load_flat_state(self, state: Mapping[str, np.ndarray], holders: Sequence[str]) -> None:
        """Restore a :meth:`flat_state` of this pad (bit-exact)."""
        S, V = self.shape
        if np.shape(state["force"]) != (S, 3) or np.shape(state["nodes"]) != (V, 3):
            raise ConfigError(f"EquilibriumPad({self.pad.name!r}).load_flat_state: the state holds "
                              f"{np.shape(state['force'])[0]} surface points and {np.shape(state['nodes'])[0]} "
                              f"nodes, this pad has {S} and {V} (another pad or resolution)")
        def first(key):  # the one value of a [1] entry
            return np.asarray(state[key]).ravel()[0]

        self.release()
        h = int(first("holder"))
        self.holder = None if h < 0 else list(holders)[h]
        self._pose = np.array(state["pose"], np.float64) if bool(first("has_pose")) else None
        if not bool(first("solved")):
            return
        counts = np.asarray(state["counts"]).ravel()
        self.result = ContactResult(
            np.array(state["force"], np.float64), np.array(state["displacement"], np.float64),
            np.array(state["gap"], np.float64), int(counts[0]), int(counts[1]),
            nodes=np.array(state["nodes"], np.float64) if first("has_nodes") else None,
            residual=float(first("residual")),
            state=np.array(state["contact_state"], np.int64),
            anchors=np.array(state["anchors"], np.float64) if first("has_result_pose") else None,
            pose=np.array(state["result_pose"], np.float64) if first("has_result_pose") else None)

    def state(self) -> dict:
        """A copy of what the next solve starts from (restore with :meth:`load_state`)."""
        return copy.deepcopy({"result": self.result, "holder": self.holder, "pose": self._pose})

    def load_state(self, state: dict) -> None:
        """Restore a :meth:`state` of this pad."""
        self.release()
        s = copy.deepcopy(state)
        self.result, self.holder, self._pose = s["result"], s["holder"], s["pose"]

    @property
    def touching(self) -> bool:
        """Whether the last solve left any contact force on the pad."""
        return self.result is not None and bool(np.any(self.result.force))

    def _derived(self) -> dict:
        """The quantities computed from the last solution (node displacements, the particles'
        link-frame state), each once per solution: a new result starts an empty dict."""
        if self._cache_of is not self.result:
            self._cache, self._cache_of = {}, self.result
        return self._cache

    def node_displacement(self) -> np.ndarray:
        """[V, 3] displacement [m] of every node of the body, link frame (zeros at rest; a
        linear body solves once for it after each contact solve, then keeps it)."""
        d = self._derived()
        if "nodes" not in d:
            res = self.result
            if res is None:
                d["nodes"] = np.zeros((len(self.body.body.nodes), 3))
            elif res.nodes is not None:
                d["nodes"] = res.nodes
            else:
                idx = np.flatnonzero(np.abs(res.force).sum(1) > 0)
                d["nodes"] = (self.body.nodal_displacement(idx, res.force[idx]) if len(idx)
                              else np.zeros((len(self.body.body.nodes), 3)))
        return d["nodes"]

    def _local_particles(self):
        """The particles' positions, F, Cauchy stresses and contact forces in the link frame
        (:meth:`particle_state`), computed once per solution."""
        d = self._derived()
        if "particles" not in d:
            pad = self.pad
            n = pad.num_particles
            local = pad.rest.astype(np.float64).copy()
            F = np.tile(np.eye(3), (n, 1, 1))
            sigma = np.zeros((n, 3, 3))
            force = np.zeros((n, 3))
            if self.result is not None:
                body = self.body
                u = self.node_displacement()
                local[self.soft] += u[body.body.element_nodes].mean(1)
                F[self.soft], sigma[self.soft] = centre_state(body.body, u, body.E, body.nu, self.model)
                np.add.at(force, self.point_particles, self.result.force)
            d["particles"] = (local, F, sigma, force)
        return d["particles"]

    # ------------------------------------------------------------------ readout
    def particle_state(self, link_pose: np.ndarray):
        """The pad's particles as the MPM world would hold them, world frame:
        positions [N, 3] m, deformation gradients [N, 3, 3] (link rotation times the
        element's F), Cauchy stresses [N, 3, 3] Pa (zero on kinematic particles) and contact
        forces [N, 3] N (on the particles under a surface point; zero elsewhere)."""
        T = np.asarray(link_pose, float)
        R, t = T[:3, :3], T[:3, 3]
        local, F, sigma, force = self._local_particles()
        return (local @ R.T + t, R @ F, R @ sigma @ R.T, force @ R.T)

    def contact_points(self, link_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The loaded contact points of the last solve, world frame: their displaced positions
        [m, 3] m and the forces [m, 3] N the collider exerts on the pad there. The pad has no
        mass: it passes them to its link, and the collider receives the opposite forces."""
        if self.result is None:
            return np.zeros((0, 3)), np.zeros((0, 3))
        T, res = np.asarray(link_pose, float), self.result
        idx = np.flatnonzero(np.abs(res.force).sum(1) > 0)
        return (self.body.points[idx] + res.displacement[idx]) @ T[:3, :3].T + T[:3, 3], res.force[idx] @ T[:3, :3].T

    def indentation(self) -> float:
        """Largest displacement [m] of a loaded contact point (0 when nothing touches)."""
        if self.result is None:
            return 0.0
        loaded = np.abs(self.result.force).sum(1) > 0
        return float(np.linalg.norm(self.result.displacement[loaded], axis=1).max()) if loaded.any() else 0.0

    def stress_force(self) -> np.ndarray:
        """Total contact force [3] N on the pad read from its stress, link frame: the sum of the
        elements' internal nodal forces over the nodes not held by the bond (minus the bond's
        reaction). At equilibrium it equals the contact force up to the solve's residual, by
        construction of the method: a check that the solve converged, not an independent
        physics reading. (The MPM's virtual-work reading with one-point quadrature at the
        element centres reads +8 % at 1 mm and +13 % at 0.5 mm elements here, from the
        lattice's staircase bond.)"""
        if self.result is None:
            return np.zeros(3)
        body = self.body
        return np.where(body.fixed, 0.0, body.internal_forces(self.node_displacement())).sum(0)
