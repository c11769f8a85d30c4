"""One pad solved at equilibrium on a moving link, read as the MPM's pads are read.

:class:`EquilibriumPad` holds a pad's quasi-static body (:func:`~.pad.pad_body`, built the
first time the pad touches something), the last contact solution (the warm state: where
stuck points hold, the finite-strain iterate) and turns it into what the tactile maps, the
wrenches and the renderer read from a pad: each particle's world position, deformation
gradient, Cauchy stress and contact force.

The body has a cube element centred on each soft particle (the first elements, in order; the
cubes are cut by the layer's surface and bond, and cut cubes without a particle complete it:
:func:`~.pad.pad_cells`), so a particle's displacement is the mean of its element's eight nodes
and its stress the element's at its centre (:func:`~.hex.centre_state`). A surface point (on
the link mesh, ``depth`` along ``normal`` from its particle) passes its contact force to its
particle. Kinematic particles
ride with the link. Units: SI; "link frame" is the pad's link's frame, "world" the scene's.
"""
from __future__ import annotations

import copy
import functools
import time
import warnings
from collections import OrderedDict
from typing import Mapping, Sequence

import numpy as np

from ..cache import array_digest
from ..errors import ConfigError, CostWarning, SimulationWarning
from .compliance import estimated_bytes
from .contact import ContactResult
from .indenters import Indenters
from .hex import centre_state
from .pad import collider_indenter, pad_body, pad_elements

__all__ = ["EquilibriumPad", "PRECOMPUTE_BYTES", "forget_bodies"]

#: Largest compliance [bytes] an :class:`EquilibriumPad` computes in full by default (the index
#: pad at the default dx = 1 mm: 1994 surface points, 143 MB; at dx = 0.75 mm, 452 MB: solved
#: point by point instead).
PRECOMPUTE_BYTES = 256 * 2 ** 20
#: Bodies kept in this process (the most recently used), by pad geometry, material and model: a
#: scene rebuilt at every reset (a task's) finds its pads' factors and compliances again instead
#: of assembling them anew. Each holds its compliance (143 MB at the default resolution), its
#: maps' responses (25 MB) and, once something needs a
#: solve of the whole body (the camera drawing the pad deformed, the finite-strain model, the
#: columns of a pad solved point by point), its factor (~0.5 GB). :func:`forget_bodies` lets them go.
BODY_CACHE = 4
#: Surface motion, as a fraction of the layer's thickness, beyond which a linear pad says its
#: forces are not physical (the tasks' experts stay under 25 %; random actions reach 160 %).
LINEAR_LIMIT = 0.5
#: Smallest relaxation factor of the shape soft objects meet (:meth:`EquilibriumPad.relax_surface`):
#: 1 / (1 + κ) for κ, the object's stiffness over the pad's at the contact, up to 19.
MIN_SURFACE_RELAX = 0.05
_SURFACE_KEYS = ("surface_offset", "surface_change", "surface_solved")  # flat_state's keys of the coupling
_BODIES: OrderedDict = OrderedDict()
_NODES: dict = {}  # nodes of each pad geometry's body (EquilibriumPad.shape), by _body_key


def forget_bodies() -> None:
    """Drop the bodies kept in this process (their memory returns once no pad uses them)."""
    _BODIES.clear()


def _warn_point_by_point(body) -> None:
    """Say that ``body``'s compliance is too large to compute in full by default, what that
    costs, and how to avoid it (:class:`~gausstac_maniskill.errors.CostWarning`)."""
    S = body.num_points
    warnings.warn(CostWarning(
        f"{body.name}: its compliance among {S} surface points would take {estimated_bytes(S) / 1e9:.2f} GB "
        f"(over fem.sensor.PRECOMPUTE_BYTES = {PRECOMPUTE_BYTES / 2 ** 20:.0f} MiB), so it is solved point by "
        f"point: each point that newly comes into contact costs three solves of the whole pad "
        f"({body.num_free} unknowns), seconds per press step on a large pad (`bench patch --pad-solver fem`). "
        f"GaussTacSim(fem_precompute=True) (or BatchedCosim's, or the tasks' kwarg) computes it once instead "
        f"({3 * S} solves, with a progress bar, kept on disk), after which a press costs milliseconds."),
        stacklevel=4)


