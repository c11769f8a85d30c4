"""Record layouts of the MPM kernels: the argument packs (what each member is, its shape and
unit), the substep's :class:`ActiveBox` and :class:`Flags`, and the constants they share.

The grid is a dense box around the active particles (plus a margin): node (i, j, k) sits at
world position ``(origin + (i, j, k)) * dx`` and is stored at flat index ``(i * ny + j) * nz + k``.
Envs (independent scenes) share the launches: the grid arrays hold box copy
``field * n_env + env`` at offset ``copy * ncell`` (``Scene.group_copy``); envs may overlap in
space but never share a node, and a particle tests only its own env's colliders.
"""
from typing import Any, NamedTuple

import taichi as ti

from ...kernel_launch import NDF, NDF2, NDI, NDI2, NDM, NDV  # noqa: F401  (re-exported)

vec3 = ti.math.vec3
vec4 = ti.math.vec4
mat3 = ti.math.mat3
NDV2 = ti.types.ndarray(dtype=ti.math.vec2, ndim=1)
NDV4 = ti.types.ndarray(dtype=ti.math.vec4, ndim=1)
NDV6 = ti.types.ndarray(dtype=ti.types.vector(6, ti.f32), ndim=1)

DYNAMIC, KINEMATIC = 0, 1  # Particles.kind
PIN_FRACTION = 0.25  # kinematic share of a node's mass that pins it to its link (see pinned)
BOND_REACH = 2.0  # cells from the bond surface to where a ghost node reads the layer's motion (bond_ghosts)
FILL = 0.9  # two fields touch at a node once their volumes fill this share of its cell (field_contact) ...
SHARE = 0.1  # ... and each brings at least this share (the node lies at both surfaces)
SOFT_CONTACT = -2  # contact_id of a particle touched by the other field (colliders are >= 0)
BIG = 1 << 29
NCHUNK = 16  # particle chunks of the bounds/health reductions (rows of their output arrays)
BOND_STRETCH = 2.0  # a bound particle's principal stretches stay in [1/BOND_STRETCH, BOND_STRETCH] (limit_stretch)
MAX_STRETCH = 3.0  # ... and a free particle's in [1/MAX_STRETCH, MAX_STRETCH]
RECOVERY = 0.05  # cells per substep by which contact takes back a penetration it did not cause (contact_scatter)
BOX = 8  # active box layout: origin xyz, dims xyz (nodes), number of slabs, slab axis
SLAB_CAP = 1 << 16  # slabs are 2 cells: the active box may span 131072 cells along one axis
# rows of Scene.counts and Scene.consts
N_LINKS, N_GROUPS, N_COL, N_WALLS, N_ACTIVE, N_KIN, N_ENVS = range(7)
DX, GX, GY, GZ, DAMPING, REACH, MARGIN, FIELD_MU, BOND = range(9)


# --------------------------------------------------------------------------- argument packs
# Kernel arguments are grouped by what they describe, in one argument pack per kernel:
# `World` (the particles P, the grid G, the scene S: materials, links, groups, walls,
# colliders, constants; and the particle order O) for `advance`, `Placement` for
# `prepare`. Taichi 1.7 allows one pack per kernel and 64 scalar elements per launch
# (ndarrays count one each), so counts and constants live in small arrays. It spends time
# per ndarray on the Python side of every launch (to look up the compiled variant, which
# @cached_kernel skips while the same packs come back, and to set the arguments), so each
# pack holds only what its kernel reads. A substep is two launches: `prepare` (the host reads
# the active box's size back to size the grid) and `advance`. Member names are unique over the
# packs (Taichi flattens them). Shapes: N particle rows, M grid nodes (every box copy), K cell
# slots, L links, G groups, E envs, C colliders.

