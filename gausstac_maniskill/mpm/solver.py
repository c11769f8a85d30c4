"""MPMWorld: a partly controlled MLS-MPM world (Hu et al. 2018): soft bodies driven by rigid links.

A world holds particle *groups* (a fingertip pad, a sponge, ...): dynamic particles, and
optionally kinematic ones that follow a rigid *link* exactly yet scatter momentum and mass to
the grid, so they drive the soft particles next to them. Rigid objects are SDF *colliders*.
Free groups (no kinematic particles) keep their physical mass. Quasi-static groups (bound to a
link) are solved by *dynamic relaxation*: density × ``SolverSettings.mass_scaling`` (a
pseudo-mass: fewer substeps) and motion relative to the link damped at a rate ζ near critical
for the layer's slowest mode, so they settle to elastic equilibrium within a control step (their
core holds them and weight uses the physical mass, so the pseudo-mass shows in no fall or
swing). The equilibrium does not depend on the pseudo-mass, so a
settled pad whose boundary stands still takes ``SolverSettings.hold_scaling`` times more.
``SolverSettings.pressure = "implicit"`` solves the Neo-Hookean λ ln J term per grid cell
(``kernels.pressure_solve``); ``SolverSettings.patch_radius`` simulates only the part of a
pad near a contact (:mod:`.patch`).

:meth:`MPMWorld.step` advances one control step: poses move from the previous to the last set
one (lerp/slerp per substep), in substeps from the CFL bound Δt ≤ C·dx / (c + |v|max),
c = √((λ + 2μ)/ρ), on a grid box around the awake particles (sleeping groups cost nothing).
Independent scenes (*envs*, ``env=``) each have their own grid box and colliders and step in
the same kernel launches (:class:`gausstac_maniskill.batch.BatchedCosim`).
The world is composed of its parts, one module each: :mod:`.model` (what it is built from),
:mod:`.state` (host and device arrays, state_dict), :mod:`.stepper` (CFL substeps, hold, patch,
the launches), :mod:`.readouts` (what is read back).
Units: metres, kilograms, seconds, pascals, newtons.
"""
from __future__ import annotations

import weakref

import numpy as np
import taichi as ti

from .. import backend
from ..config import Material, SolverSettings
from ..errors import ConfigError
from ..geometry.colliders import Collider, MeshCollider
from ..transforms import as_pose_matrices, as_pose_matrix, quat_to_matrix
from .building import WorldBuilder
from .model import Model, no_anchor
from .patch import ActivePatch
from .readouts import WorldReadouts
from .rows import forget_contact, move_rigidly, put_at_rest
from .state import DeviceArrays, Group, ParticleArrays, WorldState
from .stepper import StepInfo, WorldStepper, atomic_scatter

__all__ = ["MPMWorld", "StepInfo", "Group", "Model"]

_WORLDS: "weakref.WeakSet[MPMWorld]" = weakref.WeakSet()


@backend.before_shutdown
def _release_packs() -> None:
    """Free every world's kernel argument packs while Taichi still runs: a pack left to the
    interpreter's teardown prints a TypeError from Taichi's ArgPack.__del__ at exit."""
    for world in list(_WORLDS):
        world._pack.clear()


