"""The immutable description of an MPM world (:class:`Model`): its links, particle groups,
materials, colliders, slip walls and the per-particle rest data (:class:`ParticleModel`), like
MuJoCo's ``mjModel``. What changes while the world steps (positions, velocities, stresses, poses,
which groups are awake) is its state (:mod:`.state`). A model is never changed in place: adding
a link, group, collider or wall gives a new model (``with_*``), which the world then builds its
device arrays from. Units: metres, kilograms, seconds."""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Mapping, NamedTuple

import numpy as np

from ..config import Material, SolverSettings
from ..errors import ConfigError
from ..geometry.colliders import Collider, MeshCollider


def no_anchor(n: int) -> np.ndarray:
    """Static-friction anchors of ``n`` particles that stick to nothing ([n, 4]: point, collider -1)."""
    out = np.zeros((n, 4), np.float32)
    out[:, 3] = -1.0
    return out


@dataclass(frozen=True)
class GroupModel:
    """One particle group as built: a contiguous block of particle rows ``start:stop``."""

    name: str
    start: int
    count: int
    material: Material
    link: int  # -1: not bound to a link
    n_kinematic: int
    spacing: float  # [m]
    quasi_static: bool = False  # pseudo-mass (settings.mass_scaling) + relaxation; see add_group
    mass_scale: float = 1.0  # density multiplier of its dynamic particles (1: physical inertia)
    relaxation: float = 0.0  # damping rate ζ [1/s] of its motion relative to its link
    field: int = 0  # velocity field (0 or 1): groups of different fields are separate bodies in contact
    env: int = 0  # the env (scene) of a batched world it belongs to: it touches only that env's groups and colliders
    tear: float = 0.0  # quasi-static: a particle this far [m] from its rest place has lost its core (0: no check)

    @property
    def stop(self) -> int:
        return self.start + self.count


class LinkModel(NamedTuple):
    """A rigid link that kinematic particles follow."""

    name: str
    env: int


class Wall(NamedTuple):
    """A bilateral frictionless slip wall on the grid: nodes on the side opposite ``side`` of
    ``position`` [m] along ``axis`` get zero velocity along it."""

    axis: int
    position: float
    side: float  # +1.0: keep the + side, -1.0: keep the - side


@dataclass(frozen=True)
class ColliderModel:
    """What the kernels need of a rigid collider's shape, fixed when it is added: its kind,
    shape parameters (4 floats), friction, whether it is sticky, bounding radius [m] and, for a
    mesh, its SDF grid's shape. Its pose and SDF values move with the scene and are state (the
    collider object the world holds: ``MPMWorld.colliders``)."""

    name: str
    kind: int
    params: tuple[float, float, float, float]
    friction: float
    sticky: bool
    bound: float  # [m] (:func:`_collider_bound`)
    sdf_shape: tuple[int, int, int] | None  # a mesh collider's SDF grid (None for analytic shapes)
    env: int

    @classmethod
    def of(cls, c: Collider, env: int) -> "ColliderModel":
        sdf = tuple(int(s) for s in c.sdf.shape) if isinstance(c, MeshCollider) else None
        return cls(c.name, int(c.kind), tuple(float(p) for p in np.asarray(c.params(), np.float32)),
                   float(c.friction), bool(c.sticky), _collider_bound(c), sdf, int(env))


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr = np.ascontiguousarray(arr)
    arr.flags.writeable = False
    return arr


#: the per-particle arrays of the model: (dtype, row shape, unit, meaning); the state's are in state.PARTICLE_FIELDS
REST_FIELDS = {
    "X0": (np.float32, (3,), "m", "rest coordinates in the link frame (0 without a link)"),
    "bond": (np.float32, (4,), "-, m", "bond surface normal (link frame), signed distance (0: none)"),
    "vol": (np.float32, (), "m³", "rest volume"),
    "radius": (np.float32, (), "m", "contact radius"),
    "kind": (np.int32, (), "-", "kernels.DYNAMIC or KINEMATIC"),
    "matid": (np.int32, (), "-", "material row"),
    "link": (np.int32, (), "-", "link (-1: none)"),
    "group": (np.int32, (), "-", "group"),
    "env": (np.int32, (), "-", "env of the particle's group"),
}


@dataclass(frozen=True, eq=False)
class ParticleModel:
    """The per-particle rest data of a model, [N, ...] rows in group order, read-only
    (:data:`REST_FIELDS`)."""

    X0: np.ndarray
    bond: np.ndarray
    vol: np.ndarray
    radius: np.ndarray
    kind: np.ndarray
    matid: np.ndarray
    link: np.ndarray
    group: np.ndarray
    env: np.ndarray

    @classmethod
    def empty(cls) -> "ParticleModel":
        return cls(**{k: _frozen(np.zeros((0, *row), dt)) for k, (dt, row, _, _) in REST_FIELDS.items()})

    def joined(self, rows: dict) -> "ParticleModel":
        """A new ParticleModel with ``rows`` (one array per :data:`REST_FIELDS` entry) after these."""
        return ParticleModel(**{k: _frozen(np.concatenate([getattr(self, k), np.asarray(rows[k], dt)]))
                                for k, (dt, _, _, _) in REST_FIELDS.items()})

    def __len__(self) -> int:
        return len(self.kind)


