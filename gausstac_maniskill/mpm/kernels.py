"""Taichi kernels of one MLS-MPM substep (APIC transfers, quadratic B-splines).

All kernels take ``ti.types.ndarray`` arguments, so one compiled set serves every
:class:`~gausstac_maniskill.mpm.solver.MPMWorld` in the process, on cpu and cuda.

The grid is a dense box that covers only the active particles (plus a margin);
node (i, j, k) of the box sits at world position ``(origin + (i, j, k)) * dx`` and is
stored at flat index ``(i * ny + j) * nz + k``.

Two velocity fields (multi-field MPM, Bardenhagen et al. 2000, J. Comput. Phys.
160:235 — written here from the paper's algorithm): when groups of both fields are
awake (field 0 the pads, field 1 soft objects), every grid array holds two copies of
the box, field f at offset ``f * ncell``. Each field is transferred, stressed and
bounded on its own, so a pad and a sponge are two bodies, not one continuum; where
both meet, :func:`field_contact` exchanges momentum by a frictional non-penetration
rule. With one field (``two_field`` off) nothing of this is compiled in.

Several envs (independent scenes of a batched world) share the launches: every group and
collider has an env, and the grid arrays hold one copy of the box per env and field, copy
``field * n_env + env`` at offset ``copy * ncell`` (``Scene.group_copy``). Envs may overlap in
space; they never share a node, and a particle tests only its own env's colliders.

Particle-to-grid without atomics (the CPU's way): particles are counting-sorted into
*slabs* two cells thick along the longer of the grid's x and y axes (z varies fastest in
memory: z slabs would share cache lines between threads). A particle whose stencil base
cell is b touches nodes b..b+2, so slabs s and s+2 never write the same node; the even
slabs are scattered in parallel, then the odd ones. Within a slab particles are
visited in a fixed order, which makes a substep bit-reproducible for any number
of threads. A GPU needs thousands of threads, not one per slab: with ``atomic`` every
particle scatters in its own thread with atomic adds (same sums, in a run-dependent
order: not bit-reproducible).
"""

import taichi as ti

from ..kernel_launch import cached_kernel
from . import materials as mat
from .colliders import collider_contact
from .kinematics import frame_at, pose_at, quat_to_mat, write_frames

vec3 = ti.math.vec3
vec4 = ti.math.vec4
mat3 = ti.math.mat3
NDI = ti.types.ndarray(dtype=ti.i32, ndim=1)
NDI2 = ti.types.ndarray(dtype=ti.i32, ndim=2)
NDF = ti.types.ndarray(dtype=ti.f32, ndim=1)
NDF2 = ti.types.ndarray(dtype=ti.f32, ndim=2)
NDV = ti.types.ndarray(dtype=vec3, ndim=1)
NDM = ti.types.ndarray(dtype=mat3, ndim=1)
NDV4 = ti.types.ndarray(dtype=ti.math.vec4, ndim=1)
NDV6 = ti.types.ndarray(dtype=ti.types.vector(6, ti.f32), ndim=1)

DYNAMIC, KINEMATIC = 0, 1
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


@ti.func
def bspline_weights(fx):
    """Quadratic B-spline weights for the 3 nodes of a stencil (fx in [0.5, 1.5))."""
    return [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]


@ti.func
def stencil(xp, inv_dx, origin):
    """Base node (box coordinates), offset from it in cells, and B-spline weights of
    the 3x3x3 stencil of a particle at world position xp."""
    Xp = xp * inv_dx - origin
    base = ti.cast(ti.floor(Xp - 0.5), ti.i32)
    fx = Xp - base
    return base, fx, bspline_weights(fx)


@ti.func
def kinematic_update(kin: ti.template(), n: ti.template(), x: ti.template(),
        v: ti.template(), C: ti.template(), X0: ti.template(), link: ti.template(),
        link_frames: ti.template(), dt: ti.template()):
    """Place kinematic particles on their link at the start of the substep.

    Their velocity is the finite difference of the link transform over this substep
    applied to the rest coordinate X0 (link frame) and C is the matching velocity gradient
    (R1 - R0) R0ᵀ / Δt. Their F and stress are left to :func:`g2p` (bound particles next
    to the soft layer strain with it).
    """
    for ii in range(n):
        p = kin[ii]
        R0, t0, R1, t1 = frame_at(link_frames, link[p])
        x0 = R0 @ X0[p] + t0
        x[p] = x0
        v[p] = (R1 @ X0[p] + t1 - x0) / dt
        C[p] = (R1 - R0) @ R0.transpose() / dt


@ti.func
def link_motion_at(link_frames: ti.template(), l, xi, dt):
    """Rigid motion of link ``l`` over the substep at world point xi:
    (velocity [m/s], angular velocity ω [rad/s], link origin at the substep's start)."""
    R0, t0, R1, t1 = frame_at(link_frames, l)
    W = R1 @ R0.transpose()
    omega = 0.5 / dt * ti.Vector([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]])
    return (R1 @ (R0.transpose() @ (xi - t0)) + t1 - xi) / dt, omega, t0


# Taichi 1.7's CPU backend hands a range-for to its threads in blocks of at least 512
# iterations (its "adaptive" block size; neither loop_config(block_dim=...) nor
# cpu_block_dim_adaptive=False changed that here), so a loop over the ~10 slabs of a pad ran
# on one thread. A serial-by-design loop over a few heavy items (slabs, chunks) therefore
# spreads them TASK_SPREAD iterations apart: each block holds one item, the other iterations
# do nothing. The work and its order are the same; only the threads that take it change.
TASK_SPREAD = 512


@ti.func
def spread_tasks(n_items):
    """Loop count that puts each of ``n_items`` heavy items in a thread block of its own."""
    return n_items * TASK_SPREAD


@ti.func
def spread_item(q):
    """Item of spread iteration q (see :func:`spread_tasks`), or -1 for a filler iteration."""
    return q // TASK_SPREAD if q % TASK_SPREAD == 0 else -1


@ti.func
def chunk_bounds(active: ti.template(), n: ti.template(), x: ti.template(),
        inv_dx: ti.template(), nchunk: ti.template(), out: ti.template()):
    """Per chunk of particles, min/max of the stencil base cell (out[c] = lo xyz, hi xyz)."""
    ti.loop_config(block_dim=TASK_SPREAD)
    for q in range(spread_tasks(nchunk)):  # a thread block per chunk
        c = spread_item(q)
        if c >= 0:
            lo = ti.Vector([BIG, BIG, BIG])
            hi = ti.Vector([-BIG, -BIG, -BIG])
            start = c * n // nchunk
            end = (c + 1) * n // nchunk
            for ii in range(start, end):
                base = ti.cast(ti.floor(x[active[ii]] * inv_dx - 0.5), ti.i32)
                lo = ti.min(lo, base)
                hi = ti.max(hi, base)
            for d in ti.static(range(3)):
                out[c, d] = lo[d]
                out[c, 3 + d] = hi[d]


@ti.func
def sort_into_slabs(active: ti.template(), n: ti.template(), x: ti.template(),
        inv_dx: ti.template(), axis: ti.template(), lo_axis: ti.template(),
        n_slabs: ti.template(), slab_of: ti.template(), slab_start: ti.template(),
        cursor: ti.template(), order: ti.template()):
    """Stable counting sort of the active particles by slab (two cells along ``axis``)."""
    ti.loop_config(serialize=True)
    for s in range(n_slabs + 1):
        slab_start[s] = 0
    ti.loop_config(serialize=True)
    for ii in range(n):
        base = ti.cast(ti.floor(x[active[ii]][axis] * inv_dx - 0.5), ti.i32)
        s = (base - lo_axis) // 2
        slab_of[ii] = s
        slab_start[s + 1] += 1
    ti.loop_config(serialize=True)
    for s in range(n_slabs):
        slab_start[s + 1] += slab_start[s]
        cursor[s] = slab_start[s]
    ti.loop_config(serialize=True)
    for ii in range(n):
        s = slab_of[ii]
        order[cursor[s]] = active[ii]
        cursor[s] += 1


