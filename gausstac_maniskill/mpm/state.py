"""Where an MPM world keeps its state (:class:`WorldState`, part of
:class:`~gausstac_maniskill.mpm.solver.MPMWorld`): the per-particle arrays on the host and their
device copies (:class:`ParticleArrays`), the other device arrays, the kernels' argument packs over
them, the active lists, the per-step uploads (constants, poses), and ``state_dict`` /
``load_state_dict``, whole or per env."""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np
import taichi as ti

from ..errors import ConfigError
from ..geometry.colliders import MeshCollider
from ..geometry.kinematics import FRAME
from ..transforms import matrix_to_quat
from . import kernels as K
from .materials import material_table
from .model import REST_FIELDS, GroupModel, _env_index, no_anchor


class Group:
    """A particle group of a world: its description (``model``, a :class:`~.model.GroupModel`,
    whose fields read through: ``g.start``, ``g.link``, ...) and what changes while the world
    steps: whether it is awake, its link's pose when it fell asleep, its active-patch state and
    whether it holds (its pseudo-mass times ``hold_scaling``) with the drift that decides it."""

    __slots__ = ("model", "awake", "sleep_pose", "patch_state", "hold", "drift")

    def __init__(self, model: GroupModel):
        self.model = model
        self.awake = True
        self.sleep_pose: np.ndarray | None = None  # link pose when the group fell asleep
        self.patch_state = 0  # active patch (mpm.patch): 0 at rest, 1 patched in contact, 2 released (whole)
        self.hold = False  # quasi-static: held and settled, its pseudo-mass times settings.hold_scaling
        self.drift = math.inf  # quasi-static: largest particle speed relative to its link at the last step's end [m/s]

    def __getattr__(self, name: str):
        return getattr(object.__getattribute__(self, "model"), name)

    def __setattr__(self, name: str, value) -> None:
        if name not in Group.__slots__:
            raise AttributeError(f"Group.{name} is part of the world's model (GroupModel), fixed when the "
                                 f"group was added")
        object.__setattr__(self, name, value)

    @property
    def stop(self) -> int:
        return self.model.stop

    def __repr__(self) -> str:
        return f"Group({self.model!r}, awake={self.awake}, patch_state={self.patch_state}, hold={self.hold})"


class ParticleField(NamedTuple):
    """One per-particle array of the world (host ``_host_parts.<key>``, device
    ``_dev_parts.<key>``: :class:`ParticleArrays`, [N, *row] rows in group order; a row's env is
    its group's ``env``)."""

    dtype: object  # Taichi scalar type of the device array
    row: tuple  # shape of one row: () scalar, (k,) vector, (k, k) matrix
    unit: str
    doc: str