Particles = ti.types.argpack(  # P: one row per particle [N]
    x=NDV,  # position [m]
    v=NDV,  # velocity [m/s]
    C=NDM,  # APIC velocity gradient [1/s]
    F=NDM,  # deformation gradient
    tau=NDM,  # Kirchhoff stress τ [Pa]
    Jp=NDF,  # plastic volume change (foam)
    impulse=NDV,  # contact impulse of this control step [N s]
    contact_id=NDI,  # collider touched (-1 none, SOFT_CONTACT the other field)
    anchor=NDV4,  # static friction: stuck point in its collider's frame [m], that collider (-1: none)
    mass=NDF,  # mass [kg] (a quasi-static group's pseudo-mass)
    vol=NDF,  # rest volume V0 [m³]
    radius=NDF,  # contact radius [m]
    kind=NDI,  # DYNAMIC | KINEMATIC
    link=NDI,  # link row (-1: none)
    matid=NDI,  # row of Scene.mat_table
    group=NDI,  # group row
    bond=NDV4)  # bound particles: bond surface normal (link frame), signed distance [m] (0: none)
Grid = ti.types.argpack(  # G: one row per node [M] unless said
    grid_pm=NDV4,  # P2G's sums: momentum [kg m/s] and mass [kg], one record per node
    grid_v=NDV,  # velocity [m/s], from grid_update
    grid_m=NDF,  # mass [kg], from grid_update
    grid_mq=NDF,  # quasi-static mass [kg]
    grid_link=NDI,  # link of bound and quasi-static particles
    grid_dp=NDV,  # particle-detected contact momentum [N s]
    grid_vol=NDV2,  # F-bar: (Σ w V0, Σ w V0 J) [m³], then (Σ w V0, J_i)
    grid_vc=NDF,  # two fields: deformed volume Σ w V0 J [m³]
    grid_ds=NDV,  # two fields: field 0's contact Δv [m/s]
    grid_kin=NDV6,  # bound particles: Σ w m (n, d, 1) of those that know the bond surface [kg, kg m, kg], Σ w m
    cell_slot=NDI,  # cell pressure: box cell -> slot (-1: none) [M]
    slot_cell=NDI,  # slot -> box cell [K]
    cell_count=NDI,  # (slots, 1 if the slots ran out) [2]
    cell_a=NDV4,  # per slot: (Σ V0 [m³], Σ V0 ln J, Σ V0 λ [N m], CG diagonal) [K]
    cell_b=NDV4,  # per slot: CG (π [Pa], r, p, Ap) [K]
    cell_G=NDV,  # Σ V0 ∇w per slot and node of its 4³ [m²] [64 K]
    grid_t=NDV,  # M⁻¹ G q per node
    cg_sum=NDF)  # CG sums: NCHUNK partial sums, then CG_RZ, CG_RZ0, CG_DONE [CG_ROWS]
Scene = ti.types.argpack(  # S: what the substep reads of the scene
    counts=NDI,  # rows N_LINKS ... N_ENVS
    consts=NDF,  # rows DX ... BOND [m, m/s², 1/s, m, cells, -]
    mat_table=NDF2,  # materials.material_table rows
    group_qs=NDI,  # per group: quasi-static? [G]
    group_frames=NDF2,  # per group: binding frames (write_binding_frames) [G, 24]
    group_field=NDI,  # per group: velocity field [G]
    group_env=NDI,  # per group: env [G]
    group_copy=NDI,  # per group: box copy in the grid arrays (field · N_ENVS + env) [G]
    env_relax=NDF,  # per env: relaxation rate ζ [1/s] of its quasi-static nodes (largest of its awake groups) [E]
    link_frames=NDF2,  # kinematics frame rows of links [L, 24]
    walls=NDF2,  # slip walls (axis, position [m], side)
    col_kind=NDI,  # per collider: shape [C]
    col_prm=NDF2,  # per collider: shape parameters [m] [C, 4]
    col_frames=NDF2,  # per collider: frame rows [C, 24]
    col_friction=NDF2,  # per collider: (μ, 1 if sticky) [C, 2]
    sdf=NDF,  # mesh colliders' SDF samples [m]
    sdf_info=NDI2,  # per mesh collider: (offset in sdf, samples along x, y, z) [C, 4]
    col_impulse=NDF2,  # per collider: grid-contact reaction (impulse [N s], moment [N m s]) [C, 6]
    col_env=NDI,  # per collider: env [C]
    col_bound=NDF)  # per collider: radius [m] of a sphere about its origin that holds it (contact_scatter) [C]
