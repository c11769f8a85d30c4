"""Soft tactile pads built from a hand link's collision mesh.

A :class:`Pad` is a :class:`~gausstac_maniskill.config.PadSpec` turned into
particles in the link frame (the MPM pad's particles; the equilibrium pad's cube elements
sit on the same lattice): a lattice filling the link's (watertight) mesh, cut
to the region within ``cone_deg`` of the pad axis and within ``thickness`` (soft)
plus two grid cells (kinematic, carried by the link) of the surface. Each particle
also records its depth below the surface and the outward normal of the nearest
surface point, which the tactile maps use.
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass

import numpy as np

from ..config import PadSpec
from ..errors import AssetError, ConfigError, ResolutionWarning
from ..geometry.sampling import mesh_particles

__all__ = ["Pad", "build_pad", "pad_mesh", "pad_core_meshes", "allegro_pad_specs", "pad_specs_for_links", "ALLEGRO_TIPS"]

#: Fingertip links of ManiSkill's Allegro right hand (thumb, index, middle, ring).
ALLEGRO_TIPS = ("link_15.0_tip", "link_3.0_tip", "link_7.0_tip", "link_11.0_tip")


@dataclass
class Pad:
    """A pad's particles and sensor geometry, all in the link frame (metres).

    Attributes:
        spec: the description it was built from.
        rest: [N, 3] particle rest positions in the link frame.
        kinematic: [N] bool, particles bound to the link.
        depth: [N] distance below the link surface at rest.
        normal: [N, 3] outward unit normal of the nearest surface point.
        surface: [N] bool, the outermost particle layer (depth < spacing).
        sensor_frame: 4x4 sensor frame in the link frame (z out of the pad, x along the finger).
        spacing: particle spacing [m].
        cell: the MPM grid spacing [m] the pad was built for (0: not known).
    """

    spec: PadSpec
    rest: np.ndarray
    kinematic: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    surface: np.ndarray
    sensor_frame: np.ndarray
    spacing: float
    cell: float = 0.0

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def num_particles(self) -> int:
        return len(self.rest)

    @property
    def footprint(self) -> float:
        """Width [m] of the square of the sensor plane each particle stands for in the tactile
        maps: one grid cell, at least one particle spacing (:mod:`.extract`)."""
        return max(float(self.spacing), float(self.cell))

    def sensor_coords(self) -> np.ndarray:
        """[N, 3] rest positions in the sensor frame."""
        S = self.sensor_frame
        return (self.rest - S[:3, 3]) @ S[:3, :3]

    @property
    def contact_radius(self) -> np.ndarray:
        """[N] contact radius [m] of each particle: for the outermost layer (depth < spacing)
        its distance below the link mesh (at least 5 % of a spacing), so the contact surface
        is the mesh's own, whatever the lattice's alignment with it; half a spacing inside
        (``GaussTacSim(pad_surface="mesh")``, the default; ``"particles"`` puts every
        particle's surface half a spacing out, which on a curved pad lies up to half a spacing
        off the mesh, differently at each resolution)."""
        h = self.spacing
        return np.where(self.depth < h, np.clip(self.depth, 0.05 * h, h), 0.5 * h)

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """(centre [3], radius) of the pad's particles in the link frame, metres (computed once:
        the co-simulator asks every step)."""
        if "_sphere" not in self.__dict__:
            c = self.rest.mean(0)
            self.__dict__["_sphere"] = (c, float(np.linalg.norm(self.rest - c, axis=1).max() + self.spacing))
        c, r = self.__dict__["_sphere"]
        return c.copy(), r


def pad_mesh(spec: PadSpec, urdf: str):
    """The mesh a pad is cut from, in its link frame: ``spec.mesh`` if given, else the
    link's collision mesh in ``urdf``.

    Raises:
        AssetError: ``spec.mesh`` names no file; the URDF or link mesh is missing.
    """
    import os

    import trimesh

    from ..urdf import link_mesh

    if spec.mesh is None:
        return link_mesh(urdf, spec.link)
    if not os.path.isfile(spec.mesh):
        raise AssetError(f"{spec.mesh}: pad mesh file not found (PadSpec.mesh of pad {spec.name!r})")
    return trimesh.load(spec.mesh, force="mesh")


#: Depth of a pad link's rigid core below the pad surface, as a fraction of the pad's thickness:
#: an object that reaches the core has compressed the layer to a quarter of its thickness.
#: With the core at the full thickness, an object stopped by it would touch the bound particles
#: behind the layer, and the last soft cells crushed between them make the MPM pad blow up
#: (PressCube with the hand closed hard, 2 mm grid).
CORE_DEPTH = 0.75


def _cone_centre(mesh) -> np.ndarray:
    """The point a pad's cone is seen from: the mesh's centre of mass (bounds centre if it has no volume)."""
    return mesh.center_mass if mesh.is_volume else mesh.bounds.mean(0)


def pad_core_meshes(specs, mesh, mesh_name: str = "") -> list:
    """The rigid core of a pad link: its collision geometry without the soft layers, as
    convex pieces (what SAPIEN collides with).

    * The inset: the link's (convex hull of its) mesh with every face plane moved inward by
      ``CORE_DEPTH · thickness`` (the deepest over ``specs``). In front of it lies the layer
      that compresses; an object that reaches it has squeezed the pad to a quarter of its
      thickness, and stops the finger (hard stop).
    * The back: the convex hull of the mesh's vertices outside every pad's cone (the link's
      own rigid surface), when they span a volume and do not cover a pad's apex. On a long
      link (a phalanx with a pad on its side) they do, and the core is the inset alone:
      there an object touching the link off the pad meets the core ``CORE_DEPTH · thickness``
      late.

    The union of both contains everything deeper than the stop. Near a cone's rim the back's
    hull also covers some of the layer (it is convex): there an object meets the rigid link
    sooner, as it would at the edge of a real fingertip's pulp.

    Args:
        specs: the :class:`PadSpec` (or several) on one link.
        mesh: the pad mesh (``trimesh.Trimesh``, link frame, metres), as :func:`pad_mesh` gives.
        mesh_name: label for error messages.

    Returns:
        One or two convex ``trimesh.Trimesh`` in the link frame [m] (the inset first).

    Raises:
        ConfigError: a pad's ``thickness`` leaves no core (the stop lies deeper than the
            mesh's centre is from its nearest face).
    """
    import trimesh
    from scipy.spatial import HalfspaceIntersection

    specs = [specs] if isinstance(specs, PadSpec) else list(specs)
    hull = mesh if mesh.is_convex else mesh.convex_hull
    centre = _cone_centre(hull)
    normals = hull.face_normals
    offsets = np.einsum("ij,ij->i", normals, hull.triangles[:, 0])  # face planes n·x = d
    room = float(np.min(offsets - normals @ centre))
    for spec in specs:
        if CORE_DEPTH * spec.thickness >= room:
            raise ConfigError(
                f"pad {spec.name!r} on {spec.link!r}: PadSpec.thickness={spec.thickness:g} m leaves no rigid core "
                f"in {mesh_name or 'its mesh'} (the surface is {room:g} m from the centre at its nearest); "
                "use a thinner pad")
    depth = CORE_DEPTH * max(spec.thickness for spec in specs)
    # the inset: every face plane moved to n·x = d - depth (scipy's half-spaces are
    # A x + b <= 0); many planes meet near each corner, so the corners are merged to 0.1 mm
    # (PhysX simplifies a convex mesh to 255 vertices anyway)
    inset = HalfspaceIntersection(np.column_stack([normals, depth - offsets]), centre).intersections
    inset = inset[trimesh.grouping.unique_rows(inset, digits=4)[0]]
    direction = hull.vertices - centre
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    back = np.ones(len(hull.vertices), bool)
    for spec in specs:
        back &= direction @ np.asarray(spec.axis) < math.cos(math.radians(spec.cone_deg))
    pieces = [trimesh.convex.convex_hull(inset)]
    if back.sum() >= 4 and np.linalg.matrix_rank(hull.vertices[back][1:] - hull.vertices[back][0], tol=1e-6) == 3:
        rear = trimesh.convex.convex_hull(hull.vertices[back])
        # on a long link (a phalanx) the rest of the link spans over the pad: then the inset alone
        apexes = [hull.vertices[np.argmax(hull.vertices @ np.asarray(s.axis))] - 0.5 * depth * np.asarray(s.axis)
                  for s in specs]
        if not rear.contains(np.array(apexes)).any():
            pieces.append(rear)
    return pieces


def build_pad(spec: PadSpec, mesh, spacing: float, dx: float, mesh_name: str = "") -> Pad:
    """Fill ``spec``'s region of ``mesh`` (link frame) with particles: a new Pad at each call
    (:func:`pad_geometry` is the cached way a scene gets its pads).

    Args:
        spec: the pad description.
        mesh: watertight ``trimesh.Trimesh`` of the link, in the link frame.
        spacing: particle spacing [m] (the MPM grid spacing / particles per axis).
        dx: MPM grid spacing [m]; the kinematic layer is one cell thick.

    Raises:
        AssetError: the mesh is not watertight / has no volume.
        ConfigError: the region selects no soft or no kinematic particle.
    """
    label = mesh_name or f"collision mesh of {spec.link!r}"
    check_layer_resolution(spec, dx)
    if not mesh.is_watertight or not mesh.volume > 0:
        raise AssetError(f"{label}: the pad mesh must be watertight with positive volume "
                         f"(watertight={mesh.is_watertight}, volume={mesh.volume:.3g} m^3)")
    pts, dist, nrm = mesh_particles(mesh, spacing, name=label, with_query=True)
    keep = dist <= spec.thickness + KINEMATIC_CELLS * dx
    axis = np.asarray(spec.axis)
    centre = _cone_centre(mesh)
    direction = pts - centre
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    keep &= direction @ axis >= math.cos(math.radians(spec.cone_deg))
    soft = keep & (dist <= spec.thickness)
    kin = keep & ~soft
    if not soft.any() or not kin.any():
        raise ConfigError(
            f"pad {spec.name!r} on {spec.link!r}: the region (axis={spec.axis}, cone_deg={spec.cone_deg}, "
            f"thickness={spec.thickness} m) selects {int(soft.sum())} soft and {int(kin.sum())} kinematic "
            f"particles at spacing {spacing:g} m; widen the cone, change the axis or refine the spacing")
    rest, dist, nrm = pts[keep], dist[keep], nrm[keep]
    # sensor frame: origin on the pad's particle surface (outermost particles plus half
    # a spacing) where it is furthest along the axis, so zero depth is first contact
    # whatever the lattice's alignment with the mesh; z = axis, x = ``spec.along`` or the
    # link's z (along the finger) made orthogonal to the axis
    origin = centre + axis * (float(((rest - centre) @ axis).max()) + 0.5 * spacing)
    x = np.asarray(spec.along, float) if spec.along is not None else np.array([0.0, 0.0, 1.0]) - axis * axis[2]
    if np.linalg.norm(x) < 1e-6:
        x = np.array([1.0, 0.0, 0.0]) - axis * axis[0]
    x /= np.linalg.norm(x)
    S = np.eye(4)
    S[:3, 0], S[:3, 1], S[:3, 2], S[:3, 3] = x, np.cross(axis, x), axis, origin
    return Pad(spec, rest, kin[keep], dist, nrm, dist < spacing, S, spacing, float(dx))


class _PadCache:
    """The built pads of this process (:func:`pad_geometry`): by request (spec, URDF, spacing,
    grid spacing), so that a scene's pads are found without reading a mesh; and by shape (the
    mesh's vertices and faces, the spec's axis, along, cone and thickness, the spacings), so
    that pads cut alike from one mesh are built once."""

    def __init__(self):
        self.by_request: dict = {}
        self.by_shape: dict = {}

    def get(self, spec: PadSpec, urdf: str, spacing: float, dx: float) -> Pad:
        request = (spec, str(urdf), float(spacing), float(dx))
        pad = self.by_request.get(request)
        if pad is not None:
            check_layer_resolution(spec, dx)  # each scene built from it is told
            return pad
        mesh = pad_mesh(spec, urdf)
        shape = (mesh.vertices.tobytes(), mesh.faces.tobytes(), spec.axis, spec.along, spec.cone_deg,
                 spec.thickness, float(spacing), float(dx))
        twin = self.by_shape.get(shape)
        if twin is None:
            twin = self.by_shape[shape] = build_pad(spec, mesh, spacing, dx)
            for arr in (twin.rest, twin.kinematic, twin.depth, twin.normal, twin.surface, twin.sensor_frame):
                arr.flags.writeable = False  # shared by every scene that asks
        else:
            check_layer_resolution(spec, dx)
        pad = self.by_request[request] = dataclasses.replace(twin, spec=spec)
        return pad


_PADS = _PadCache()


def pad_geometry(spec: PadSpec, urdf: str, spacing: float, dx: float) -> Pad:
    """The pad of ``spec`` cut from its mesh (``spec.mesh`` or the link's collision mesh in
    ``urdf``) at particle ``spacing`` [m] on a grid of spacing ``dx`` [m], built by
    :func:`build_pad` once per process and then shared, with read-only arrays, by every scene
    and task that asks. Specs that differ only in what does not shape a pad (name, link,
    material, taxel layout) on the same mesh share one build: the four Allegro tips are cut
    once. Warns about an under-resolved layer at every call, as :func:`build_pad` does."""
    return _PADS.get(spec, urdf, spacing, dx)


#: Grid cells the soft layer must span for its contact force to converge (with 1–2 cells the
#: force is off by 2.7–11× against Hertz theory: ``bench hand``'s fingertip press).
MIN_LAYER_CELLS = 4


def check_layer_resolution(spec: PadSpec, dx: float) -> None:
    """Refuse a soft layer thinner than one grid cell; warn when it spans fewer than
    ``MIN_LAYER_CELLS`` cells (its forces are then not converged).

    Raises:
        ConfigError: ``spec.thickness < dx``.
    """
    cells = spec.thickness / dx
    if cells < 1.0 - 1e-9:
        raise ConfigError(
            f"pad {spec.name!r}: PadSpec.thickness={spec.thickness:g} m is thinner than one grid cell "
            f"(SolverSettings.dx={dx:g} m); the layer cannot be simulated. Use dx <= "
            f"{spec.thickness / MIN_LAYER_CELLS:g} m (4 cells) or a thicker pad")
    if cells < MIN_LAYER_CELLS - 1e-9:
        warnings.warn(
            f"pad {spec.name!r}: the soft layer (PadSpec.thickness={spec.thickness:g} m) spans only "
            f"{cells:.1f} grid cells at dx={dx:g} m; contact forces are not converged below "
            f"{MIN_LAYER_CELLS} cells (use dx <= {spec.thickness / MIN_LAYER_CELLS:g} m)",
            ResolutionWarning, stacklevel=3)

#: Thickness of the kinematic layer in grid cells. With one cell, the grid nodes at the
#: soft/kinematic interface get only ~half their mass from kinematic particles and stay
#: free, and the soft layer slips 0.5 mm after a frictional slide; two cells pin them.
KINEMATIC_CELLS = 2


def pad_specs_for_links(links, **fields) -> list[PadSpec]:
    """One pad per link name — the drop-in tactile sensor for any hand agent.

    ``fields`` are :class:`PadSpec` fields shared by all pads (``axis``, ``thickness``,
    ``material``, ...). Link names are checked against the URDF when the pads are built.
    """
    if isinstance(links, str) or not links:
        raise ConfigError(f"pad_specs_for_links needs a non-empty list of link names, got {links!r}")
    return [PadSpec(link=name, **fields) for name in links]


def allegro_pad_specs(**overrides) -> list[PadSpec]:
    """Default pads on the Allegro right hand's four fingertips (palmar side = +x)."""
    return pad_specs_for_links(ALLEGRO_TIPS, **overrides)