#: every per-particle array, in the order _push uploads them
PARTICLE_FIELDS = {
    "x": ParticleField(ti.f32, (3,), "m", "position"),
    "v": ParticleField(ti.f32, (3,), "m/s", "velocity"),
    "impulse": ParticleField(ti.f32, (3,), "N s", "contact impulse of the last control step"),
    "X0": ParticleField(ti.f32, (3,), "m", "rest coordinates in the link frame (0 without a link)"),
    "bond": ParticleField(ti.f32, (4,), "-, m", "bond surface normal (link frame), signed distance (0: none)"),
    "anchor": ParticleField(ti.f32, (4,), "m, -", "static friction: stuck point in its collider's frame, collider"),
    "C": ParticleField(ti.f32, (3, 3), "1/s", "APIC velocity gradient"),
    "F": ParticleField(ti.f32, (3, 3), "-", "deformation gradient"),
    "tau": ParticleField(ti.f32, (3, 3), "Pa", "Kirchhoff stress"),
    "Jp": ParticleField(ti.f32, (), "-", "plastic volume change"),
    "mass": ParticleField(ti.f32, (), "kg", "mass (a quasi-static group's pseudo-mass)"),
    "vol": ParticleField(ti.f32, (), "m³", "rest volume"),
    "radius": ParticleField(ti.f32, (), "m", "contact radius"),
    "kind": ParticleField(ti.i32, (), "-", "kernels.DYNAMIC or KINEMATIC"),
    "matid": ParticleField(ti.i32, (), "-", "material row"),
    "link": ParticleField(ti.i32, (), "-", "link (-1: none)"),
    "group": ParticleField(ti.i32, (), "-", "group"),
    "contact_id": ParticleField(ti.i32, (), "-", "collider touched (-1: none, kernels.SOFT_CONTACT the other field)"),
}
@dataclass(eq=False)
class ParticleArrays:
    """The per-particle arrays of a world, one attribute per entry of :data:`PARTICLE_FIELDS`
    (same name, dtype, row and unit), plus ``env``. Rows are particles in group order ([N, ...],
    N = the world's particle count). The world holds two: ``_host_parts`` (numpy arrays, the
    state as built and as last read back) and ``_dev_parts`` (their Taichi ndarray copies, which
    the kernels step). On the host, the rest fields (:data:`~.model.REST_FIELDS`: ``X0``,
    ``bond``, ``vol``, ``radius``, ``kind``, ``matid``, ``link``, ``group``, ``env``) are the
    world model's read-only arrays; the others are the state. An attribute is None until the
    first group (host) or the first upload with particles (device). ``env`` is host-only (None
    on the device: the kernels find a particle's env through its group). The other device
    arrays (grid, cells, links, colliders, counts, constants, SDF, active lists, the patch's
    arrays) are the world's ``_dev``."""

    x: Any = None  #: [N, 3] f32, m: position
    v: Any = None  #: [N, 3] f32, m/s: velocity
    impulse: Any = None  #: [N, 3] f32, N s: contact impulse of the last control step
    X0: Any = None  #: [N, 3] f32, m: rest coordinates in the link frame (0 without a link)
    bond: Any = None  #: [N, 4] f32, (-, m): bond surface normal (link frame), signed distance (0: none)
    anchor: Any = None  #: [N, 4] f32, (m, -): static friction: stuck point in its collider's frame, collider
    C: Any = None  #: [N, 3, 3] f32, 1/s: APIC velocity gradient
    F: Any = None  #: [N, 3, 3] f32, -: deformation gradient
    tau: Any = None  #: [N, 3, 3] f32, Pa: Kirchhoff stress
    Jp: Any = None  #: [N] f32, -: plastic volume change
    mass: Any = None  #: [N] f32, kg: mass (a quasi-static group's pseudo-mass)
    vol: Any = None  #: [N] f32, m³: rest volume
    radius: Any = None  #: [N] f32, m: contact radius
    kind: Any = None  #: [N] i32: kernels.DYNAMIC or KINEMATIC
    matid: Any = None  #: [N] i32: material row
    link: Any = None  #: [N] i32: link (-1: none)
    group: Any = None  #: [N] i32: group
    contact_id: Any = None  #: [N] i32: collider touched (-1: none, kernels.SOFT_CONTACT the other field)
    env: Any = None  #: [N] i32: env of the particle's group (host only)

    def get(self, key: str):
        """The array called ``key`` (None where there is none yet)."""
        return getattr(self, key)

    def set(self, key: str, arr) -> None:
        """Make ``arr`` the array called ``key``."""
        if key not in _PARTICLE_KEYS:
            raise KeyError(key)
        setattr(self, key, arr)


_PARTICLE_KEYS = frozenset(f.name for f in fields(ParticleArrays))
assert [f.name for f in fields(ParticleArrays)] == [*PARTICLE_FIELDS, "env"]

