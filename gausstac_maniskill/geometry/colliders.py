"""Rigid colliders: signed-distance functions with pose and Coulomb friction.

A collider is described in its own (local) frame and placed by a 4x4 pose [m] that the
user updates every control step (a solver takes its velocity as the finite difference of
consecutive poses). The signed distance φ [m] is negative inside. Shapes:

* :class:`Sphere` (radius), :class:`Box` (half extents), :class:`Capsule`
  (radius, half length along local z), :class:`HalfSpace` (solid below local
  z = 0), and :class:`MeshCollider` (a watertight trimesh mesh, sampled to a
  regular SDF grid and interpolated trilinearly).

Both pad solvers read them: the MPM inside its kernels (:func:`local_sdf`, through
:func:`~gausstac_maniskill.mpm.colliders.collider_contact`), the equilibrium pads through
:func:`signed_distance` (:func:`~gausstac_maniskill.fem.pad.collider_indenter`), which runs
the same Taichi code on the host's points. ``friction`` is the Coulomb coefficient of contact;
``sticky=True`` removes all tangential slip.
"""

from dataclasses import dataclass, field

import numpy as np
import taichi as ti

from ..cache import SDFS, array_digest, cached_array
from ..errors import AssetError, ConfigError
from ..transforms import as_pose_matrix
from .kinematics import pose_at

NONE, SPHERE, BOX, CAPSULE, MESH, HALFSPACE = range(6)


@dataclass
class Collider:
    """Base class: ``pose`` is the 4x4 world transform of the collider frame [m]."""

    pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    friction: float = 0.5
    sticky: bool = False
    name: str = ""

    kind: int = field(default=NONE, init=False, repr=False)

    def __post_init__(self) -> None:
        label = self.name or type(self).__name__
        self.pose = as_pose_matrix(self.pose, f"{label}.pose")
        f = float(self.friction)
        if not np.isfinite(f) or f < 0:
            raise ConfigError(f"{label}.friction={self.friction!r} must be a finite number >= 0")
        self.friction = f

    def params(self) -> np.ndarray:
        """Shape parameters as 4 floats (meaning depends on the shape)."""
        return np.zeros(4, np.float32)


def _positive(label: str, name: str, value: float) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise ConfigError(f"{label}.{name}={value!r} m must be > 0")
    return v


@dataclass
class Sphere(Collider):
    """Solid sphere of ``radius`` [m] centred on the collider frame origin."""

    radius: float = 0.01

    def __post_init__(self) -> None:
        super().__post_init__()
        self.radius = _positive(self.name or "Sphere", "radius", self.radius)
        self.kind = SPHERE

    def params(self) -> np.ndarray:
        return np.array([self.radius, 0, 0, 0], np.float32)


@dataclass
class Box(Collider):
    """Solid box with ``half_extents`` [m] along the collider frame axes."""

    half_extents: tuple = (0.01, 0.01, 0.01)

    def __post_init__(self) -> None:
        super().__post_init__()
        label = self.name or "Box"
        h = tuple(self.half_extents)
        if len(h) != 3:
            raise ConfigError(f"{label}.half_extents must have 3 values, got {self.half_extents!r}")
        self.half_extents = tuple(_positive(label, "half_extents", v) for v in h)
        self.kind = BOX

    def params(self) -> np.ndarray:
        return np.array([*self.half_extents, 0], np.float32)


@dataclass
class Capsule(Collider):
    """Capsule of ``radius`` [m] around the segment z ∈ [-half_length, half_length]."""

    radius: float = 0.005
    half_length: float = 0.01

    def __post_init__(self) -> None:
        super().__post_init__()
        label = self.name or "Capsule"
        self.radius = _positive(label, "radius", self.radius)
        self.half_length = _positive(label, "half_length", self.half_length)
        self.kind = CAPSULE

    def params(self) -> np.ndarray:
        return np.array([self.radius, self.half_length, 0, 0], np.float32)


