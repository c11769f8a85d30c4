"""Quasi-static bodies for the product's pads and for the thin-layer benchmark.

* :func:`pad_body`: a :class:`~gausstac_maniskill.tactile.pad.Pad` (link frame) as cube
  elements on its particle lattice (edge: the particle spacing), touched on the link mesh (the
  point ``depth`` along ``normal`` from each outermost particle, as
  ``GaussTacSim(pad_surface="mesh")``). By default the cubes are cut by the layer's curved
  surface and bond (:func:`pad_cells`); ``cells="voxel"``: one whole cube per soft particle,
  bonded where it meets the kinematic particles (a staircase).
* :func:`layer_body`: a flat layer of thickness h bonded to a rigid base (a quarter, with
  symmetry planes x = 0 and y = 0, or the whole layer), touched at its top face.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError
from .contact import QuasiStaticBody
from .hex import CORNERS, voxel_body

__all__ = ["pad_body", "pad_elements", "pad_cells", "pad_lattice", "layer_body", "collider_indenter"]

#: Sub-cells per axis at which a cut cell samples what it holds (4: 64 per cube).
SUBCELLS = 4
#: Relative stiffness of a cut cell's part outside the layer (the finite cell method's α: keeps
#: a cell with a sliver of material from a near-singular stiffness).
EMPTY_STIFFNESS = 1e-4


def pad_body(pad, E: float | None = None, nu: float | None = None, model: str = "linear",
             cells: str = "cut") -> QuasiStaticBody:
    """The soft layer of ``pad`` as a quasi-static body in its link frame (metres).

    Args:
        pad: a :class:`~gausstac_maniskill.tactile.pad.Pad` (particles on a lattice of
            spacing ``pad.spacing``, as :func:`~gausstac_maniskill.tactile.pad.build_pad` makes).
        E, nu: Young's modulus [Pa] and Poisson's ratio (default: the pad's material).
        model: ``"linear"`` or ``"neo_hookean"`` (:class:`QuasiStaticBody`).
        cells: ``"cut"`` (default, :func:`pad_cells`; for both models, as finite strain
            keeps its cut cubes' empty parts linear, :func:`~.hex.neo_hookean_remainder`) or
            ``"voxel"`` (a whole cube per soft particle: the layer's curved surface and bond as
            staircases).

    Element e < (number of soft particles) is the cube of the e-th soft particle either way;
    each surface point passes its force to the particle ``point_sources`` names.
    """
    mat = pad.spec.material
    E = mat.E if E is None else E
    nu = mat.nu if nu is None else nu
    soft = ~pad.kinematic
    surface = np.flatnonzero(pad.surface[soft])
    points = pad.rest[soft][surface] + pad.depth[soft][surface, None] * pad.normal[soft][surface]
    body, fixed = pad_elements(pad, cells)
    elements = surface
    if body.fill is not None:  # each point is interpolated from the cut cell that holds it
        key = _lattice_key(pad_lattice(pad)[1])
        element_keys = key(body.voxels)
        order = np.argsort(element_keys)
        wanted = key(np.floor((points - body.origin) / body.size).astype(np.int64))
        at = np.minimum(np.searchsorted(element_keys, wanted, sorter=order), len(order) - 1)
        held = element_keys[order[at]] == wanted
        elements = np.where(held, order[at], surface)
    return QuasiStaticBody(body, E, nu, fixed, points, elements, name=f"pad {pad.name!r}", model=model,
                           point_sources=surface)


def pad_elements(pad, cells: str):
    """The elements of ``pad``'s body and its held nodes: (body, fixed [V] bool). ``cells``:
    ``"cut"`` (:func:`pad_cells`) or ``"voxel"`` (a whole cube per soft particle, held at every
    node it shares with a kinematic particle's cube)."""
    if cells == "cut":
        return pad_cells(pad)
    if cells != "voxel":
        raise ConfigError(f"pad {pad.name!r}: cells={cells!r} must be 'cut' or 'voxel'")
    origin, ijk = pad_lattice(pad)
    body = voxel_body(ijk[~pad.kinematic], origin, pad.spacing)
    key = _lattice_key(ijk)
    return body, np.isin(key(body.nodes), key(ijk[pad.kinematic][:, None, :] + CORNERS[None]))


def _lattice_key(ijk: np.ndarray):
    """One integer per lattice index [..., 3] (a cell or a node) within one step around the
    cells ``ijk`` [N, 3]: the function that maps them."""
    span = ijk.max(0) + 4  # indices −1 … max + 2, shifted by 1

    def key(v):
        v = np.asarray(v) + 1
        return (v[..., 0] * span[1] + v[..., 1]) * span[2] + v[..., 2]

    return key


def pad_cells(pad):
    """The soft layer of ``pad`` as cut cells on its particle lattice: (body, fixed [V] bool).

    The layer is where the depth below the link mesh lies in [0, thickness]. Each particle
    knows its depth d and the outward normal n of the nearest face, so near it the depth at x is
    d − n·(x − x_p) (exact for a plane; off by s²/2ρ for a surface of curvature radius ρ). The
    cubes are every soft particle's (first, in order), every kinematic particle's that the bond
    cuts, and every empty one next to a surface particle that the surface cuts (its centre
    outside the mesh, each read from the nearest surface particle). Each cube samples the depth
    at :data:`SUBCELLS`³ sub-cell centres: 1 in the layer, :data:`EMPTY_STIFFNESS` outside it
    (the fill of :class:`~.hex.VoxelBody`). The bond holds the nodes deeper than half an edge
    above it: the nearest plane of nodes, not a stiff base inside the cut cubes, whose trilinear
    field cannot bend at the bond and would lock their soft part (the layer would read stiffer
    where the bond cuts the cubes, 0.75 mm elements 8 % above 1 mm ones). At the rim,
    where the pad's cone ends the layer, the cubes stay whole (a staircase there, away from
    where the pad is pressed).
    """
    from .hex import subcell_points

    s, t = pad.spacing, pad.spec.thickness
    origin, ijk = pad_lattice(pad)
    key = _lattice_key(ijk)
    soft = np.flatnonzero(~pad.kinematic)
    kin = np.flatnonzero(pad.kinematic)
    # empty cubes next to the surface particles: each read from its nearest one
    surf = np.flatnonzero(pad.surface & ~pad.kinematic)
    cand = (ijk[surf][:, None, :] + _NEIGHBOURS[None]).reshape(-1, 3)
    src = np.repeat(surf, len(_NEIGHBOURS))
    dist2 = np.tile((_NEIGHBOURS ** 2).sum(1), len(surf))
    keys = key(cand)
    free = ~np.isin(keys, key(ijk))
    cand, src, dist2, keys = cand[free], src[free], dist2[free], keys[free]
    order = np.lexsort((dist2, keys))
    first = order[np.r_[True, keys[order][1:] != keys[order][:-1]]]
    cand, src = cand[first], src[first]
    centre_depth = pad.depth[src] - np.einsum("ij,ij->i", pad.normal[src], (cand - ijk[src]) * s)
    cand, src = cand[centre_depth < 0], src[centre_depth < 0]  # outside the mesh only (not past the rim)
    voxels = np.concatenate([ijk[soft], ijk[kin], cand])
    source = np.concatenate([soft, kin, src])
    sub = 0.5 * subcell_points(SUBCELLS)  # offsets from a cube's centre, in cube edges
    x = (voxels - ijk[source])[:, None, :] + sub[None]  # [C, Q, 3] from the source particle, in edges
    depth = pad.depth[source][:, None] - np.einsum("ci,cqi->cq", pad.normal[source], x) * s
    layer = (depth >= 0) & (depth <= t)
    fill = np.where(layer, 1.0, EMPTY_STIFFNESS)
    keep = layer.any(1)
    keep[:len(soft)] = True  # every soft particle's cube, in order
    voxels, source, fill = _face_connected(voxels[keep], source[keep], fill[keep])
    body = voxel_body(voxels, origin, s, fill)
    # a node is held where it lies deeper than half an edge above the bond, read from the cubes around it
    corner = (body.voxels[:, None, :] + CORNERS[None] - 0.5 - ijk[source][:, None, :]) * s  # [E, 8, 3]
    corner_depth = pad.depth[source][:, None] - np.einsum("ei,eai->ea", pad.normal[source], corner)
    nodes = body.element_nodes.ravel()
    mean_depth = np.bincount(nodes, corner_depth.ravel(), len(body.nodes)) / np.bincount(nodes, minlength=len(body.nodes))
    return body, mean_depth > t - 0.5 * s


#: a lattice cell's 26 neighbours (faces, edges, corners) and its 6 face neighbours
_NEIGHBOURS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) != (0, 0, 0)])
_FACES = _NEIGHBOURS[np.abs(_NEIGHBOURS).sum(1) == 1]


