"""The kernels the host launches: :func:`prepare` and :func:`advance`, one substep (two launches),
:func:`fbar_update` after a step, and the control step's :func:`follow_links`,
:func:`reset_contact`, :func:`fill_mass`."""
import taichi as ti

from ...geometry.kinematics import frame_at, quat_to_mat, write_frames
from ...kernel_launch import NDF2, NDI, cached_kernel
from .contact import contact_apply, contact_scatter, field_contact
from .grid import bond_ghosts, clear_grid, grid_update
from .layout import (BIG, BOX, BOND, DAMPING, DX, DYNAMIC, GX, GY, GZ, MARGIN, N_ACTIVE, N_COL, N_ENVS, N_GROUPS,
                     N_KIN, N_LINKS, N_WALLS, NCHUNK, REACH, SLAB_CAP, ActiveBox, Flags, Particles, Placement, World,
                     vec3)
from .pressure import number_cells, pressure_solve
from .slabs import chunk_bounds, sort_into_slabs
from .transfer import g2p, nodal_volume_change, p2g, report_stress, volume_scatter

@ti.func
def kinematic_update(W: ti.template(), dt: ti.template()):
    """Place the kinematic particles ``W.kin`` on their link at the start of the substep.

    Their velocity is the finite difference of the link transform over this substep
    applied to the rest coordinate X0 (link frame) and C is the matching velocity gradient
    (R1 - R0) R0ᵀ / Δt. Their F and stress are left to :func:`g2p` (bound particles next
    to the soft layer strain with it).
    """
    for ii in range(W.counts[N_KIN]):
        p = W.kin[ii]
        R0, t0, R1, t1 = frame_at(W.link_frames, W.link[p])
        x0 = R0 @ W.X0[p] + t0
        W.x[p] = x0
        W.v[p] = (R1 @ W.X0[p] + t1 - x0) / dt
        W.C[p] = (R1 - R0) @ R0.transpose() / dt


@ti.func
def write_binding_frames(W: ti.template(), serial: ti.template()):
    """Frame rows ``W.group_frames`` of each group's *binding rotation* Q = R Rbᵀ at the
    substep's start and end: its link's rotation relative to the pose the group was bound at
    (``W.group_bind``), the rigid part of a bound particle's deformation gradient (translations
    0; identity if unbound). ``serial`` as in
    :func:`~gausstac_maniskill.geometry.kinematics.write_frames`."""
    ti.loop_config(serialize=serial)
    for g in range(W.counts[N_GROUPS]):
        Q0 = ti.Matrix.identity(ti.f32, 3)
        Q1 = ti.Matrix.identity(ti.f32, 3)
        l = W.group_link[g]
        if l >= 0:
            R0, _t0, R1, _t1 = frame_at(W.link_frames, l)
            Rb = quat_to_mat(ti.Vector([W.group_bind[g, 0], W.group_bind[g, 1], W.group_bind[g, 2],
                                        W.group_bind[g, 3]]))
            Q0 = R0 @ Rb.transpose()
            Q1 = R1 @ Rb.transpose()
        for a, b in ti.static(ti.ndrange(3, 3)):
            W.group_frames[g, 3 * a + b] = Q0[a, b]
            W.group_frames[g, 12 + 3 * a + b] = Q1[a, b]
        for a in ti.static(range(3)):
            W.group_frames[g, 9 + a] = 0.0
            W.group_frames[g, 21 + a] = 0.0


@cached_kernel
@ti.kernel
def follow_links(P: Particles, active: NDI, n: ti.i32, group_qs: NDI, group_touched: NDI, twist_change: NDF2):
    """Carry quasi-static particles through their link's change of rigid velocity.

    A pad's pseudo-mass must resist only its deformation, not the hand's acceleration.
    Link motion is piecewise uniform (constant linear and angular velocity within a
    control step), so the link accelerates only between steps; there each dynamic
    particle of a quasi-static group takes the change of the link's rigid velocity
    field, Δv(x) = Δv_o + Δω × (x - o), and its APIC gradient the change [Δω]×.
    ``twist_change`` rows: (Δv_o xyz, Δω xyz, o xyz), o the link origin.
    Groups that touched a collider in the last step (``group_touched``) keep their velocity:
    the jump would reach the object as a pseudo-mass impulse (it kicks a light cube away, and
    skipping only the touching particles still shakes a held one). Such a pad lags its link
    by up to |Δv|/ζ instead (after a hard strike the solver finds it torn,
    ``MPMWorld._rest_torn``). The choice is per group: the untouched pads of the same env
    follow their links.
    """
    for ii in range(n):
        p = active[ii]
        l = P.link[p]
        if P.kind[p] == DYNAMIC and l >= 0 and group_qs[P.group[p]] > 0 and group_touched[P.group[p]] == 0:
            dv = ti.Vector([twist_change[l, 0], twist_change[l, 1], twist_change[l, 2]])
            dw = ti.Vector([twist_change[l, 3], twist_change[l, 4], twist_change[l, 5]])
            o = ti.Vector([twist_change[l, 6], twist_change[l, 7], twist_change[l, 8]])
            P.v[p] += dv + dw.cross(P.x[p] - o)
            P.C[p] += ti.Matrix([[0.0, -dw[2], dw[1]], [dw[2], 0.0, -dw[0]], [-dw[1], dw[0], 0.0]])