@dataclass(frozen=True, eq=False)
class Model:
    """The immutable description of an MPM world (see the module docstring).

    Attributes:
        settings: the numerical settings.
        contact: ``"particle"`` or ``"grid"`` (where colliders are enforced).
        links: [L] the links, in order of addition.
        groups: [G] the particle groups, in order (rows ``start:stop`` of ``particles``).
        materials: the distinct materials, the rows of the kernels' material table.
        colliders: [C] the colliders' shapes, in order of addition.
        walls: the slip walls.
        particles: the per-particle rest data.
        group_bind: [G, 4] float32, the world quaternion (w, x, y, z) of each group's link when
            the group was added (identity without a link): the frame its deformation gradients
            are measured from.
        num_envs: 1 + the largest env index of a link, group or collider.
    """

    settings: SolverSettings
    contact: str = "particle"
    links: tuple[LinkModel, ...] = ()
    groups: tuple[GroupModel, ...] = ()
    materials: tuple[Material, ...] = ()
    colliders: tuple[ColliderModel, ...] = ()
    walls: tuple[Wall, ...] = ()
    particles: ParticleModel = field(default_factory=ParticleModel.empty)
    group_bind: np.ndarray = field(default_factory=lambda: _frozen(np.zeros((0, 4), np.float32)))
    num_envs: int = 1
    _link_at: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}), repr=False)
    _group_at: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}), repr=False)

    def __post_init__(self) -> None:
        if self.contact not in ("particle", "grid"):
            raise ConfigError(f"MPMWorld(contact={self.contact!r}) must be 'particle' or 'grid'")

    @property
    def num_particles(self) -> int:
        return len(self.particles)

    @property
    def link_names(self) -> tuple[str, ...]:
        return tuple(link.name for link in self.links)

    def link_index(self, link) -> int:
        """Index of a link given by name or index; a clear error if it does not exist."""
        if isinstance(link, (int, np.integer)):
            if not 0 <= link < len(self.links):
                raise ConfigError(f"link index {link} out of range (have {len(self.links)} links)")
            return int(link)
        if link not in self._link_at:
            raise ConfigError(f"unknown link {link!r}; registered links: {list(self.link_names)}")
        return self._link_at[link]

    def has_link(self, name: str) -> bool:
        return name in self._link_at

    def group_index(self, name: str) -> int:
        """Index of the group called ``name`` (a clear error if unknown)."""
        if name not in self._group_at:
            raise ConfigError(f"unknown group {name!r}; groups: {[g.name for g in self.groups]}")
        return self._group_at[name]

    def pair_slots(self) -> tuple[int, np.ndarray]:
        """(slots per link, [C] each collider's slot): a link's contact pairs are its env's
        colliders, numbered in their order of addition, then one slot for the other field."""
        env = np.asarray([c.env for c in self.colliders], np.int64)
        count = np.bincount(env, minlength=1)
        order = np.argsort(env, kind="stable")  # env by env, each in its order of addition
        slot = np.empty(len(env), np.int64)
        slot[order] = np.arange(len(env)) - (np.cumsum(count) - count)[env[order]]
        return int(count.max()) + 1, slot

    def with_link(self, name: str, env: int) -> "Model":
        """This model with one more link (a clear error if the name is taken)."""
        if name in self._link_at:
            raise ConfigError(f"link {name!r} is already registered")
        return replace(self, links=self.links + (LinkModel(name, env),), num_envs=max(self.num_envs, env + 1),
                       _link_at=MappingProxyType({**self._link_at, name: len(self.links)}))

    def with_group(self, group: GroupModel, rows: dict, bind: np.ndarray) -> "Model":
        """This model with one more group: its description (``start`` = the current particle
        count, ``material`` a row of the material table, added if new), its rest rows
        (:data:`REST_FIELDS`, ``matid`` and ``group`` filled here) and its link's quaternion."""
        if group.name in self._group_at:
            raise ConfigError(f"group {group.name!r} already exists")
        materials = self.materials if group.material in self.materials else self.materials + (group.material,)
        n = group.count
        rows = {**rows, "matid": np.full(n, materials.index(group.material), np.int32),
                "group": np.full(n, len(self.groups), np.int32), "env": np.full(n, group.env, np.int32)}
        return replace(self, groups=self.groups + (replace(group, start=self.num_particles),),
                       materials=materials, particles=self.particles.joined(rows),
                       group_bind=_frozen(np.concatenate([self.group_bind, np.asarray(bind, np.float32)[None]])),
                       num_envs=max(self.num_envs, group.env + 1),
                       _group_at=MappingProxyType({**self._group_at, group.name: len(self.groups)}))

    def with_collider(self, collider: ColliderModel) -> "Model":
        """This model with one more collider."""
        return replace(self, colliders=self.colliders + (collider,), num_envs=max(self.num_envs, collider.env + 1))

    def with_wall(self, wall: Wall) -> "Model":
        """This model with one more slip wall."""
        return replace(self, walls=self.walls + (wall,))


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
    from ..geometry import colliders as col

    if c.kind == col.SPHERE:
        return c.radius
    if c.kind == col.BOX:
        return float(np.linalg.norm(c.half_extents))
    if c.kind == col.CAPSULE:
        return c.radius + c.half_length
    if c.kind == col.MESH:
        return float(np.linalg.norm(np.abs(c.mesh.bounds).max(0)))
    return math.inf