@dataclass(eq=False)
class DeviceArrays:
    """The world's device arrays other than the per-particle ones (Taichi ndarrays, None until
    the first upload). The kernels' argument packs (:mod:`~.kernels.layout`: Grid, Scene, Order,
    Placement, Reduction) group them, and document each member's meaning; the shapes are
    M grid nodes (every box copy), K cell slots, N particle rows, G groups, L links, C
    colliders, E envs."""

    # grid [M] (kernels.Grid), sized by _alloc_grid, grown with the active box
    grid_pm: Any = None  #: [M, 4] momentum [kg m/s], mass [kg]
    grid_v: Any = None  #: [M, 3] velocity [m/s]
    grid_m: Any = None  #: [M] mass [kg]
    grid_mq: Any = None  #: [M] quasi-static mass [kg]
    grid_link: Any = None  #: [M] link of bound and quasi-static particles
    grid_dp: Any = None  #: [M, 3] particle-detected contact momentum [N s]
    grid_vol: Any = None  #: [M, 2] F-bar volume sums [m³]
    grid_vc: Any = None  #: [M] two fields: deformed volume [m³]
    grid_ds: Any = None  #: [M, 3] two fields: field 0's contact Δv [m/s]
    grid_kin: Any = None  #: [M, 6] bound particles' bond sums
    grid_t: Any = None  #: [M, 3] cell pressure: M⁻¹ G q
    cell_slot: Any = None  #: [M] cell pressure: box cell -> slot (-1: none)
    # cell pressure [K] (kernels.pressure_solve)
    slot_cell: Any = None  #: [K] slot -> box cell
    cell_a: Any = None  #: [K, 4] per slot: volume sums, CG diagonal
    cell_b: Any = None  #: [K, 4] per slot: CG vectors
    cell_G: Any = None  #: [64 K, 3] Σ V0 ∇w per slot and node [m²]
    cell_count: Any = None  #: [2] slots used, overflow flag
    cg_sum: Any = None  #: [CG_ROWS] CG reductions
    # scene (kernels.Scene)
    counts: Any = None  #: [7] rows N_LINKS ... N_ENVS
    consts: Any = None  #: [9] rows DX ... BOND
    mat_table: Any = None  #: [materials, *] materials.material_table
    env_relax: Any = None  #: [E] relaxation rate ζ of each env's quasi-static nodes [1/s]
    walls: Any = None  #: [walls, 3] (axis, position [m], side)
    group_qs: Any = None  #: [G] quasi-static?
    group_tear: Any = None  #: [G] tear distance [m]
    group_field: Any = None  #: [G] velocity field
    group_env: Any = None  #: [G] env
    group_copy: Any = None  #: [G] box copy in the grid arrays
    group_link: Any = None  #: [G] link (-1: none)
    group_bind: Any = None  #: [G, 4] binding quaternion
    group_frames: Any = None  #: [G, FRAME] binding frames
    torn: Any = None  #: [G] particles past their tear distance
    group_touched: Any = None  #: [G] touched this step
    group_drift: Any = None  #: [G] largest speed relative to the link [m/s]
    link_pose: Any = None  #: [L, 14] pose rows of the step (start, end)
    link_frames: Any = None  #: [L, FRAME] frame rows
    twist_change: Any = None  #: [L, 9] change of each link's motion over the step
    pair_impulse: Any = None  #: [L · slots, 7] per (link, slot): J, moment, depth
    col_kind: Any = None  #: [C] shape
    col_prm: Any = None  #: [C, 4] shape parameters [m]
    col_friction: Any = None  #: [C, 2] (μ, 1 if sticky)
    col_bound: Any = None  #: [C] bounding radius [m]
    col_env: Any = None  #: [C] env
    col_slot: Any = None  #: [C] pair slot
    col_pose: Any = None  #: [C, 14] pose rows of the step
    col_frames: Any = None  #: [C, FRAME] frame rows
    col_impulse: Any = None  #: [C, 6] grid-contact reaction (impulse [N s], moment [N m s])
    sdf: Any = None  #: [samples] mesh colliders' SDF values [m]
    sdf_info: Any = None  #: [C, 4] (offset, samples along x, y, z)
    # active lists and the particle order (kernels.Order, Placement)
    active: Any = None  #: [N] awake particle rows, env-major
    active_kin: Any = None  #: [N] the kinematic ones among them
    env_rows: Any = None  #: [E + 1] where each env's rows start in ``active``
    order: Any = None  #: [N] awake particles sorted by slab
    slab_of: Any = None  #: [N] each particle's slab
    slab_start: Any = None  #: [SLAB_CAP] first index of each slab
    cursor: Any = None  #: [SLAB_CAP] slab sort cursors
    bounds: Any = None  #: [NCHUNK, 6] per chunk: bounding box [cells]
    box: Any = None  #: [BOX] the active box
    first_bad: Any = None  #: [NCHUNK] first non-finite particle per chunk
    vmax_chunk: Any = None  #: [NCHUNK] largest speed per chunk [m/s]
    # active patch (mpm.patch)
    X_rest: Any = None  #: [N, 3] rest coordinates as built (the device's X0 is rebound)
    patch_gap: Any = None  #: [N] rest gap to the nearest collider [m]
    patch_cand: Any = None  #: [N] candidate rows
    patch_frozen: Any = None  #: [N] frozen rows
    patch_bind: Any = None  #: [N] rows bound to the link this step
    patch_contact: Any = None  #: [G] in contact?


#: the particle fields a step changes: what state_dict holds and _pull brings back
_STATE_FIELDS = ("x", "v", "C", "F", "tau", "Jp", "impulse", "contact_id", "anchor")


def _renumber(parts: dict, new_id: np.ndarray) -> None:
    """Map the collider ids (>= 0) of the particles' contacts and static-friction anchors
    through ``new_id`` (old id -> new id), in place."""
    cid = parts["contact_id"]
    hit = cid >= 0
    cid[hit] = new_id[cid[hit]]
    a = parts["anchor"][:, 3]
    stuck = a >= 0
    a[stuck] = new_id[a[stuck].astype(int)]