@dataclass
class HalfSpace(Collider):
    """Solid half-space z < 0 of the collider frame (a floor or a wall)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        self.kind = HALFSPACE


@dataclass
class MeshCollider(Collider):
    """A watertight triangle mesh, sampled to an SDF grid of spacing ``sdf_dx`` [m].

    Args:
        mesh: a ``trimesh.Trimesh`` or a path to a mesh file, in the collider frame.
        sdf_dx: SDF grid spacing [m]; ``None`` picks 1/48 of the largest extent.
        padding: cells of SDF kept around the mesh bounds.

    The sampled SDF is kept by mesh and grid, in this process and on disk (``sdfs/`` of
    :mod:`gausstac_maniskill.cache`): a fingertip at 0.5 mm takes about 7 s on 2 cores the
    first time.
    """

    mesh: object = None
    sdf_dx: "float | None" = None
    padding: int = 3

    sdf: np.ndarray = field(default=None, init=False, repr=False)
    sdf_origin: np.ndarray = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        super().__post_init__()
        import trimesh

        label = self.name or "MeshCollider"
        mesh = self.mesh
        if mesh is None:
            raise ConfigError(f"{label}.mesh is required")
        if isinstance(mesh, (str, bytes)) or hasattr(mesh, "__fspath__"):
            path = str(mesh)
            import os

            if not os.path.isfile(path):
                raise AssetError(f"{path}: mesh file not found ({label}.mesh)")
            try:
                mesh = trimesh.load(path, force="mesh")
            except Exception as exc:  # noqa: BLE001
                raise AssetError(f"{path}: cannot read mesh ({label}.mesh): {exc}") from None
            label = f"{label} ({path})"
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise AssetError(f"{label}.mesh is not a triangle mesh with faces")
        if not mesh.is_watertight:
            raise AssetError(
                f"{label}.mesh is not watertight ({len(mesh.faces)} faces, "
                "open edges present): a signed distance needs a closed surface — "
                "repair it (e.g. trimesh.repair.fill_holes) or use a convex hull")
        self.mesh = mesh
        ext = float(np.max(mesh.extents))
        h = float(self.sdf_dx) if self.sdf_dx is not None else ext / 48.0
        if not np.isfinite(h) or h <= 0:
            raise ConfigError(f"{label}.sdf_dx={self.sdf_dx!r} must be > 0")
        lo = mesh.bounds[0] - self.padding * h
        n = np.ceil((mesh.bounds[1] + self.padding * h - lo) / h).astype(int) + 1
        if np.prod(n) > 4_000_000:
            raise ConfigError(f"{label}: SDF grid {tuple(n)} is too large; increase sdf_dx")
        self.sdf = _sampled_sdf(mesh, lo, h, n, label)
        self.sdf_origin = lo.astype(np.float32)
        self.sdf_dx = h
        self.kind = MESH

    def params(self) -> np.ndarray:
        return np.array([*self.sdf_origin, self.sdf_dx], np.float32)


_SDFS: dict = {}  # sampled mesh SDFs of this process, by mesh and grid (MeshCollider)


def _sampled_sdf(mesh, lo: np.ndarray, h: float, n: np.ndarray, label: str) -> np.ndarray:
    """[nx, ny, nz] float32 signed distance [m] of ``mesh`` at the grid ``lo + h·ijk``, computed
    once per mesh and grid (kept in this process and on disk). Callers must not change it."""
    key = array_digest((np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64), lo, n), repr(h))
    if key not in _SDFS:
        def compute():
            from .mesh_query import signed_distance_to_mesh

            axes = [lo[d] + h * np.arange(n[d]) for d in range(3)]
            pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
            return signed_distance_to_mesh(mesh, pts).reshape(tuple(n)).astype(np.float32)

        sdf = cached_array(SDFS, label, f"sdf-{key}", tuple(int(v) for v in n), compute)
        sdf.setflags(write=False)  # shared by every collider of this mesh and grid
        _SDFS[key] = sdf
    return _SDFS[key]


# --------------------------------------------------------------------------- Taichi side


@ti.func
def _mesh_sdf_at(sdf: ti.template(), info: ti.template(), prm, k, q):
    """Trilinear SDF of mesh collider k at local point q, and its gradient.

    ``info[k]`` = (offset into ``sdf``, nx, ny, nz); ``prm`` = (origin xyz, spacing).
    """
    off, nx, ny, nz = info[k, 0], info[k, 1], info[k, 2], info[k, 3]
    o = ti.Vector([prm[0], prm[1], prm[2]])
    h = prm[3]
    g = (q - o) / h
    hi = ti.Vector([nx - 1.001, ny - 1.001, nz - 1.001])
    gc = ti.min(ti.max(g, 0.0), hi)
    outside = (g - gc).norm() * h  # distance beyond the sampled box
    i0 = ti.cast(ti.floor(gc), ti.i32)
    f = gc - i0
    phi = 0.0
    grad = ti.Vector([0.0, 0.0, 0.0])
    for a, b, c in ti.static(ti.ndrange(2, 2, 2)):
        val = sdf[off + ((i0[0] + a) * ny + i0[1] + b) * nz + i0[2] + c]
        wx = f[0] if a else 1.0 - f[0]
        wy = f[1] if b else 1.0 - f[1]
        wz = f[2] if c else 1.0 - f[2]
        phi += wx * wy * wz * val
        grad += val * ti.Vector([(1.0 if a else -1.0) * wy * wz,
                                 wx * (1.0 if b else -1.0) * wz,
                                 wx * wy * (1.0 if c else -1.0)]) / h
    return phi + outside, grad


@ti.func
def local_sdf(kind, prm, sdf: ti.template(), info: ti.template(), k, q):
    """Signed distance φ [m] and outward unit normal, both in the collider frame."""
    phi = 1e9
    n = ti.Vector([0.0, 0.0, 1.0])
    if kind == SPHERE:
        r = q.norm()
        phi = r - prm[0]
        if r > 1e-12:
            n = q / r
    elif kind == BOX:
        h = ti.Vector([prm[0], prm[1], prm[2]])
        d = ti.abs(q) - h
        dpos = ti.max(d, 0.0)
        outside = dpos.norm()
        if outside > 0.0:
            phi = outside
            n = (dpos * ti.math.sign(q)) / outside
        else:
            ax = 0
            if d[1] > d[ax]:
                ax = 1
            if d[2] > d[ax]:
                ax = 2
            phi = d[ax]
            n = ti.Vector([0.0, 0.0, 0.0])
            n[ax] = 1.0 if q[ax] >= 0.0 else -1.0
    elif kind == CAPSULE:
        c = ti.Vector([0.0, 0.0, ti.min(ti.max(q[2], -prm[1]), prm[1])])
        d = q - c
        r = d.norm()
        phi = r - prm[0]
        if r > 1e-12:
            n = d / r
    elif kind == HALFSPACE:
        phi = q[2]
    elif kind == MESH:
        val, grad = _mesh_sdf_at(sdf, info, prm, k, q)
        phi = val
        gn = grad.norm()
        if gn > 1e-12:
            n = grad / gn
    return phi, n


@ti.kernel
def _sdf_query(points: ti.types.ndarray(dtype=ti.math.vec3, ndim=1), kind: ti.i32,
               prm: ti.types.ndarray(dtype=ti.f32, ndim=2), pose: ti.types.ndarray(dtype=ti.f32, ndim=2),
               sdf: ti.types.ndarray(dtype=ti.f32, ndim=1), info: ti.types.ndarray(dtype=ti.i32, ndim=2),
               phi_out: ti.types.ndarray(dtype=ti.f32, ndim=1),
               n_out: ti.types.ndarray(dtype=ti.math.vec3, ndim=1)):
    for i in range(points.shape[0]):
        kinds_dummy = kind
        R, t = pose_at(pose, 0, 1.0)
        q = R.transpose() @ (points[i] - t)
        p4 = ti.Vector([prm[0, 0], prm[0, 1], prm[0, 2], prm[0, 3]])
        phi, n = local_sdf(kinds_dummy, p4, sdf, info, 0, q)
        phi_out[i] = phi
        n_out[i] = R @ n


def signed_distance(collider: Collider, points) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance [m] (negative inside) and outward unit normal of ``collider``
    at world ``points`` [N, 3], evaluated by the same Taichi code the solver uses."""
    from .. import backend
    from ..transforms import pose_to_vec7

    backend.ensure_init()
    # NumPy arrays straight into the kernel (Taichi copies them to the device and back where it
    # must): creating Taichi ndarrays per query cost ~0.1 ms each, eight per query
    pts = np.ascontiguousarray(np.asarray(points, np.float32).reshape(-1, 3))
    pose = np.concatenate([pose_to_vec7(collider.pose)] * 2).astype(np.float32)[None]
    prm = np.ascontiguousarray(collider.params()[None], np.float32)
    if isinstance(collider, MeshCollider):
        grid = np.ascontiguousarray(collider.sdf.ravel(), np.float32)
        info = np.array([[0, *collider.sdf.shape]], np.int32)
    else:
        grid = np.zeros(1, np.float32)
        info = np.zeros((1, 4), np.int32)
    phi = np.empty(len(pts), np.float32)
    nrm = np.empty((len(pts), 3), np.float32)
    if len(pts):
        _sdf_query(pts, collider.kind, prm, pose, grid, info, phi, nrm)
    return phi, nrm