def _body_key(pad, model: str) -> str:
    """Digest of what a pad's body is built from: its particles (rest positions, bond, surface,
    depth and normal of the contact surface), spacing, layer thickness (where the cut cells
    place the bond), material and the model."""
    mat = pad.spec.material
    return array_digest((pad.rest, pad.kinematic, pad.surface, pad.depth, pad.normal),
                        repr((pad.spacing, pad.spec.thickness, mat.E, mat.nu, model)))


class EquilibriumPad:
    """A :class:`~gausstac_maniskill.tactile.pad.Pad` solved at equilibrium against one rigid
    collider at a time (no inertia, no time step: what a pad on a link is at control rates).

    Args:
        pad: the pad (rest geometry in the link frame, particles on a lattice).
        model: ``"linear"`` (small strain; one factored solve per new contact point, then
            dense algebra on the contact points) or ``"neo_hookean"`` (finite strain, fixed-point
            iterations on the linear factor: accurate at the pad's tens of per cent strain,
            much slower per step). See :class:`~.contact.QuasiStaticBody`.
        geometry: where a ``"linear"`` body reads the contact conditions, ``"deformed"``
            (default: at the displaced surface, as the MPM does) or ``"rest"``.
        precompute: compute the body's compliance among all its surface points when the body
            is built (:meth:`~.contact.QuasiStaticBody.precompute_compliance`, with a linear
            pad's maps' response in the same sweep, the first time on a machine, then read from
            the disk cache), so that a press or a slide costs no sparse
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
        self.solve_time = 0.0  # wall time [s] of the last solve (and of building the body, the first time)
        self._cache, self._cache_of = {}, object()  # what _derived() computed, and from which result
        self._pose: dict | None = None  # {key: the collider's frame in the link frame [4, 4]} at the last solve
        self._strained = False  # the last solve moved the surface beyond LINEAR_LIMIT (warned)
        self._maps_key: tuple = (None, None)  # (binning, its key in the body's derived data), see tactile_maps
        #: outer iterations of a solve before it gives up (the finite-strain fixed point takes up to ~200)
        self.max_iterations = 60 if model == "linear" else 400
        # the shape soft objects meet (relax_surface): the normal offset [S] m of the surface they
        # met in the last step, its change from the step before, the pad's solved shape then, κ
        self._surface: tuple = (None, None, None, 0.0)
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
        """The pad's :class:`~.contact.QuasiStaticBody`, assembled on first use (and its
        compliance computed or loaded, see ``precompute``; its factor comes when a solve needs it)."""
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
                if not precompute:
                    _warn_point_by_point(body)
            if precompute:
                # a linear pad's maps read its default binning's response (tactile_maps): where the
                # compliance has to be computed, that response comes in the same sweep
                body.precompute_compliance(readouts=self._default_readouts(body) if self.model == "linear" else ())
            self._body = body
        return self._body

    def _default_readouts(self, body):
        """A callable giving [the map readout of the pad's default binning] on ``body``
        (:func:`~.maps.map_readout`; built only when asked for)."""
        def readouts():
            from ..tactile.extract import TaxelBinning
            from .maps import map_readout

            return [map_readout(self.pad, body, TaxelBinning.for_pad(self.pad))]

        return readouts

    @property
    def point_particles(self) -> np.ndarray:
        """[S] the pad particle of each of the body's surface points."""
        return self.soft[self.body.point_sources]

    # ------------------------------------------------------------------ solving
    def solve(self, colliders, link_pose: np.ndarray, load: np.ndarray | None = None) -> ContactResult:
        """Equilibrium with ``colliders`` (``{key: MPM Collider}``, each at its world pose, with
        its friction coefficient; the key names it; may be empty where ``load`` is given) and
        the link at world pose ``link_pose`` [4, 4]. Each surface point meets the collider
        nearest it (:class:`~.indenters.Indenters`); the last solution warms the next one, and a
        point's friction hold carries over while it stays on the same collider. ``load``: [S, 3]
        forces [N] on the surface points, link frame, besides the colliders' (a soft object's
        push: :meth:`soft_load`); linear pads only."""
        t0 = time.perf_counter()
        if load is not None and not np.any(load):
            load = None
        indenters = {key: collider_indenter(c, link_pose) for key, c in colliders.items()}
        pose = {key: ind.pose for key, ind in indenters.items()}
        warm = self.result
        if (warm is not None and load is None and warm.load is None
                and self._relative_motion(pose) <= self.hold_tolerance):
            # no collider has moved relative to the link: the equilibrium (and with friction
            # every hold: a zero increment slips nowhere) is the last one, to the solver's tolerance
            self.solve_time = time.perf_counter() - t0
            return self.result
        if indenters:
            self.result = self.body.solve(Indenters(indenters), geometry=self.geometry, warm=warm,
                                          max_iterations=self.max_iterations, margin=self.margin, load=load)
        elif load is not None:  # the load alone: no contact problem
            if self.model != "linear":
                raise ConfigError(f"EquilibriumPad({self.pad.name!r}): a given load needs model='linear'")
            S = self.body.num_points
            self.result = ContactResult(np.zeros((S, 3)), self.body.loaded(load), np.full(S, np.inf), 0, 0,
                                        load=load)
        else:
            self.release()
            return None
        self._pose = pose
        if self.model == "linear":
            self._check_strain()
        self.solve_time = time.perf_counter() - t0
        return self.result

    def _check_strain(self) -> None:
        """Say so (a :class:`~gausstac_maniskill.errors.SimulationWarning`, once each time it
        happens) when the surface moves farther than :data:`LINEAR_LIMIT` of the layer's
        thickness: the linear model's forces are then far from the silicone's."""
        h = self.pad.spec.thickness
        moved = float(np.sqrt((self.result.displacement ** 2).sum(1)).max())
        over = moved > LINEAR_LIMIT * h
        if over and not self._strained:
            warnings.warn(SimulationWarning(
                f"pad {self.pad.name!r} (pad_solver='fem', fem_model='linear'): its surface moved {moved * 1e3:.2f} mm, "
                f"{moved / h:.0%} of its {h * 1e3:g} mm layer, beyond the linear model's small-strain range (at 25 % "
                f"its force is already 7–16 % below finite strain). Its contact forces and maps are not physical "
                f"until it comes back under {LINEAR_LIMIT:.0%}; fem_model='neo_hookean' solves finite strain."),
                stacklevel=4)
        self._strained = over

    @property
    def holders(self) -> tuple:
        """The keys of the colliders the last solution's loaded points touch (sorted)."""
        r = self.result
        if r is None or r.owner is None:
            return ()
        return tuple(sorted({r.keys[c] for c in np.unique(r.owner[np.abs(r.force).sum(1) > 0])}, key=str))

    @property
    def hold_tolerance(self) -> float:
        """[m] the contact solve's tolerance (:meth:`QuasiStaticBody.solve`'s default, 1e-4 of an
        element): colliders that moved less than this relative to the link, at every surface
        point of the pad, leave the last equilibrium standing."""
        return 1e-4 * self.pad.spacing

    def _relative_motion(self, pose: dict) -> float:
        """[m] how far the colliders' motion from the last solve to now (``pose``: {key: its frame in
        the link frame now}) moves the pad's surface points, at most (inf without a last solve
        or with other colliders)."""
        if self._pose is None or set(self._pose) != set(pose):
            return float("inf")
        p = self.body.points
        out = 0.0
        for key, now in pose.items():
            D = now @ np.linalg.inv(self._pose[key])
            out = max(out, float(np.abs(p @ (D[:3, :3] - np.eye(3)).T + D[:3, 3]).max()))
        return out

    def release(self) -> None:
        """Nothing touches the pad: the unloaded equilibrium is the rest shape, exactly."""
        self.result, self._pose, self.solve_time, self._strained = None, None, 0.0, False

    @functools.cached_property
    def shape(self) -> tuple[int, int]:
        """(S, V): the body's surface points and nodes, from the pad alone (no assembly)."""
        key = _body_key(self.pad, self.model)
        if key not in _NODES:  # the same pad in every env of a batch: its cells once
            _NODES[key] = len(pad_elements(self.pad, "cut")[0].nodes)
        return int(self.pad.surface[self.soft].sum()), _NODES[key]

    def flat_state(self, holders: Sequence[str]) -> dict[str, np.ndarray]:
        """:meth:`state` as a flat dict of fixed-shape arrays (S, V from :attr:`shape`, H =
        len(``holders``), the names a collider may have), so that the states of identical scenes
        stack. Colliders are stored by their index in ``holders``."""
        S, V = self.shape
        H = len(holders)
        index = {h: i for i, h in enumerate(holders)}
        r = self.result
        out = {"solved": np.array([r is not None]), "force": np.zeros((S, 3)), "displacement": np.zeros((S, 3)),
               "gap": np.zeros(S), "contact_state": np.zeros(S, np.int64), "anchors": np.full((S, 3), np.nan),
               "result_pose": np.tile(np.eye(4), (H, 1, 1)), "has_result_pose": np.zeros(H, bool),
               "owner": np.full(S, -1, np.int64), "nodes": np.zeros((V, 3)),
               "has_nodes": np.array([False]), "counts": np.zeros(2, np.int64), "residual": np.zeros(1),
               "cut_cells_linear": np.array([False]), "load": np.zeros((S, 3)),
               "surface_offset": np.zeros(S), "surface_change": np.zeros(S), "surface_solved": np.zeros(S),
               "surface_has": np.zeros(3, bool), "surface_kappa": np.array([self._surface[3]]),
               "pose": np.tile(np.eye(4), (H, 1, 1)), "has_pose": np.zeros(H, bool)}
        for key, T in (self._pose or {}).items():
            out["pose"][index[key]], out["has_pose"][index[key]] = T, True
        for i, (key, value) in enumerate(zip(_SURFACE_KEYS, self._surface[:3])):
            if value is not None:
                out[key], out["surface_has"][i] = value.copy(), True
        if r is not None:
            out.update(force=r.force.copy(), displacement=r.displacement.copy(), gap=r.gap.copy(),
                       counts=np.array([r.iterations, r.candidates], np.int64), residual=np.array([r.residual]),
                       cut_cells_linear=np.array([r.cut_cells_linear]),
                       load=np.zeros((S, 3)) if r.load is None else r.load.copy())
            if r.state is not None:
                out["contact_state"] = r.state.copy()
            if r.anchors is not None:
                out["anchors"] = r.anchors.copy()
            if r.owner is not None:
                slots = np.array([index[k] for k in r.keys])
                out["owner"] = slots[r.owner]
                if r.pose is not None:
                    out["result_pose"][slots], out["has_result_pose"][slots] = r.pose, True
            if r.nodes is not None:
                out["nodes"], out["has_nodes"] = r.nodes.copy(), np.array([True])
        return out

    def load_flat_state(self, state: Mapping[str, np.ndarray], holders: Sequence[str]) -> None:
        """Restore a :meth:`flat_state` of this pad (bit-exact)."""
        S, V = self.shape
        missing = sorted({"force", "nodes", "owner", "pose", "has_pose", "result_pose", "has_result_pose"} - set(state))
        if missing:
            raise ConfigError(f"EquilibriumPad({self.pad.name!r}).load_flat_state: the state lacks {missing} "
                              "(saved by another version of gausstac_maniskill?)")
        if np.shape(state["force"]) != (S, 3) or np.shape(state["nodes"]) != (V, 3):
            raise ConfigError(f"EquilibriumPad({self.pad.name!r}).load_flat_state: the state holds "
                              f"{np.shape(state['force'])[0]} surface points and {np.shape(state['nodes'])[0]} "
                              f"nodes, this pad has {S} and {V} (another pad or resolution)")
        if np.shape(state["pose"]) != (len(holders), 4, 4):
            raise ConfigError(f"EquilibriumPad({self.pad.name!r}).load_flat_state: the state holds the poses of "
                              f"{np.shape(state['pose'])[0]} objects, this scene has {len(holders)} ({list(holders)})")

        def first(key):  # the one value of a [1] entry
            return np.asarray(state[key]).ravel()[0]

        self.release()
        self._surface = (None, None, None, 0.0)
        if "surface_has" in state:  # (a state without the soft-object coupling: none)
            has = np.asarray(state["surface_has"], bool)
            self._surface = tuple(np.array(state[key], np.float64) if h else None
                                  for key, h in zip(_SURFACE_KEYS, has)) + (float(first("surface_kappa")),)
        has_pose = np.asarray(state["has_pose"], bool)
        if has_pose.any():
            self._pose = {holders[h]: np.array(state["pose"][h], np.float64) for h in np.flatnonzero(has_pose)}
        if not bool(first("solved")):
            return
        counts = np.asarray(state["counts"]).ravel()
        owner = np.asarray(state["owner"], np.int64)
        slots = np.flatnonzero(np.asarray(state["has_result_pose"], bool))
        frictional = len(slots) > 0
        keys, pose = (None,), None
        if frictional:  # the solve's colliders: those with a pose
            position = np.full(len(holders), -1, np.int64)
            position[slots] = np.arange(len(slots))
            keys, owner, pose = tuple(holders[h] for h in slots), position[owner], np.array(state["result_pose"][slots])
        elif (owner >= 0).any():
            keys = tuple(holders)
        else:
            owner = None
        self.result = ContactResult(
            np.array(state["force"], np.float64), np.array(state["displacement"], np.float64),
            np.array(state["gap"], np.float64), int(counts[0]), int(counts[1]),
            nodes=np.array(state["nodes"], np.float64) if first("has_nodes") else None,
            residual=float(first("residual")),
            # (a state without it: the cut cubes finite)
            cut_cells_linear=bool(first("cut_cells_linear")) if "cut_cells_linear" in state else False,
            load=np.array(state["load"], np.float64) if "load" in state and np.any(state["load"]) else None,
            state=np.array(state["contact_state"], np.int64),
            anchors=np.array(state["anchors"], np.float64) if frictional else None,
            pose=pose, owner=owner, keys=keys)

    def state(self) -> dict:
        """A copy of what the next solve starts from (restore with :meth:`load_state`)."""
        return copy.deepcopy({"result": self.result, "pose": self._pose, "surface": self._surface})

    def load_state(self, state: dict) -> None:
        """Restore a :meth:`state` of this pad."""
        self.release()
        s = copy.deepcopy(state)
        self.result, self._pose = s["result"], s["pose"]
        self._surface = s.get("surface", (None, None, None, 0.0))

    @property
    def touching(self) -> bool:
        """Whether the last solve left any contact force on the pad."""
        return self.result is not None and bool(np.any(self.result.surface_force))

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
                force = res.surface_force
                idx = np.flatnonzero(np.abs(force).sum(1) > 0)
                d["nodes"] = (self.body.nodal_displacement(idx, force[idx]) if len(idx)
                              else np.zeros((len(self.body.body.nodes), 3)))
        return d["nodes"]

    def tactile_maps(self, binning) -> dict | None:
        """The tactile maps of the last solution under ``binning`` (a
        :class:`~gausstac_maniskill.tactile.extract.TaxelBinning` of this pad), as
        :func:`~gausstac_maniskill.tactile.extract.tactile_maps` gives them, read as one matrix
        times the contact forces (:class:`~.maps.PadMaps`: no solve of the body); None where
        that does not apply (finite strain, or a body without its full compliance): read
        :meth:`particle_state` then."""
        if self.result is None or self.model != "linear" or not self.body.has_compliance:
            return None
        from .maps import PadMaps

        if self._maps_key[0] is not binning:  # the digest once per binning
            digest = array_digest((binning.taxel, binning.weight, self.pad.sensor_frame, self.point_particles))
            self._maps_key = (binning, ("maps", digest))
        key = self._maps_key[1]
        derived = self.body.derived
        if key not in derived:
            derived[key] = PadMaps(self.pad, self.body, binning, self.point_particles)
        return derived[key].maps(self.result.surface_force)

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
                cubes = body.body.first(len(self.soft))  # element e is soft particle e's cube (pad_body)
                local[self.soft] += u[cubes.element_nodes].mean(1)
                F[self.soft], sigma[self.soft] = centre_state(cubes, u, body.E, body.nu, self.model)
                np.add.at(force, self.point_particles, self.result.surface_force)
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

    def _loaded(self, key=None) -> np.ndarray:
        """The surface points the last solve loaded (on collider ``key`` only, if given)."""
        res = self.result
        loaded = np.abs(res.force).sum(1) > 0
        if key is not None and res.owner is not None:
            loaded &= res.owner == (res.keys.index(key) if key in res.keys else -1)
        return np.flatnonzero(loaded)

    def _given(self) -> np.ndarray:
        """The surface points the last solve's given load (:meth:`soft_load`) acts on."""
        r = self.result
        return np.zeros(0, np.int64) if r is None or r.load is None else np.flatnonzero(np.abs(r.load).sum(1) > 0)

    def _world_points(self, idx: np.ndarray, force: np.ndarray, link_pose: np.ndarray):
        """Surface points ``idx`` displaced, and ``force`` [S, 3] there, in the world frame."""
        T = np.asarray(link_pose, float)
        return (self.body.points[idx] + self.result.displacement[idx]) @ T[:3, :3].T + T[:3, 3], force[idx] @ T[:3, :3].T

    def _depth(self, idx: np.ndarray) -> float:
        """Largest displacement [m] of surface points ``idx`` (0 for none)."""
        return float(np.linalg.norm(self.result.displacement[idx], axis=1).max()) if len(idx) else 0.0

    def contact_points(self, link_pose: np.ndarray, key=None) -> tuple[np.ndarray, np.ndarray]:
        """The loaded contact points of the last solve (those on collider ``key`` only, if
        given), world frame: their displaced positions [m, 3] m and the forces [m, 3] N the
        collider exerts on the pad there. The pad has no mass: it passes them to its link, and
        the collider receives the opposite forces."""
        if self.result is None:
            return np.zeros((0, 3)), np.zeros((0, 3))
        return self._world_points(self._loaded(key), self.result.force, link_pose)

    def indentation(self, key=None) -> float:
        """Largest displacement [m] of a loaded contact point (on collider ``key`` only, if
        given; 0 when nothing touches)."""
        return 0.0 if self.result is None else self._depth(self._loaded(key))

    def soft_load(self, positions: np.ndarray, forces: np.ndarray, link_pose: np.ndarray) -> np.ndarray:
        """[S, 3] link-frame load [N] on the surface points from forces [m, 3] N (world frame)
        that soft bodies exert at world ``positions`` [m, 3] m on the pad's surface (for
        :meth:`solve`'s ``load``): each force goes to the surface point nearest to where it acts."""
        T = np.asarray(link_pose, float)
        R, t = T[:3, :3], T[:3, 3]
        load = np.zeros((self.body.num_points, 3))
        if len(positions):
            np.add.at(load, self.nearest_points((np.asarray(positions, float) - t) @ R), np.asarray(forces, float) @ R)
        return load

    def nearest_points(self, local: np.ndarray) -> np.ndarray:
        """[m] the body's surface point nearest to each link-frame point ``local`` [m, 3] m (at rest)."""
        from scipy.spatial import cKDTree

        derived = self.body.derived
        if "point_tree" not in derived:  # the rest surface points, searched once per body
            derived["point_tree"] = cKDTree(self.body.points)
        return derived["point_tree"].query(local)[1]

    def grid_nearest_points(self, origin, spacing: float, shape) -> np.ndarray:
        """[nx·ny·nz] the surface point nearest each node of the link-frame grid ``origin`` +
        ``spacing``·ijk of ``shape`` (a surface collider's SDF grid), computed once per body and grid."""
        key = ("grid_nearest", tuple(np.asarray(origin, np.float64)), float(spacing), tuple(shape))
        derived = self.body.derived
        if key not in derived:
            lo = np.asarray(origin, np.float64)
            axes = [lo[d] + spacing * np.arange(shape[d]) for d in range(3)]
            derived[key] = self.nearest_points(np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3))
        return derived[key]

    def normal_displacement(self) -> np.ndarray:
        """[S] the last solution's displacement [m] of each surface point along its outward
        normal (negative: pushed in; zeros at rest)."""
        if self.result is None:
            return np.zeros(self.body.num_points)
        return np.einsum("si,si->s", self.result.displacement, self.pad.normal[self.point_particles])

    def load_points(self, link_pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The surface points of the last solve's given load (:meth:`soft_load`), world frame:
        their displaced positions [m, 3] m and the forces [m, 3] N on the pad there."""
        idx = self._given()
        if not len(idx):
            return np.zeros((0, 3)), np.zeros((0, 3))
        return self._world_points(idx, self.result.load, link_pose)

    def load_indentation(self) -> float:
        """Largest displacement [m] of a point under the last solve's given load (0 without one)."""
        return self._depth(self._given())

    def relax_surface(self) -> np.ndarray | None:
        """[S] the outward normal offset [m] of the surface that soft objects meet in the next step
        (the pad's surface collider, :meth:`~gausstac_maniskill.cosim.GaussTacSim.add_soft_object`).

        The object's push in a step loads the pad, whose solved shape u is what the object meets
        next: a staggered (Dirichlet–Neumann) coupling. Where the object is as stiff as the pad,
        the shape it meets and the shape solved from it swing about the balance for good (κ ≈ 1:
        the solved shape falls by κ times what the met one rose), and grow where it is stiffer. The
        shape it meets is therefore relaxed, s ← s + ω (u − s) with ω = 1 / (1 + κ), which puts a
        fixed contact at its balance in one step; κ = −Δu·Δs / Δs·Δs is read from the last two
        steps' changes (Δs the met shape's, Δu the solved one's). An object that moves moves both
        the same way (κ ≤ 0: ω = 1, no lag); κ is kept from step to step while the met shape
        hardly changes. At rest (no solution) it is the rest shape (None), and κ starts again
        from 0. Call it once per step: it advances the coupling."""
        if self.result is None:
            self._surface = (None, None, None, 0.0)
            return None
        offset, change, solved, kappa = self._surface
        u = self.normal_displacement()
        if offset is None:
            offset = np.zeros_like(u)
        if change is not None and solved is not None:
            d = float(change @ change)
            if d > self.hold_tolerance ** 2 * len(u):  # the met shape changed beyond the solve's tolerance
                kappa = max(0.0, -float((u - solved) @ change) / d)
        relax = max(MIN_SURFACE_RELAX, 1.0 / (1.0 + kappa))
        step = relax * (u - offset)
        self._surface = (offset + step, step, u, kappa)
        return offset + step

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
        forces = body.internal_forces(self.node_displacement(), cut_cells=not self.result.cut_cells_linear)
        return np.where(body.fixed, 0.0, forces).sum(0)