class MPMWorld(WorldBuilder, WorldReadouts, WorldStepper, WorldState):
    """A partly controlled MLS-MPM world. See the module docstring.

    Example::

        world = MPMWorld(SolverSettings(dx=1e-3))
        world.add_link("tip", np.eye(4))
        world.add_group("pad", pts, Material(E=3e5, nu=0.45), link="tip", kinematic=pts[:, 2] < 0.002)
        ball = world.add_collider(Sphere(radius=0.005, pose=make_pose([0, 0, 0.02])))
        world.set_collider_pose(ball, make_pose([0, 0, 0.015]))
        world.step(0.01)
        force, torque = world.collider_wrench(ball)

    Args:
        settings: numerical settings (grid spacing, CFL number, ...).
        contact: ``"particle"`` (default) enforces colliders on particles, whose
            surface is half a particle spacing beyond their centre; ``"grid"``
            enforces them on grid nodes (classic MPM boundary conditions; the
            contact surface then sits up to one cell early).
    """

    def __init__(self, settings: SolverSettings | None = None, contact: str = "particle"):
        backend.ensure_init()
        self.model = Model(settings or SolverSettings(), contact)  # the immutable description (add_* replace it)
        self.groups: list[Group] = []  # each group's description (model.groups) and its awake/hold/patch state
        self._link_prev = np.zeros((0, 4, 4))  # [L, 4, 4] pose at the start of the next step
        self._link_next = np.zeros((0, 4, 4))  # [L, 4, 4] pose at its end (last set)
        self._link_twist = np.zeros((0, 6))  # [L, 6] (v_origin, ω) [m/s, rad/s] of the last step
        self.colliders: list[Collider] = []  # their shapes are the model's, their poses (and SDF values) state
        self._col_prev = np.zeros((0, 4, 4))  # [C, 4, 4] collider poses at the start of the next step
        self.time = 0.0
        self.step_count = 0
        self.last_step: StepInfo | None = None
        self._host_parts = ParticleArrays()  # per-particle host arrays (numpy)
        self._dev_parts = ParticleArrays()  # their device copies (Taichi ndarrays)
        self._dev = DeviceArrays()  # the other device arrays (grid, links, colliders, ...)
        self._grid_cap = 0
        self._dirty = True
        self._awake_changed = False  # groups woke or slept after the last push (the active lists are old)
        self._sdf_stale = False  # a mesh collider's SDF changed after the last upload (set_collider_sdf)
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

    @property
    def settings(self) -> SolverSettings:
        """The numerical settings (the model's)."""
        return self.model.settings

    @property
    def contact(self) -> str:
        """Where colliders are enforced: ``"particle"`` or ``"grid"`` (the model's)."""
        return self.model.contact

    @property
    def materials(self) -> tuple[Material, ...]:
        """The distinct materials of the groups, in the order of the kernels' material table."""
        return self.model.materials

    @property
    def link_names(self) -> tuple[str, ...]:
        """The links' names, in order of addition."""
        return self.model.link_names

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
        on waking, its particles are moved by the link's motion while it slept.
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
                hp = self._host_parts
                hp.x[sl] = (hp.x[sl].astype(np.float64) @ R.T + t).astype(np.float32)
                hp.v[sl] = (hp.v[sl] @ R.T).astype(np.float32)
                for key in ("C", "tau"):
                    hp.get(key)[sl] = (R @ hp.get(key)[sl] @ R.T).astype(np.float32)
                hp.F[sl] = (R @ hp.F[sl]).astype(np.float32)
        g.awake = bool(awake)
        if on_device:
            self._awake_changed = True  # the active lists follow at the next push; the state stays
        else:
            self._dirty = True

    def _on_device(self) -> bool:
        """Whether the device holds the world as built (no structural change pending), so a
        group's rows can be changed there in place (mpm/rows.py) instead of on the host."""
        return not self._dirty and self.num_particles > 0 and "P" in self._pack

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
        bind = quat_to_matrix(self.model.group_bind[self.groups.index(g)].astype(np.float64))
        F_rest = T[:3, :3] @ bind.T
        if on_device:  # X0 as built (the active patch rebinds some rows of the device's X0)
            X0 = self._dev.X_rest if self._patch is not None else self._dev_parts.X0
            put_at_rest(self._pack["P"], X0, g.start, g.stop, ti.math.mat3(T[:3, :3]), ti.math.vec3(T[:3, 3]),
                             ti.math.mat3(F_rest))
            self._stale |= {"x", "v", "C", "tau", "Jp", "F", "impulse", "contact_id", "anchor"}
        else:
            sl, hp = slice(g.start, g.stop), self._host_parts
            hp.x[sl] = (hp.X0[sl].astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
            hp.v[sl] = 0.0
            hp.C[sl] = 0.0
            hp.tau[sl] = 0.0
            hp.Jp[sl] = 1.0
            hp.F[sl] = F_rest.astype(np.float32)
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
        sl, hp = slice(g.start, g.stop), self._host_parts
        hp.impulse[sl] = 0.0
        hp.contact_id[sl] = -1
        hp.anchor[sl] = no_anchor(g.count)