class WorldState:
    """The host and device arrays of an :class:`~gausstac_maniskill.mpm.solver.MPMWorld` (a part of
    it: the arrays are the world's)."""

    def _grow_particles(self, rows: dict) -> None:
        """The host arrays after the model gained a group: its rest fields are the model's,
        its state fields these plus ``rows`` (one array per state field, the new group's)."""
        hp = self._host_parts
        for key, arr in rows.items():
            old = hp.get(key)
            hp.set(key, arr if old is None else np.concatenate([old, arr]))
        for key in REST_FIELDS:
            hp.set(key, getattr(self.model.particles, key))

    def _upload_counts(self) -> None:
        self._dev.counts.from_numpy(np.array([len(self.link_names), len(self.groups), len(self.colliders),
                                                 len(self.model.walls), self._n_active, self._n_kin, self.num_envs],
                                                np.int32))

    def _sdf_values(self) -> np.ndarray:
        """Every mesh collider's SDF samples, one after another (``sdf_info`` holds the offsets)."""
        parts = [c.sdf.ravel() for c in self.colliders if isinstance(c, MeshCollider)]
        return np.concatenate(parts) if parts else np.zeros(1, np.float32)

    def _upload_consts(self) -> None:
        """Scene constants of the kernels (kernels.DX ...): spacing, gravity, damping rate,
        reach, margin, friction between the two velocity fields, bond mode; and per env the
        relaxation rate ζ of its quasi-static nodes (the largest of its awake groups)."""
        s = self.settings
        rate = np.zeros(self.num_envs, np.float32)
        for g in self.groups:
            if g.awake and g.quasi_static:
                rate[g.env] = max(rate[g.env], g.relaxation / math.sqrt(self._hold_factor(g)))
        self._dev.env_relax.from_numpy(rate)
        self._dev.consts.from_numpy(np.array([s.dx, *s.gravity, s.damping, self._reach, s.grid_margin,
                                                 s.soft_friction, float(s.bond == "surface")], np.float32))

    def _alloc_grid(self, cap: int) -> None:
        d = self._dev
        d.grid_pm = ti.Vector.ndarray(4, ti.f32, shape=cap)
        d.grid_v = ti.Vector.ndarray(3, ti.f32, shape=cap)
        d.grid_m = ti.ndarray(ti.f32, shape=cap)
        d.grid_mq = ti.ndarray(ti.f32, shape=cap)
        d.grid_link = ti.ndarray(ti.i32, shape=cap)
        d.grid_dp = ti.Vector.ndarray(3, ti.f32, shape=cap)
        d.grid_vol = ti.Vector.ndarray(2, ti.f32, shape=cap)
        d.grid_vc = ti.ndarray(ti.f32, shape=cap)
        d.grid_ds = ti.Vector.ndarray(3, ti.f32, shape=cap)
        d.grid_kin = ti.Vector.ndarray(6, ti.f32, shape=cap)
        d.cell_slot = ti.ndarray(ti.i32, shape=cap)
        d.grid_t = ti.Vector.ndarray(3, ti.f32, shape=cap)
        self._grid_cap = cap
        self._alloc_cells()

    def _alloc_cells(self) -> None:
        """Per-cell arrays of the cell pressure (kernels.pressure_solve): room for one occupied cell
        per two particles (8 per cell when seeded; kernels.number_cells flags an overflow, which
        step() reports); and the Grid pack."""
        d = self._dev
        cells = max(self.num_particles // 2, 1) + 64 if self._cellp else 1
        if d.slot_cell is None or d.slot_cell.shape[0] != cells:
            d.slot_cell = ti.ndarray(ti.i32, shape=cells)
            d.cell_a = ti.Vector.ndarray(4, ti.f32, shape=cells)
            d.cell_b = ti.Vector.ndarray(4, ti.f32, shape=cells)
            d.cell_G = ti.Vector.ndarray(3, ti.f32, shape=cells * 64)
        if d.cell_count is None:
            d.cell_count = ti.ndarray(ti.i32, shape=2)
            d.cg_sum = ti.ndarray(ti.f32, shape=K.CG_ROWS)
        self._pack["W"] = None
        self._pack["G"] = K.Grid(**{k: getattr(d, k) for k in ("grid_pm", "grid_v", "grid_m", "grid_mq", "grid_link",
                                                       "grid_dp", "grid_vol", "grid_vc", "grid_ds", "grid_kin",
                                                       "cell_slot", "slot_cell", "cell_count",
                                                       "cell_a", "cell_b", "cell_G", "grid_t", "cg_sum")})

    def _env_major(self, parts) -> tuple[np.ndarray, np.ndarray]:
        """The active list from ``parts`` [(env, particle rows)] in group order: env by env
        (each env's rows in their order: a node only ever sums its own env's particles, so
        this order changes no sum), and where each env's rows start in it ([num_envs + 1])."""
        parts = sorted(parts, key=lambda p: p[0])  # stable: group order within an env
        active = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0, np.int32)
        count = np.bincount([p[0] for p in parts], [len(p[1]) for p in parts], minlength=self.num_envs)
        return active.astype(np.int32), np.concatenate([[0], np.cumsum(count)]).astype(np.int32)

    def _pull(self, keys=_STATE_FIELDS) -> None:
        """Copy the state fields ``keys`` (all by default) back to the host arrays, those the
        device holds newer: a read after a step copies only the field it reads, not the
        whole particle state."""
        stale = getattr(self, "_stale", None)
        if stale and self._dev.counts is not None:
            hp, dp = self._host_parts, self._dev_parts
            for key in [k for k in keys if k in stale and dp.get(k) is not None]:
                hp.set(key, dp.get(key).to_numpy()[: self.num_particles])
                stale.discard(key)

    def _push(self) -> None:
        """(Re)build device arrays from the host after any structural change; after groups
        only woke or fell asleep, renew just the active lists (:meth:`_refresh_active`)."""
        if not self._dirty:
            if self._awake_changed:
                self._refresh_active()
            if self._sdf_stale:
                self._dev.sdf.from_numpy(self._sdf_values())
                self._sdf_stale = False
            return
        self.rebuilds += 1
        self._pull()
        if self.num_particles == 0 and not self.groups:
            self._n_active = 0
            self._n_kin = 0
        d, hp, dp = self._dev, self._host_parts, self._dev_parts
        n = max(self.num_particles, 1)

        def make(arr, dtype, shape=()):
            nd = (ti.Vector.ndarray(shape[0], dtype, shape=len(arr)) if len(shape) == 1 else
                  ti.Matrix.ndarray(shape[0], shape[1], dtype, shape=len(arr)) if len(shape) == 2 else
                  ti.ndarray(dtype, shape=arr.shape))
            nd.from_numpy(np.ascontiguousarray(arr))
            return nd

        def upload(key, arr, dtype, shape=()):
            setattr(d, key, make(arr, dtype, shape))

        if self.num_particles:
            for key, f in PARTICLE_FIELDS.items():
                dp.set(key, make(hp.get(key), f.dtype, f.row))
            upload("group_bind", self.model.group_bind, ti.f32)
        self._fbar, self._cellp = self._stress_flags()  # from the materials, which only _push sees change
        # room for every particle: the lists are rewritten when groups wake or sleep, and with
        # the active patch every step
        d.active, d.active_kin = ti.ndarray(ti.i32, shape=n), ti.ndarray(ti.i32, shape=n)
        d.env_rows = ti.ndarray(ti.i32, shape=self.num_envs + 1)
        if self._patch is not None:
            self._patch.forget()
            upload("X_rest", hp.X0 if self.num_particles else np.zeros((1, 3), np.float32), ti.f32, (3,))
            for key in ("patch_gap", "patch_cand", "patch_frozen", "patch_bind"):
                setattr(d, key, ti.ndarray(ti.f32 if key == "patch_gap" else ti.i32, shape=n))
            d.patch_contact = ti.ndarray(ti.i32, shape=max(len(self.groups), 1))
        for key in ("order", "slab_of"):
            setattr(d, key, ti.ndarray(ti.i32, shape=n))
        if d.slab_start is None:
            d.slab_start = ti.ndarray(ti.i32, shape=K.SLAB_CAP)
            d.cursor = ti.ndarray(ti.i32, shape=K.SLAB_CAP)
        d.bounds = ti.ndarray(ti.i32, shape=(K.NCHUNK, 6))
        d.box = ti.ndarray(ti.i32, shape=K.BOX)
        d.first_bad = ti.ndarray(ti.i32, shape=K.NCHUNK)
        d.vmax_chunk = ti.ndarray(ti.f32, shape=K.NCHUNK)
        upload("mat_table", material_table(self.materials, self.settings.pressure), ti.f32)
        upload("group_qs", np.array([int(g.quasi_static) for g in self.groups] or [0], np.int32), ti.i32)
        upload("group_tear", np.array([g.tear for g in self.groups] or [0.0], np.float32), ti.f32)
        d.torn = ti.ndarray(ti.i32, shape=max(len(self.groups), 1))
        d.group_touched = ti.ndarray(ti.i32, shape=max(len(self.groups), 1))
        d.group_drift = ti.ndarray(ti.f32, shape=max(len(self.groups), 1))
        upload("group_field", np.array([g.field for g in self.groups] or [0], np.int32), ti.i32)
        upload("group_env", np.array([g.env for g in self.groups] or [0], np.int32), ti.i32)
        # the grid holds one box per env and awake field: each group's copy (_refresh_active)
        d.group_copy = ti.ndarray(ti.i32, shape=max(len(self.groups), 1))
        cm = self.model.colliders
        upload("col_env", np.array([c.env for c in cm] or [0], np.int32), ti.i32)
        walls = np.array(self.model.walls, np.float32).reshape(-1, 3)
        upload("walls", walls if len(walls) else np.zeros((1, 3), np.float32), ti.f32)
        # colliders
        nc = max(len(cm), 1)
        kinds = np.zeros(nc, np.int32)
        prm = np.zeros((nc, 4), np.float32)
        friction = np.zeros((nc, 2), np.float32)  # (μ, 1 if sticky)
        info = np.zeros((nc, 4), np.int32)
        offset = 0
        for i, c in enumerate(cm):
            kinds[i], prm[i], friction[i] = c.kind, c.params, (c.friction, float(c.sticky))
            if c.sdf_shape is not None:
                info[i] = (offset, *c.sdf_shape)
                offset += math.prod(c.sdf_shape)
        upload("col_kind", kinds, ti.i32)
        upload("col_prm", prm, ti.f32)
        upload("col_friction", friction, ti.f32)
        upload("col_bound", np.array([c.bound for c in cm] or [0.0], np.float32), ti.f32)
        upload("sdf_info", info, ti.i32)
        upload("sdf", self._sdf_values(), ti.f32)
        self._sdf_stale = False
        d.col_pose = ti.ndarray(ti.f32, shape=(nc, 14))
        d.col_impulse = ti.ndarray(ti.f32, shape=(nc, 6))
        d.link_pose = ti.ndarray(ti.f32, shape=(max(len(self.link_names), 1), 14))
        n_slot, slot = self.pair_slots()
        d.pair_impulse = ti.ndarray(ti.f32, shape=(max(len(self.link_names), 1) * n_slot, 7))
        upload("col_slot", slot.astype(np.int32) if len(slot) else np.zeros(1, np.int32), ti.i32)
        d.link_frames = ti.ndarray(ti.f32, shape=(max(len(self.link_names), 1), FRAME))
        d.col_frames = ti.ndarray(ti.f32, shape=(nc, FRAME))
        d.group_frames = ti.ndarray(ti.f32, shape=(max(len(self.groups), 1), FRAME))
        upload("group_link", np.array([g.link for g in self.groups] or [-1], np.int32), ti.i32)
        if d.group_bind is None:
            upload("group_bind", np.tile(np.array([1.0, 0, 0, 0], np.float32), (1, 1)), ti.f32)
        d.twist_change = ti.ndarray(ti.f32, shape=(max(len(self.link_names), 1), 9))
        d.counts = ti.ndarray(ti.i32, shape=7)
        self._refresh_active()
        d.consts = ti.ndarray(ti.f32, shape=9)
        d.env_relax = ti.ndarray(ti.f32, shape=self.num_envs)
        self._upload_consts()
        self._build_packs()
        if self._grid_cap == 0:
            self._alloc_grid(4096)
        else:
            self._alloc_cells()  # the particle count or the materials may have changed
        self._link_radius = np.zeros(len(self.link_names))
        if self.num_particles:
            bound = (hp.kind == 1) & (hp.link >= 0)
            np.maximum.at(self._link_radius, hp.link[bound], np.linalg.norm(hp.X0[bound], axis=1))
        self._dirty = False
        self._stale = set()

    def _refresh_active(self) -> None:
        """The awake groups' particles as the active list (env-major, :meth:`_env_major`),
        its kinematic ones, each env's rows, the counts, and whether two velocity fields are
        awake (then the grid holds two box copies per env: see add_group's ``field``)."""
        d, n = self._dev, max(self.num_particles, 1)
        kind = self._host_parts.kind if self.num_particles else np.zeros(n, np.int32)
        active, env_rows = self._env_major([(g.env, np.arange(g.start, g.stop, dtype=np.int32))
                                            for g in self.groups if g.awake])
        active_kin = active[kind[active] == 1]
        self._n_active, self._n_kin = len(active), len(active_kin)
        self._two_fields = len({g.field for g in self.groups if g.awake}) == 2
        B = self.num_envs  # each group's grid copy: field · num_envs + env, the field only with two
        d.group_copy.from_numpy(np.array([(g.field if self._two_fields else 0) * B + g.env for g in self.groups]
                                            or [0], np.int32))
        d.env_rows.from_numpy(env_rows)
        d.active.from_numpy(np.resize(active, n))
        d.active_kin.from_numpy(np.resize(active_kin, n))
        self._upload_counts()
        self._awake_changed = False

    def _build_packs(self) -> None:
        """Group the device arrays into the kernels' argument packs (kernels.Particles, Scene,
        Order, Placement, Reduction; the Grid pack is built with the grid in _alloc_grid). Built
        once per rebuild of the arrays: a kernel_launch.CachedKernel re-checks a new pack."""
        d, dp, pk = self._dev, self._dev_parts, self._pack
        pk["W"] = None  # World is assembled on first use (_world_pack)
        if self.num_particles:
            pk["P"] = K.Particles(**{k: dp.get(k) for k in (
                "x", "v", "C", "F", "tau", "Jp", "impulse", "contact_id", "anchor", "mass", "vol", "radius",
                "kind", "link", "matid", "group", "bond")})
            pk["placement"] = K.Placement(
                **{k: dp.get(k) for k in ("x", "v", "C", "X0", "link")},
                **{k: getattr(d, k) for k in ("counts", "consts", "link_frames", "col_frames",
                                     "group_bind", "group_link", "group_frames", "active", "bounds", "slab_of",
                                     "cursor", "order", "slab_start")},
                link_poses=d.link_pose, col_poses=d.col_pose, kin=d.active_kin, active_box=d.box)
        pk["S"] = K.Scene(**{k: getattr(d, k) for k in (
            "counts", "consts", "mat_table", "group_qs", "group_frames", "group_field", "group_env", "group_copy",
            "env_relax", "link_frames", "walls", "col_kind", "col_prm", "col_frames", "col_friction", "sdf",
            "sdf_info", "col_impulse", "col_env", "col_bound")})
        pk["O"] = K.Order(order=d.order, slab_start=d.slab_start, active_box=d.box)
        pk["R"] = K.Reduction(env_rows=d.env_rows, col_slot=d.col_slot, col_ends=d.col_pose,
                              link_ends=d.link_pose, col_sums=d.col_impulse, pair_sums=d.pair_impulse)

    def _upload_poses(self) -> None:
        """The step's pose rows (kinematics.py: start position, quaternion, end position,
        quaternion on the same hemisphere) of every link and collider."""
        def pose_rows(prev, nxt):
            out = np.zeros((max(len(prev), 1), 14), np.float32)
            if len(prev):
                qa, qb = matrix_to_quat(prev[:, :3, :3]), matrix_to_quat(nxt[:, :3, :3])
                qb *= np.where(np.einsum("ij,ij->i", qa, qb) < 0, -1.0, 1.0)[:, None]
                out[:len(prev)] = np.concatenate([prev[:, :3, 3], qa, nxt[:, :3, 3], qb], 1)
            return out

        self._dev.link_pose.from_numpy(pose_rows(self._link_prev, self._link_next))
        self._dev.col_pose.from_numpy(pose_rows(self._col_prev, self._collider_poses()))

    def _collider_poses(self) -> np.ndarray:
        """[C, 4, 4] the colliders' target poses (where they end the next step)."""
        return np.array([c.pose for c in self.colliders]).reshape(-1, 4, 4)

    def _env_parts(self, env: int | None):
        """Indices of what env ``env`` owns (all with None): particle rows, groups, links,
        colliders; a clear error for an env this world does not have."""
        if env is None:
            return (np.arange(self.num_particles), np.arange(len(self.groups)), np.arange(len(self.link_names)),
                    np.arange(len(self.colliders)))
        env = _env_index(env, "state of env")
        if env >= self.num_envs:
            raise ConfigError(f"env={env}: this world has {self.num_envs} env(s)")
        groups = np.array([i for i, g in enumerate(self.groups) if g.env == env], int)
        rows = np.concatenate([np.arange(self.groups[i].start, self.groups[i].stop) for i in groups]) \
            if len(groups) else np.zeros(0, int)
        return (rows, groups, np.flatnonzero(np.array([link.env for link in self.model.links], int) == env),
                np.flatnonzero(np.array([c.env for c in self.model.colliders], int) == env))

    def state_dict(self, env: int | None = None) -> dict:
        """The mutable state (numpy arrays and scalars); see :meth:`load_state_dict`. With
        ``env``, only that env's part (its groups' particles, its links and colliders, in
        world order): the same layout as the state of a world that holds that scene alone,
        so a batched env's state loads into a single scene and back. The scalars (time, step
        count, largest speed) are the world's."""
        self._pull()
        rows, groups, links, cols = self._env_parts(env)
        G = [self.groups[i] for i in groups]
        parts = {k: self._host_parts.get(k)[rows].copy() for k in _STATE_FIELDS} if len(rows) else {}
        if parts and env is not None:  # collider ids of contacts and anchors: the env's own numbering
            local = np.full(len(self.colliders), -1)
            local[cols] = np.arange(len(cols))
            _renumber(parts, local)
        return {
            "particles": parts,
            "link_prev": self._link_prev[links],
            "link_next": self._link_next[links],
            "link_twist": self._link_twist[links],
            "collider_prev": self._col_prev[cols],
            "collider_pose": np.array([self.colliders[i].pose for i in cols]).copy(),
            "awake": np.array([g.awake for g in G]),
            "patch_state": np.array([g.patch_state for g in G], np.int32),
            "hold": np.array([g.hold for g in G]), "drift": np.array([g.drift for g in G]),
            "sleep_pose": [None if g.sleep_pose is None else g.sleep_pose.copy() for g in G],
            "time": self.time, "step_count": self.step_count, "vmax": self._vmax,
            "collider_impulse": self._col_impulse[cols].copy(), "last_dt_ctrl": self._last_dt_ctrl,
            "pair_impulse": self._pairs(links, cols),
        }

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Restore a state from :meth:`state_dict` of a world built the same way (bit-exact);
        with ``env``, only that env's part (from ``state_dict(env=...)`` of this or another
        world, or from the whole state of a world that holds that scene alone). The world's
        clock (time, step count, last step) comes from the state; with other envs in the
        world, its largest speed (for the next substep count) becomes the larger of the two."""
        rows, groups, links, cols = self._env_parts(env)
        parts = dict(state.get("particles", {}))
        if len(rows) and "anchor" not in parts and "x" in parts:  # a state without anchors: nothing sticks
            parts["anchor"] = no_anchor(len(parts["x"]))
        for k in _STATE_FIELDS if len(rows) else ():
            need = (len(rows),) + self._host_parts.get(k).shape[1:]
            if k not in parts or parts[k].shape != need:
                got = None if k not in parts else parts[k].shape
                raise ConfigError(f"load_state_dict: particles[{k!r}] has shape {got}, "
                                  f"this world{'' if env is None else f's env {env}'} needs {need}")
        if len(state["awake"]) != len(groups):
            raise ConfigError(f"load_state_dict: state has {len(state['awake'])} groups, world"
                              f"{'' if env is None else f' env {env}'} has {len(groups)}")
        self._pull()
        if len(rows) and env is not None:
            parts = {k: v.copy() for k, v in parts.items()}
            _renumber(parts, cols)  # the env's collider numbering back to the world's
        for k in _STATE_FIELDS if len(rows) else ():
            self._host_parts.get(k)[rows] = parts[k]
        twist = state.get("link_twist")
        self._link_prev[links] = np.asarray(state["link_prev"]).reshape(-1, 4, 4)
        self._link_next[links] = np.asarray(state["link_next"]).reshape(-1, 4, 4)
        self._link_twist[links] = 0.0 if twist is None else np.asarray(twist).reshape(-1, 6)
        self._col_prev[cols] = np.asarray(state["collider_prev"]).reshape(-1, 4, 4)
        for n, i in enumerate(cols):
            self.colliders[i].pose = state["collider_pose"][n].copy()
        patch = state.get("patch_state", np.zeros(len(groups), np.int32))
        hold = state.get("hold", np.zeros(len(groups), bool))
        drift = state.get("drift", np.full(len(groups), np.inf))
        for n, i in enumerate(groups):
            g, sp = self.groups[i], state["sleep_pose"][n]
            g.awake, g.sleep_pose, g.patch_state = bool(state["awake"][n]), (None if sp is None else sp.copy()), \
                int(patch[n])
            g.drift = float(drift[n])
            self._set_hold(g, bool(hold[n]))
        # one clock for all envs: every env's state carries the world's scalars, so restoring
        # all of them is exact; the largest speed (the next substep count) is kept at least
        # where it was while other envs share the world
        self.time, self.step_count = float(state["time"]), int(state["step_count"])
        self._last_dt_ctrl = float(state["last_dt_ctrl"])
        one = env is None or self.num_envs == 1
        self._vmax = float(state["vmax"]) if one else max(self._vmax, float(state["vmax"]))
        self._col_impulse[cols] = state["collider_impulse"]
        self._pair_impulse[links] = 0.0
        if "pair_impulse" in state:  # [links, cols + the other field] (see _pairs), back into the slots
            pairs = np.asarray(state["pair_impulse"], np.float64)
            li, ci = np.nonzero(self._same_env(links, cols))
            self._pair_impulse[links[li], self.pair_slots()[1][cols[ci]]] = pairs[li, ci]
            self._pair_impulse[links, -1] = pairs[:, -1]
        elif state.get("link_impulse") is not None:  # a state without per-object pairs: the link's sum, no depth
            self._pair_impulse[links, -1, :6] = np.asarray(state["link_impulse"], np.float64).reshape(-1, 6)
        self._dirty = True
