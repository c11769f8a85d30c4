"""MPMWorld: a partly controlled MLS-MPM world (soft bodies driven by rigid links).

One world holds several particle *groups* (a fingertip pad, a sponge, ...). A group
is made of dynamic particles (simulated) and optionally kinematic particles bound
to a rigid *link*: those follow the link's transform exactly, yet still scatter
their momentum and mass to the grid, so they drive the soft particles next to
them. Rigid objects enter as SDF *colliders*.

Time integration differs by kind of group (explicit MLS-MPM substeps for all):

* **free groups** (no kinematic particles: a dropped or grasped sponge) have their
  physical mass: they fall at g and carry their real momentum;
* **quasi-static groups** (bound to a link: fingertip pads, a sponge glued to a
  holder) are solved by *dynamic relaxation*: their density is multiplied by
  ``SolverSettings.mass_scaling`` (a pseudo-mass that lowers the wave speed and so
  the substep count) and their motion relative to their link is damped at a rate ζ
  near critical for the layer's slowest mode, so they settle to elastic equilibrium
  within a control step. Their kinematic core holds them, so the pseudo-mass never
  shows as a wrong fall or swing of the pad; weight always uses the physical mass.
  Dynamic relaxation's equilibrium does not depend on the pseudo-mass, only its path to
  it does, so a pad that has settled while nothing moves its boundary (its link and its
  env's colliders stand still, no soft body is awake) takes ``SolverSettings.hold_scaling``
  times more (4× fewer substeps at the default 16) until its boundary moves again.

With ``SolverSettings.pressure = "implicit"`` the λ ln J term of Neo-Hookean groups is one
value per grid cell, solved backward Euler in every substep (``kernels.pressure_solve``); the
rest of the stress stays explicit, and the substep follows √(2μ/ρ) instead of the P-wave.

Each :meth:`MPMWorld.step` advances one control step Δt_ctrl: link and collider
poses move from the previous pose to the one last set (position lerp, rotation
slerp per substep); the substep count comes from the CFL bound
Δt ≤ C·dx / (c + |v|max), c = √((λ + 2μ)/ρ). The grid covers only the bounding
box of awake particles plus a margin and follows them; sleeping groups are not
touched at all. With ``SolverSettings.patch_radius`` only the part of a pad near a contact
is simulated and the rest rides rigidly with its link (:mod:`.patch`).

A world can hold several independent scenes, *envs* (``env=`` of :meth:`MPMWorld.add_link`,
:meth:`~MPMWorld.add_group`, :meth:`~MPMWorld.add_collider`): each env has its own copy of the
grid box and touches only its own colliders, and all envs step in the same kernel launches
(:class:`gausstac_maniskill.batch.BatchedCosim` builds such worlds).

Units: metres, kilograms, seconds, pascals, newtons.

Example::

    world = MPMWorld(SolverSettings(dx=1e-3))
    world.add_link("tip", np.eye(4))
    world.add_group("pad", pts, Material(E=3e5, nu=0.45), link="tip", kinematic=pts[:, 2] < 0.002)
    ball = world.add_collider(Sphere(radius=0.005, pose=make_pose([0, 0, 0.02])))
    world.set_collider_pose(ball, make_pose([0, 0, 0.015]))
    world.step(0.01)
    force, torque = world.collider_wrench(ball)
"""
from __future__ import annotations

import math
import os
import time
import warnings
import weakref
from dataclasses import dataclass

import numpy as np
import taichi as ti

from .. import backend
from ..config import Material, SolverSettings, _finite
from ..errors import ConfigError, SimulationError, SimulationWarning
from ..transforms import as_pose_matrices, as_pose_matrix, matrix_to_quat, quat_to_matrix, turn_angle
from . import kernels as K
from .rows import forget_contact, move_rigidly, put_at_rest
from .colliders import Collider, MeshCollider
from .kinematics import FRAME
from .materials import cell_pressure, material_table
from .patch import ActivePatch, bind_in_place, carry_rigidly, groups_in_contact, rest_gap

__all__ = ["MPMWorld", "StepInfo", "Group"]

_WORLDS: "weakref.WeakSet[MPMWorld]" = weakref.WeakSet()


@backend.before_shutdown
def _release_packs() -> None:
    """Free every world's kernel argument packs while Taichi still runs: a pack left to the
    interpreter's teardown prints a TypeError from Taichi's ArgPack.__del__ at exit."""
    for world in list(_WORLDS):
        world._pack.clear()


_STATE_FIELDS = ("x", "v", "C", "F", "tau", "Jp", "impulse", "contact_id", "anchor")


def no_anchor(n: int) -> np.ndarray:
    """Static-friction anchors of ``n`` particles that stick to nothing ([n, 4]: point, collider -1)."""
    out = np.zeros((n, 4), np.float32)
    out[:, 3] = -1.0
    return out


@dataclass
class Group:
    """Book-keeping of one particle group (a contiguous block of particle indices)."""

    name: str
    start: int
    count: int
    material: Material
    link: int  # -1: not bound to a link
    n_kinematic: int
    spacing: float
    quasi_static: bool = False  # pseudo-mass (settings.mass_scaling) + relaxation; see add_group
    mass_scale: float = 1.0  # density multiplier of its dynamic particles (1: physical inertia)
    relaxation: float = 0.0  # damping rate ζ [1/s] of its motion relative to its link
    field: int = 0  # velocity field (0 or 1): groups of different fields are separate bodies in contact
    awake: bool = True
    sleep_pose: np.ndarray | None = None  # link pose when the group fell asleep
    patch_state: int = 0  # active patch (mpm.patch): 0 at rest, 1 patched in contact, 2 released (whole)
    env: int = 0  # the env (scene) of a batched world it belongs to: it touches only that env's groups and colliders
    tear: float = 0.0  # quasi-static: a particle this far [m] from its rest place has lost its core (0: no check)
    hold: bool = False  # quasi-static: held and settled, its pseudo-mass times settings.hold_scaling
    drift: float = math.inf  # quasi-static: largest particle speed relative to its link at the last step's end [m/s]

    @property
    def stop(self) -> int:
        return self.start + self.count


@dataclass
class StepInfo:
    """What one control step did: substeps, substep length [s], wall time [s]."""

    substeps: int
    dt_substep: float
    wall_time: float
    active_particles: int
    grid_cells: int