@cached_kernel
@ti.kernel
def reset_contact(P: Particles, active: NDI, n: ti.i32):
    """The ``n`` active particles start the control step with no contact impulse and no collider."""
    for ii in range(n):
        p = active[ii]
        P.impulse[p] = vec3(0.0)
        P.contact_id[p] = -1


@ti.kernel
def fill_mass(P: Particles, start: ti.i32, stop: ti.i32, mass: ti.f32):
    """Rows [start, stop): mass ← ``mass`` [kg] (a pad's pseudo-mass changed)."""
    for p in range(start, stop):
        P.mass[p] = mass


@cached_kernel
@ti.kernel
def prepare(W: Placement, alpha0: ti.f32, alpha1: ti.f32, dt: ti.f32,
            atomic: ti.template()) -> ti.i64:
    """Interpolate link, group and collider frames for the substep [alpha0, alpha1] of the
    control step, move kinematic particles, find the active box, sort particles into slabs
    (with ``atomic`` scatter no sort is needed: the order is the active list, and the
    serial counting sort would cost a GPU more than the whole substep).

    Writes the box to ``W.active_box`` (BOX layout) for :func:`advance` and returns its number
    of cells (the host sizes the grid), or -1 where the number of slabs would exceed SLAB_CAP
    (nothing is sorted then; the box's slab count is -1). One scalar, not the box: Taichi
    builds a returned vector element by element in Python, a scalar it reads in one call.
    """
    n = W.counts[N_ACTIVE]
    inv_dx = 1.0 / W.consts[DX]
    margin = ti.cast(W.consts[MARGIN], ti.i32)
    if ti.static(atomic):  # a top-level loop (parallel); inside a runtime branch it would run serially
        for ii in range(n):
            W.order[ii] = W.active[ii]
    # the CPU (slab scatter) writes the few frame rows in one thread: no hand-over to its threads
    write_frames(W.link_poses, W.counts[N_LINKS], alpha0, alpha1, W.link_frames, ti.static(not atomic))
    write_frames(W.col_poses, W.counts[N_COL], alpha0, alpha1, W.col_frames, ti.static(not atomic))
    write_binding_frames(W, ti.static(not atomic))
    kinematic_update(W, dt)
    chunk_bounds(W, n, inv_dx)
    lo = ti.Vector([BIG, BIG, BIG])
    hi = ti.Vector([-BIG, -BIG, -BIG])
    for c in ti.static(range(NCHUNK)):  # tiny reduction, unrolled (serial)
        for d in ti.static(range(3)):
            lo[d] = ti.min(lo[d], W.bounds[c, d])
            hi[d] = ti.max(hi[d], W.bounds[c, 3 + d])
    dims = hi - lo + 3 + 2 * margin
    # slabs across the longer of the grid's two slow axes (x, y; the layout is z-fastest): two
    # threads' slabs then write separate runs of memory. Slabs along z interleave their nodes
    # in the same cache lines, and that false sharing takes away the CPU's second thread's gain.
    axis = 0 if dims[0] >= dims[1] else 1
    n_slabs = (hi[axis] - lo[axis]) // 2 + 1
    if n_slabs < 1 or n_slabs + 1 > SLAB_CAP:  # too wide, or int overflow from a NaN position
        n_slabs = -1
    elif ti.static(atomic):
        W.slab_start[0] = 0
        W.slab_start[n_slabs] = n  # the atomic scatter loops run over slab_start[n_slabs] particles
    else:
        sort_into_slabs(W, n, inv_dx, axis, lo[axis], n_slabs)
    o = lo - margin
    out = ti.Vector([o[0], o[1], o[2], dims[0], dims[1], dims[2], n_slabs, axis])
    for i in ti.static(range(BOX)):
        W.active_box[i] = out[i]
    cells = ti.cast(dims[0], ti.i64) * dims[1] * dims[2]
    return ti.select(n_slabs < 0, ti.cast(-1, ti.i64), cells)