def _face_connected(voxels, source, fill, rounds: int = 4):
    """Cubes ``voxels`` [C, 3] (their ``source`` particles [C] and ``fill`` [C, Q]) joined face
    to face: a group of cubes that touches the rest along an edge or at a corner only would
    turn about it freely (a mechanism: a zero pivot in the stiffness, which a load on those
    cubes sends to 10⁹ m). Each round adds empty cubes (fill :data:`EMPTY_STIFFNESS`, their
    source the group's particle) that join such groups to the main body: those face to face
    with a group and within one cube of the main body. The first cube's body is the main one."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    for _ in range(rounds):
        lo = voxels.min(0) - 3  # room for two steps out on every side
        key = _lattice_key(voxels - lo)
        keys = key(voxels - lo)
        order = np.argsort(keys)
        nb = key((voxels[:, None, :] + _FACES[None]).reshape(-1, 3) - lo)
        pos = np.clip(np.searchsorted(keys[order], nb), 0, len(keys) - 1)
        hit = keys[order[pos]] == nb
        a = np.repeat(np.arange(len(voxels)), 6)[hit]
        graph = coo_matrix((np.ones(len(a)), (a, order[pos][hit])), shape=(len(voxels),) * 2)
        labels = connected_components(graph, directed=False)[1]
        stray = labels != labels[0]
        if not stray.any():
            break
        cand = (voxels[stray][:, None, :] + _FACES[None]).reshape(-1, 3)
        src = np.repeat(source[stray], 6)
        cand_key = key(cand - lo)
        new = ~np.isin(cand_key, keys)
        main_key = key(voxels[~stray] - lo)
        near = np.isin(key(cand[:, None, :] + _NEIGHBOURS[None] - lo), main_key).any(1)  # within one cube of it
        take = np.flatnonzero(new & near)
        take = take[np.unique(cand_key[take], return_index=True)[1]]
        if not len(take):
            break
        voxels = np.concatenate([voxels, cand[take]])
        source = np.concatenate([source, src[take]])
        fill = np.concatenate([fill, np.full((len(take), fill.shape[1]), EMPTY_STIFFNESS)])
    return voxels, source, fill


def pad_lattice(pad) -> tuple[np.ndarray, np.ndarray]:
    """(origin [3] m, ijk [N, 3] int): the lattice of ``pad``'s particles (spacing
    ``pad.spacing``) and each particle's cell on it. Raises ConfigError off a lattice."""
    s = pad.spacing
    origin = pad.rest.min(0) - 0.5 * s
    ijk = np.round((pad.rest - origin) / s - 0.5).astype(np.int64)
    if np.abs((pad.rest - origin) / s - 0.5 - ijk).max() > 1e-6:
        raise ConfigError(f"pad {pad.name!r}: particles are not on a lattice of spacing {s:g} m")
    return origin, ijk