class MPMWorld:
    """A partly controlled MLS-MPM world. See the module docstring.

    Args:
        settings: numerical settings (grid spacing, CFL number, ...).
        contact: ``"particle"`` (default) enforces colliders on particles, whose
            surface is half a particle spacing beyond their centre; ``"grid"``
            enforces them on grid nodes (classic MPM boundary conditions; the
            contact surface then sits up to one cell early).
    """

    def __init__(self, settings: SolverSettings | None = None, contact: str = "particle"):
        backend.ensure_init()
        self.settings = settings or SolverSettings()
        if contact not in ("particle", "grid"):
            raise ConfigError(f"MPMWorld(contact={contact!r}) must be 'particle' or 'grid'")
        self.contact = contact
        self.groups: list[Group] = []
        self.materials: list[Material] = []
        self.link_names: list[str] = []
        self._link_prev = np.zeros((0, 4, 4))  # [L, 4, 4] pose at the start of the next step
        self._link_next = np.zeros((0, 4, 4))  # [L, 4, 4] pose at its end (last set)
        self._link_twist = np.zeros((0, 6))  # [L, 6] (v_origin, ω) [m/s, rad/s] of the last step
        self._link_env: list[int] = []
        self._link_at: dict[str, int] = {}  # link name -> index
        self._group_at: dict[str, int] = {}  # group name -> index
        self._num_envs = 1
        self.colliders: list[Collider] = []
        self._col_env: list[int] = []
        self._col_prev = np.zeros((0, 4, 4))  # [C, 4, 4] collider poses at the start of the next step
        self._walls: list[tuple[int, float, float]] = []
        self.time = 0.0
        self.step_count = 0
        self.last_step: StepInfo | None = None
        self._n = 0
        self._host: dict[str, np.ndarray] = {}
        self._dev: dict[str, object] = {}
        self._grid_cap = 0
        self._dirty = True
        self._awake_changed = False  # groups woke or slept since the last push (the active lists are old)
        self._sdf_stale = False  # a mesh collider's SDF changed since the last upload (set_collider_sdf)
        self.rebuilds = 0  # full rebuilds of the device arrays from the host (structural changes)
        self._vmax = 0.0
        self._col_impulse = np.zeros((0, 6))
        # [link, slot, J | moment | depth]: slot = the collider's number among its env's colliders
        # (:meth:`pair_slots`), the last slot the other field; linear in the env count
        self._pair_impulse = np.zeros((0, 1, 7))
        self._last_dt_ctrl = 1.0
        self._reach = 0.0
        self._link_radius = np.zeros(0)  # [L] farthest bound particle from the link origin [m]
        self._pack: dict = {}  # kernel argument packs (kernels.Particles, Grid, Scene, Order)
        self._atomic = atomic_scatter()
        self._two_fields = False  # set by _push from the awake groups' fields
        self._fbar, self._cellp = bool(self.settings.fbar), 0  # kernel switches, set by _push (_stress_flags)
        r = self.settings.patch_radius
        self._patch = ActivePatch(r, self.settings.dx) if r else None
        self._patched: list[int] = []  # groups simulated by patch in the current step
        _WORLDS.add(self)

    # ------------------------------------------------------------------ building
    def add_link(self, name: str, pose, env: int = 0) -> int:
        """Register a rigid link that kinematic particles can bind to, in env ``env`` of a
        batched world (see :attr:`num_envs`); returns its index."""
        if name in self._link_at:
            raise ConfigError(f"link {name!r} is already registered")
        T = as_pose_matrix(pose, f"pose of link {name!r}")
        self._link_env.append(self._note_env(env, f"add_link({name!r})"))
        self._link_at[name] = len(self.link_names)
        self.link_names.append(name)
        self._link_prev = np.concatenate([self._link_prev, T[None]])
        self._link_next = np.concatenate([self._link_next, T[None]])
        self._link_twist = np.concatenate([self._link_twist, np.zeros((1, 6))])
        self._pair_impulse = np.concatenate([self._pair_impulse, np.zeros((1,) + self._pair_impulse.shape[1:])])
        self._dirty = True
        return len(self.link_names) - 1

    def link_index(self, link) -> int:
        """Index of a link given by name or index; a clear error if it does not exist."""
        if isinstance(link, (int, np.integer)):
            if not 0 <= link < len(self.link_names):
                raise ConfigError(f"link index {link} out of range (have {len(self.link_names)} links)")
            return int(link)
        if link not in self._link_at:
            raise ConfigError(f"unknown link {link!r}; registered links: {self.link_names}")
        return self._link_at[link]

    def has_link(self, name: str) -> bool:
        """Whether a link called ``name`` is registered."""
        return name in self._link_at

    def add_group(self, name: str, positions, material: Material, *, link=None, kinematic=None,
                  velocity=None, particle_volume: float | None = None,
                  spacing: float | None = None, quasi_static: bool | None = None,
                  relaxation: float | None = None, field: int = 0, contact_radius=None,
                  bond_distance=None, bond_normal=None, env: int | None = None) -> Group:
        """Add a group of particles.

        Args:
            name: unique group name (used in error messages and :meth:`group`).
            positions: [N, 3] world positions [m] in the current configuration,
                which is taken as the rest configuration (F = I).
            material: constitutive model and parameters of the dynamic particles.
            link: name or index of the link that kinematic particles follow.
            kinematic: [N] bool mask (or ``True`` for all) of particles bound to ``link``.
            velocity: optional [N, 3] or [3] initial velocity [m/s].
            particle_volume: rest volume per particle [m^3]; default ``spacing**3``.
            spacing: particle spacing [m] of these positions; default
                ``settings.particle_spacing``.
            contact_radius: [N] or scalar distance [m] from a particle's centre to the
                surface it stands for (colliders touch that surface); default ``spacing / 2``.
            bond_distance, bond_normal: where the dynamic particles are bonded to the
                kinematic ones: [N] signed distance [m] of each particle from the bond surface
                (negative in the kinematic core) and [N, 3] that surface's normal pointing into
                the soft layer (world frame, current configuration); only the kinematic
                particles' values are used. The grid then holds the layer at that surface, not
                at the nearest node plane (``kernels.bond_ghosts``). Default: estimated from
                the kinematic mask, from each kinematic particle's nearest dynamic particle
                (exact for a flat bond on the particle lattice). Pads pass their geometry.
            quasi_static: solve the group by dynamic relaxation (pseudo-mass
                ``settings.mass_scaling``, damping relative to its link). Default: True
                when the group has kinematic particles. A free group (no kinematic
                particle) always keeps its physical inertia; asking otherwise is an error.
            relaxation: damping rate ζ [1/s] of a quasi-static group's motion relative
                to its link. Default: ω1 = (π/2)·c_s/L, the layer's lowest shear
                frequency, with c_s the (pseudo-mass) shear wave speed and L the largest
                distance of a dynamic particle from the kinematic core. (Measured on a
                block pad: ζ = ω1/4 … ω1 relax alike, 2·ω1 is slower.)
            field: velocity field, 0 or 1 (multi-field MPM). Groups in one field form one
                continuum where they touch (their particles share grid velocities); groups
                in different fields are separate bodies that touch through a frictional,
                non-adhesive contact rule on the grid (friction
                ``settings.soft_friction``). Pads use field 0 and soft objects field 1
                (:class:`~gausstac_maniskill.cosim.GaussTacSim` does this). While groups
                of both fields are awake the grid holds two copies of the active box.
            env: the env (independent scene) of a batched world the group belongs to
                (default: its link's env, or 0). Groups of different envs never interact
                and touch only their own env's colliders, yet all envs step in the same
                kernel launches (:attr:`num_envs`).
        """
        if name in self._group_at:
            raise ConfigError(f"group {name!r} already exists")
        if field not in (0, 1) or isinstance(field, bool):
            raise ConfigError(f"add_group({name!r}): field={field!r} must be 0 or 1")
        if not isinstance(material, Material):
            raise ConfigError(f"add_group({name!r}): material must be a Material, got {type(material).__name__}")
        pts = np.asarray(positions, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ConfigError(f"add_group({name!r}): positions must have shape [N, 3], got {pts.shape}")
        if len(pts) == 0:
            raise ConfigError(f"add_group({name!r}): positions is empty (the particle set has no particles)")
        if not np.all(np.isfinite(pts)):
            raise ConfigError(f"add_group({name!r}): positions contain NaN or inf")
        n = len(pts)
        kin = np.zeros(n, bool)
        if kinematic is not None:
            kin = np.broadcast_to(np.asarray(kinematic, bool), (n,)).copy()
        lidx = -1
        if kin.any() or link is not None:
            if link is None:
                raise ConfigError(f"add_group({name!r}): kinematic particles need a link")
            lidx = self.link_index(link)
        if env is None:
            env = self._link_env[lidx] if lidx >= 0 else 0
        env = self._note_env(env, f"add_group({name!r})")
        if lidx >= 0 and self._link_env[lidx] != env:
            raise ConfigError(f"add_group({name!r}): env={env} but its link {self.link_names[lidx]!r} is in env "
                              f"{self._link_env[lidx]}")
        h = float(spacing if spacing is not None else self.settings.particle_spacing)
        if not (h > 0 and math.isfinite(h)):
            raise ConfigError(f"add_group({name!r}): spacing={spacing!r} must be > 0")
        vol = float(particle_volume if particle_volume is not None else h ** 3)
        if not (vol > 0 and math.isfinite(vol)):
            raise ConfigError(f"add_group({name!r}): particle_volume={particle_volume!r} must be > 0")
        radius = np.full(n, 0.5 * h)
        if contact_radius is not None:
            radius = np.broadcast_to(np.asarray(contact_radius, np.float64), (n,)).copy()
            if not (np.all(np.isfinite(radius)) and np.all(radius > 0)):
                raise ConfigError(f"add_group({name!r}): contact_radius must be > 0 and finite")
        bond = _bond_table(name, pts, kin, h, bond_distance, bond_normal)
        vel = np.zeros((n, 3))
        if velocity is not None:
            vel = np.broadcast_to(np.asarray(velocity, np.float64), (n, 3)).copy()
            if not np.all(np.isfinite(vel)):
                raise ConfigError(f"add_group({name!r}): velocity contains NaN or inf")

        if quasi_static is None:
            quasi_static = bool(kin.any())
        if quasi_static and not kin.any():
            raise ConfigError(f"add_group({name!r}): quasi_static=True needs kinematic particles; a free "
                              f"group keeps its physical inertia (it must fall and move at its real mass)")
        scale = self.settings.mass_scaling if quasi_static else 1.0
        relax = tear = 0.0
        if quasi_static:
            layer = _layer_thickness(pts, kin)
            # farther than the layer's largest stretch, plus the grid stencil's reach, from its rest
            # place, a particle cannot be held by its core any more (_rest_torn)
            tear = K.MAX_STRETCH * layer + 2.0 * self.settings.dx
            relax = _relaxation_rate(layer, material, scale) if relaxation is None else relaxation
            relax = _finite(f"add_group({name!r}): relaxation", relax)
            if relax < 0.0:
                raise ConfigError(f"add_group({name!r}): relaxation={relax!r} must be a rate >= 0 [1/s]")
        elif relaxation is not None:
            raise ConfigError(f"add_group({name!r}): relaxation is for quasi-static groups only")

        self._pull()
        if material not in self.materials:
            self.materials.append(material)
        mid = self.materials.index(material)
        gid = len(self.groups)
        rho = material.density * scale
        new = {
            "x": pts.astype(np.float32), "v": vel.astype(np.float32),
            "C": _velocity_gradient(pts, vel).astype(np.float32), "F": np.tile(np.eye(3, dtype=np.float32), (n, 1, 1)),
            "tau": np.zeros((n, 3, 3), np.float32), "Jp": np.ones(n, np.float32),
            "impulse": np.zeros((n, 3), np.float32), "contact_id": np.full(n, -1, np.int32),
            "anchor": no_anchor(n),
            "mass": np.full(n, rho * vol, np.float32), "vol": np.full(n, vol, np.float32),
            "radius": radius.astype(np.float32), "kind": kin.astype(np.int32),
            "matid": np.full(n, mid, np.int32), "link": np.full(n, lidx, np.int32),
            "group": np.full(n, gid, np.int32), "X0": np.zeros((n, 3), np.float32),
        }
        if lidx >= 0:
            T = self._link_next[lidx]
            new["X0"] = ((pts - T[:3, 3]) @ T[:3, :3]).astype(np.float32)
            new["v"][kin] = 0.0
            new["C"][kin] = 0.0  # kinematic_update gives them their link's gradient
            bond[:, :3] = bond[:, :3] @ T[:3, :3]  # normals to the link frame
        new["bond"] = bond.astype(np.float32)
        for key, arr in new.items():
            self._host[key] = arr if key not in self._host else np.concatenate([self._host[key], arr])
        bind = matrix_to_quat(self._link_next[lidx][:3, :3]) if lidx >= 0 else np.array([1.0, 0, 0, 0])
        self._host["group_bind"] = np.concatenate(
            [self._host.get("group_bind", np.zeros((0, 4), np.float32)), bind[None].astype(np.float32)])
        group = Group(name, self._n, n, material, lidx, int(kin.sum()), h, bool(quasi_static), scale, relax,
                      int(field), env=env, tear=tear)
        self._group_at[name] = len(self.groups)
        self.groups.append(group)
        self._n += n
        self._dirty = True
        return group

    def add_collider(self, collider: Collider, env: int = 0) -> int:
        """Add a rigid SDF collider that the groups of env ``env`` touch; returns its index
        (for poses and wrenches)."""
        if not isinstance(collider, Collider) or type(collider) is Collider:
            raise ConfigError(f"add_collider expects a Sphere, Box, Capsule, HalfSpace or MeshCollider, "
                              f"got {type(collider).__name__}")
        self._col_env.append(self._note_env(env, "add_collider"))
        self.colliders.append(collider)
        self._col_prev = np.concatenate([self._col_prev, collider.pose[None]])
        # one impulse row per collider from the start, so the state keeps its shape before
        # and after the first step (recorders stack states of successive steps)
        self._col_impulse = np.concatenate([self._col_impulse, np.zeros((1, 6))])
        n_slot = self.pair_slots()[0]
        if n_slot > self._pair_impulse.shape[1]:  # the env with the most colliders got one more
            self._pair_impulse = np.insert(self._pair_impulse, self._pair_impulse.shape[1] - 1, 0.0, axis=1)
        self._dirty = True
        return len(self.colliders) - 1

    def pair_slots(self) -> tuple[int, np.ndarray]:
        """(slots per link, [C] each collider's slot): a link's contact pairs are its env's
        colliders, numbered in their order of addition, then one slot for the other field."""
        env = np.asarray(self._col_env, np.int64)
        count = np.bincount(env, minlength=1)
        order = np.argsort(env, kind="stable")  # env by env, each in its order of addition
        slot = np.empty(len(env), np.int64)
        slot[order] = np.arange(len(env)) - (np.cumsum(count) - count)[env[order]]
        return int(count.max()) + 1, slot

    def _pairs(self, links: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """[len(links), len(cols) + 1, 7] pair sums of ``links`` with colliders ``cols`` (zero
        for a collider of another env), then with the other field."""
        n_slot, slot = self.pair_slots()
        sums = self._pair_impulse[links]
        out = np.zeros((len(links), len(cols) + 1, 7))
        out[:, :-1] = np.where(self._same_env(links, cols)[..., None], sums[:, slot[cols]], 0.0)
        out[:, -1] = sums[:, n_slot - 1]
        return out

    def _same_env(self, links: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """[len(links), len(cols)] whether link links[i] and collider cols[j] share an env."""
        return np.asarray(self._link_env)[links][:, None] == np.asarray(self._col_env, np.int64)[cols][None, :]

    def add_slip_wall(self, axis: int, position: float, keep: str = "+") -> None:
        """A bilateral frictionless wall on the grid (e.g. a symmetry plane).

        Grid nodes with coordinate ``axis`` on the ``keep``-opposite side of
        ``position`` [m], or on it, get zero velocity along ``axis``.
        """
        if axis not in (0, 1, 2) or keep not in ("+", "-"):
            raise ConfigError(f"add_slip_wall(axis={axis!r}, keep={keep!r}): axis in 0..2, keep '+' or '-'")
        self._walls.append((axis, float(position), 1.0 if keep == "+" else -1.0))
        self._dirty = True

    # ------------------------------------------------------------------ queries
    def group(self, name: str) -> Group:
        """The group called ``name`` (clear error if unknown)."""
        if name not in self._group_at:
            raise ConfigError(f"unknown group {name!r}; groups: {[g.name for g in self.groups]}")
        return self.groups[self._group_at[name]]

    @property
    def bit_reproducible(self) -> bool:
        """Whether a step from a given state always gives the same bits (the CPU's slab
        scatter); the atomic scatter on CUDA sums in a run-dependent order."""
        return not self._atomic

    @property
    def num_envs(self) -> int:
        """Number of envs (independent scenes) in this world: 1 + the largest env index given
        to :meth:`add_link`, :meth:`add_group` or :meth:`add_collider`. Every env has its own
        copy of the grid box; all step together, in the same kernel launches, with one
        substep count (the smallest that every env's CFL bound allows)."""
        return self._num_envs

    def _note_env(self, env, where: str) -> int:
        """``env`` checked (:func:`_env_index`) and counted in :attr:`num_envs`."""
        env = _env_index(env, where)
        self._num_envs = max(self._num_envs, env + 1)
        return env

    @property
    def num_particles(self) -> int:
        return self._n

    def _read(self, key: str, group: str | None):
        self._pull((key,))  # only the field read comes back from the device
        arr = self._host[key]
        if group is None:
            return arr.copy()
        g = self.group(group)
        return arr[g.start:g.stop].copy()

    def positions(self, group: str | None = None) -> np.ndarray:
        """Particle positions [N, 3] in metres (all groups, or one)."""
        return self._read("x", group)

    def velocities(self, group: str | None = None) -> np.ndarray:
        """Particle velocities [N, 3] in m/s."""
        return self._read("v", group)

    def deformation_gradients(self, group: str | None = None) -> np.ndarray:
        """Deformation gradients F [N, 3, 3] relative to the rest configuration."""
        return self._read("F", group)

    def stresses(self, group: str | None = None) -> np.ndarray:
        """Cauchy stress σ = τ / J [N, 3, 3] in pascals."""
        tau = self._read("tau", group)
        J = np.linalg.det(self._read("F", group))
        return tau / np.maximum(J, 1e-6)[:, None, None]

    def device_state(self, keys=("x", "v", "F", "tau")) -> dict:
        """The particle state arrays ``keys`` where the kernels keep them (Taichi ndarrays on
        the arch's device, all groups, [N, ...] rows), up to date with every change made on
        the host: for kernels that read the state without copying it back
        (:class:`~gausstac_maniskill.tactile.readout.TactileReadout`). Do not write them."""
        self._push()
        missing = [k for k in keys if k not in self._dev]
        if missing:
            raise ConfigError(f"device_state: the world has no particles (no device array {missing[0]!r})")
        return {k: self._dev[k] for k in keys}

    def rest_positions(self, group: str | None = None) -> np.ndarray:
        """Kinematic particles' rest coordinates [N, 3] in their link frame (0 for others)."""
        return self._read("X0", group)

    def rest_volumes(self, group: str | None = None) -> np.ndarray:
        """Rest volume V0 [m³] of each particle, [N]."""
        return self._read("vol", group)

    def virtual_work_force(self, group: str, grad_phi) -> np.ndarray:
        """Force [N, world frame] that a group's boundary loads exert where a test field φ is 1,
        read from its stress: ∫ σ ∇φ dV = ∫ φ t dA (weak form of equilibrium, exact in
        equilibrium when φ vanishes wherever else the group is loaded, e.g. at its bond).

        Args:
            group: group name.
            grad_phi: [N, 3] ∇φ of each particle [1/m] in the rest configuration (world frame
                at binding, see :meth:`binding_rotation`); zero rows drop a particle.
        Returns:
            [3] Σ_p V0_p J_p σ_p F_p⁻ᵀ ∇φ_p = Σ_p V0_p τ_p F_p⁻ᵀ ∇φ_p (τ Kirchhoff).
        """
        g = np.asarray(grad_phi, np.float64)
        n = self.group(group).count
        if g.shape != (n, 3):
            raise ConfigError(f"virtual_work_force({group!r}): grad_phi must have shape {(n, 3)}, got {g.shape}")
        use = np.any(g != 0.0, axis=1)
        F = self.deformation_gradients(group)[use].astype(np.float64)
        tau = self._read("tau", group)[use].astype(np.float64)
        grad_x = np.linalg.solve(np.transpose(F, (0, 2, 1)), g[use][..., None])[..., 0]
        return np.einsum("n,nij,nj->i", self.rest_volumes(group)[use], tau, grad_x)

    def binding_rotation(self, group: str) -> np.ndarray:
        """World rotation (3x3) of a group's link when the group was added: the frame its
        deformation gradients are measured from (identity for a group without a link)."""
        self._pull()
        self.group(group)  # clear error if unknown
        return quat_to_matrix(self._host["group_bind"][self._group_at[group]].astype(np.float64))

    def kinematic_mask(self, group: str | None = None) -> np.ndarray:
        """[N] bool: which particles are kinematic."""
        return self._read("kind", group).astype(bool)

    def contact_forces(self, group: str | None = None) -> np.ndarray:
        """Mean contact force [N, 3] (newtons) each particle received from colliders
        during the last control step (impulse / Δt_ctrl); zero where no contact."""
        return self._read("impulse", group) / self._last_dt_ctrl

    def contact_collider(self, group: str | None = None) -> np.ndarray:
        """[N] index of the collider each particle last touched (-1: none)."""
        return self._read("contact_id", group)

    def collider_wrench(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Mean reaction (force [N], torque [N·m] about the collider origin) that
        collider ``index`` received from the particles during the last control step."""
        self._collider(index)
        J = self._col_impulse[index] / self._last_dt_ctrl if len(self._col_impulse) else np.zeros(6)
        return J[:3].copy(), J[3:].copy()

    def link_wrench(self, link) -> tuple[np.ndarray, np.ndarray]:
        """Mean reaction (force [N], torque [N·m] about the link's origin, world frame) that
        ``link`` (name or index) received through the particles bound to it during the last
        control step: the contact impulses those particles took from colliders and from the
        other field, passed on by a massless layer (see :func:`kernels.reduce_contact`).
        Equal and opposite to the colliders' share of :meth:`collider_wrench`."""
        J = self._pair_impulse[self.link_index(link), :, :6].sum(0) / self._last_dt_ctrl
        return J[:3].copy(), J[3:].copy()

    def link_contacts(self, link) -> np.ndarray:
        """[len(colliders) + 1, 7] per object that ``link``'s particles touched during the last
        control step: the mean force [N] and torque [N·m] (about the link's origin, world
        frame) it passed to the link, and the indentation [m] (the deepest displacement of
        a touching particle from its rest place on the link, along its push). Row c < C:
        collider c; the last row: the other velocity field (soft objects). Rows sum to
        :meth:`link_wrench`."""
        out = self._pairs(np.array([self.link_index(link)]), np.arange(len(self.colliders)))[0]
        out[:, :6] /= self._last_dt_ctrl
        return out

    def energy(self) -> tuple[float, float]:
        """(kinetic, elastic) energy [J] of the awake dynamic particles; the kinetic energy is
        APIC's, with the affine velocity's share (:func:`kernels.energies`)."""
        self._push()
        out = ti.ndarray(ti.f32, shape=2)
        active = self._dev["active"]
        K.energies(active, self._n_active, self._dev["v"], self._dev["C"], self._dev["F"], self._dev["Jp"],
                   self._dev["kind"], self._dev["matid"], self._dev["mass"], self._dev["vol"],
                   self._dev["mat_table"], self.settings.dx, out)
        e = out.to_numpy()
        return float(e[0]), float(e[1])

    def wave_speed(self) -> float:
        """Largest explicit wave speed [m/s] of the awake groups (quasi-static ones with their
        pseudo-mass): the P-wave √((λ+2μ)/ρ), or √(2μ/ρ) where the volume term λ ln J is
        solved implicitly on cells (``SolverSettings.pressure``)."""
        speeds = [(math.sqrt(2.0 * g.material.mu / g.material.density)
                   if cell_pressure(g.material, self.settings.pressure) else g.material.wave_speed)
                  / math.sqrt(g.mass_scale * self._hold_factor(g))
                  for g in self.groups if g.awake and g.count > g.n_kinematic]
        return max(speeds, default=0.0)

    # ------------------------------------------------------------------ driving
    def link_pose(self, link) -> np.ndarray:
        """World pose (4x4) of a link at the end of the last step: where its particles are."""
        return self._link_prev[self.link_index(link)].copy()

    def link_poses(self) -> np.ndarray:
        """[L, 4, 4] world poses [m] of every link (in :attr:`link_names` order) at the end of
        the last step."""
        return self._link_prev.copy()

    def link_twist(self, link) -> tuple[np.ndarray, np.ndarray]:
        """(velocity of the link origin [m/s], angular velocity [rad/s]) over the last step."""
        w = self._link_twist[self.link_index(link)]
        return w[:3].copy(), w[3:].copy()

    @property
    def last_dt_ctrl(self) -> float:
        """Length [s] of the last control step."""
        return self._last_dt_ctrl

    def set_link_pose(self, link, pose) -> None:
        """Target world pose (4x4) of a link at the end of the next control step."""
        i = self.link_index(link)
        self._link_next[i] = as_pose_matrix(pose, f"pose of link {self.link_names[i]!r}")

    def set_link_poses(self, poses, links=None) -> None:
        """Targets for many links at once: a dict name -> 4x4; or an array [K, 4, 4] for the
        link indices ``links`` [K] (all links in order when None). Checked in one pass."""
        if isinstance(poses, dict):
            links, poses = [self.link_index(n) for n in poses], list(poses.values())
        idx = np.arange(len(self.link_names)) if links is None else np.asarray(links, np.int64).reshape(-1)
        if len(idx) and (idx.min() < 0 or idx.max() >= len(self.link_names)):
            raise ConfigError(f"set_link_poses: link index out of range (have {len(self.link_names)} links)")
        arr = np.asarray(poses, np.float64)
        if arr.shape != (len(idx), 4, 4):
            raise ConfigError(f"set_link_poses: expected shape {(len(idx), 4, 4)}, got {arr.shape}")
        self._link_next[idx] = as_pose_matrices(arr, "set_link_poses poses")

    def _collider(self, index: int) -> Collider:
        """Collider ``index`` (a clear error where there is none)."""
        if not 0 <= index < len(self.colliders):
            raise ConfigError(f"collider index {index} out of range ({len(self.colliders)} colliders)")
        return self.colliders[index]

    def collider_start_pose(self, index: int) -> np.ndarray:
        """World pose (4x4) of collider ``index`` at the end of the last step, where the next
        step moves it from (its target is ``colliders[index].pose``)."""
        self._collider(index)
        return self._col_prev[index].copy()

    def set_collider_pose(self, index: int, pose) -> None:
        """Target world pose (4x4) of collider ``index`` at the end of the next control step."""
        c = self._collider(index)
        c.pose = as_pose_matrix(pose, f"pose of collider {index} ({c.name or type(c).__name__})")

    def set_collider_sdf(self, index: int, sdf) -> None:
        """New signed distances [m] on mesh collider ``index``'s SDF grid (the same grid:
        :attr:`MeshCollider.sdf`'s shape), for a surface that deforms (a pad solved at
        equilibrium, seen by soft objects); they take effect at the next step."""
        c = self._collider(index)
        if not isinstance(c, MeshCollider):
            raise ConfigError(f"set_collider_sdf: collider {index} ({c.name or type(c).__name__}) is not a MeshCollider")
        sdf = np.asarray(sdf, np.float32)
        if sdf.shape != c.sdf.shape:
            raise ConfigError(f"set_collider_sdf: collider {index} ({c.name}) samples {c.sdf.shape}, got {sdf.shape}")
        c.sdf = sdf
        self._sdf_stale = True

    def set_awake(self, name: str, awake: bool) -> None:
        """Put a group to sleep (it costs nothing and is not changed) or wake it.

        A group bound to a link is carried rigidly with the link while asleep:
        on waking, its particles are moved by the link's motion since it fell asleep.
        """
        g = self.group(name)
        if g.awake == bool(awake):
            return
        on_device = self._on_device()
        if not on_device:
            self._pull()
        if not awake:
            if g.link >= 0:
                g.sleep_pose = self._link_prev[g.link].copy()
            self._forget_contact(g, on_device)
        elif g.link >= 0 and g.sleep_pose is not None:
            T = self._link_prev[g.link] @ np.linalg.inv(g.sleep_pose)
            R, t = T[:3, :3], T[:3, 3]
            if on_device:
                move_rigidly(self._pack["P"], g.start, g.stop, ti.math.mat3(R), ti.math.vec3(t))
                self._stale |= {"x", "v", "C", "tau", "F"}
            else:
                sl = slice(g.start, g.stop)
                h = self._host
                h["x"][sl] = (h["x"][sl].astype(np.float64) @ R.T + t).astype(np.float32)
                h["v"][sl] = (h["v"][sl] @ R.T).astype(np.float32)
                for key in ("C", "tau"):
                    h[key][sl] = (R @ h[key][sl] @ R.T).astype(np.float32)
                h["F"][sl] = (R @ h["F"][sl]).astype(np.float32)
        g.awake = bool(awake)
        if on_device:
            self._awake_changed = True  # the active lists follow at the next push; the state stays
        else:
            self._dirty = True

    def _on_device(self) -> bool:
        """Whether the device holds the world as built (no structural change pending), so a
        group's rows can be changed there in place (mpm/rows.py) instead of on the host."""
        return not self._dirty and self._n > 0 and "P" in self._pack

    def rest_group(self, name: str) -> None:
        """Put a link-bound group exactly on its rest shape on the link's current pose
        (x = R X0 + t, v = 0, F = link rotation, zero stress): the elastic solution with no
        load, used when a settled pad leaves every contact (drops numerical plasticity)."""
        g = self.group(name)
        if g.link < 0:
            raise ConfigError(f"rest_group({name!r}): the group is not bound to a link")
        on_device = self._on_device()
        if not on_device:
            self._pull()
        T = self._link_prev[g.link]
        bind = quat_to_matrix(self._host["group_bind"][self.groups.index(g)].astype(np.float64))
        F_rest = T[:3, :3] @ bind.T
        if on_device:  # X0 as built (the active patch rebinds some rows of the device's X0)
            X0 = self._dev["X_rest" if self._patch is not None else "X0"]
            put_at_rest(self._pack["P"], X0, g.start, g.stop, ti.math.mat3(T[:3, :3]), ti.math.vec3(T[:3, 3]),
                             ti.math.mat3(F_rest))
            self._stale |= {"x", "v", "C", "tau", "Jp", "F", "impulse", "contact_id", "anchor"}
        else:
            sl, h = slice(g.start, g.stop), self._host
            h["x"][sl] = (h["X0"][sl].astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
            h["v"][sl] = 0.0
            h["C"][sl] = 0.0
            h["tau"][sl] = 0.0
            h["Jp"][sl] = 1.0
            h["F"][sl] = F_rest.astype(np.float32)
            self._forget_contact(g, False)
            self._dirty = True
        g.patch_state = 0

    def _forget_contact(self, g: Group, on_device: bool) -> None:
        """Clear group g's contact state: impulses, touched colliders, friction anchors (on the
        device, or on the host when the world is to be rebuilt from it)."""
        if on_device:
            forget_contact(self._pack["P"], g.start, g.stop)
            self._stale |= {"impulse", "contact_id", "anchor"}
            return
        sl, h = slice(g.start, g.stop), self._host
        h["impulse"][sl] = 0.0
        h["contact_id"][sl] = -1
        h["anchor"][sl] = no_anchor(g.count)

    def plan_substeps(self, dt: float, driver_speed: float | None = None) -> tuple[int, float]:
        """Substeps for a control step of ``dt`` seconds from the CFL bound.

        Raises:
            SimulationError: the bound needs more than ``settings.max_substeps``.
        """
        self._push()
        if self._n_active == 0:
            return 1, dt  # nothing awake: nothing to resolve, whatever moves around
        s = self.settings
        c = self.wave_speed()
        v = self._vmax + (self._driver_speed(dt) if driver_speed is None else driver_speed)
        dt_max = s.cfl * s.dx / max(c + v, 1e-12)
        n = max(1, math.ceil(dt / dt_max - 1e-9))
        if n > s.max_substeps:
            raise SimulationError(
                f"control step dt={dt:g} s needs {n} substeps (CFL: Δt ≤ {s.cfl}·dx/(c+|v|) = "
                f"{dt_max:.3g} s with dx={s.dx:g} m, wave speed c={c:.3g} m/s, |v|max={v:.3g} m/s) but "
                f"SolverSettings.max_substeps={s.max_substeps}. Use a shorter control step, a coarser dx, "
                f"a softer material, quasi-static SolverSettings.mass_scaling > 1, or raise max_substeps.")
        return n, dt / n

    def _driver_speed(self, dt: float, travel=None) -> float:
        """Upper bound of link/collider surface speeds [m/s] over the next step of dt seconds
        (from :meth:`_boundary_travel`, or ``travel`` it returned)."""
        links, cols = self._boundary_travel() if travel is None else travel
        return float(max(links.max(initial=0.0), cols.max(initial=0.0))) / dt

    def _boundary_travel(self) -> tuple[np.ndarray, np.ndarray]:
        """Upper bounds [m] of how far each link's [L] and each collider's [C] surface moves over
        the next step: the origin's travel plus the turn's angle times the body's radius."""
        links = _surface_travel(self._link_prev, self._link_next, self._link_radius)
        cols = np.zeros(0)
        if self.colliders:
            nxt = self._collider_poses()
            r = np.array([_collider_radius(c) for c in self.colliders])
            far = ~np.isfinite(r)
            if far.any():  # no bound: the farthest particle from the collider's end origin
                self._pull(("x",))
                x = self._host["x"] if self._n else np.zeros((1, 3))
                r[far] = [float(np.linalg.norm(x - T[:3, 3], axis=1).max()) for T in nxt[far]]
            cols = _surface_travel(self._col_prev, nxt, r)
        return links, cols

    def step(self, dt: float, min_substeps: int = 1) -> StepInfo:
        """Advance one control step of ``dt`` seconds; links and colliders move from
        their previous pose to the last one set. Returns a :class:`StepInfo`.

        ``min_substeps``: take at least this many substeps (more than the CFL bound asks):
        a single scene then steps exactly as it would inside a batch whose other envs
        needed that many (the batched co-simulator's equivalence test).

        Raises:
            ConfigError: dt is not a positive finite number.
            SimulationError: the CFL bound cannot be met, a value became NaN/inf,
                or the active region grew beyond ``settings.max_grid_cells``.
        """
        if not (isinstance(dt, (int, float, np.floating)) and math.isfinite(dt) and dt > 0):
            raise ConfigError(f"step(dt={dt!r}): dt must be a positive finite number of seconds")
        t0 = time.perf_counter()
        self._push()
        travel = self._boundary_travel()
        driver = self._driver_speed(float(dt), travel)
        if self.settings.hold_scaling > 1.0:
            self._choose_hold(float(dt), travel)
        n_sub, dt_sub = self.plan_substeps(float(dt), driver)
        if int(min_substeps) > n_sub and self._n_active:
            n_sub, dt_sub = int(min_substeps), float(dt) / int(min_substeps)
        # particles farther than this from a collider cannot reach it within a substep
        self._reach = 2.0 * (self._vmax + driver) * dt_sub
        self._upload_consts()
        self._upload_poses()
        frozen = self._choose_patch() if self._patch is not None else None
        d = self._dev
        twists = _twists(self._link_prev, self._link_next, float(dt))
        if self._n_active:
            # groups that touched a collider in the last step keep their velocity (follow_links)
            change = np.zeros((max(len(twists), 1), 9), np.float32)
            change[:len(twists)] = np.concatenate([twists - self._link_twist, self._link_prev[:, :3, 3]], 1)
            if np.any(change[:, :6]) and any(g.awake and g.quasi_static for g in self.groups):
                d["twist_change"].from_numpy(change)
                d["group_touched"].fill(0)
                groups_in_contact(d["active"], self._n_active, d["contact_id"], d["group"], True,
                                  d["group_touched"])
                K.follow_links(d["active"], self._n_active, d["v"], d["C"], d["x"], d["kind"], d["link"],
                               d["group"], d["group_qs"], d["group_touched"], d["twist_change"])
            K.reset_contact(d["active"], self._n_active, d["impulse"], d["contact_id"])
        d["col_impulse"].fill(0.0)
        d["pair_impulse"].fill(0.0)
        self._stale = set(_STATE_FIELDS)  # from here on the device holds the newer state
        cells = 0
        flags = self._advance_flags()
        for k in range(n_sub):
            if self._n_active == 0:
                break
            cells = self._substep(k / n_sub, (k + 1) / n_sub, dt_sub, flags)
        self._check_health()
        if self._cellp and self._n_active and int(d["cell_count"].to_numpy()[1]):
            raise SimulationError(
                f"the cell pressure ran out of cell slots at step {self.step_count + 1} ({d['slot_cell'].shape[0]} "
                f"for {self._n} particles): the material spread to more than one cell per two particles. "
                f"Use SolverSettings(pressure='explicit') for such strongly expanding bodies.")
        if self._n_active and n_sub:
            # kinematic particles onto the link's end pose (the substeps place them at each
            # substep's start); with F-bar the stress is then brought up to the final F
            self._prepare(1.0, 1.0 + 1e-6, dt_sub)
            if self._fbar or self._cellp:
                K.fbar_update(self._world_pack(), self._nh_only(), self._two_fields, self._atomic, self._fbar,
                              self._cellp)
        if frozen is not None and len(frozen):
            carry_rigidly(d["patch_frozen"], len(frozen), float(dt), d["link_pose"], d["x"], d["v"], d["C"],
                          d["F"], d["tau"], d["impulse"], d["contact_id"], d["link"])
        if self._patched and self._n_active:
            self._note_patch_contact()
        if self._n_active and self.contact == "particle":
            K.reduce_contact(self._pack["P"], d["X0"], d["active"], self._pack["R"], self.num_envs,
                             self._pair_impulse.shape[1])
        self._col_impulse = d["col_impulse"].to_numpy().astype(np.float64)[: len(self.colliders)]
        n_slot = self._pair_impulse.shape[1]
        pairs = d["pair_impulse"].to_numpy().astype(np.float64)
        self._pair_impulse = pairs[: len(self.link_names) * n_slot].reshape(len(self.link_names), n_slot, 7)
        torn = self._torn_groups() if self._n_active else []
        if self.settings.hold_scaling > 1.0 and self._n_active and any(g.quasi_static for g in self.groups):
            d["group_drift"].fill(0.0)
            K.group_drift(self._pack["P"], d["active"], self._n_active, d["link_pose"], float(dt), d["group_drift"])
            drift = d["group_drift"].to_numpy()
            for i, g in enumerate(self.groups):
                g.drift = float(drift[i]) if g.awake else math.inf
        self._link_prev = self._link_next.copy()
        self._link_twist = twists
        self._col_prev = self._collider_poses()
        self._last_dt_ctrl = float(dt)
        self.time += float(dt)
        self.step_count += 1
        self._rest_torn(torn, driver)
        self.last_step = StepInfo(n_sub, dt_sub, time.perf_counter() - t0, self._n_active, cells)
        return self.last_step

    def _choose_hold(self, dt: float, travel: tuple[np.ndarray, np.ndarray]) -> None:
        """Which awake quasi-static groups hold (see the module docstring): those whose link and
        env colliders move their surfaces slower than ``hold_speed / 5`` over the step (``travel``:
        :meth:`_boundary_travel`), with no soft body awake in their env, and that either hold
        already or drifted slower than ``hold_speed`` relative to their link at the end of the
        last step."""
        s = self.settings
        limit = 0.2 * s.hold_speed * dt  # boundary travel [m] that counts as standing still
        links, cols = travel
        for g in self.groups:
            if not (g.awake and g.quasi_static and g.link >= 0):
                continue
            still = links[g.link] <= limit and all(cols[k] <= limit for k in range(len(cols))
                                                   if self._col_env[k] == g.env)
            still = still and not any(h.awake and not h.quasi_static and h.env == g.env for h in self.groups)
            self._set_hold(g, still and (g.hold or g.drift < s.hold_speed))

    def _hold_factor(self, g: Group) -> float:
        """What group g's pseudo-mass is multiplied by now: ``hold_scaling`` while it holds, else 1.
        Its relaxation rate is divided by the square root (the same damping ratio)."""
        return self.settings.hold_scaling if g.hold else 1.0

    def _set_hold(self, g: Group, hold: bool) -> None:
        """Put group g on its hold pseudo-mass or back. Its particles' mass is set anew from
        density, pseudo-mass and rest volume, as add_group set it, so switching back and forth
        never drifts; its ``mass_scale`` and ``relaxation`` stay as add_group set them."""
        if hold == g.hold:
            return
        g.hold = hold
        mass = np.float32(g.material.density * g.mass_scale * self._hold_factor(g)
                          * float(self._host["vol"][g.start]))
        if self._on_device():
            K.fill_mass(self._pack["P"], g.start, g.stop, float(mass))
        self._host["mass"][g.start:g.stop] = mass

    def _torn_groups(self) -> list[tuple[Group, int]]:
        """Awake quasi-static groups with particles beyond their ``tear`` distance from their
        rest places after this step, and how many (:func:`kernels.torn_particles`)."""
        if not any(g.awake and g.tear > 0.0 for g in self.groups):
            return []
        d = self._dev
        d["torn"].fill(0)
        K.torn_particles(self._pack["P"], d["X_rest" if self._patch is not None else "X0"], d["active"],
                         self._n_active, d["link_pose"], d["group_tear"], d["torn"])
        counts = d["torn"].to_numpy()
        return [(g, int(counts[i])) for i, g in enumerate(self.groups) if g.awake and counts[i] > 0]

    def _rest_torn(self, torn: list[tuple[Group, int]], driver: float) -> None:
        """Put torn groups back on their rest shape, and say so. An object pushed into a pad's
        core by the pose source (a link driven through it faster than the rigid solver holds it
        out) leaves the layer no elastic state: contact pushes it out while its core is inside,
        and the part pushed beyond the grid stencil of its core stays detached, reading a
        depth the pad cannot have (a 13.6 m/s strike on GraspLiftCube's cube did this). An
        object that drags a stuck layer farther than it stretches does the same."""
        for g, count in torn:
            warnings.warn(SimulationWarning(
                f"group {g.name!r}: {count} of its {g.count - g.n_kinematic} soft particles were torn more than "
                f"{g.tear * 1e3:.3g} mm from their rest places on link {self.link_names[g.link]!r} at step "
                f"{self.step_count} (t={self.time:.4g} s; link surfaces moved up to {driver:.3g} m/s), farther than "
                f"any elastic state of its layer reaches: an object was driven into its core, or dragged the "
                f"layer off it. The group was put back on its rest shape; its contact and maps of this step "
                f"are not physical."), stacklevel=3)
            self.rest_group(g.name)

    # ------------------------------------------------------------------ internals
    def _prepare(self, a0: float, a1: float, dt: float) -> int:
        """Frames, kinematic particles and the slab sort for the substep [a0, a1] of the
        control step; returns the active box's number of cells (see :func:`kernels.prepare`)."""
        s = self.settings
        ncell = int(K.prepare(self._pack["placement"], a0, a1, dt, self._atomic))
        if ncell > s.max_grid_cells or ncell < 0:
            ox, oy, oz, nx, ny, nz = (int(b) for b in self._dev["box"].to_numpy()[:6])
            raise SimulationError(self._explode_message(np.array([ox, oy, oz]) + s.grid_margin,
                                                        np.array([ox + nx, oy + ny, oz + nz]) - s.grid_margin - 3))
        need = ncell * (2 if self._two_fields else 1) * self.num_envs
        if need > self._grid_cap:
            self._alloc_grid(int(min(need * 1.5, 2 * s.max_grid_cells)))
        return ncell

    def _world_pack(self):
        """The kernels' argument pack (kernels.World) over the current device arrays."""
        pk = self._pack
        if pk.get("W") is None:
            pk["W"] = K.World(P=pk["P"], G=pk["G"], S=pk["S"], O=pk["O"])
        return pk["W"]

    def _upload_counts(self) -> None:
        self._dev["counts"].from_numpy(np.array([len(self.link_names), len(self.groups), len(self.colliders),
                                                 len(self._walls), self._n_active, self._n_kin, self.num_envs],
                                                np.int32))

    def _choose_patch(self) -> np.ndarray | None:
        """The active patch of this step (:mod:`~gausstac_maniskill.mpm.patch`): rewrites the
        awake lists, the kinematic flags and the shell's rest coordinates on the device.
        Returns the indices of the frozen particles (carried rigidly after the substeps),
        or None when every awake particle is simulated."""
        h, d, n = self._host, self._dev, max(self._n, 1)
        self._patched = []
        if not any(g.awake for g in self.groups):
            return None
        kind = h["kind"]
        gids = [i for i, g in enumerate(self.groups) if g.awake and g.quasi_static and g.link >= 0
                and g.count > g.n_kinematic and g.patch_state != 2]
        gaps = {}
        if gids and self.colliders and not self._two_fields:
            cand = np.concatenate([np.arange(self.groups[i].start, self.groups[i].stop, dtype=np.int32)
                                   for i in gids])
            d["patch_cand"].from_numpy(np.resize(cand, n))
            rest_gap(self._pack["P"], self._pack["S"], d["X_rest"], d["link_pose"], d["col_pose"],
                     d["patch_cand"], len(cand), d["patch_gap"])
            gap = d["patch_gap"].to_numpy()
            start = 0
            for i in gids:
                gaps[i] = gap[start:start + self.groups[i].count]
                start += self.groups[i].count
        parts, bind, frozen = [], [], []
        for i, g in enumerate(self.groups):
            if not g.awake:
                continue
            idx = np.arange(g.start, g.stop, dtype=np.int32)
            sl = slice(g.start, g.stop)
            split = self._patch.split(i, h["X0"][sl], kind[sl] == 0, gaps[i]) if i in gaps else None
            if split is not None and not split[0].any() and g.patch_state == 1:
                g.patch_state, split = 2, None  # its contact has just ended: relax it whole
            if split is None:
                parts.append((g.env, idx))
                continue
            patch, shell = split  # nothing touches a group at rest: all of it rides with the link
            self._patched.append(i)
            parts.append((g.env, idx[patch | shell]))
            bind.append(idx[shell & (kind[sl] == 0)])
            frozen.append(idx[~(patch | shell)])
        active, env_rows = self._env_major(parts)
        d["env_rows"].from_numpy(env_rows)
        kd = kind.copy()
        bind = np.concatenate(bind) if bind else np.zeros(0, np.int32)
        kd[bind] = 1
        active_kin = active[kd[active] == 1]
        d["kind"].from_numpy(np.resize(kd, n))
        d["active"].from_numpy(np.resize(active, n))
        d["active_kin"].from_numpy(np.resize(active_kin, n))
        self._n_active, self._n_kin = len(active), len(active_kin)
        self._upload_counts()
        if len(bind):
            d["patch_bind"].from_numpy(np.resize(bind, n))
            bind_in_place(d["patch_bind"], len(bind), d["link_pose"], d["x"], d["X0"], d["link"])
        if not frozen:
            return None
        frozen = np.concatenate(frozen)
        d["patch_frozen"].from_numpy(np.resize(frozen, n))
        return frozen

    def _note_patch_contact(self) -> None:
        """After a patched step: a patched group in contact holds frozen deformation (state 1);
        once its contact ends it is simulated whole until put back at rest (state 2)."""
        d = self._dev
        d["patch_contact"].from_numpy(np.zeros(max(len(self.groups), 1), np.int32))
        groups_in_contact(d["active"], self._n_active, d["contact_id"], d["group"], False, d["patch_contact"])
        touched = d["patch_contact"].to_numpy()
        for i in self._patched:
            g = self.groups[i]
            if touched[i]:
                g.patch_state = 1
            elif g.patch_state == 1:
                g.patch_state = 2

    def _nh_only(self) -> bool:
        return all(m.model == "neo_hookean" for m in self.materials)

    def _stress_flags(self) -> tuple[bool, int]:
        """(F-bar for some material, CG iterations of the cells' volume term or 0): the kernels'
        compile-time switches for this world's materials."""
        s = self.settings
        cells = [cell_pressure(m, s.pressure) for m in self.materials]
        return bool(s.fbar) and not all(cells), (int(s.pressure_iterations) if any(cells) else 0)

    def _advance_flags(self) -> tuple:
        """:func:`kernels.advance`'s compile-time switches for this world, in its order after dt."""
        mode = 0 if not self.colliders else (1 if self.contact == "particle" else 2)
        return self._fbar, mode, self._nh_only(), self._two_fields, self._atomic, self._cellp

    def _substep(self, a0: float, a1: float, dt: float, flags: tuple) -> int:
        """One substep [a0, a1] of the control step, ``dt`` seconds long (``flags``:
        :meth:`_advance_flags`); returns its active box's number of cells."""
        ncell = self._prepare(a0, a1, dt)
        K.advance(self._world_pack(), dt, *flags)
        return ncell

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
        self._dev["env_relax"].from_numpy(rate)
        self._dev["consts"].from_numpy(np.array([s.dx, *s.gravity, s.damping, self._reach, s.grid_margin,
                                                 s.soft_friction, float(s.bond == "surface")], np.float32))

    def _alloc_grid(self, cap: int) -> None:
        d = self._dev
        d["grid_pm"] = ti.Vector.ndarray(4, ti.f32, shape=cap)
        d["grid_v"] = ti.Vector.ndarray(3, ti.f32, shape=cap)
        d["grid_m"] = ti.ndarray(ti.f32, shape=cap)
        d["grid_mq"] = ti.ndarray(ti.f32, shape=cap)
        d["grid_link"] = ti.ndarray(ti.i32, shape=cap)
        d["grid_dp"] = ti.Vector.ndarray(3, ti.f32, shape=cap)
        d["grid_vol"] = ti.Vector.ndarray(2, ti.f32, shape=cap)
        d["grid_vc"] = ti.ndarray(ti.f32, shape=cap)
        d["grid_ds"] = ti.Vector.ndarray(3, ti.f32, shape=cap)
        d["grid_kin"] = ti.Vector.ndarray(6, ti.f32, shape=cap)
        d["cell_slot"] = ti.ndarray(ti.i32, shape=cap)
        d["grid_t"] = ti.Vector.ndarray(3, ti.f32, shape=cap)
        self._grid_cap = cap
        self._alloc_cells()

    def _alloc_cells(self) -> None:
        """Per-cell arrays of the cell pressure (kernels.pressure_solve): room for one occupied cell
        per two particles (8 per cell when seeded; kernels.number_cells flags an overflow, which
        step() reports); and the Grid pack."""
        d = self._dev
        cells = max(self._n // 2, 1) + 64 if self._cellp else 1
        if d.get("slot_cell") is None or d["slot_cell"].shape[0] != cells:
            d["slot_cell"] = ti.ndarray(ti.i32, shape=cells)
            d["cell_a"] = ti.Vector.ndarray(4, ti.f32, shape=cells)
            d["cell_b"] = ti.Vector.ndarray(4, ti.f32, shape=cells)
            d["cell_G"] = ti.Vector.ndarray(3, ti.f32, shape=cells * 64)
        if d.get("cell_count") is None:
            d["cell_count"] = ti.ndarray(ti.i32, shape=2)
            d["cg_sum"] = ti.ndarray(ti.f32, shape=K.CG_ROWS)
        self._pack["W"] = None
        self._pack["G"] = K.Grid(**{k: d[k] for k in ("grid_pm", "grid_v", "grid_m", "grid_mq", "grid_link",
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

    def _explode_message(self, lo, hi) -> str:
        x = self._dev["x"].to_numpy()
        parts = []
        for g in self.groups:
            if g.awake:
                gx = x[g.start:g.stop]
                parts.append(f"{g.name!r}: [{gx.min(0).round(4).tolist()} .. {gx.max(0).round(4).tolist()}] m")
        ext = (hi - lo + 1) * self.settings.dx
        return (f"the active particles spread over {ext.round(4).tolist()} m "
                f"(> SolverSettings.max_grid_cells={self.settings.max_grid_cells} cells of dx="
                f"{self.settings.dx:g} m) at t={self.time:.4g} s, step {self.step_count}: particles are "
                f"flying apart (unstable simulation?). Group extents: " + "; ".join(parts))

    def _check_health(self) -> None:
        if not self._n_active:
            self._vmax = 0.0
            return
        d = self._dev
        K.chunk_health(d["active"], self._n_active, d["x"], d["v"], d["F"], d["kind"], K.NCHUNK,
                       d["first_bad"], d["vmax_chunk"])
        bad = d["first_bad"].to_numpy()
        self._vmax = float(d["vmax_chunk"].to_numpy().max())
        bad = bad[bad >= 0]
        if len(bad):
            p = int(bad.min())
            g = next(g for g in self.groups if g.start <= p < g.stop)
            raise SimulationError(
                f"particle {p - g.start} of group {g.name!r} has a NaN/inf position, velocity or "
                f"deformation gradient after step {self.step_count + 1} (t={self.time:.4g} s, "
                f"{self.last_step.substeps if self.last_step else '?'} substeps of the previous step). "
                f"The simulation is unstable: lower SolverSettings.cfl, check material parameters "
                f"(E={g.material.E:g} Pa, nu={g.material.nu:g}) and link/collider motions.")

    def _pull(self, keys=_STATE_FIELDS) -> None:
        """Copy the state fields ``keys`` (all by default) back to the host arrays, those the
        device holds newer: a read after a step copies only the field it reads, not the
        whole particle state."""
        stale = getattr(self, "_stale", None)
        if stale and self._dev:
            for key in [k for k in keys if k in stale]:
                self._host[key] = self._dev[key].to_numpy()[: self._n]
                stale.discard(key)

    def _push(self) -> None:
        """(Re)build device arrays from the host after any structural change; after groups
        only woke or fell asleep, renew just the active lists (:meth:`_refresh_active`)."""
        if not self._dirty:
            if self._awake_changed:
                self._refresh_active()
            if self._sdf_stale:
                self._dev["sdf"].from_numpy(self._sdf_values())
                self._sdf_stale = False
            return
        self.rebuilds += 1
        self._pull()
        if self._n == 0 and not self.groups:
            self._n_active = 0
            self._n_kin = 0
        h, d = self._host, self._dev
        n = max(self._n, 1)

        def upload(key, arr, dtype, shape=()):
            nd = (ti.Vector.ndarray(shape[0], dtype, shape=len(arr)) if len(shape) == 1 else
                  ti.Matrix.ndarray(shape[0], shape[1], dtype, shape=len(arr)) if len(shape) == 2 else
                  ti.ndarray(dtype, shape=arr.shape))
            nd.from_numpy(np.ascontiguousarray(arr))
            d[key] = nd

        if self._n:
            for key in ("x", "v", "impulse", "X0"):
                upload(key, h[key], ti.f32, (3,))
            upload("bond", h["bond"], ti.f32, (4,))
            upload("anchor", h["anchor"], ti.f32, (4,))
            for key in ("C", "F", "tau"):
                upload(key, h[key], ti.f32, (3, 3))
            for key in ("Jp", "mass", "vol", "radius"):
                upload(key, h[key], ti.f32)
            for key in ("kind", "matid", "link", "group", "contact_id"):
                upload(key, h[key], ti.i32)
            upload("group_bind", h["group_bind"].astype(np.float32), ti.f32)
        self._fbar, self._cellp = self._stress_flags()  # from the materials, which only _push sees change
        # room for every particle: the lists are rewritten when groups wake or sleep, and with
        # the active patch every step
        d["active"], d["active_kin"] = ti.ndarray(ti.i32, shape=n), ti.ndarray(ti.i32, shape=n)
        d["env_rows"] = ti.ndarray(ti.i32, shape=self.num_envs + 1)
        if self._patch is not None:
            self._patch.forget()
            upload("X_rest", h["X0"] if self._n else np.zeros((1, 3), np.float32), ti.f32, (3,))
            for key in ("patch_gap", "patch_cand", "patch_frozen", "patch_bind"):
                d[key] = ti.ndarray(ti.f32 if key == "patch_gap" else ti.i32, shape=n)
            d["patch_contact"] = ti.ndarray(ti.i32, shape=max(len(self.groups), 1))
        for key in ("order", "slab_of"):
            d[key] = ti.ndarray(ti.i32, shape=n)
        if "slab_start" not in d:
            d["slab_start"] = ti.ndarray(ti.i32, shape=K.SLAB_CAP)
            d["cursor"] = ti.ndarray(ti.i32, shape=K.SLAB_CAP)
        d["bounds"] = ti.ndarray(ti.i32, shape=(K.NCHUNK, 6))
        d["box"] = ti.ndarray(ti.i32, shape=K.BOX)
        d["first_bad"] = ti.ndarray(ti.i32, shape=K.NCHUNK)
        d["vmax_chunk"] = ti.ndarray(ti.f32, shape=K.NCHUNK)
        upload("mat_table", material_table(self.materials, self.settings.pressure), ti.f32)
        upload("group_qs", np.array([int(g.quasi_static) for g in self.groups] or [0], np.int32), ti.i32)
        upload("group_tear", np.array([g.tear for g in self.groups] or [0.0], np.float32), ti.f32)
        d["torn"] = ti.ndarray(ti.i32, shape=max(len(self.groups), 1))
        d["group_touched"] = ti.ndarray(ti.i32, shape=max(len(self.groups), 1))
        d["group_drift"] = ti.ndarray(ti.f32, shape=max(len(self.groups), 1))
        upload("group_field", np.array([g.field for g in self.groups] or [0], np.int32), ti.i32)
        upload("group_env", np.array([g.env for g in self.groups] or [0], np.int32), ti.i32)
        # the grid holds one box per env and awake field: each group's copy (_refresh_active)
        d["group_copy"] = ti.ndarray(ti.i32, shape=max(len(self.groups), 1))
        upload("col_env", np.array(self._col_env or [0], np.int32), ti.i32)
        walls = np.array(self._walls, np.float32).reshape(-1, 3)
        upload("walls", walls if len(walls) else np.zeros((1, 3), np.float32), ti.f32)
        # colliders
        nc = max(len(self.colliders), 1)
        kinds = np.zeros(nc, np.int32)
        prm = np.zeros((nc, 4), np.float32)
        friction = np.zeros((nc, 2), np.float32)  # (μ, 1 if sticky)
        info = np.zeros((nc, 4), np.int32)
        offset = 0
        for i, c in enumerate(self.colliders):
            kinds[i], prm[i], friction[i] = c.kind, c.params(), (c.friction, float(c.sticky))
            if isinstance(c, MeshCollider):
                info[i] = (offset, *c.sdf.shape)
                offset += c.sdf.size
        upload("col_kind", kinds, ti.i32)
        upload("col_prm", prm, ti.f32)
        upload("col_friction", friction, ti.f32)
        upload("col_bound", np.array([_collider_bound(c) for c in self.colliders] or [0.0], np.float32), ti.f32)
        upload("sdf_info", info, ti.i32)
        upload("sdf", self._sdf_values(), ti.f32)
        self._sdf_stale = False
        d["col_pose"] = ti.ndarray(ti.f32, shape=(nc, 14))
        d["col_impulse"] = ti.ndarray(ti.f32, shape=(nc, 6))
        d["link_pose"] = ti.ndarray(ti.f32, shape=(max(len(self.link_names), 1), 14))
        n_slot, slot = self.pair_slots()
        d["pair_impulse"] = ti.ndarray(ti.f32, shape=(max(len(self.link_names), 1) * n_slot, 7))
        upload("col_slot", slot.astype(np.int32) if len(slot) else np.zeros(1, np.int32), ti.i32)
        d["link_frames"] = ti.ndarray(ti.f32, shape=(max(len(self.link_names), 1), FRAME))
        d["col_frames"] = ti.ndarray(ti.f32, shape=(nc, FRAME))
        d["group_frames"] = ti.ndarray(ti.f32, shape=(max(len(self.groups), 1), FRAME))
        upload("group_link", np.array([g.link for g in self.groups] or [-1], np.int32), ti.i32)
        if "group_bind" not in d:
            upload("group_bind", np.tile(np.array([1.0, 0, 0, 0], np.float32), (1, 1)), ti.f32)
        d["twist_change"] = ti.ndarray(ti.f32, shape=(max(len(self.link_names), 1), 9))
        d["counts"] = ti.ndarray(ti.i32, shape=7)
        self._refresh_active()
        d["consts"] = ti.ndarray(ti.f32, shape=9)
        d["env_relax"] = ti.ndarray(ti.f32, shape=self.num_envs)
        self._upload_consts()
        self._build_packs()
        if self._grid_cap == 0:
            self._alloc_grid(4096)
        else:
            self._alloc_cells()  # the particle count or the materials may have changed
        self._link_radius = np.zeros(len(self.link_names))
        if self._n:
            bound = (h["kind"] == 1) & (h["link"] >= 0)
            np.maximum.at(self._link_radius, h["link"][bound], np.linalg.norm(h["X0"][bound], axis=1))
        self._dirty = False
        self._stale = set()

    def _refresh_active(self) -> None:
        """The awake groups' particles as the active list (env-major, :meth:`_env_major`),
        its kinematic ones, each env's rows, the counts, and whether two velocity fields are
        awake (then the grid holds two box copies per env: see add_group's ``field``)."""
        d, n = self._dev, max(self._n, 1)
        kind = self._host["kind"] if self._n else np.zeros(n, np.int32)
        active, env_rows = self._env_major([(g.env, np.arange(g.start, g.stop, dtype=np.int32))
                                            for g in self.groups if g.awake])
        active_kin = active[kind[active] == 1]
        self._n_active, self._n_kin = len(active), len(active_kin)
        self._two_fields = len({g.field for g in self.groups if g.awake}) == 2
        B = self.num_envs  # each group's grid copy: field · num_envs + env, the field only with two
        d["group_copy"].from_numpy(np.array([(g.field if self._two_fields else 0) * B + g.env for g in self.groups]
                                            or [0], np.int32))
        d["env_rows"].from_numpy(env_rows)
        d["active"].from_numpy(np.resize(active, n))
        d["active_kin"].from_numpy(np.resize(active_kin, n))
        self._upload_counts()
        self._awake_changed = False

    def _build_packs(self) -> None:
        """Group the device arrays into the kernels' argument packs (kernels.Particles, Scene,
        Order, Placement, Reduction; the Grid pack is built with the grid in _alloc_grid). Built
        once per rebuild of the arrays: a kernel_launch.CachedKernel re-checks a new pack."""
        d, pk = self._dev, self._pack
        pk["W"] = None  # World is assembled on first use (_world_pack)
        if self._n:
            pk["P"] = K.Particles(**{k: d[k] for k in (
                "x", "v", "C", "F", "tau", "Jp", "impulse", "contact_id", "anchor", "mass", "vol", "radius",
                "kind", "link", "matid", "group", "bond")})
            pk["placement"] = K.Placement(
                **{k: d[k] for k in ("x", "v", "C", "X0", "link", "counts", "consts", "link_frames", "col_frames",
                                     "group_bind", "group_link", "group_frames", "active", "bounds", "slab_of",
                                     "cursor", "order", "slab_start")},
                link_poses=d["link_pose"], col_poses=d["col_pose"], kin=d["active_kin"], active_box=d["box"])
        pk["S"] = K.Scene(**{k: d[k] for k in (
            "counts", "consts", "mat_table", "group_qs", "group_frames", "group_field", "group_env", "group_copy",
            "env_relax", "link_frames", "walls", "col_kind", "col_prm", "col_frames", "col_friction", "sdf",
            "sdf_info", "col_impulse", "col_env", "col_bound")})
        pk["O"] = K.Order(order=d["order"], slab_start=d["slab_start"], active_box=d["box"])
        pk["R"] = K.Reduction(env_rows=d["env_rows"], col_slot=d["col_slot"], col_ends=d["col_pose"],
                              link_ends=d["link_pose"], col_sums=d["col_impulse"], pair_sums=d["pair_impulse"])

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

        self._dev["link_pose"].from_numpy(pose_rows(self._link_prev, self._link_next))
        self._dev["col_pose"].from_numpy(pose_rows(self._col_prev, self._collider_poses()))

    def _collider_poses(self) -> np.ndarray:
        """[C, 4, 4] the colliders' target poses (where they end the next step)."""
        return np.array([c.pose for c in self.colliders]).reshape(-1, 4, 4)

    # ------------------------------------------------------------------ state
    def _env_parts(self, env: int | None):
        """Indices of what env ``env`` owns (all with None): particle rows, groups, links,
        colliders; a clear error for an env this world does not have."""
        if env is None:
            return (np.arange(self._n), np.arange(len(self.groups)), np.arange(len(self.link_names)),
                    np.arange(len(self.colliders)))
        env = _env_index(env, "state of env")
        if env >= self.num_envs:
            raise ConfigError(f"env={env}: this world has {self.num_envs} env(s)")
        groups = np.array([i for i, g in enumerate(self.groups) if g.env == env], int)
        rows = np.concatenate([np.arange(self.groups[i].start, self.groups[i].stop) for i in groups]) \
            if len(groups) else np.zeros(0, int)
        return (rows, groups, np.flatnonzero(np.array(self._link_env, int) == env),
                np.flatnonzero(np.array(self._col_env, int) == env))

    def state_dict(self, env: int | None = None) -> dict:
        """The mutable state (numpy arrays and scalars); see :meth:`load_state_dict`. With
        ``env``, only that env's part (its groups' particles, its links and colliders, in
        world order): the same layout as the state of a world that holds that scene alone,
        so a batched env's state loads into a single scene and back. The scalars (time, step
        count, largest speed) are the world's."""
        self._pull()
        rows, groups, links, cols = self._env_parts(env)
        G = [self.groups[i] for i in groups]
        parts = {k: self._host[k][rows].copy() for k in _STATE_FIELDS} if len(rows) else {}
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
        if len(rows) and "anchor" not in parts and "x" in parts:  # saved before anchors: nothing sticks
            parts["anchor"] = no_anchor(len(parts["x"]))
        for k in _STATE_FIELDS if len(rows) else ():
            need = (len(rows),) + self._host[k].shape[1:]
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
            self._host[k][rows] = parts[k]
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
        elif state.get("link_impulse") is not None:  # saved before per-object pairs: the link's sum, no depth
            self._pair_impulse[links, -1, :6] = np.asarray(state["link_impulse"], np.float64).reshape(-1, 6)
        self._dirty = True


def atomic_scatter() -> bool:
    """How the kernels scatter particles to the grid: with atomic adds, one thread per
    particle, on CUDA (a GPU needs thousands of threads); by slab colouring, atomic-free and
    bit-reproducible, on the CPU. ``GAUSSTAC_SCATTER=atomic|slabs`` overrides (benchmarks)."""
    mode = os.environ.get("GAUSSTAC_SCATTER", "")
    if mode not in ("", "atomic", "slabs"):
        raise ConfigError(f"GAUSSTAC_SCATTER={mode!r} must be 'atomic' or 'slabs' (or unset)")
    return mode == "atomic" if mode else backend.current_arch() == "cuda"


def _twists(a: np.ndarray, b: np.ndarray, dt: float) -> np.ndarray:
    """[N, 6] (v_origin, ω) [m/s, rad/s] of the uniform motions from poses a [N, 4, 4] to
    poses b in dt seconds (world frame; the slerp/lerp interpolation of the substeps has
    exactly these)."""
    from scipy.spatial.transform import Rotation

    if not len(a):
        return np.zeros((0, 6))
    w = Rotation.from_matrix(b[:, :3, :3] @ a[:, :3, :3].transpose(0, 2, 1)).as_rotvec() / dt
    return np.concatenate([(b[:, :3, 3] - a[:, :3, 3]) / dt, w], 1)


def _surface_travel(a: np.ndarray, b: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """[N] bound on how far a point within ``radius`` [N] of the origin moves from pose a
    [N, 4, 4] to pose b [m]: the origin's travel plus the turn's angle times the radius."""
    return np.linalg.norm(b[:, :3, 3] - a[:, :3, 3], axis=1) + turn_angle(a, b) * radius


def _bond_table(name: str, pts: np.ndarray, kin: np.ndarray, spacing: float, distance, normal) -> np.ndarray:
    """[N, 4] bond rows of add_group (world-frame normal, signed distance [m]); zero rows for
    dynamic particles and where the group has no kinematic or no dynamic particle."""
    n = len(pts)
    out = np.zeros((n, 4))
    if not kin.any() or kin.all():
        return out
    if (distance is None) != (normal is None):
        raise ConfigError(f"add_group({name!r}): give bond_distance and bond_normal together")
    if distance is None:
        from scipy.spatial import cKDTree

        # nearest dynamic particle of each kinematic one: the bond is half a spacing short of it
        r, j = cKDTree(pts[~kin]).query(pts[kin])
        out[kin, :3] = (pts[~kin][j] - pts[kin]) / np.maximum(r, 1e-12)[:, None]
        out[kin, 3] = 0.5 * spacing - r
        return out
    dist = np.broadcast_to(np.asarray(distance, np.float64), (n,))
    nrm = np.broadcast_to(np.asarray(normal, np.float64), (n, 3))
    if not (np.all(np.isfinite(dist[kin])) and np.all(np.isfinite(nrm[kin]))):
        raise ConfigError(f"add_group({name!r}): bond_distance / bond_normal contain NaN or inf")
    length = np.linalg.norm(nrm[kin], axis=1)
    if np.any(np.abs(length - 1.0) > 1e-3):
        raise ConfigError(f"add_group({name!r}): bond_normal must be unit vectors (lengths "
                          f"{length.min():.3g}..{length.max():.3g})")
    out[kin, :3], out[kin, 3] = nrm[kin], dist[kin]
    return out


def _velocity_gradient(pts: np.ndarray, vel: np.ndarray, neighbours: int = 19) -> np.ndarray:
    """[N, 3, 3] least-squares velocity gradient C_ab = ∂v_a/∂x_b [1/s] of an initial velocity
    ``vel`` [N, 3] given at ``pts`` [N, 3] [m], fitted on each point's nearest ``neighbours``
    (itself, its 6 face and 12 edge neighbours on a lattice) within 1.75 lattice spacings (the
    median nearest-neighbour distance): the affine velocity APIC carries (Jiang et al. 2015). A
    rigid spin is affine and fitted exactly; with C = 0 its first transfer to the grid lost 11 %
    of its angular momentum (``test_free_body_keeps_its_spin``). Zero for a uniform velocity; the
    least-norm fit (pseudo-inverse) where the points around one are too few or flat to give all
    three directions. The radius keeps the fit inside one body where a group holds several
    bodies apart by more than 1.75 spacings: across the gap between two bodies moving apart, a
    fit over plain nearest neighbours gave their facing layers a strain rate they do not have."""
    n = len(pts)
    out = np.zeros((n, 3, 3))
    if n < 2 or np.all(vel == vel[0]):
        return out
    from scipy.spatial import cKDTree

    tree = cKDTree(pts)
    reach = 1.75 * float(np.median(tree.query(pts, k=2)[0][:, 1]))
    pts_pad = np.vstack([pts, np.zeros((1, 3))])  # row n: where a point has fewer neighbours in reach
    vel_pad = np.vstack([vel, np.zeros((1, 3))])
    for lo in range(0, n, 65536):  # in chunks: [chunk, k, 3] float64 temporaries
        rows = slice(lo, min(n, lo + 65536))
        _, nb = tree.query(pts[rows], k=min(n, neighbours), distance_upper_bound=reach)
        near = (nb < n)[..., None]
        dX = np.where(near, pts_pad[nb] - pts[rows, None], 0.0)  # [chunk, k, 3]
        dV = np.where(near, vel_pad[nb] - vel[rows, None], 0.0)
        # normal equations per point: (Σ dX dXᵀ) Cᵀ = Σ dX dVᵀ
        Ct = np.linalg.pinv(np.einsum("nki,nkj->nij", dX, dX)) @ np.einsum("nki,nkj->nij", dX, dV)
        out[rows] = np.swapaxes(Ct, 1, 2)
    return out


def _layer_thickness(pts: np.ndarray, kin: np.ndarray) -> float:
    """L [m]: the largest distance of a dynamic particle from the kinematic core (the layer
    thickness of a pad; 0 without dynamic particles)."""
    from scipy.spatial import cKDTree

    dyn = pts[~kin]
    return float(cKDTree(pts[kin]).query(dyn)[0].max()) if len(dyn) else 0.0


def _relaxation_rate(L: float, material: Material, scale: float) -> float:
    """Relaxation rate ζ = ω1 [1/s], the lowest shear frequency of a layer of thickness L [m]
    (:func:`_layer_thickness`), ω1 = (π/2)·c_s/L, c_s = √(μ/(ρ·scale)) the shear wave speed
    with the pseudo-mass (0 for no layer)."""
    if L <= 0.0:
        return 0.0
    c_s = math.sqrt(material.mu / (material.density * scale))
    return (math.pi / 2.0) * c_s / L


def _renumber(parts: dict, new_id: np.ndarray) -> None:
    """Map the collider ids (>= 0) of the particles' contacts and static-friction anchors
    through ``new_id`` (old id -> new id), in place."""
    cid = parts["contact_id"]
    hit = cid >= 0
    cid[hit] = new_id[cid[hit]]
    a = parts["anchor"][:, 3]
    stuck = a >= 0
    a[stuck] = new_id[a[stuck].astype(int)]


def _env_index(env, where: str) -> int:
    """``env`` as an env index (an int >= 0), or a ConfigError naming ``where``."""
    if isinstance(env, bool) or not isinstance(env, (int, np.integer)) or env < 0:
        raise ConfigError(f"{where}: env={env!r} must be an integer >= 0 (the env of a batched world)")
    return int(env)


def _collider_bound(c: Collider) -> float:
    """Radius [m] of a sphere about collider ``c``'s origin that holds all of it, capped for float32
    (a half-space has none): for a mesh, its SDF grid's box, which holds the surface in any of
    the shapes :meth:`MPMWorld.set_collider_sdf` gives it (kernels.beyond_bound)."""
    if isinstance(c, MeshCollider):
        prm = c.params()
        lo = np.asarray(prm[:3], np.float64)
        hi = lo + prm[3] * (np.asarray(c.sdf.shape, np.float64) - 1.0)
        return float(np.linalg.norm(np.maximum(np.abs(lo), np.abs(hi))))
    return min(_collider_radius(c), 1e30)


def _collider_radius(c: Collider) -> float:
    from . import colliders as col

    if c.kind == col.SPHERE:
        return c.radius
    if c.kind == col.BOX:
        return float(np.linalg.norm(c.half_extents))
    if c.kind == col.CAPSULE:
        return c.radius + c.half_length
    if c.kind == col.MESH:
        return float(np.linalg.norm(np.abs(c.mesh.bounds).max(0)))
    return math.inf