Order = ti.types.argpack(  # O: the particle order of the substep
    order=NDI,  # awake particles sorted by slab [N]
    slab_start=NDI,  # first index of each slab
    active_box=NDI)  # the active box of the substep (BOX layout), written by prepare
World = ti.types.argpack(P=Particles, G=Grid, S=Scene, O=Order)


class ActiveBox(NamedTuple):
    """One substep's active box and step constants, as the ``ti.func`` of a substep read them
    (``B``). Built by :func:`substep` from ``O.active_box`` and ``S.consts``; its members are
    Taichi scalars of the kernel, the tuple a compile-time template. A pass that needs only some
    leaves the others None.

    ox, oy, oz: the box's first node [cells]; nx, ny, nz: nodes along each axis (z fastest);
    ncell = nx ny nz nodes of one box copy; ntot = ncell × n_env × fields, every box copy;
    n_slabs: slabs of the particle sort (:func:`prepare`); n_env: envs; n: awake particles;
    n_col: colliders; n_walls: slip walls; n_bond: nodes :func:`bond_ghosts` visits (ntot, or 0
    without a bond); dx [m], inv_dx [1/m]: node spacing; dt [s]: the substep; gravity [m/s²];
    damping: velocity factor per substep; max_push [m/s]: cap of a contact's normal velocity
    change; reach [m]: particles farther than this from a collider skip it.
    """
    ox: Any = None
    oy: Any = None
    oz: Any = None
    nx: Any = None
    ny: Any = None
    nz: Any = None
    ncell: Any = None
    ntot: Any = None
    n_slabs: Any = None
    n_env: Any = None
    n: Any = None
    n_col: Any = None
    n_walls: Any = None
    n_bond: Any = None
    dx: Any = None
    inv_dx: Any = None
    dt: Any = None
    gravity: Any = None
    damping: Any = None
    max_push: Any = None
    reach: Any = None


class Flags(NamedTuple):
    """The compile-time switches of a substep (``flags``; Python values, one compiled variant each).

    fbar: F-bar stress for some material; contact_mode: 0 no colliders, 1 particle-detected
    (grid-applied), 2 on grid nodes; nh_only: every material Neo-Hookean (no SVD compiled in);
    two_field: groups of both velocity fields are awake (the grid arrays hold 2 boxes); atomic:
    scatter with atomic adds, one thread per particle (GPUs), not by slabs; cellp: 0, or the most
    CG iterations of the cells' volume term (:func:`pressure_solve`).
    """
    fbar: bool
    contact_mode: int
    nh_only: bool
    two_field: bool
    atomic: bool
    cellp: int


Reduction = ti.types.argpack(  # what reduce_contact reads and sums into
    env_rows=NDI,  # first row of each env's particles in the active list (num_envs + 1 rows)
    col_slot=NDI,  # per collider: its number among its env's colliders (its pair slot)
    col_ends=NDF2, link_ends=NDF2,  # pose rows of the step (kinematics.py): the end poses are read
    col_sums=NDF2, pair_sums=NDF2)  # per collider: -J, moment; per (link, slot): J, moment, depth


Placement = ti.types.argpack(  # what prepare reads and writes
    x=NDV, v=NDV, C=NDM, X0=NDV, link=NDI,  # particle state; rest coords in the link frame
    counts=NDI, consts=NDF,
    link_poses=NDF2, link_frames=NDF2, col_poses=NDF2, col_frames=NDF2,  # pose rows -> frame rows
    group_bind=NDF2, group_link=NDI, group_frames=NDF2,  # binding quaternion and link of each group
    active=NDI, kin=NDI,  # awake particles (counts[N_ACTIVE]), the kinematic ones among them (counts[N_KIN])
    bounds=NDI2, slab_of=NDI, cursor=NDI, order=NDI, slab_start=NDI, active_box=NDI)  # slab sort