def layer_body(h: float, half_width: float, size: float, E: float, nu: float, model: str = "linear",
               quarter: bool = True) -> QuasiStaticBody:
    """A flat layer of thickness ``h`` [m] of cube elements of edge ``size`` [m], bonded to a
    rigid base at z = 0 and touched at the centres of its top faces (z = h); its outer faces
    are free. ``model`` as in :class:`QuasiStaticBody`.

    ``quarter`` (default): the quarter [0, W]² × [0, h] (W = ``half_width``) with frictionless
    symmetry planes x = 0 and y = 0; forces on it are a quarter of the whole layer's under a
    load symmetric about both planes. Otherwise the whole layer [−W, W]² × [0, h]."""
    nz = int(round(h / size))
    if nz < 1 or abs(nz * size - h) > 1e-6 * h:
        raise ConfigError(f"layer_body: h={h!r} m is not a whole number of elements of {size!r} m")
    nxy = math.ceil(half_width / size - 1e-9)
    span = np.arange(nxy) if quarter else np.arange(-nxy, nxy)
    i, j, k = np.meshgrid(span, span, np.arange(nz), indexing="ij")
    body = voxel_body(np.stack([i, j, k], -1).reshape(-1, 3), np.zeros(3), size)
    nodes = body.nodes
    fixed = np.zeros((len(nodes), 3), bool)
    fixed[nodes[:, 2] == 0] = True
    if quarter:
        fixed[nodes[:, 0] == 0, 0] = True
        fixed[nodes[:, 1] == 0, 1] = True
    top = np.flatnonzero(body.voxels[:, 2] == nz - 1)
    points = (body.voxels[top] + [0.5, 0.5, 1.0]) * size
    return QuasiStaticBody(body, E, nu, fixed, points, top, name="layer" if quarter else "whole layer", model=model)


def collider_indenter(collider, link_pose=None) -> "Indenter":
    """A :class:`~gausstac_maniskill.geometry.Collider` (any shape, its ``pose`` in
    the world) as the :class:`~.indenters.Indenter` a pad on a link at ``link_pose`` (4x4, world;
    default identity) sees: its signed distance in its own frame (the same Taichi code the MPM
    uses), its pose in the link frame, its friction."""
    import dataclasses

    from ..geometry.colliders import signed_distance
    from .indenters import Indenter

    local = dataclasses.replace(collider, pose=np.eye(4))

    def local_sdf(q):
        phi, n = signed_distance(local, q)
        return phi.astype(np.float64), n.astype(np.float64)

    L = np.eye(4) if link_pose is None else np.asarray(link_pose, float)
    return Indenter(local_sdf, np.linalg.inv(L) @ collider.pose, collider.friction)
