"""How an MPM world is built (:class:`WorldBuilder`, part of
:class:`~gausstac_maniskill.mpm.solver.MPMWorld`): ``add_link``, ``add_group``, ``add_collider`` and
``add_slip_wall`` check what they are given, derive what a group is added with (bond table,
initial velocity gradient, layer thickness, relaxation rate), and replace the world's immutable
:class:`~.model.Model` by one with the new part, its state by one with the new rows."""
from __future__ import annotations

import math

import numpy as np

from ..config import Material, _finite
from ..errors import ConfigError
from ..geometry.colliders import Collider
from ..transforms import as_pose_matrix, matrix_to_quat
from . import kernels as K
from .model import ColliderModel, GroupModel, Wall, _env_index, no_anchor
from .state import Group


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
    rigid spin is affine and fitted exactly; with C = 0 its first transfer to the grid loses 11 %
    of its angular momentum (``test_free_body_keeps_its_spin``). Zero for a uniform velocity; the
    least-norm fit (pseudo-inverse) where the points around one are too few or flat to give all
    three directions. The radius keeps the fit inside one body where a group holds several
    bodies apart by more than 1.75 spacings: across the gap between two bodies moving apart, a
    fit over plain nearest neighbours gives their facing layers a strain rate they do not have."""
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


class WorldBuilder:
    """The ``add_*`` calls of an :class:`~gausstac_maniskill.mpm.solver.MPMWorld` (a part of it:
    each replaces the world's ``model`` and grows its state)."""

    def add_link(self, name: str, pose, env: int = 0) -> int:
        """Register a rigid link that kinematic particles can bind to, in env ``env`` of a
        batched world (see :attr:`num_envs`); returns its index."""
        T = as_pose_matrix(pose, f"pose of link {name!r}")
        self.model = self.model.with_link(name, _env_index(env, f"add_link({name!r})"))
        self._link_prev = np.concatenate([self._link_prev, T[None]])
        self._link_next = np.concatenate([self._link_next, T[None]])
        self._link_twist = np.concatenate([self._link_twist, np.zeros((1, 6))])
        self._pair_impulse = np.concatenate([self._pair_impulse, np.zeros((1,) + self._pair_impulse.shape[1:])])
        self._dirty = True
        return len(self.model.links) - 1

    def link_index(self, link) -> int:
        """Index of a link given by name or index; a clear error if it does not exist."""
        return self.model.link_index(link)

    def has_link(self, name: str) -> bool:
        """Whether a link called ``name`` is registered."""
        return self.model.has_link(name)

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
                distance of a dynamic particle from the kinematic core (on a block pad
                ζ = ω1/4 … ω1 relax alike, 2·ω1 is slower).
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
        if name in self.model._group_at:
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
        link_env = self.model.links[lidx].env if lidx >= 0 else 0
        env = _env_index(link_env if env is None else env, f"add_group({name!r})")
        if lidx >= 0 and link_env != env:
            raise ConfigError(f"add_group({name!r}): env={env} but its link {self.link_names[lidx]!r} is in env "
                              f"{link_env}")
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
        model = self.model
        rho = material.density * scale
        state_rows = {
            "x": pts.astype(np.float32), "v": vel.astype(np.float32),
            "C": _velocity_gradient(pts, vel).astype(np.float32), "F": np.tile(np.eye(3, dtype=np.float32), (n, 1, 1)),
            "tau": np.zeros((n, 3, 3), np.float32), "Jp": np.ones(n, np.float32),
            "impulse": np.zeros((n, 3), np.float32), "contact_id": np.full(n, -1, np.int32),
            "anchor": no_anchor(n), "mass": np.full(n, rho * vol, np.float32),
        }
        rest_rows = {"vol": np.full(n, vol, np.float32), "radius": radius.astype(np.float32),
                     "kind": kin.astype(np.int32), "link": np.full(n, lidx, np.int32),
                     "X0": np.zeros((n, 3), np.float32)}
        if lidx >= 0:
            T = self._link_next[lidx]
            rest_rows["X0"] = ((pts - T[:3, 3]) @ T[:3, :3]).astype(np.float32)
            state_rows["v"][kin] = 0.0
            state_rows["C"][kin] = 0.0  # kinematic_update gives them their link's gradient
            bond[:, :3] = bond[:, :3] @ T[:3, :3]  # normals to the link frame
        rest_rows["bond"] = bond.astype(np.float32)
        bind = matrix_to_quat(self._link_next[lidx][:3, :3]) if lidx >= 0 else np.array([1.0, 0, 0, 0])
        spec = GroupModel(name, model.num_particles, n, material, lidx, int(kin.sum()), h, bool(quasi_static),
                          scale, relax, int(field), env=env, tear=tear)
        self.model = model.with_group(spec, rest_rows, bind)
        self._grow_particles(state_rows)
        group = Group(self.model.groups[-1])
        self.groups.append(group)
        self._dirty = True
        return group

    def add_collider(self, collider: Collider, env: int = 0) -> int:
        """Add a rigid SDF collider that the groups of env ``env`` touch; returns its index
        (for poses and wrenches)."""
        if not isinstance(collider, Collider) or type(collider) is Collider:
            raise ConfigError(f"add_collider expects a Sphere, Box, Capsule, HalfSpace or MeshCollider, "
                              f"got {type(collider).__name__}")
        self.model = self.model.with_collider(ColliderModel.of(collider, _env_index(env, "add_collider")))
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
        """(slots per link, [C] each collider's slot): see :meth:`Model.pair_slots`."""
        return self.model.pair_slots()

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
        link_env = np.asarray([link.env for link in self.model.links], np.int64)
        col_env = np.asarray([c.env for c in self.model.colliders], np.int64)
        return link_env[links][:, None] == col_env[cols][None, :]

    def add_slip_wall(self, axis: int, position: float, keep: str = "+") -> None:
        """A bilateral frictionless wall on the grid (e.g. a symmetry plane).

        Grid nodes with coordinate ``axis`` on the ``keep``-opposite side of
        ``position`` [m], or on it, get zero velocity along ``axis``.
        """
        if axis not in (0, 1, 2) or keep not in ("+", "-"):
            raise ConfigError(f"add_slip_wall(axis={axis!r}, keep={keep!r}): axis in 0..2, keep '+' or '-'")
        self.model = self.model.with_wall(Wall(axis, float(position), 1.0 if keep == "+" else -1.0))
        self._dirty = True

    def group(self, name: str) -> Group:
        """The group called ``name`` (clear error if unknown)."""
        return self.groups[self.model.group_index(name)]

    @property
    def num_envs(self) -> int:
        """Number of envs (independent scenes) in this world: 1 + the largest env index given
        to :meth:`add_link`, :meth:`add_group` or :meth:`add_collider`. Every env has its own
        copy of the grid box; all step together, in the same kernel launches, with one
        substep count (the smallest that every env's CFL bound allows)."""
        return self.model.num_envs

    @property
    def num_particles(self) -> int:
        return self.model.num_particles

    def _collider(self, index: int) -> Collider:
        """Collider ``index`` (a clear error where there is none)."""
        if not 0 <= index < len(self.colliders):
            raise ConfigError(f"collider index {index} out of range ({len(self.colliders)} colliders)")
        return self.colliders[index]