@ti.func
def scatter_tasks(atomic: ti.template(), slab_start: ti.template(), n_slabs, color: ti.template()):
    """Loop count of a scatter loop: every sorted particle (``atomic``), or the slabs of
    colour ``color`` (slab 2h + color), spread a block apart (:func:`spread_tasks`)."""
    n = 0
    if ti.static(atomic):
        n = slab_start[n_slabs]
    else:
        n = spread_tasks((n_slabs - color + 1) // 2)
    return n


@ti.func
def slab_range(atomic: ti.template(), slab_start: ti.template(), color: ti.template(), q):
    """Sorted particles [lo, hi) of iteration q of a scatter loop (:func:`scatter_tasks`): slab
    2h + color for h = spread_item(q), empty for a filler iteration, or (``atomic``) the single
    particle q."""
    lo, hi = q, q + 1
    if ti.static(not atomic):
        h = spread_item(q)
        lo, hi = 0, 0
        if h >= 0:
            s = 2 * h + color
            lo, hi = slab_start[s], slab_start[s + 1]
    return lo, hi


@ti.func
def add_to(a: ti.template(), idx, value, atomic: ti.template()):
    """a[idx] += value: atomically, or as a plain read-modify-write where the slab
    colouring guarantees that no other thread writes a[idx] meanwhile."""
    if ti.static(atomic):
        ti.atomic_add(a[idx], value)
    else:
        a[idx] = a[idx] + value


@ti.func
def field_offset(group_copy: ti.template(), group: ti.template(), p, ncell):
    """Offset of particle p's box copy in the grid arrays: its env's box of its velocity
    field (``Scene.group_copy``; 0 with one env and one field)."""
    return group_copy[group[p]] * ncell


@ti.func
def clear_grid(ntot: ti.template(), grid_pm: ti.template(), grid_mq: ti.template(), grid_dp: ti.template(),
        grid_vol: ti.template(), grid_vc: ti.template(), grid_ds: ti.template(), grid_kin: ti.template(),
        two_field: ti.template(),
        cellp: ti.template(), cell_slot: ti.template()):
    for i in range(ntot):
        if ti.static(cellp):
            cell_slot[i] = 0
        grid_pm[i] = vec4(0.0)
        grid_kin[i] = ti.Vector([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        grid_dp[i] = vec3(0.0)
        grid_vol[i] = ti.Vector([0.0, 0.0])
        grid_mq[i] = 0.0
        if ti.static(two_field):
            grid_vc[i] = 0.0
            grid_ds[i] = vec3(0.0)


@ti.func
def p2g(gravity: ti.template(), order: ti.template(), slab_start: ti.template(), n_slabs: ti.template(),
        x: ti.template(), v: ti.template(), C: ti.template(), F: ti.template(), tau: ti.template(), Jp: ti.template(),
        mass: ti.template(), vol: ti.template(), kind: ti.template(), link: ti.template(),
        matid: ti.template(), mat_table: ti.template(), group: ti.template(), group_qs: ti.template(),
        ox: ti.template(), oy: ti.template(), oz: ti.template(), ny: ti.template(),
        nz: ti.template(), inv_dx: ti.template(), dt: ti.template(), grid_pm: ti.template(),
        grid_mq: ti.template(), grid_link: ti.template(),
        grid_vol: ti.template(), fbar: ti.template(), nh_only: ti.template(),
        group_copy: ti.template(), ncell: ti.template(), two_field: ti.template(), grid_vc: ti.template(),
        bond: ti.template(), link_frames: ti.template(), grid_kin: ti.template(), atomic: ti.template(),
        cellp: ti.template(), cell_slot: ti.template(), cell_a: ti.template(), cell_G: ti.template()):
    """Scatter APIC momentum (with the stress impulse) and mass to the grid, one record
    (p, m) per node in ``grid_pm`` (to the particle's own velocity field; with two fields
    also its deformed volume V0 J to ``grid_vc``, for :func:`field_contact`).

    Momentum to node i: w_ip [m_p v_p + (m_p C_p - Δt V0_p (4/dx²) τ_p)(x_i - x_p)].
    Bound (kinematic) particles also scatter their own record to ``grid_kin``,
    w m (n, s + n·(x_i - x_p), b, 1), and their link id to ``grid_link``: b = 1 for those that
    know the bond surface (``bond``: its normal n in the link frame and their signed distance s
    from it; the linear extrapolation of that distance serves :func:`bond_ghosts`), n = s = b = 0
    for the others; the last entry is the node's kinematic mass (:func:`pinned`).
    Dynamic particles of quasi-static groups scatter their mass to ``grid_mq`` (and the link id).
    One record per node and kind of sum, not one array per quantity: a scatter's time is
    mostly its read-modify-writes, and a record of 4 or 6 floats is one of them (BENCHMARKS,
    twentieth session).
    With ``fbar`` the stress τ_p is first evaluated here, on the same stencil, from the
    nodal volume change that :func:`volume_scatter` and :func:`nodal_volume_change` left in ``grid_vol``.
    With ``cellp``, a particle whose λ ln J term is solved on cells (:func:`pressure_solve`)
    adds (V0, V0 ln J, V0 λ) to its cell's ``cell_a`` and V0 ∇w_ip to the cell's operator
    ``cell_G`` (the cell holds 4³ nodes, those of its particles' stencils). Its cell lies
    between nodes floor(x/dx) and floor(x/dx) + 1, inside the stencil: the slab colouring holds.
    """
    origin = ti.Vector([ox, oy, oz])
    for color in ti.static(range(1 if ti.static(atomic) else 2)):
        ti.loop_config(block_dim=128 if ti.static(atomic) else TASK_SPREAD)
        for q in range(scatter_tasks(atomic, slab_start, n_slabs, color)):
            lo, hi = slab_range(atomic, slab_start, color, q)
            for ii in range(lo, hi):
                p = order[ii]
                base, fx, w = stencil(x[p], inv_dx, origin)
                off = field_offset(group_copy, group, p, ncell)
                if ti.static(fbar or cellp):
                    tau[p] = stress_at(nh_only, fbar, cellp, False, F[p], Jp[p], matid[p], mat_table, grid_vol,
                                       base, w, ny, nz, off)
                slot = -1
                cell = ti.Vector([0, 0, 0])
                if ti.static(cellp):
                    if mat_table[matid[p], mat.CELL_P] > 0.0:
                        cell = ti.cast(ti.floor(x[p] * inv_dx - origin), ti.i32)
                        slot = cell_slot[off + (cell[0] * ny + cell[1]) * nz + cell[2]]
                        if slot >= 0:
                            lnJ = ti.log(ti.max(F[p].determinant(), mat.MIN_J))
                            add_to(cell_a, slot, vol[p] * ti.Vector([1.0, lnJ, mat_table[matid[p], 1], 0.0]), atomic)
                vj = 0.0
                if ti.static(two_field):
                    vj = vol[p] * F[p].determinant()
                m = mass[p]
                affine = m * C[p] - (dt * vol[p] * 4.0 * inv_dx * inv_dx) * tau[p]
                # momentum plus this substep's weight impulse; weight is the physical mass
                # ρ V0 (a quasi-static group's pseudo-mass slows its inertia, not its weight)
                mv = m * v[p] + (dt * vol[p] * mat_table[matid[p], 6]) * gravity
                is_kin = kind[p] == KINEMATIC
                is_qs = (not is_kin) and group_qs[group[p]] > 0
                lk = link[p]
                bn = ti.Vector([bond[p][0], bond[p][1], bond[p][2]])
                bond_d = bond[p][3]
                bonded = 0.0  # 1 for a bound particle that knows the bond surface
                if is_kin and bn.norm_sqr() > 0.0:
                    R0, _t0, _R1, _t1 = frame_at(link_frames, lk)  # the pose kinematic_update placed it at
                    bn = R0 @ bn
                    bonded = 1.0
                for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                    dpos = (ti.Vector([i, j, k]) - fx) / inv_dx
                    weight = w[i][0] * w[j][1] * w[k][2]
                    idx = off + ((base[0] + i) * ny + base[1] + j) * nz + base[2] + k
                    mom = mv + affine @ dpos
                    add_to(grid_pm, idx, weight * ti.Vector([mom[0], mom[1], mom[2], m]), atomic)
                    if ti.static(cellp):
                        if slot >= 0:  # V0 ∇w_ip, ∇w_ip = (4/dx²) w_ip (x_i - x_p) (MLS)
                            lcl = base + ti.Vector([i, j, k]) - cell + 1
                            add_to(cell_G, slot * 64 + (lcl[0] * 4 + lcl[1]) * 4 + lcl[2],
                                   (vol[p] * 4.0 * inv_dx * inv_dx * weight) * dpos, atomic)
                    if ti.static(two_field):
                        add_to(grid_vc, idx, weight * vj, atomic)
                    if is_kin:
                        wm = weight * m
                        add_to(grid_kin, idx, ti.Vector([wm * bn[0], wm * bn[1], wm * bn[2],
                                                         wm * (bond_d + bn.dot(dpos)), wm * bonded, wm]), atomic)
                        grid_link[idx] = lk
                    elif is_qs:
                        add_to(grid_mq, idx, weight * m, atomic)
                        grid_link[idx] = lk


@ti.func
def grid_update(ntot: ti.template(), ncell: ti.template(), ox: ti.template(), oy: ti.template(),
        oz: ti.template(), ny: ti.template(), nz: ti.template(), dx: ti.template(),
        dt: ti.template(), damping: ti.template(), env_relax: ti.template(), n_env: ti.template(),
        grid_pm: ti.template(), grid_v: ti.template(), grid_m: ti.template(),
        grid_kin: ti.template(), grid_mq: ti.template(), grid_link: ti.template(), link_frames: ti.template(),
        walls: ti.template(),
        n_walls: ti.template(), grid_contact: ti.template(), n_col: ti.template(),
        col_kind: ti.template(), col_prm: ti.template(), col_frames: ti.template(),
        col_friction: ti.template(), sdf: ti.template(),
        sdf_info: ti.template(), col_impulse: ti.template(), col_env: ti.template()):
    """Momentum -> velocity, damping, then boundary conditions per node (gravity is in P2G):
    P2G's record (p, m) in ``grid_pm`` becomes ``grid_v`` and ``grid_m`` of every node of the box.

    * Nodes where kinematic mass is at least PIN_FRACTION of the node mass move exactly with
      their link (Dirichlet), so a kinematic layer is rigid, not a viscous drag (with
      ``SolverSettings.bond = "surface"``, :func:`bond_ghosts` then moves those next to a bond
      surface so that the layer is held at that surface).
    * Nodes where most mass belongs to quasi-static groups (pads) relax towards
      equilibrium: their velocity *relative to the link's rigid motion* is scaled by
      exp(-ζ Δt), ζ = ``env_relax`` of the node's env (dynamic relaxation; a pad carried by
      a moving hand is not dragged, only its elastic ringing decays).
    * Slip walls (symmetry planes): the normal velocity of nodes on or beyond the
      wall is zeroed (bilateral).
    * With ``grid_contact`` set, colliders are enforced here on nodes with φ < 0
      (unilateral, Coulomb friction; only the node's own env's) and their reaction impulse
      is accumulated.
    Every box copy (``ntot`` = fields × envs × ``ncell``; copy = field · n_env + env) is
    updated alike.
    """
    for idx in range(ntot):
        pm = grid_pm[idx]
        m = pm[3]
        grid_m[idx] = m
        vel = vec3(0.0)
        if m > 0.0:
            env = (idx // ncell) % n_env
            relax = ti.exp(-env_relax[env] * dt)
            xi = node_position(idx, ncell, ox, oy, oz, ny, nz, dx)
            vel = ti.Vector([pm[0], pm[1], pm[2]]) / m
            vel *= damping
            if pinned(grid_m, grid_kin, idx):
                vel, _omega, _t0 = link_motion_at(link_frames, grid_link[idx], xi, dt)
            else:
                if grid_mq[idx] >= 0.5 * m:
                    # the link's rigid velocity here, and its centripetal acceleration
                    # ω × (ω × r): the pseudo-mass must not turn a spinning hand into a load
                    v_link, omega, t0 = link_motion_at(link_frames, grid_link[idx], xi, dt)
                    vel += dt * omega.cross(omega.cross(xi - t0))
                    vel = v_link + relax * (vel - v_link)
                vel = slip_walls(walls, n_walls, xi, vel)
                if grid_contact:
                    for c in range(n_col):
                        if col_env[c] != env:
                            continue
                        phi, nrm, vc = collider_contact(col_kind, col_prm, col_frames, sdf, sdf_info, c, xi, dt)
                        if phi < 0.0:
                            vrel = vel - vc
                            vn = vrel.dot(nrm)
                            if vn < 0.0:
                                vt = vrel - vn * nrm
                                vtn = vt.norm()
                                if col_friction[c, 1] > 0.0 or vtn <= -col_friction[c, 0] * vn:
                                    vt = vec3(0.0)
                                else:
                                    vt *= 1.0 + col_friction[c, 0] * vn / vtn
                                new_vel = vc + vt
                                dp = m * (new_vel - vel)
                                ti.atomic_add(col_impulse[c, 0], -dp[0])
                                ti.atomic_add(col_impulse[c, 1], -dp[1])
                                ti.atomic_add(col_impulse[c, 2], -dp[2])
                                _R0, _t0, _R1, t1 = frame_at(col_frames, c)
                                tq = (xi - t1).cross(-dp)
                                ti.atomic_add(col_impulse[c, 3], tq[0])
                                ti.atomic_add(col_impulse[c, 4], tq[1])
                                ti.atomic_add(col_impulse[c, 5], tq[2])
                                vel = new_vel
        grid_v[idx] = vel


@ti.func
def node_position(idx, ncell: ti.template(), ox: ti.template(), oy: ti.template(), oz: ti.template(),
        ny: ti.template(), nz: ti.template(), dx: ti.template()):
    """World position [m] of grid node ``idx`` (of either velocity field: idx modulo ncell)."""
    cell = idx % ncell
    i, j, k = cell // (ny * nz), (cell // nz) % ny, cell % nz
    return ti.Vector([ox + i, oy + j, oz + k], ti.f32) * dx


@ti.func
def slip_walls(walls: ti.template(), n_walls, xi, v):
    """The vector v with its normal component dropped on every slip wall (symmetry plane,
    bilateral) that node position xi [m] lies on or beyond."""
    out = v
    for w in range(n_walls):
        ax = ti.cast(walls[w, 0], ti.i32)
        if walls[w, 2] * (xi[ax] - walls[w, 1]) <= 1e-9:
            out[ax] = 0.0
    return out


@ti.func
def pinned(grid_m: ti.template(), grid_kin: ti.template(), idx):
    """A node is held by its link when kinematic particles bring at least PIN_FRACTION of
    its mass (Dirichlet): it moves rigidly with the link (:func:`grid_update`), or, where its
    bound particles know the bond surface, as :func:`bond_ghosts` sets it."""
    return grid_kin[idx][5] >= PIN_FRACTION * grid_m[idx]


@ti.func
def mass_gradient(grid_m: ti.template(), idx, ny: ti.template(), nz: ti.template()):
    """Direction of the nodal mass gradient at node idx (central differences; it points
    into the body). The active box keeps >= 2 empty cells around every node with mass,
    so the neighbours exist."""
    g = ti.Vector([grid_m[idx + ny * nz] - grid_m[idx - ny * nz], grid_m[idx + nz] - grid_m[idx - nz],
                   grid_m[idx + 1] - grid_m[idx - 1]])
    return g / ti.max(g.norm(), 1e-30)


@ti.func
def field_contact(stride: ti.template(), ny: ti.template(), nz: ti.template(), dx: ti.template(),
        mu: ti.template(), grid_v: ti.template(), grid_m: ti.template(), grid_kin: ti.template(),
        grid_vc: ti.template(), grid_ds: ti.template()):
    """Contact between the two velocity fields (multi-field MPM, Bardenhagen et al. 2000).

    At a node where both fields have mass, the contact normal n (from body 0 into
    body 1) is the difference of the two unit mass gradients. The bodies touch there when
    the node lies at both surfaces, each deformed volume V_f = Σ w V0 J ≥ SHARE dx³, and
    together they fill its cell, V_0 + V_1 ≥ FILL dx³. Without this test the B-spline
    supports make bodies meet up to 1.5 cells early; with it, a gap under 0.2 cells
    (1D estimate for these constants) still counts as contact. If they approach,
    (v_0 - v_1)·n > 0, the impulse P on body 0 stops their normal approach and resists
    the slip with Coulomb friction μ:

        P = -m* [(v_r·n) n + min(1, μ (v_r·n)/|v_t|) v_t],   v_r = v_0 - v_1,

    m* = m0 m1/(m0 + m1), or the free body's mass where the other node is pinned to its
    link (it is then rigid). Body 0 takes +P, body 1 -P: momentum is conserved, and no
    pulling (adhesive) force can arise. Field 0's velocity change P/m0 is kept in
    ``grid_ds``: :func:`g2p` turns it into the pad particles' contact impulses.
    Field 1's copy of node i0 is node i0 + ``stride`` (``stride`` = envs × ncell: every env's
    box of field 0, then every env's box of field 1).
    """
    for i0 in range(stride):
        i1 = i0 + stride
        m0 = grid_m[i0]
        m1 = grid_m[i1]
        V0, V1, cell = grid_vc[i0], grid_vc[i1], dx * dx * dx
        if m0 > 0.0 and m1 > 0.0 and ti.min(V0, V1) >= SHARE * cell and V0 + V1 >= FILL * cell:
            pin0 = pinned(grid_m, grid_kin, i0)
            pin1 = pinned(grid_m, grid_kin, i1)
            if not (pin0 and pin1):
                n = mass_gradient(grid_m, i1, ny, nz) - mass_gradient(grid_m, i0, ny, nz)
                if n.norm() > 1e-6:
                    n = n.normalized()
                    vr = grid_v[i0] - grid_v[i1]
                    vn = vr.dot(n)
                    if vn > 0.0:
                        m_eff = m1 if pin0 else (m0 if pin1 else m0 * m1 / (m0 + m1))
                        vt = vr - vn * n
                        vtn = vt.norm()
                        stick = 1.0 if vtn <= mu * vn else mu * vn / vtn
                        P = -m_eff * (vn * n + stick * vt)
                        if not pin0:
                            grid_v[i0] = grid_v[i0] + P / m0
                            grid_ds[i0] = P / m0
                        if not pin1:
                            grid_v[i1] = grid_v[i1] - P / m1


@ti.func
def elastic_stress(nh_only: ti.template(), F, jp, mi, mat_table: ti.template()):
    """Kirchhoff stress τ [Pa] of material row ``mi`` at deformation gradient F."""
    tau = ti.Matrix.zero(ti.f32, 3, 3)
    if ti.static(nh_only):  # every material Neo-Hookean: no SVD code compiled in
        tau = mat.neo_hookean_stress(F, mat_table[mi, 0], mat_table[mi, 1])
    else:
        tau = mat.kirchhoff_stress(F, jp, mat_table[mi, 0], mat_table[mi, 1], ti.cast(mat_table[mi, 2], ti.i32),
                                   mat_table[mi, 5])
    return tau


@ti.func
def write_binding_frames(link_frames: ti.template(), group_bind: ti.template(), group_link: ti.template(),
        n_groups, group_frames: ti.template(), serial: ti.template()):
    """Frame rows of each group's *binding rotation* Q = R Rbᵀ at the substep's start and
    end: its link's rotation relative to the pose the group was bound at, the rigid part
    of a bound particle's deformation gradient (translations 0; identity if unbound).
    ``serial`` as in :func:`~gausstac_maniskill.mpm.kinematics.write_frames`."""
    ti.loop_config(serialize=serial)
    for g in range(n_groups):
        Q0 = ti.Matrix.identity(ti.f32, 3)
        Q1 = ti.Matrix.identity(ti.f32, 3)
        l = group_link[g]
        if l >= 0:
            R0, _t0, R1, _t1 = frame_at(link_frames, l)
            Rb = quat_to_mat(ti.Vector([group_bind[g, 0], group_bind[g, 1], group_bind[g, 2], group_bind[g, 3]]))
            Q0 = R0 @ Rb.transpose()
            Q1 = R1 @ Rb.transpose()
        for a, b in ti.static(ti.ndrange(3, 3)):
            group_frames[g, 3 * a + b] = Q0[a, b]
            group_frames[g, 12 + 3 * a + b] = Q1[a, b]
        for a in ti.static(range(3)):
            group_frames[g, 9 + a] = 0.0
            group_frames[g, 21 + a] = 0.0


@ti.func
def g2p(nh_only: ti.template(), order: ti.template(), n: ti.template(), x: ti.template(), v: ti.template(),
        C: ti.template(), F: ti.template(), tau: ti.template(), Jp: ti.template(),
        kind: ti.template(), matid: ti.template(), mat_table: ti.template(),
        group: ti.template(), group_frames: ti.template(), ox: ti.template(),
        oy: ti.template(), oz: ti.template(), ny: ti.template(), nz: ti.template(),
        inv_dx: ti.template(), dt: ti.template(), grid_v: ti.template(), grid_m: ti.template(),
        grid_kin: ti.template(), fbar: ti.template(), group_copy: ti.template(), group_field: ti.template(),
        ncell: ti.template(),
        two_field: ti.template(), grid_ds: ti.template(), mass: ti.template(), impulse: ti.template(),
        contact_id: ti.template(), cellp: ti.template()):
    """Gather velocity and its gradient, update F (and plasticity) and stress, advect.

    Bound (kinematic) particles keep their link-given position and velocity, but strain
    with the grid like the material they belong to: F = Q1 (I + Δt Q0ᵀ(∇v - ∇v_link) Q0) Q0ᵀ F,
    Q the link's rotation since binding (rigid motion exactly, no drift). Their stress
    completes the quadrature of the free nodes next to the bond, so the soft layer is held
    where its bound particles are, not a cell deeper (``bench thinlayer``). Where every
    node of the stencil is pinned, F is the rotation Q1 and the stress zero.
    With ``fbar`` or ``cellp`` the stress is left to the next :func:`p2g` (:func:`stress_at`).
    With two fields a particle gathers from its own field, and a dynamic particle of
    field 0 records its share m_p Σ w_ip Δv_i of the other field's contact impulse
    (:func:`field_contact`) in ``impulse``, with ``contact_id`` SOFT_CONTACT where no
    collider touched it.
    """
    origin = ti.Vector([ox, oy, oz])
    for ii in range(n):
        p = order[ii]
        is_kin = kind[p] == KINEMATIC
        base, fx, w = stencil(x[p], inv_dx, origin)
        off = field_offset(group_copy, group, p, ncell)
        # velocity v = Σ w_i v_i and APIC gradient C = (4/dx²) Σ w_i v_i (x_i - x_p)ᵀ
        #   = (4/dx) [Σ w_i v_i (i, j, k)ᵀ - v fxᵀ]: the node offsets (i, j, k) are the
        # stencil's own integers, so the moment sums only add (no product per node)
        new_v = vec3(0.0)
        moment = ti.Matrix.zero(ti.f32, 3, 3)  # columns Σ w_i v_i i, Σ w_i v_i j, Σ w_i v_i k
        soft_dv = vec3(0.0)
        for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
            weight = w[i][0] * w[j][1] * w[k][2]
            idx = off + ((base[0] + i) * ny + base[1] + j) * nz + base[2] + k
            wv = weight * grid_v[idx]
            new_v += wv
            for d, o in ti.static(enumerate((i, j, k))):
                if ti.static(o > 0):
                    moment[:, d] += wv if ti.static(o == 1) else 2.0 * wv
            if ti.static(two_field):
                soft_dv += weight * grid_ds[idx]
        new_C = (4.0 * inv_dx) * (moment - new_v.outer_product(fx))
        all_pinned = is_kin
        if is_kin:
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                all_pinned = all_pinned and pinned(grid_m, grid_kin,
                                                   off + ((base[0] + i) * ny + base[1] + j) * nz + base[2] + k)
        mi = matid[p]
        if ti.static(two_field):
            if group_field[group[p]] == 0 and not is_kin and soft_dv.norm_sqr() > 0.0:
                impulse[p] += mass[p] * soft_dv
                if contact_id[p] == -1:
                    contact_id[p] = SOFT_CONTACT
        if not is_kin:
            # deformation gradient: F <- (I + Δt ∇v) F, kept in the stretch range the explicit
            # step can carry (limit_stretch), then the material's return map
            Fn = limit_stretch((ti.Matrix.identity(ti.f32, 3) + dt * new_C) @ F[p], MAX_STRETCH)
            jp = Jp[p]
            if ti.static(not nh_only):
                if ti.cast(mat_table[mi, 2], ti.i32) == mat.FOAM:
                    Fn, jp = mat.plastic_return(Fn, jp, mat_table[mi, 3], mat_table[mi, 4])
            if ti.static(not (fbar or cellp)):
                tau[p] = elastic_stress(nh_only, Fn, jp, mi, mat_table)
            v[p] = new_v
            C[p] = new_C
            F[p] = Fn
            Jp[p] = jp
            x[p] = x[p] + dt * new_v
        else:
            Q0, _o0, Q1, _o1 = frame_at(group_frames, group[p])
            if all_pinned:
                F[p] = Q1
                tau[p] = ti.Matrix.zero(ti.f32, 3, 3)
            else:
                # C[p] is the link's rigid velocity gradient (kinematic_update)
                strain_rate = Q0.transpose() @ (new_C - C[p]) @ Q0
                Fn = limit_stretch(Q1 @ (ti.Matrix.identity(ti.f32, 3) + dt * strain_rate) @ Q0.transpose() @ F[p],
                                   BOND_STRETCH)
                F[p] = Fn
                if ti.static(not (fbar or cellp)):
                    tau[p] = elastic_stress(nh_only, Fn, Jp[p], mi, mat_table)


@ti.func
def limit_stretch(F, bound: ti.template()):
    """F with its principal stretches clamped to [1/bound, bound]: a numerical safeguard far
    outside a silicone pad's working range, where the explicit step fails.

    A pad closed hard on an object is crushed to a quarter of its thickness against its
    rigid core and dragged along: the last cells shear without bound, and a stretch of 70×
    made the stress (μ F Fᵀ), the wave speed and then the pad blow up (PressCube, the whole
    hand closed). Clamped, the excess is lost like plastic flow (the layer tears). A bound
    particle cannot move at all, so its F integrates whatever gradient the free nodes beside
    it carry: it gets the tighter ``BOND_STRETCH`` (a bond strained two-fold has torn).
    The SVD runs only where the invariants of C = FᵀF allow a stretch outside the range:
    λ_max(C) ≤ tr C and λ_min(C) ≥ det C / I2(C)."""
    C = F.transpose() @ F
    i1 = C.trace()
    i2 = 0.5 * (i1 * i1 - (C @ C).trace())
    out = F
    if i1 > bound * bound or C.determinant() * bound * bound < i2:
        U, sig, V = ti.svd(F)
        for d in ti.static(range(3)):
            sig[d, d] = ti.min(ti.max(sig[d, d], 1.0 / bound), bound)
        out = U @ sig @ V.transpose()
    return out


@ti.func
def volume_scatter(order: ti.template(), slab_start: ti.template(), n_slabs: ti.template(),
        x: ti.template(), F: ti.template(), vol: ti.template(), kind: ti.template(), matid: ti.template(),
        mat_table: ti.template(), ox: ti.template(),
        oy: ti.template(), oz: ti.template(), ny: ti.template(), nz: ti.template(), inv_dx: ti.template(),
        grid_vol: ti.template(), group: ti.template(), group_copy: ti.template(), ncell: ti.template(),
        two_field: ti.template(), atomic: ti.template()):
    """F-bar, step 1: each node gathers the rest volume Σ w V0 and the deformed volume
    Σ w V0 J of the particles around it (slab-ordered like :func:`p2g`; per field, so
    two bodies that touch do not average their volume change). Particles whose volume term
    is solved on cells (``mat.CELL_P``) take no part."""
    origin = ti.Vector([ox, oy, oz])
    for color in ti.static(range(1 if ti.static(atomic) else 2)):
        ti.loop_config(block_dim=128 if ti.static(atomic) else TASK_SPREAD)
        for q in range(scatter_tasks(atomic, slab_start, n_slabs, color)):
            lo, hi = slab_range(atomic, slab_start, color, q)
            for ii in range(lo, hi):
                p = order[ii]
                if kind[p] == DYNAMIC and mat_table[matid[p], mat.CELL_P] <= 0.0:
                    base, fx, w = stencil(x[p], inv_dx, origin)
                    off = field_offset(group_copy, group, p, ncell)
                    vj = vol[p] * ti.Vector([1.0, F[p].determinant()])
                    for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                        idx = off + ((base[0] + i) * ny + base[1] + j) * nz + base[2] + k
                        add_to(grid_vol, idx, (w[i][0] * w[j][1] * w[k][2]) * vj, atomic)


@ti.func
def stress_at(nh_only: ti.template(), fbar: ti.template(), cellp: ti.template(), report: ti.template(), Fp, jp, mi,
        mat_table: ti.template(), grid_vol: ti.template(), base, w, ny: ti.template(), nz: ti.template(), off):
    """Kirchhoff stress [Pa] of a particle (deformation gradient Fp, plastic J jp, material row
    mi, stencil (base, w)) as the substep uses it: for a material whose λ ln J term is solved on
    cells, μ(F Fᵀ - I) (with ``report``, for readings after a step, the whole Neo-Hookean
    stress); else the F-bar stress (:func:`fbar_stress_at`) or the plain elastic stress."""
    tau = ti.Matrix.zero(ti.f32, 3, 3)
    on_cells = False
    if ti.static(cellp):
        on_cells = mat_table[mi, mat.CELL_P] > 0.0
    if on_cells:
        tau = mat.neo_hookean_shear(Fp, mat_table[mi, 0])
        if ti.static(report):
            tau += mat_table[mi, 1] * ti.log(ti.max(Fp.determinant(), mat.MIN_J)) * ti.Matrix.identity(ti.f32, 3)
    else:
        if ti.static(fbar):
            tau = fbar_stress_at(nh_only, Fp, jp, mi, mat_table, grid_vol, base, w, ny, nz, off)
        else:
            tau = elastic_stress(nh_only, Fp, jp, mi, mat_table)
    return tau


@ti.func
def fbar_stress_at(nh_only: ti.template(), Fp, jp, mi, mat_table: ti.template(), grid_vol: ti.template(),
        base, w, ny: ti.template(), nz: ti.template(), off):
    """F-bar, step 2 (anti-locking for ν → 0.5): Kirchhoff stress of a particle with
    deformation gradient Fp and stencil (base, w) whose λ (bulk) term is evaluated at the
    grid-smoothed volume change J̄ = Σ_i w_ip J_i, J_i = (Σ w V0 J)_i / (Σ w V0)_i, instead
    of the particle's own J; the μ terms keep the particle's F. One bulk constraint per
    node instead of one per particle, so a nearly incompressible material is not
    over-constrained (volumetric locking). This is the selective form of F-bar / J-bar
    (de Souza Neto et al. 1996; for MPM, Coombs et al. 2018): replacing the whole F by
    (J̄/J)^{1/3} F was tried and lets particles trade volume at no cost (a pad crept 7 µm
    after contact); the μ terms' own volume stiffness stops that. ``grid_vol`` holds
    (Σ w V0, J_i) per node (:func:`nodal_volume_change`). A Neo-Hookean material takes
    μ(F Fᵀ - I) + λ ln J̄ I at once (its own λ ln J is never formed). P2G is bound by its
    arithmetic per particle, so both matter (BENCHMARKS, twenty-first session)."""
    J = ti.max(Fp.determinant(), mat.MIN_J)
    J_sum, w_sum = 0.0, 0.0
    for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
        gv = grid_vol[off + ((base[0] + i) * ny + base[1] + j) * nz + base[2] + k]
        if gv[0] > 0.0:
            weight = w[i][0] * w[j][1] * w[k][2]
            J_sum += weight * gv[1]  # the node's J_i (nodal_volume_change)
            w_sum += weight
    J_bar = J if w_sum <= 0.0 else J_sum / w_sum
    s_bar = mat.volumetric_stress(nh_only, ti.max(J_bar, mat.MIN_J), jp, mi, mat_table)
    tau = ti.Matrix.zero(ti.f32, 3, 3)
    if ti.static(nh_only):  # μ(F Fᵀ - I) + λ ln J̄ I: the particle's own λ ln J is never needed
        tau = mat.neo_hookean_shear(Fp, mat_table[mi, 0]) + s_bar * ti.Matrix.identity(ti.f32, 3)
    else:
        dp = s_bar - mat.volumetric_stress(nh_only, J, jp, mi, mat_table)
        tau = elastic_stress(nh_only, Fp, jp, mi, mat_table) + dp * ti.Matrix.identity(ti.f32, 3)
    return tau


@ti.func
def nodal_volume_change(ntot, grid_vol: ti.template()):
    """F-bar, step 1b: each node's (Σ w V0, Σ w V0 J) becomes (Σ w V0, J_i = Σ w V0 J / Σ w V0): one
    division per node instead of one per particle and stencil node (:func:`fbar_stress_at`)."""
    for idx in range(ntot):
        gv = grid_vol[idx]
        if gv[0] > 0.0:
            grid_vol[idx] = ti.Vector([gv[0], gv[1] / gv[0]])


@ti.func
def report_stress(nh_only: ti.template(), fbar: ti.template(), cellp: ti.template(), order: ti.template(),
        n: ti.template(), x: ti.template(),
        F: ti.template(), tau: ti.template(), Jp: ti.template(), matid: ti.template(),
        mat_table: ti.template(), ox: ti.template(), oy: ti.template(), oz: ti.template(),
        ny: ti.template(), nz: ti.template(), inv_dx: ti.template(), grid_vol: ti.template(),
        group: ti.template(), group_copy: ti.template(), ncell: ti.template(), two_field: ti.template()):
    """:func:`stress_at` (whole, with ``report``) for every particle: the stress reported after a step."""
    origin = ti.Vector([ox, oy, oz])
    for ii in range(n):
        p = order[ii]
        base, _fx, w = stencil(x[p], inv_dx, origin)
        off = field_offset(group_copy, group, p, ncell)
        tau[p] = stress_at(nh_only, fbar, cellp, True, F[p], Jp[p], matid[p], mat_table, grid_vol, base, w, ny,
                           nz, off)


@ti.func
def beyond_bound(col_frames: ti.template(), col_bound: ti.template(), c, x, reach):
    """World point x lies more than ``reach`` [m] beyond collider c's bounding sphere (radius
    ``col_bound[c]`` about its origin at the substep's end): nothing of c is within ``reach``, and
    its signed distance there exceeds ``reach`` (a mesh's SDF too: its grid lies inside the sphere
    and is positive on its border), so it need not be evaluated."""
    _R0, _t0, _R1, t1 = frame_at(col_frames, c)
    return (x - t1).norm() - col_bound[c] > reach


@ti.func
def contact_scatter(order: ti.template(), slab_start: ti.template(),
        n_slabs: ti.template(), x: ti.template(), kind: ti.template(), mass: ti.template(),
        radius: ti.template(), impulse: ti.template(), contact_id: ti.template(),
        ox: ti.template(), oy: ti.template(), oz: ti.template(), ny: ti.template(),
        nz: ti.template(), inv_dx: ti.template(), dt: ti.template(), grid_v: ti.template(),
        grid_m: ti.template(), grid_kin: ti.template(),
        grid_dp: ti.template(), n_col: ti.template(), col_kind: ti.template(),
        col_prm: ti.template(), col_frames: ti.template(), col_friction: ti.template(),
        sdf: ti.template(), sdf_info: ti.template(),
        max_push: ti.template(), reach: ti.template(), group: ti.template(), group_copy: ti.template(),
        ncell: ti.template(), two_field: ti.template(), atomic: ti.template(), anchor: ti.template(),
        group_env: ti.template(), col_env: ti.template(), col_bound: ti.template()):
    """Particle-detected contact, applied as momentum on the grid (of the particle's field).

    For each dynamic particle near a collider, its free velocity v* is gathered
    from the grid and its end-of-substep position x + Δt v* is tested against the
    collider's surface inflated by the particle radius (the material's surface lies
    half a particle spacing beyond the centres). If it would penetrate, the velocity
    change Δv that puts it on the surface (normal part, capped at ``max_push``) with
    Coulomb friction on the tangential slip is turned into the impulse m_p Δv, which
    is scattered to the particle's grid stencil (weights w_ip), so the whole
    continuum - not only the particle - feels the collider. Pinned (kinematic) nodes
    take no momentum (:func:`contact_apply`), so the particle records only the part
    that reaches free nodes, Σ_free w_ip · m_p Δv: that is the impulse the pad really
    exchanged, stored per particle (contact forces / tactile) and, negated, acting on
    the collider.

    Static friction holds a position, not a velocity. A particle that sticks keeps an
    anchor, the point of the collider it stuck to (in the collider's frame, ``anchor``).
    While it stays in contact, the tangential change asked for is the one that brings its
    predicted position back onto the anchor, -d_t/Δt (d_t the tangential drift from the
    anchor), not only the one that cancels its present slip velocity. The impulse of one
    particle reaches its nodes only in part (the rest of their mass belongs to other
    particles), so a velocity-level stick removes only that part of the slip in every
    substep and a loaded contact creeps at a speed proportional to its shear load: a
    held, sheared pad let go of 79 % of its tangential force in 0.4 s, at μ = 0.5 and 5
    alike (``bench pad`` plate slide, 2026-11-23). With the anchor the drift the partial impulses
    leave is taken back in the next substep, like the normal penetration. Where
    |d_t|/Δt exceeds μ times the normal velocity change the particle slides (Coulomb),
    its friction opposes the drift, and its anchor moves to where it is predicted to end
    the substep. A particle that leaves contact forgets its anchor.
    Slab-ordered like :func:`p2g` (atomic-free and deterministic), or atomic.
    """
    origin = ti.Vector([ox, oy, oz])
    for color in ti.static(range(1 if ti.static(atomic) else 2)):
        ti.loop_config(block_dim=128 if ti.static(atomic) else TASK_SPREAD)
        for q in range(scatter_tasks(atomic, slab_start, n_slabs, color)):
            lo, hi = slab_range(atomic, slab_start, color, q)
            for ii in range(lo, hi):
                p = order[ii]
                if kind[p] == DYNAMIC:
                    env = group_env[group[p]]  # a particle touches only its own env's colliders
                    near = False
                    for c in range(n_col):
                        if col_env[c] == env and not beyond_bound(col_frames, col_bound, c, x[p], radius[p] + reach):
                            phi, nrm, vc = collider_contact(col_kind, col_prm, col_frames, sdf, sdf_info, c, x[p],
                                                            dt)
                            if phi - radius[p] < reach:
                                near = True
                    stuck_to = -1  # collider whose anchor the particle keeps after this substep
                    slid = False
                    if near:
                        base, fx, w = stencil(x[p], inv_dx, origin)
                        off = field_offset(group_copy, group, p, ncell)
                        v0 = vec3(0.0)
                        for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                            v0 += w[i][0] * w[j][1] * w[k][2] * grid_v[off + ((base[0] + i) * ny + base[1] + j) * nz
                                                                        + base[2] + k]
                        vp = v0
                        for c in range(n_col):
                            if col_env[c] != env or beyond_bound(col_frames, col_bound, c, x[p] + dt * vp, radius[p]):
                                continue  # (not this env's, or too far to touch)
                            phi, nrm, vc = collider_contact(col_kind, col_prm, col_frames, sdf, sdf_info,
                                                            c, x[p] + dt * vp, dt)
                            gap = phi - radius[p]
                            if gap < 0.0:
                                vrel = vp - vc
                                # stop the approach, and take back an older penetration by at most
                                # RECOVERY cells per substep: the push stays in the particle's velocity
                                approach = ti.max(-vrel.dot(nrm), 0.0)
                                dvn = ti.min(-gap / dt, approach + RECOVERY / (inv_dx * dt), max_push)
                                want = -(vrel - vrel.dot(nrm) * nrm)  # stop the slip (first contact)
                                anchored = ti.cast(anchor[p][3], ti.i32) == c
                                if anchored:  # back onto the anchor
                                    _R0, _t0, R1, t1 = frame_at(col_frames, c)
                                    a = ti.Vector([anchor[p][0], anchor[p][1], anchor[p][2]])
                                    drift = x[p] + dt * vp - (R1 @ a + t1)
                                    want = -(drift - drift.dot(nrm) * nrm) / dt
                                wn = want.norm()
                                if wn > max_push:  # a jump of the anchor (a teleported collider) is not a load
                                    want *= max_push / wn
                                    wn = max_push
                                dvt = want
                                slides = col_friction[c, 1] <= 0.0 and wn > col_friction[c, 0] * dvn
                                if slides:  # Coulomb
                                    dvt = (col_friction[c, 0] * dvn / wn) * want
                                vp = vp + dvn * nrm + dvt
                                contact_id[p] = c
                                # sliding or a new contact: anchor where it ends this substep
                                slid = slid or slides or not anchored
                                stuck_to = c
                        if stuck_to >= 0 and slid:
                            _R0, _t0, R1, t1 = frame_at(col_frames, stuck_to)
                            a = R1.transpose() @ (x[p] + dt * vp - t1)
                            anchor[p] = ti.Vector([a[0], a[1], a[2], ti.cast(stuck_to, ti.f32)])
                        if contact_id[p] >= 0:
                            J = mass[p] * (vp - v0)
                            free = 0.0
                            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                                idx = off + ((base[0] + i) * ny + base[1] + j) * nz + base[2] + k
                                wi = w[i][0] * w[j][1] * w[k][2]
                                add_to(grid_dp, idx, wi * J, atomic)
                                if not pinned(grid_m, grid_kin, idx):
                                    free += wi
                            impulse[p] += free * J
                    if stuck_to < 0:
                        anchor[p][3] = -1.0


@ti.func
def contact_apply(ntot: ti.template(), ncell: ti.template(), ox: ti.template(), oy: ti.template(),
        oz: ti.template(), ny: ti.template(), nz: ti.template(), dx: ti.template(),
        grid_v: ti.template(), grid_m: ti.template(), grid_kin: ti.template(),
        grid_dp: ti.template(), walls: ti.template(), n_walls: ti.template()):
    """Add the scattered contact momentum to free nodes (not pinned, walls kept)."""
    for idx in range(ntot):
        m = grid_m[idx]
        dp = grid_dp[idx]
        if m > 0.0 and not pinned(grid_m, grid_kin, idx) and dp.norm_sqr() > 0.0:
            xi = node_position(idx, ncell, ox, oy, oz, ny, nz, dx)
            grid_v[idx] = grid_v[idx] + slip_walls(walls, n_walls, xi, dp / m)


@ti.func
def bond_ghosts(ntot: ti.template(), ncell: ti.template(), ox: ti.template(), oy: ti.template(),
        oz: ti.template(), nx: ti.template(), ny: ti.template(), nz: ti.template(), dx: ti.template(),
        dt: ti.template(), grid_v: ti.template(), grid_m: ti.template(), grid_kin: ti.template(),
        grid_link: ti.template(), link_frames: ti.template()):
    """The bond of a layer to its link's rigid core, placed where the bond surface is, not on a
    node plane (a ghost-node Dirichlet condition, as in ghost-fluid methods).

    A pinned node (:func:`pinned`) whose kinematic mass all knows the bond surface lies at a
    signed distance d from it (positive in the layer; from ``grid_kin``, the mass-weighted
    linear extrapolation of the bound particles' distances) along the surface normal n. Pinned
    to the link's rigid velocity, it would hold the layer at the node plane, up to a cell from
    the bond: the layer's stiffness then depends on how the grid lies (±11 % at 4 cells).
    Instead the node takes the velocity that vanishes, relative to the link, at the bond and
    grows linearly into the layer:

        v_i = v_link(x_i) + (d / D) [v(x_m) - v_link(x_m)],   x_m = x_i + (D - d) n,

    with v(x_m) the trilinear mean of the free (unpinned) nodes around the point x_m a
    distance D = BOND_REACH cells inside the layer. A uniform strain of the layer is then
    exactly an equilibrium whatever the offset of the bond from the nodes (B-splines reproduce
    linear fields). |d/D| is clamped to 1. Nodes with kinematic mass that does not know the
    bond (the active patch's shell, bound where it is) stay pinned to the rigid motion.
    """
    for idx in range(ntot):
        m = grid_m[idx]
        b = grid_kin[idx]
        if m > 0.0 and b[4] > 0.0 and pinned(grid_m, grid_kin, idx) and b[4] >= 0.999 * b[5]:
            nrm = ti.Vector([b[0], b[1], b[2]])
            if nrm.norm() > 1e-3 * b[4]:
                nrm = nrm.normalized()
                d = b[3] / b[4]
                reach = BOND_REACH * dx
                xi = node_position(idx, ncell, ox, oy, oz, ny, nz, dx)
                xm = xi + (reach - d) * nrm
                off = idx - idx % ncell
                # trilinear mean of the free nodes of the cell around xm
                g = xm / dx - ti.Vector([ox, oy, oz], ti.f32)
                base = ti.cast(ti.floor(g), ti.i32)
                f = g - base
                vsum = vec3(0.0)
                wsum = 0.0
                for a, c, e in ti.static(ti.ndrange(2, 2, 2)):
                    q = base + ti.Vector([a, c, e])
                    if 0 <= q[0] < nx and 0 <= q[1] < ny and 0 <= q[2] < nz:
                        j = off + (q[0] * ny + q[1]) * nz + q[2]
                        if grid_m[j] > 0.0 and not pinned(grid_m, grid_kin, j):
                            wt = (f[0] if a else 1.0 - f[0]) * (f[1] if c else 1.0 - f[1]) * (f[2] if e else 1.0 - f[2])
                            vsum += wt * grid_v[j]
                            wsum += wt
                if wsum > 0.25:
                    lk = grid_link[idx]
                    v_i, _w0, _t0 = link_motion_at(link_frames, lk, xi, dt)
                    v_m, _w1, _t1 = link_motion_at(link_frames, lk, xm, dt)
                    ratio = ti.max(-1.0, ti.min(1.0, d / reach))
                    grid_v[idx] = v_i + ratio * (vsum / wsum - v_m)


# --------------------------------------------------------------------------- cell pressure
# Nearly incompressible silicone (ν → 0.5) at the shear wave's time step. For a material with
# ``mat.CELL_P`` (SolverSettings.pressure = "implicit") the Neo-Hookean stress splits into
# μ(F Fᵀ - I), kept explicit on the particles, and the volume term λ ln J · I, taken as one
# value per grid cell, π_c = λ mean_(p in c)(ln J_p) (F-bar's idea with the cell as the patch,
# so the volume constraint is not counted once per particle), and solved backward Euler in
# every substep. The cell's operator is built from its particles' own MLS gradients,
# G_ci = Σ_(p in c) V0_p ∇w_ip (4³ nodes i per cell), so the force of the cell pressures,
# f_i = -Σ_c G_ci π_c, and their rate, d(mean ln J)/dt = Σ_i G_ci·v_i / V_c, are exactly
# those of the particles' transfers (an earlier try with trilinear cell gradients was not, and
# lost half the volume stiffness: BENCHMARKS.md, issue 10, seventh step). Backward Euler,
#     π⁺ = πⁿ + λ Δt Gᵀv⁺ / V,   v⁺ = v* - Δt M⁻¹ G π⁺   (free nodes; pinned ones keep v*),
# gives the symmetric positive definite system of the cell values
#     [diag(V/λ) + Δt² Gᵀ M⁻¹ G] π⁺ = diag(V/λ) πⁿ + Δt Gᵀ v*,
# solved by Jacobi-preconditioned conjugate gradients from πⁿ (exact in equilibrium). Cells are
# numbered each substep (``cell_slot``: box cell → slot, or -1) so the operator is stored only
# for occupied cells. Particles keep their own F (J from their velocity gradient, as always).

PRESSURE_TOL = 1e-4  # CG stops when the preconditioned residual norm falls below this share of its start
CG_RZ, CG_RZ0, CG_DONE = NCHUNK, NCHUNK + 1, NCHUNK + 2  # rows of G.cg_sum after the chunk partial sums
CG_ROWS = NCHUNK + 3


@ti.func
def number_cells(P: ti.template(), S: ti.template(), G: ti.template(), O: ti.template(), ntot, ncell, ny, nz,
        inv_dx, origin, two_field: ti.template()):
    """Number the cells that hold particles of cell-pressure materials: ``G.cell_slot[c]`` = slot
    or -1, ``G.slot_cell[slot]`` = c, ``G.cell_count`` = (slots, 1 if capacity ran out); then
    clear their ``cell_a`` and ``cell_G`` rows. In box order: bit-reproducible."""
    for ii in range(S.counts[N_ACTIVE]):  # mark (every particle of a cell writes the same 1)
        p = O.order[ii]
        if S.mat_table[P.matid[p], mat.CELL_P] > 0.0:
            off = field_offset(S.group_copy, P.group, p, ncell)
            cell = ti.cast(ti.floor(P.x[p] * inv_dx - origin), ti.i32)
            G.cell_slot[off + (cell[0] * ny + cell[1]) * nz + cell[2]] = 1
    G.cell_count[0] = 0
    G.cell_count[1] = 0
    cap = G.slot_cell.shape[0]
    ti.loop_config(serialize=True)
    for c in range(ntot):
        if G.cell_slot[c] == 1:
            k = G.cell_count[0]
            if k < cap:
                G.cell_slot[c] = k
                G.slot_cell[k] = c
                G.cell_count[0] = k + 1
            else:
                G.cell_slot[c] = -1
                G.cell_count[1] = 1
        else:
            G.cell_slot[c] = -1
    for k in range(G.cell_count[0]):
        G.cell_a[k] = ti.Vector([0.0, 0.0, 0.0, 0.0])
    for k in range(G.cell_count[0] * 64):
        G.cell_G[k] = vec3(0.0)


@ti.func
def free_node(grid_m: ti.template(), grid_kin: ti.template(), idx):
    """A node that carries mass and is not held by a link (its velocity is an unknown)."""
    return grid_m[idx] > 0.0 and not pinned(grid_m, grid_kin, idx)


@ti.func
def cell_node(c, l, ny, nz):
    """Flat index of the node at offset l ∈ {0..63} (4³, z fastest) from cell c's node c - (1, 1, 1)."""
    return c + ((l // 16 - 1) * ny + (l // 4) % 4 - 1) * nz + l % 4 - 1


@ti.func
def gather_cells(G: ti.template(), S: ti.template(), comp: ti.template(), geo, coef):
    """t_i = M⁻¹ Σ_c G_ci q_c on free nodes, 0 elsewhere, into ``G.grid_t``; q is component
    ``comp`` of ``G.cell_b`` (0: π, 2: the CG direction). Slip walls drop the normal component
    (:func:`slip_walls`, a projection: the operator stays symmetric). geo = (ntot, ncell, ny, nz, ox, oy, oz),
    coef = (Δt, 1/dx, dx, α)."""
    ntot, ncell, ny, nz = geo[0], geo[1], geo[2], geo[3]
    for idx in range(ntot):
        t = vec3(0.0)
        live = True
        if ti.static(comp == 2):  # the CG direction: nothing to do once converged
            live = G.cg_sum[CG_DONE] == 0.0
        if live:
            if free_node(G.grid_m, G.grid_kin, idx):
                cc = idx % ncell
                node = ti.Vector([cc // (ny * nz), (cc // nz) % ny, cc % nz])
                for l in range(64):
                    cell = node - ti.Vector([l // 16, (l // 4) % 4, l % 4]) + 1  # node = cell - 1 + offset l
                    if cell.min() >= 0:
                        slot = G.cell_slot[idx - cc + (cell[0] * ny + cell[1]) * nz + cell[2]]
                        if slot >= 0:
                            t += G.cell_b[slot][comp] * G.cell_G[slot * 64 + l]
                xi = node_position(idx, ncell, geo[4], geo[5], geo[6], ny, nz, coef[2])
                t = slip_walls(S.walls, S.counts[N_WALLS], xi, t / G.grid_m[idx])
        G.grid_t[idx] = t


@ti.func
def slot_sum(step: ti.template(), G: ti.template(), geo, coef, atomic: ti.template()):
    """Σ_k step(G, k, geo, coef) over the numbered cells (a step may also update its cell):
    in fixed chunks summed in a fixed order on the CPU (bit-reproducible), atomically on GPUs."""
    n = G.cell_count[0]
    total = 0.0
    if ti.static(atomic):
        G.cg_sum[0] = 0.0
        for k in range(n):
            ti.atomic_add(G.cg_sum[0], step(G, k, geo, coef))
        total = G.cg_sum[0]
    else:
        ti.loop_config(block_dim=TASK_SPREAD)
        for q in range(spread_tasks(NCHUNK)):  # a thread block per chunk
            ch = spread_item(q)
            if ch >= 0:
                s = 0.0
                for k in range(ch * n // NCHUNK, (ch + 1) * n // NCHUNK):
                    s += step(G, k, geo, coef)
                G.cg_sum[ch] = s
        for ch in ti.static(range(NCHUNK)):
            total += G.cg_sum[ch]
    return total


@ti.func
def cell_apply(G: ti.template(), k, geo, with_v: ti.template(), t_scale):
    """Σ_i G_ci·u_i over the 4³ nodes of numbered cell k, u = v - t_scale·t with ``with_v``
    (v = ``grid_v``), else u = t (t = ``grid_t``)."""
    ny, nz = geo[2], geo[3]
    c = G.slot_cell[k]
    s = 0.0
    for l in range(64):
        i = cell_node(c, l, ny, nz)
        u = G.grid_t[i]
        if ti.static(with_v):
            u = G.grid_v[i] - t_scale * u
        s += G.cell_G[k * 64 + l].dot(u)
    return s


@ti.func
def cg_start(G: ti.template(), k, geo, coef):
    """Cell k: the Jacobi diagonal V/λ + Δt² Σ_i |G_ci|²/m_i, and the residual at the guess πⁿ,
    r = Δt Gᵀ(v* - Δt M⁻¹ G πⁿ), z = r / diag, p = z. Returns rᵀz."""
    ny, nz = geo[2], geo[3]
    dt = coef[0]
    a = G.cell_a[k]
    c = G.slot_cell[k]
    diag = a[0] * a[0] / a[2]  # V/λ̄, λ̄ = Σ V0 λ / V
    for l in range(64):
        i = cell_node(c, l, ny, nz)
        if free_node(G.grid_m, G.grid_kin, i):
            diag += dt * dt * G.cell_G[k * 64 + l].norm_sqr() / G.grid_m[i]
    r = dt * cell_apply(G, k, geo, True, dt)
    G.cell_a[k][3] = diag
    G.cell_b[k] = ti.Vector([G.cell_b[k][0], r, r / diag, 0.0])
    return r * r / diag


@ti.func
def cg_apply(G: ti.template(), k, geo, coef):
    """Cell k: (A p)_k = (V/λ̄) p_k + Δt² (Gᵀ t)_k with t = M⁻¹ G p; returns p_k (A p)_k."""
    dt = coef[0]
    pAp = 0.0
    if G.cg_sum[CG_DONE] == 0.0:
        a = G.cell_a[k]
        p = G.cell_b[k][2]
        Ap = p * a[0] * a[0] / a[2] + dt * dt * cell_apply(G, k, geo, False, 0.0)
        G.cell_b[k][3] = Ap
        pAp = p * Ap
    return pAp


@ti.func
def cg_update(G: ti.template(), k, geo, coef):
    """Cell k: π += α p, r -= α A p (α = coef[3]); returns the new rᵀz."""
    b = G.cell_b[k]
    alpha = coef[3]
    r = b[1] - alpha * b[3]
    G.cell_b[k][0] = b[0] + alpha * b[2]
    G.cell_b[k][1] = r
    return r * r / G.cell_a[k][3]


@ti.func
def pressure_solve(G: ti.template(), S: ti.template(), geo, dt, inv_dx, iters: ti.template(),
        atomic: ti.template()):
    """The cells' values π⁺ (see the section comment) by at most ``iters`` Jacobi-PCG iterations
    from πⁿ, then v ← v* - Δt M⁻¹ G π⁺ on free nodes. Expects ``G.cell_a`` = (Σ V0, Σ V0 ln J,
    Σ V0 λ, -) and ``G.cell_G`` of the numbered cells from :func:`p2g`."""
    ntot = geo[0]
    coef = ti.Vector([dt, inv_dx, 1.0 / inv_dx, 0.0])
    for k in range(G.cell_count[0]):  # the guess πⁿ = λ̄ mean(ln J)
        a = G.cell_a[k]
        G.cell_b[k] = ti.Vector([a[1] * a[2] / (a[0] * a[0]), 0.0, 0.0, 0.0])
    G.cg_sum[CG_DONE] = 0.0
    gather_cells(G, S, 0, geo, coef)  # t = M⁻¹ G πⁿ
    rz = slot_sum(cg_start, G, geo, coef, atomic)
    G.cg_sum[CG_RZ0] = rz
    if rz <= 0.0:
        G.cg_sum[CG_DONE] = 1.0
    for _it in ti.static(range(iters)):
        gather_cells(G, S, 2, geo, coef)  # t = M⁻¹ G p
        pAp = slot_sum(cg_apply, G, geo, coef, atomic)
        alpha = 0.0
        if G.cg_sum[CG_DONE] == 0.0 and pAp > 0.0:
            alpha = rz / pAp
        coef[3] = alpha
        rz_new = slot_sum(cg_update, G, geo, coef, atomic)
        beta = 0.0
        if alpha != 0.0:
            beta = rz_new / rz
            rz = rz_new
        if rz <= PRESSURE_TOL * PRESSURE_TOL * G.cg_sum[CG_RZ0]:
            G.cg_sum[CG_DONE] = 1.0
        for k in range(G.cell_count[0]):  # p = z + β p
            if alpha != 0.0:
                G.cell_b[k][2] = G.cell_b[k][1] / G.cell_a[k][3] + beta * G.cell_b[k][2]
    G.cg_sum[CG_RZ] = rz
    gather_cells(G, S, 0, geo, coef)  # t = M⁻¹ G π⁺
    for idx in range(ntot):
        if free_node(G.grid_m, G.grid_kin, idx):
            G.grid_v[idx] = G.grid_v[idx] - dt * G.grid_t[idx]


@cached_kernel
@ti.kernel
def follow_links(active: NDI, n: ti.i32, v: NDV, C: NDM, x: NDV, kind: NDI, link: NDI, group: NDI,
                 group_qs: NDI, group_touched: NDI, twist_change: NDF2):
    """Carry quasi-static particles through their link's change of rigid velocity.

    A pad's pseudo-mass must resist only its deformation, not the hand's acceleration.
    Link motion is piecewise uniform (constant linear and angular velocity within a
    control step), so the link accelerates only between steps; there each dynamic
    particle of a quasi-static group takes the change of the link's rigid velocity
    field, Δv(x) = Δv_o + Δω × (x - o), and its APIC gradient the change [Δω]×.
    ``twist_change`` rows: (Δv_o xyz, Δω xyz, o xyz), o the link origin.
    Groups that touched a collider in the last step (``group_touched``) keep their velocity:
    the jump would reach the object as a pseudo-mass impulse (a 62 g cube was kicked to
    0.1 m/s; taking it everywhere but at the touching particles still shook a held 0.5 kg
    cube at 15 mm/s). Such a pad lags its link by up to |Δv|/ζ instead (0.1 m at a 13.6 m/s
    strike: the solver then finds it torn, ``MPMWorld._rest_torn``). Before, one touching
    pad stopped every pad of its env from following, and GraspLiftCube's untouched pads
    were torn apart by the strike.
    """
    for ii in range(n):
        p = active[ii]
        l = link[p]
        if kind[p] == DYNAMIC and l >= 0 and group_qs[group[p]] > 0 and group_touched[group[p]] == 0:
            dv = ti.Vector([twist_change[l, 0], twist_change[l, 1], twist_change[l, 2]])
            dw = ti.Vector([twist_change[l, 3], twist_change[l, 4], twist_change[l, 5]])
            o = ti.Vector([twist_change[l, 6], twist_change[l, 7], twist_change[l, 8]])
            v[p] += dv + dw.cross(x[p] - o)
            C[p] += ti.Matrix([[0.0, -dw[2], dw[1]], [dw[2], 0.0, -dw[0]], [-dw[1], dw[0], 0.0]])


@cached_kernel
@ti.kernel
def reset_contact(active: NDI, n: ti.i32, impulse: NDV, contact_id: NDI):
    for ii in range(n):
        p = active[ii]
        impulse[p] = vec3(0.0)
        contact_id[p] = -1


@cached_kernel
@ti.kernel
def chunk_health(active: NDI, n: ti.i32, x: NDV, v: NDV, F: NDM, kind: NDI, nchunk: ti.i32,
                 first_bad: NDI, vmax: NDF):
    """Per chunk: first particle with a non-finite x, v or F (or -1), and max |v|."""
    ti.loop_config(block_dim=TASK_SPREAD)
    for q in range(spread_tasks(nchunk)):  # a thread block per chunk
        c = spread_item(q)
        if c >= 0:
            bad = -1
            vm = 0.0
            start = c * n // nchunk
            end = (c + 1) * n // nchunk
            for ii in range(start, end):
                p = active[ii]
                s = x[p].sum() + v[p].sum() + F[p].sum()
                if bad < 0 and not (s == s and ti.abs(s) < 1e30):
                    bad = p
                if kind[p] == DYNAMIC:
                    vm = ti.max(vm, v[p].norm())
            first_bad[c] = bad
            vmax[c] = vm


@ti.kernel
def energies(active: NDI, n: ti.i32, v: NDV, C: NDM, F: NDM, Jp: NDF, kind: NDI, matid: NDI,
             mass: NDF, vol: NDF, mat_table: NDF2, dx: ti.f32, out: NDF):
    """out[0] = kinetic energy [J] of dynamic particles, out[1] = elastic energy [J]. The kinetic
    energy is APIC's, ½ m (|v|² + tr(C D Cᵀ)) with D = (Δx²/4) I for quadratic B-splines
    (Jiang et al. 2015): the velocity's variation over a particle's stencil carries energy too,
    and the grid holds it after P2G."""
    out[0] = 0.0
    out[1] = 0.0
    for ii in range(n):
        p = active[ii]
        if kind[p] == DYNAMIC:
            mi = matid[p]
            out[0] += 0.5 * mass[p] * (v[p].norm_sqr() + 0.25 * dx * dx * (C[p] * C[p]).sum())
            out[1] += vol[p] * mat.strain_energy_density(
                F[p], Jp[p], mat_table[mi, 0], mat_table[mi, 1],
                ti.cast(mat_table[mi, 2], ti.i32), mat_table[mi, 5])


# --------------------------------------------------------------------------- fused substep
# Kernel arguments are grouped by what they describe, in one argument pack per kernel:
# `World` (the particles, the grid, the scene: materials, links, groups, walls,
# colliders, constants; and the particle order) for `advance`, `Placement` for
# `prepare`. Taichi 1.7 allows one pack per kernel and 64 scalar elements per launch
# (ndarrays count one each), so counts and constants live in small arrays. It spends
# ~7 µs per ndarray on the Python side per launch (to look up the compiled variant, which
# @cached_kernel skips while the same packs come back, and to set the arguments), so each
# pack holds only what its kernel reads. A substep is two launches: `prepare` (the host reads
# the active box's size back to size the grid) and `advance`.

NDV2 = ti.types.ndarray(dtype=ti.math.vec2, ndim=1)
BOX = 8  # active box layout: origin xyz, dims xyz (nodes), number of slabs, slab axis
SLAB_CAP = 1 << 16  # slabs are 2 cells: the active box may span 131072 cells along one axis
# rows of Scene.counts and Scene.consts
N_LINKS, N_GROUPS, N_COL, N_WALLS, N_ACTIVE, N_KIN, N_ENVS = range(7)
DX, GX, GY, GZ, DAMPING, REACH, MARGIN, FIELD_MU, BOND = range(9)

Particles = ti.types.argpack(  # member names are unique over the packs (Taichi flattens them)
    x=NDV, v=NDV, C=NDM, F=NDM, tau=NDM, Jp=NDF,  # state: position [m], velocity, APIC C, F, τ [Pa], plastic J
    impulse=NDV, contact_id=NDI,  # contact impulse [N s] of this control step, collider touched
    anchor=NDV4,  # static friction: stuck point in its collider's frame [m], and that collider (-1: none)
    mass=NDF, vol=NDF, radius=NDF,  # mass [kg], rest volume [m³], contact radius [m]
    kind=NDI, link=NDI, matid=NDI, group=NDI,  # DYNAMIC | KINEMATIC, link, material row, group
    bond=NDV4)  # bound particles: normal of the bond surface (link frame), signed distance [m] (0: none)
Grid = ti.types.argpack(
    grid_pm=NDV4,  # P2G's sums: momentum [kg m/s] and mass [kg], one record per node
    grid_v=NDV, grid_m=NDF,  # velocity [m/s] and mass [kg], from grid_update
    grid_mq=NDF, grid_link=NDI,  # quasi-static mass [kg], link of bound and quasi-static particles
    grid_dp=NDV, grid_vol=NDV2,  # contact momentum [N s]; (Σ w V0, Σ w V0 J), then (Σ w V0, J_i), for F-bar
    grid_vc=NDF, grid_ds=NDV,  # two fields: deformed volume Σ w V0 J [m³]; field 0's contact Δv [m/s]
    # bound particles' record: Σ w m (n, d, 1) of those that know the bond surface (bond_ghosts), Σ w m
    grid_kin=NDV6,
    # cell pressure (pressure_solve): box cell -> slot (-1: none), slot -> box cell, (slots, overflow)
    cell_slot=NDI, slot_cell=NDI, cell_count=NDI,
    cell_a=NDV4, cell_b=NDV4,  # per slot: (Σ V0, Σ V0 ln J, Σ V0 λ, CG diagonal); CG (π, r, p, Ap)
    cell_G=NDV, grid_t=NDV, cg_sum=NDF)  # Σ V0 ∇w per slot and node (64 rows); M⁻¹Gq per node; CG sums
Scene = ti.types.argpack(
    counts=NDI, consts=NDF,  # rows N_LINKS.., and DX.. [m, m/s², 1/s, m, cells, -]
    mat_table=NDF2,  # materials.material_table rows
    group_qs=NDI, group_frames=NDF2, group_field=NDI,  # per group: quasi-static?, binding frames, field
    group_env=NDI, group_copy=NDI,  # ... its env, its box copy in the grid arrays (field · N_ENVS + env)
    env_relax=NDF,  # per env: relaxation rate ζ [1/s] of its quasi-static nodes (the largest of its awake groups)
    link_frames=NDF2, walls=NDF2,  # kinematics frame rows of links; slip walls (axis, position, side)
    col_kind=NDI, col_prm=NDF2, col_frames=NDF2, col_friction=NDF2,  # colliders; friction rows (μ, 1 if sticky)
    sdf=NDF, sdf_info=NDI2, col_impulse=NDF2, col_env=NDI,  # ... and each collider's env
    col_bound=NDF)  # ... and the radius [m] of a sphere about its origin that holds it (contact_scatter)
Order = ti.types.argpack(
    order=NDI, slab_start=NDI,  # awake particles sorted by slab, first index of each slab
    active_box=NDI)  # the active box of the substep (BOX layout), written by prepare
World = ti.types.argpack(P=Particles, G=Grid, S=Scene, O=Order)
Reduction = ti.types.argpack(  # what reduce_contact reads and sums into
    env_rows=NDI,  # first row of each env's particles in the active list (num_envs + 1 rows)
    col_slot=NDI,  # per collider: its number among its env's colliders (its pair slot)
    col_ends=NDF2, link_ends=NDF2,  # pose rows of the step (kinematics.py): the end poses are read
    col_sums=NDF2, pair_sums=NDF2)  # per collider: -J, moment; per (link, slot): J, moment, depth


@cached_kernel
@ti.kernel
def group_drift(P: Particles, active: NDI, n: ti.i32, link_poses: NDF2, dt: ti.f32, out: NDF):
    """out[g] = the largest speed [m/s] of a dynamic particle of group g relative to its
    link's rigid motion over the step just taken (pose rows of kinematics.py)."""
    for ii in range(n):
        p = active[ii]
        l = P.link[p]
        if P.kind[p] == DYNAMIC and l >= 0:
            R0, t0 = pose_at(link_poses, l, 0.0)
            R1, t1 = pose_at(link_poses, l, 1.0)
            x0 = R0 @ (R1.transpose() @ (P.x[p] - t1)) + t0  # where the link's motion took x from
            v_link = (P.x[p] - x0) / dt  # (zero when the link stands)
            ti.atomic_max(out[P.group[p]], (P.v[p] - v_link).norm())


@ti.kernel
def fill_mass(P: Particles, start: ti.i32, stop: ti.i32, mass: ti.f32):
    """Rows [start, stop): mass ← ``mass`` [kg] (a pad's pseudo-mass changed)."""
    for p in range(start, stop):
        P.mass[p] = mass


@cached_kernel
@ti.kernel
def torn_particles(P: Particles, X0: NDV, active: NDI, n: ti.i32, link_poses: NDF2, group_tear: NDF, torn: NDI):
    """torn[g] += the number of group g's dynamic particles farther than ``group_tear[g]`` [m]
    (0: no check) from their rest place R X0 + t on their link's end pose: no elastic state of
    the layer puts them there, so they have lost their core (an object pushed into it)."""
    for ii in range(n):
        p = active[ii]
        g = P.group[p]
        if P.kind[p] == DYNAMIC and group_tear[g] > 0.0:
            R, t = pose_at(link_poses, P.link[p], 1.0)
            if (P.x[p] - (R @ X0[p] + t)).norm() > group_tear[g]:
                ti.atomic_add(torn[g], 1)


@cached_kernel
@ti.kernel
def reduce_contact(P: Particles, X0: NDV, active: NDI, sums: Reduction, n_env: ti.i32, n_slot: ti.i32):
    """Sum the per-particle contact impulses of the control step (deterministic: the envs in
    parallel, each env's particles in the order of the active list):

    * into each collider's reaction, -J about the collider's end origin;
    * into the reaction on each particle's link, +J about the link's end origin, per
      contact pair (row ``link * n_slot + slot``, the slot the collider's number among its
      env's, ``n_slot - 1`` what came from the other field): the layer is taken as massless
      (quasi-static), so what its particles receive from an object passes to the link that
      holds them, and a pad's link and the object it presses take equal and opposite
      impulses. Column 6 of a pair row is its indentation [m]: the largest displacement of
      a touching particle from its rest place on the link (X0), along the push it received.
    """
    for e in range(n_env):
        for ii in range(sums.env_rows[e], sums.env_rows[e + 1]):
            p = active[ii]
            c = P.contact_id[p]
            if c >= 0:
                J = -P.impulse[p]  # what the particle exerted on the collider
                t1 = ti.Vector([sums.col_ends[c, 7], sums.col_ends[c, 8], sums.col_ends[c, 9]])
                tq = (P.x[p] - t1).cross(J)
                for d in ti.static(range(3)):
                    sums.col_sums[c, d] += J[d]
                    sums.col_sums[c, 3 + d] += tq[d]
            lk = P.link[p]
            if c != -1 and lk >= 0:
                R, o = pose_at(sums.link_ends, lk, 1.0)
                tq = (P.x[p] - o).cross(P.impulse[p])
                row = lk * n_slot + (sums.col_slot[c] if c >= 0 else n_slot - 1)
                for d in ti.static(range(3)):
                    sums.pair_sums[row, d] += P.impulse[p][d]
                    sums.pair_sums[row, 3 + d] += tq[d]
                push = P.impulse[p].norm()
                if push > 0.0:
                    depth = (P.x[p] - (R @ X0[p] + o)).dot(P.impulse[p]) / push
                    sums.pair_sums[row, 6] = ti.max(sums.pair_sums[row, 6], depth)


Placement = ti.types.argpack(  # what prepare reads and writes
    x=NDV, v=NDV, C=NDM, X0=NDV, link=NDI,  # particle state; rest coords in the link frame
    counts=NDI, consts=NDF,
    link_poses=NDF2, link_frames=NDF2, col_poses=NDF2, col_frames=NDF2,  # pose rows -> frame rows
    group_bind=NDF2, group_link=NDI, group_frames=NDF2,  # binding quaternion and link of each group
    active=NDI, kin=NDI,  # awake particles (counts[N_ACTIVE]), the kinematic ones among them (counts[N_KIN])
    bounds=NDI2, slab_of=NDI, cursor=NDI, order=NDI, slab_start=NDI, active_box=NDI)  # slab sort


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
    builds a returned vector in Python (~0.25 ms per call under cProfile), a scalar it reads
    in one call.
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
    write_binding_frames(W.link_frames, W.group_bind, W.group_link, W.counts[N_GROUPS], W.group_frames,
                         ti.static(not atomic))
    kinematic_update(W.kin, W.counts[N_KIN], W.x, W.v, W.C, W.X0, W.link, W.link_frames, dt)
    chunk_bounds(W.active, n, W.x, inv_dx, NCHUNK, W.bounds)
    lo = ti.Vector([BIG, BIG, BIG])
    hi = ti.Vector([-BIG, -BIG, -BIG])
    for c in ti.static(range(NCHUNK)):  # tiny reduction, unrolled (serial)
        for d in ti.static(range(3)):
            lo[d] = ti.min(lo[d], W.bounds[c, d])
            hi[d] = ti.max(hi[d], W.bounds[c, 3 + d])
    dims = hi - lo + 3 + 2 * margin
    # slabs across the longer of the grid's two slow axes (x, y; the layout is z-fastest): two
    # threads' slabs then write separate runs of memory. Slabs along z interleave their nodes
    # in the same cache lines, and that false sharing cost the CPU's second thread all its gain.
    axis = 0 if dims[0] >= dims[1] else 1
    n_slabs = (hi[axis] - lo[axis]) // 2 + 1
    if n_slabs < 1 or n_slabs + 1 > SLAB_CAP:  # too wide, or int overflow from a NaN position
        n_slabs = -1
    elif ti.static(atomic):
        W.slab_start[0] = 0
        W.slab_start[n_slabs] = n  # the atomic scatter loops run over slab_start[n_slabs] particles
    else:
        sort_into_slabs(W.active, n, W.x, inv_dx, axis, lo[axis], n_slabs, W.slab_of,
                        W.slab_start, W.cursor, W.order)
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
    (contact between the two fields), collider contact, G2P.

    ``contact_mode``: 0 no colliders, 1 particle-detected (grid-applied), 2 grid nodes.
    ``nh_only``: every material is Neo-Hookean (no SVD compiled in).
    ``two_field``: groups of both velocity fields are awake (the grid arrays hold 2 boxes).
    ``atomic``: scatter with atomic adds, one thread per particle (GPUs), not by slabs.
    ``cellp``: 0, or the most CG iterations of the cells' volume term (:func:`pressure_solve`).
    """
    substep(W.P, W.G, W.S, W.O, dt, fbar, contact_mode, nh_only, two_field, atomic, cellp)


@ti.func
def substep(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), dt,
            fbar: ti.template(), contact_mode: ti.template(), nh_only: ti.template(), two_field: ti.template(),
            atomic: ti.template(), cellp: ti.template()):
    """Body of :func:`advance` on the packs of its World (P, G, S, O)."""
    dx = S.consts[DX]
    inv_dx = 1.0 / dx
    gravity = ti.Vector([S.consts[GX], S.consts[GY], S.consts[GZ]])
    damping = ti.exp(-S.consts[DAMPING] * dt)  # global velocity damping factor
    max_push = 0.3 * dx / dt  # cap of a contact's normal velocity change [m/s]
    reach = dx + S.consts[REACH]  # particles farther than this from a collider skip it [m]
    n, n_col, n_walls, n_env = S.counts[N_ACTIVE], S.counts[N_COL], S.counts[N_WALLS], S.counts[N_ENVS]
    ox, oy, oz = O.active_box[0], O.active_box[1], O.active_box[2]
    ny, nz, n_slabs = O.active_box[4], O.active_box[5], O.active_box[6]
    ncell = O.active_box[3] * ny * nz
    ntot = ncell * n_env * (2 if ti.static(two_field) else 1)  # every env's box, of each field
    clear_grid(ntot, G.grid_pm, G.grid_mq, G.grid_dp, G.grid_vol, G.grid_vc, G.grid_ds,
               G.grid_kin, two_field, cellp, G.cell_slot)
    if ti.static(cellp):
        number_cells(P, S, G, O, ntot, ncell, ny, nz, inv_dx, ti.Vector([ox, oy, oz]), two_field)
    if ti.static(fbar):
        volume_scatter(O.order, O.slab_start, n_slabs, P.x, P.F, P.vol, P.kind, P.matid, S.mat_table, ox, oy, oz,
                       ny, nz, inv_dx, G.grid_vol, P.group, S.group_copy, ncell, two_field, atomic)
        nodal_volume_change(ntot, G.grid_vol)
    p2g(gravity, O.order, O.slab_start, n_slabs, P.x, P.v, P.C, P.F, P.tau, P.Jp, P.mass, P.vol, P.kind,
        P.link, P.matid, S.mat_table, P.group, S.group_qs, ox, oy, oz, ny, nz, inv_dx, dt,
        G.grid_pm, G.grid_mq, G.grid_link, G.grid_vol, fbar, nh_only,
        S.group_copy, ncell, two_field, G.grid_vc, P.bond, S.link_frames, G.grid_kin, atomic,
        cellp, G.cell_slot, G.cell_a, G.cell_G)
    grid_update(ntot, ncell, ox, oy, oz, ny, nz, dx, dt, damping, S.env_relax, n_env,
                G.grid_pm, G.grid_v, G.grid_m, G.grid_kin, G.grid_mq, G.grid_link, S.link_frames, S.walls, n_walls,
                1 if ti.static(contact_mode == 2) else 0, n_col, S.col_kind, S.col_prm, S.col_frames,
                S.col_friction, S.sdf, S.sdf_info, S.col_impulse, S.col_env)
    nx = O.active_box[3]
    # cells the bond's ghost nodes visit: none without a bond. A loop count, not an `if` around
    # the loop: Taichi runs a loop under a run-time `if` serially (one GPU thread, 4.5 ms a
    # substep on an H100 for the index pad, 95 % of its substep)
    n_bond = ti.select(S.consts[BOND] > 0.0, ntot, 0)
    bond_ghosts(n_bond, ncell, ox, oy, oz, nx, ny, nz, dx, dt, G.grid_v, G.grid_m, G.grid_kin,
                G.grid_link, S.link_frames)
    if ti.static(cellp):
        pressure_solve(G, S, ti.Vector([ntot, ncell, ny, nz, ox, oy, oz]), dt, inv_dx, cellp, atomic)
        # the pressure moved free nodes near the bond: the ghosts follow
        bond_ghosts(n_bond, ncell, ox, oy, oz, nx, ny, nz, dx, dt, G.grid_v, G.grid_m, G.grid_kin,
                    G.grid_link, S.link_frames)
    if ti.static(two_field):
        field_contact(ncell * n_env, ny, nz, dx, S.consts[FIELD_MU], G.grid_v, G.grid_m, G.grid_kin, G.grid_vc,
                      G.grid_ds)
    if ti.static(contact_mode == 1):
        contact_scatter(O.order, O.slab_start, n_slabs, P.x, P.kind, P.mass, P.radius, P.impulse,
                        P.contact_id, ox, oy, oz, ny, nz, inv_dx, dt, G.grid_v, G.grid_m, G.grid_kin, G.grid_dp,
                        n_col, S.col_kind, S.col_prm, S.col_frames, S.col_friction, S.sdf, S.sdf_info,
                        max_push, reach, P.group, S.group_copy, ncell, two_field, atomic, P.anchor, S.group_env,
                        S.col_env, S.col_bound)
        contact_apply(ntot, ncell, ox, oy, oz, ny, nz, dx, G.grid_v, G.grid_m, G.grid_kin, G.grid_dp, S.walls,
                      n_walls)
        # the contact moved free nodes near the bond: the ghosts follow
        bond_ghosts(n_bond, ncell, ox, oy, oz, nx, ny, nz, dx, dt, G.grid_v, G.grid_m, G.grid_kin,
                    G.grid_link, S.link_frames)
    g2p(nh_only, O.order, n, P.x, P.v, P.C, P.F, P.tau, P.Jp, P.kind, P.matid, S.mat_table, P.group,
        S.group_frames, ox, oy, oz, ny, nz, inv_dx, dt, G.grid_v, G.grid_m, G.grid_kin, fbar,
        S.group_copy, S.group_field, ncell, two_field, G.grid_ds, P.mass, P.impulse, P.contact_id, cellp)


@cached_kernel
@ti.kernel
def fbar_update(W: World, nh_only: ti.template(), two_field: ti.template(), atomic: ti.template(),
                fbar: ti.template(), cellp: ti.template()):
    """The stress of every particle at its current F and position (F-bar; the whole
    Neo-Hookean stress where the volume term is solved on cells), on the box from
    :func:`prepare`: the substeps evaluate it in P2G, this leaves it current after a step."""
    stress_pass(W.P, W.G, W.S, W.O, nh_only, two_field, atomic, fbar, cellp)


@ti.func
def stress_pass(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), nh_only: ti.template(),
                two_field: ti.template(), atomic: ti.template(), fbar: ti.template(), cellp: ti.template()):
    """Body of :func:`fbar_update`."""
    inv_dx = 1.0 / S.consts[DX]
    ox, oy, oz = O.active_box[0], O.active_box[1], O.active_box[2]
    ny, nz = O.active_box[4], O.active_box[5]
    ncell = O.active_box[3] * ny * nz
    if ti.static(fbar):
        ntot = ncell * S.counts[N_ENVS] * (2 if ti.static(two_field) else 1)  # every env's box, of each field
        for i in range(ntot):
            G.grid_vol[i] = ti.Vector([0.0, 0.0])
        volume_scatter(O.order, O.slab_start, O.active_box[6], P.x, P.F, P.vol, P.kind, P.matid, S.mat_table,
                       ox, oy, oz, ny, nz, inv_dx, G.grid_vol, P.group, S.group_copy, ncell, two_field, atomic)
        nodal_volume_change(ntot, G.grid_vol)
    report_stress(nh_only, fbar, cellp, O.order, S.counts[N_ACTIVE], P.x, P.F, P.tau, P.Jp, P.matid, S.mat_table,
                ox, oy, oz, ny, nz, inv_dx, G.grid_vol, P.group, S.group_copy, ncell, two_field)