@cached_kernel
@ti.kernel
def advance(W: World, dt: ti.f32, fbar: ti.template(), contact_mode: ti.template(), nh_only: ti.template(),
            two_field: ti.template(), atomic: ti.template(), cellp: ti.template()):
    """One MLS-MPM substep of ``dt`` seconds on the box that :func:`prepare` left in
    ``W.O.active_box``: clear grid, (F-bar volume scatter), P2G, grid update + BCs,
    (contact between the two fields), collider contact, G2P; the switches are :class:`Flags`'s.
    """
    substep(W.P, W.G, W.S, W.O, dt, ti.static(Flags(fbar, contact_mode, nh_only, two_field, atomic, cellp)))


@ti.func
def substep(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), dt, flags: ti.template()):
    """Body of :func:`advance` on the packs of its World (P, G, S, O): one MLS-MPM substep."""
    dx = S.consts[DX]
    inv_dx = 1.0 / dx
    gravity = ti.Vector([S.consts[GX], S.consts[GY], S.consts[GZ]])
    damping = ti.exp(-S.consts[DAMPING] * dt)  # global velocity damping factor
    max_push = 0.3 * dx / dt  # cap of a contact's normal velocity change [m/s]
    reach = dx + S.consts[REACH]  # particles farther than this from a collider skip it [m]
    n, n_col, n_walls, n_env = S.counts[N_ACTIVE], S.counts[N_COL], S.counts[N_WALLS], S.counts[N_ENVS]
    ox, oy, oz = O.active_box[0], O.active_box[1], O.active_box[2]
    nx, ny, nz, n_slabs = O.active_box[3], O.active_box[4], O.active_box[5], O.active_box[6]
    ncell = nx * ny * nz
    ntot = ncell * n_env * (2 if ti.static(flags.two_field) else 1)  # every env's box, of each field
    # cells the bond's ghost nodes visit: none without a bond. A loop count, not an `if` around
    # the loop: Taichi runs a loop under a run-time `if` serially (one GPU thread, most of a
    # pad's substep)
    n_bond = ti.select(S.consts[BOND] > 0.0, ntot, 0)
    B = ti.static(ActiveBox(ox=ox, oy=oy, oz=oz, nx=nx, ny=ny, nz=nz, ncell=ncell, ntot=ntot, n_slabs=n_slabs,
                            n_env=n_env, n=n, n_col=n_col, n_walls=n_walls, n_bond=n_bond, dx=dx, inv_dx=inv_dx,
                            dt=dt, gravity=gravity, damping=damping, max_push=max_push, reach=reach))
    clear_grid(G, B, flags)
    if ti.static(flags.cellp):
        number_cells(P, G, S, O, B)
    if ti.static(flags.fbar):
        volume_scatter(P, G, S, O, B, flags)
        nodal_volume_change(G, B)
    p2g(P, G, S, O, B, flags)
    grid_update(G, S, B, flags)
    bond_ghosts(G, S, B)
    if ti.static(flags.cellp):
        pressure_solve(G, S, B, flags)
        bond_ghosts(G, S, B)  # the pressure moved free nodes near the bond: the ghosts follow
    if ti.static(flags.two_field):
        field_contact(G, S, B)
    if ti.static(flags.contact_mode == 1):
        contact_scatter(P, G, S, O, B, flags)
        contact_apply(G, S, B)
        bond_ghosts(G, S, B)  # the contact moved free nodes near the bond: the ghosts follow
    g2p(P, G, S, O, B, flags)


@cached_kernel
@ti.kernel
def fbar_update(W: World, nh_only: ti.template(), two_field: ti.template(), atomic: ti.template(),
                fbar: ti.template(), cellp: ti.template()):
    """The stress of every particle at its current F and position (F-bar; the whole
    Neo-Hookean stress where the volume term is solved on cells), on the box from
    :func:`prepare`: the substeps evaluate it in P2G, this leaves it current after a step."""
    stress_pass(W.P, W.G, W.S, W.O, ti.static(Flags(fbar, 0, nh_only, two_field, atomic, cellp)))


@ti.func
def stress_pass(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), flags: ti.template()):
    """Body of :func:`fbar_update`."""
    inv_dx = 1.0 / S.consts[DX]
    ox, oy, oz = O.active_box[0], O.active_box[1], O.active_box[2]
    ny, nz = O.active_box[4], O.active_box[5]
    ncell = O.active_box[3] * ny * nz
    ntot = ncell * S.counts[N_ENVS] * (2 if ti.static(flags.two_field) else 1)  # every env's box, of each field
    n_slabs, n = O.active_box[6], S.counts[N_ACTIVE]
    B = ti.static(ActiveBox(ox=ox, oy=oy, oz=oz, ny=ny, nz=nz, ncell=ncell, ntot=ntot, n_slabs=n_slabs, n=n,
                            inv_dx=inv_dx))
    if ti.static(flags.fbar):
        for i in range(ntot):
            G.grid_vol[i] = ti.Vector([0.0, 0.0])
        volume_scatter(P, G, S, O, B, flags)
        nodal_volume_change(G, B)
    report_stress(P, G, S, O, B, flags)
