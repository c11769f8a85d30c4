"""Taichi kernels of one MLS-MPM substep (APIC transfers, quadratic B-splines).

All kernels take ``ti.types.ndarray`` arguments, so one compiled set serves every
:class:`~gausstac_maniskill.mpm.solver.MPMWorld` in the process, on cpu and cuda.

The grid is a dense box that covers only the active particles (plus a margin);
node (i, j, k) of the box sits at world position ``(origin + (i, j, k)) * dx`` and is
stored at flat index ``(i * ny + j) * nz + k``.

Particle-to-grid without atomics: particles are counting-sorted into *slabs* two
cells thick along the grid's longest axis. A particle whose stencil base cell is
b touches nodes b..b+2, so slabs s and s+2 never write the same node; the even
slabs are scattered in parallel, then the odd ones. Within a slab particles are
visited in a fixed order, which makes a substep bit-reproducible for any number
of threads.
"""

import taichi as ti

from . import materials as mat
from .colliders import collider_contact
from .kinematics import pose_at, quat_to_mat

vec3 = ti.math.vec3
mat3 = ti.math.mat3
NDI = ti.types.ndarray(dtype=ti.i32, ndim=1)
NDI2 = ti.types.ndarray(dtype=ti.i32, ndim=2)
NDF = ti.types.ndarray(dtype=ti.f32, ndim=1)
NDF2 = ti.types.ndarray(dtype=ti.f32, ndim=2)
NDV = ti.types.ndarray(dtype=vec3, ndim=1)
NDM = ti.types.ndarray(dtype=mat3, ndim=1)

DYNAMIC, KINEMATIC = 0, 1
PIN_FRACTION = 0.25  # kinematic share of a node's mass that pins it to its link (see pinned)
BIG = 1 << 29
NCHUNK = 16  # particle chunks of the bounds/health reductions (rows of their output arrays)


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
        link_poses: ti.template(), alpha0: ti.template(), alpha1: ti.template(), dt: ti.template()):
    """Place kinematic particles on their link at fraction alpha0 of the control step.

    Their velocity is the finite difference of the link transform over this substep
    applied to the rest coordinate X0 (link frame) and C is the matching velocity gradient
    (R1 - R0) R0ᵀ / Δt. Their F and stress are left to :func:`g2p` (bound particles next
    to the soft layer strain with it).
    """
    for ii in range(n):
        p = kin[ii]
        l = link[p]
        R0, t0 = pose_at(link_poses, l, alpha0)
        R1, t1 = pose_at(link_poses, l, alpha1)
        x0 = R0 @ X0[p] + t0
        x[p] = x0
        v[p] = (R1 @ X0[p] + t1 - x0) / dt
        C[p] = (R1 - R0) @ R0.transpose() / dt


@ti.func
def link_motion_at(link_poses: ti.template(), l, xi, alpha0, alpha1, dt):
    """Rigid motion of link ``l`` over the substep [alpha0, alpha1] at world point xi:
    (velocity [m/s], angular velocity ω [rad/s], link origin at alpha0)."""
    R0, t0 = pose_at(link_poses, l, alpha0)
    R1, t1 = pose_at(link_poses, l, alpha1)
    W = R1 @ R0.transpose()
    omega = 0.5 / dt * ti.Vector([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]])
    return (R1 @ (R0.transpose() @ (xi - t0)) + t1 - xi) / dt, omega, t0


@ti.func
def chunk_bounds(active: ti.template(), n: ti.template(), x: ti.template(),
        inv_dx: ti.template(), nchunk: ti.template(), out: ti.template()):
    """Per chunk of particles, min/max of the stencil base cell (out[c] = lo xyz, hi xyz)."""
    ti.loop_config(block_dim=1)
    for c in range(nchunk):
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
def clear_grid(ncell: ti.template(), grid_v: ti.template(), grid_m: ti.template(),
        grid_mk: ti.template(), grid_mq: ti.template(), grid_dp: ti.template(), grid_vol: ti.template()):
    for i in range(ncell):
        grid_v[i] = vec3(0.0)
        grid_dp[i] = vec3(0.0)
        grid_vol[i] = ti.Vector([0.0, 0.0])
        grid_m[i] = 0.0
        grid_mk[i] = 0.0
        grid_mq[i] = 0.0


@ti.func
def p2g(gravity: ti.template(), order: ti.template(), slab_start: ti.template(), n_slabs: ti.template(),
        x: ti.template(), v: ti.template(), C: ti.template(), tau: ti.template(),
        mass: ti.template(), vol: ti.template(), kind: ti.template(), link: ti.template(),
        matid: ti.template(), mat_table: ti.template(), group: ti.template(), group_qs: ti.template(),
        ox: ti.template(), oy: ti.template(), oz: ti.template(), ny: ti.template(),
        nz: ti.template(), inv_dx: ti.template(), dt: ti.template(), grid_v: ti.template(),
        grid_m: ti.template(), grid_mk: ti.template(), grid_mq: ti.template(), grid_link: ti.template()):
    """Scatter mass and APIC momentum (with the stress impulse) to the grid.

    Momentum to node i: w_ip [m_p v_p + (m_p C_p - Δt V0_p (4/dx²) τ_p)(x_i - x_p)].
    Kinematic particles also scatter their mass to ``grid_mk`` and their link id;
    dynamic particles of quasi-static groups scatter theirs to ``grid_mq`` (and the link id).
    """
    origin = ti.Vector([ox, oy, oz])
    for color in ti.static(range(2)):
        ti.loop_config(block_dim=1)
        for h in range((n_slabs - color + 1) // 2):
            s = 2 * h + color
            for ii in range(slab_start[s], slab_start[s + 1]):
                p = order[ii]
                base, fx, w = stencil(x[p], inv_dx, origin)
                m = mass[p]
                affine = m * C[p] - (dt * vol[p] * 4.0 * inv_dx * inv_dx) * tau[p]
                # momentum plus this substep's weight impulse; weight is the physical mass
                # ρ V0 (a quasi-static group's pseudo-mass slows its inertia, not its weight)
                mv = m * v[p] + (dt * vol[p] * mat_table[matid[p], 6]) * gravity
                is_kin = kind[p] == KINEMATIC
                is_qs = (not is_kin) and group_qs[group[p]] > 0
                lk = link[p]
                for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                    dpos = (ti.Vector([i, j, k]) - fx) / inv_dx
                    weight = w[i][0] * w[j][1] * w[k][2]
                    idx = ((base[0] + i) * ny + base[1] + j) * nz + base[2] + k
                    # plain read-modify-write: slabs of one colour never share a node
                    grid_v[idx] = grid_v[idx] + weight * (mv + affine @ dpos)
                    grid_m[idx] = grid_m[idx] + weight * m
                    if is_kin:
                        grid_mk[idx] = grid_mk[idx] + weight * m
                        grid_link[idx] = lk
                    elif is_qs:
                        grid_mq[idx] = grid_mq[idx] + weight * m
                        grid_link[idx] = lk


@ti.func
def grid_update(ncell: ti.template(), ox: ti.template(), oy: ti.template(),
        oz: ti.template(), ny: ti.template(), nz: ti.template(), dx: ti.template(),
        dt: ti.template(), gx: ti.template(), gy: ti.template(), gz: ti.template(),
        damping: ti.template(), relax: ti.template(), grid_v: ti.template(), grid_m: ti.template(),
        grid_mk: ti.template(), grid_mq: ti.template(), grid_link: ti.template(), link_poses: ti.template(),
        alpha0: ti.template(), alpha1: ti.template(), walls: ti.template(),
        n_walls: ti.template(), grid_contact: ti.template(), n_col: ti.template(),
        col_kind: ti.template(), col_prm: ti.template(), col_pose: ti.template(),
        col_mu: ti.template(), col_sticky: ti.template(), sdf: ti.template(),
        sdf_info: ti.template(), col_impulse: ti.template()):
    """Momentum -> velocity, damping, then boundary conditions per node (gravity is in P2G).

    * Nodes where kinematic mass is at least half the node mass move exactly with
      their link (Dirichlet), so a kinematic layer is rigid, not a viscous drag.
    * Nodes where most mass belongs to quasi-static groups (pads) relax towards
      equilibrium: their velocity *relative to the link's rigid motion* is scaled by
      ``relax`` = exp(-ζ Δt) (dynamic relaxation; a pad carried by a moving hand is
      not dragged, only its elastic ringing decays).
    * Slip walls (symmetry planes): the normal velocity of nodes on or beyond the
      wall is zeroed (bilateral).
    * With ``grid_contact`` set, colliders are enforced here on nodes with φ < 0
      (unilateral, Coulomb friction) and their reaction impulse is accumulated.
    """
    g = ti.Vector([gx, gy, gz])
    for idx in range(ncell):
        m = grid_m[idx]
        if m > 0.0:
            k = idx % nz
            j = (idx // nz) % ny
            i = idx // (ny * nz)
            xi = ti.Vector([ox + i, oy + j, oz + k], ti.f32) * dx
            vel = grid_v[idx] / m
            vel *= damping
            if pinned(grid_m, grid_mk, idx):
                vel, _omega, _t0 = link_motion_at(link_poses, grid_link[idx], xi, alpha0, alpha1, dt)
            else:
                if grid_mq[idx] >= 0.5 * m:
                    # the link's rigid velocity here, and its centripetal acceleration
                    # ω × (ω × r): the pseudo-mass must not turn a spinning hand into a load
                    v_link, omega, t0 = link_motion_at(link_poses, grid_link[idx], xi, alpha0, alpha1, dt)
                    vel += dt * omega.cross(omega.cross(xi - t0))
                    vel = v_link + relax * (vel - v_link)
                for w in range(n_walls):
                    ax = ti.cast(walls[w, 0], ti.i32)
                    if walls[w, 2] * (xi[ax] - walls[w, 1]) <= 1e-9:
                        vel[ax] = 0.0
                if grid_contact:
                    for c in range(n_col):
                        phi, nrm, vc = collider_contact(col_kind, col_prm, col_pose, sdf, sdf_info,
                                                        c, xi, alpha0, alpha1, dt)
                        if phi < 0.0:
                            vrel = vel - vc
                            vn = vrel.dot(nrm)
                            if vn < 0.0:
                                vt = vrel - vn * nrm
                                vtn = vt.norm()
                                if col_sticky[c] or vtn <= -col_mu[c] * vn:
                                    vt = vec3(0.0)
                                else:
                                    vt *= 1.0 + col_mu[c] * vn / vtn
                                new_vel = vc + vt
                                dp = m * (new_vel - vel)
                                ti.atomic_add(col_impulse[c, 0], -dp[0])
                                ti.atomic_add(col_impulse[c, 1], -dp[1])
                                ti.atomic_add(col_impulse[c, 2], -dp[2])
                                R1, t1 = pose_at(col_pose, c, alpha1)
                                tq = (xi - t1).cross(-dp)
                                ti.atomic_add(col_impulse[c, 3], tq[0])
                                ti.atomic_add(col_impulse[c, 4], tq[1])
                                ti.atomic_add(col_impulse[c, 5], tq[2])
                                vel = new_vel
            grid_v[idx] = vel


@ti.func
def pinned(grid_m: ti.template(), grid_mk: ti.template(), idx):
    """A node moves rigidly with its link when kinematic particles bring at least
    PIN_FRACTION of its mass (Dirichlet; see :func:`grid_update`)."""
    return grid_mk[idx] >= PIN_FRACTION * grid_m[idx]


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
def binding_rotation(link_poses: ti.template(), group_bind: ti.template(), l, g, alpha):
    """Rotation of link ``l`` at fraction alpha of the step relative to the pose its group
    ``g`` was bound at: the rigid part of a bound particle's deformation gradient."""
    R, _t = pose_at(link_poses, l, alpha)
    Rb = quat_to_mat(ti.Vector([group_bind[g, 0], group_bind[g, 1], group_bind[g, 2], group_bind[g, 3]]))
    return R @ Rb.transpose()


@ti.func
def g2p(nh_only: ti.template(), order: ti.template(), n: ti.template(), x: ti.template(), v: ti.template(),
        C: ti.template(), F: ti.template(), tau: ti.template(), Jp: ti.template(),
        kind: ti.template(), matid: ti.template(), mat_table: ti.template(), link: ti.template(),
        group: ti.template(), link_poses: ti.template(), group_bind: ti.template(),
        alpha0: ti.template(), alpha1: ti.template(), ox: ti.template(),
        oy: ti.template(), oz: ti.template(), ny: ti.template(), nz: ti.template(),
        inv_dx: ti.template(), dt: ti.template(), grid_v: ti.template(), grid_m: ti.template(),
        grid_mk: ti.template(), fbar: ti.template()):
    """Gather velocity and its gradient, update F (and plasticity) and stress, advect.

    Bound (kinematic) particles keep their link-given position and velocity, but strain
    with the grid like the material they belong to: F = Q1 (I + Δt Q0ᵀ(∇v - ∇v_link) Q0) Q0ᵀ F,
    Q the link's rotation since binding (rigid motion exactly, no drift). Their stress
    completes the quadrature of the free nodes next to the bond, so the soft layer is held
    where its bound particles are, not a cell deeper (``bench thinlayer``). Where every
    node of the stencil is pinned, F is the rotation Q1 and the stress zero.
    With ``fbar`` the stress is left to :func:`fbar_stress`.
    """
    origin = ti.Vector([ox, oy, oz])
    for ii in range(n):
        p = order[ii]
        is_kin = kind[p] == KINEMATIC
        base, fx, w = stencil(x[p], inv_dx, origin)
        new_v = vec3(0.0)
        new_C = ti.Matrix.zero(ti.f32, 3, 3)
        all_pinned = True
        for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
            dpos = ti.Vector([i, j, k]) - fx
            weight = w[i][0] * w[j][1] * w[k][2]
            idx = ((base[0] + i) * ny + base[1] + j) * nz + base[2] + k
            gv = grid_v[idx]
            new_v += weight * gv
            new_C += (4.0 * inv_dx * weight) * gv.outer_product(dpos)
            if is_kin:
                all_pinned = all_pinned and pinned(grid_m, grid_mk, idx)
        mi = matid[p]
        if not is_kin:
            # deformation gradient: F <- (I + Δt ∇v) F, then the material's return map
            Fn = (ti.Matrix.identity(ti.f32, 3) + dt * new_C) @ F[p]
            jp = Jp[p]
            if ti.static(not nh_only):
                if ti.cast(mat_table[mi, 2], ti.i32) == mat.FOAM:
                    Fn, jp = mat.plastic_return(Fn, jp, mat_table[mi, 3], mat_table[mi, 4])
            if ti.static(not fbar):
                tau[p] = elastic_stress(nh_only, Fn, jp, mi, mat_table)
            v[p] = new_v
            C[p] = new_C
            F[p] = Fn
            Jp[p] = jp
            x[p] = x[p] + dt * new_v
        else:
            l, g = link[p], group[p]
            Q1 = binding_rotation(link_poses, group_bind, l, g, alpha1)
            if all_pinned:
                F[p] = Q1
                tau[p] = ti.Matrix.zero(ti.f32, 3, 3)
            else:
                Q0 = binding_rotation(link_poses, group_bind, l, g, alpha0)
                # C[p] is the link's rigid velocity gradient (kinematic_update)
                strain_rate = Q0.transpose() @ (new_C - C[p]) @ Q0
                Fn = Q1 @ (ti.Matrix.identity(ti.f32, 3) + dt * strain_rate) @ Q0.transpose() @ F[p]
                F[p] = Fn
                if ti.static(not fbar):
                    tau[p] = elastic_stress(nh_only, Fn, Jp[p], mi, mat_table)


@ti.func
def volume_scatter(order: ti.template(), slab_start: ti.template(), n_slabs: ti.template(),
        x: ti.template(), F: ti.template(), vol: ti.template(), kind: ti.template(), ox: ti.template(),
        oy: ti.template(), oz: ti.template(), ny: ti.template(), nz: ti.template(), inv_dx: ti.template(),
        grid_vol: ti.template()):
    """F-bar, step 1: each node gathers the rest volume Σ w V0 and the deformed volume
    Σ w V0 J of the particles around it (slab-ordered like :func:`p2g`)."""
    origin = ti.Vector([ox, oy, oz])
    for color in ti.static(range(2)):
        ti.loop_config(block_dim=1)
        for h in range((n_slabs - color + 1) // 2):
            s = 2 * h + color
            for ii in range(slab_start[s], slab_start[s + 1]):
                p = order[ii]
                if kind[p] == DYNAMIC:
                    base, fx, w = stencil(x[p], inv_dx, origin)
                    vj = vol[p] * ti.Vector([1.0, F[p].determinant()])
                    for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                        idx = ((base[0] + i) * ny + base[1] + j) * nz + base[2] + k
                        grid_vol[idx] = grid_vol[idx] + (w[i][0] * w[j][1] * w[k][2]) * vj


@ti.func
def fbar_stress(nh_only: ti.template(), order: ti.template(), n: ti.template(), x: ti.template(),
        F: ti.template(), tau: ti.template(), Jp: ti.template(), matid: ti.template(),
        mat_table: ti.template(), ox: ti.template(), oy: ti.template(), oz: ti.template(),
        ny: ti.template(), nz: ti.template(), inv_dx: ti.template(), grid_vol: ti.template()):
    """F-bar, step 2 (anti-locking for ν → 0.5): the λ (bulk) term of the stress is
    evaluated at the grid-smoothed volume change J̄ = Σ_i w_ip J_i, J_i = (Σ w V0 J)_i /
    (Σ w V0)_i, instead of the particle's own J; the μ terms keep the particle's F. One
    bulk constraint per node instead of one per particle, so a nearly incompressible
    material is not over-constrained (volumetric locking). This is the selective form of
    F-bar / J-bar (de Souza Neto et al. 1996; for MPM, Coombs et al. 2018): replacing the
    whole F by (J̄/J)^{1/3} F was tried and lets particles trade volume at no cost (a pad
    crept 7 µm after contact); the μ terms' own volume stiffness stops that."""
    origin = ti.Vector([ox, oy, oz])
    for ii in range(n):
        p = order[ii]
        base, fx, w = stencil(x[p], inv_dx, origin)
        Fp = F[p]
        J = ti.max(Fp.determinant(), mat.MIN_J)
        J_sum, w_sum = 0.0, 0.0
        for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
            gv = grid_vol[((base[0] + i) * ny + base[1] + j) * nz + base[2] + k]
            if gv[0] > 0.0:
                weight = w[i][0] * w[j][1] * w[k][2]
                J_sum += weight * gv[1] / gv[0]
                w_sum += weight
        J_bar = J if w_sum <= 0.0 else J_sum / w_sum
        mi = matid[p]
        dp = mat.volumetric_stress(nh_only, ti.max(J_bar, mat.MIN_J), Jp[p], mi, mat_table) - \
            mat.volumetric_stress(nh_only, J, Jp[p], mi, mat_table)
        tau[p] = elastic_stress(nh_only, Fp, Jp[p], mi, mat_table) + dp * ti.Matrix.identity(ti.f32, 3)


@ti.func
def contact_scatter(order: ti.template(), slab_start: ti.template(),
        n_slabs: ti.template(), x: ti.template(), kind: ti.template(), mass: ti.template(),
        radius: ti.template(), impulse: ti.template(), contact_id: ti.template(),
        ox: ti.template(), oy: ti.template(), oz: ti.template(), ny: ti.template(),
        nz: ti.template(), inv_dx: ti.template(), dt: ti.template(), grid_v: ti.template(),
        grid_m: ti.template(), grid_mk: ti.template(),
        grid_dp: ti.template(), n_col: ti.template(), col_kind: ti.template(),
        col_prm: ti.template(), col_pose: ti.template(), col_mu: ti.template(),
        col_sticky: ti.template(), sdf: ti.template(), sdf_info: ti.template(),
        alpha0: ti.template(), alpha1: ti.template(), max_push: ti.template(),
        reach: ti.template()):
    """Particle-detected contact, applied as momentum on the grid.

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
    Slab-ordered like :func:`p2g`, hence atomic-free and deterministic.
    """
    origin = ti.Vector([ox, oy, oz])
    for color in ti.static(range(2)):
        ti.loop_config(block_dim=1)
        for h in range((n_slabs - color + 1) // 2):
            s = 2 * h + color
            for ii in range(slab_start[s], slab_start[s + 1]):
                p = order[ii]
                if kind[p] == DYNAMIC:
                    near = False
                    for c in range(n_col):
                        phi, nrm, vc = collider_contact(col_kind, col_prm, col_pose, sdf, sdf_info,
                                                        c, x[p], alpha0, alpha1, dt)
                        if phi - radius[p] < reach:
                            near = True
                    if near:
                        base, fx, w = stencil(x[p], inv_dx, origin)
                        v0 = vec3(0.0)
                        for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                            v0 += w[i][0] * w[j][1] * w[k][2] * grid_v[((base[0] + i) * ny + base[1] + j) * nz + base[2] + k]
                        vp = v0
                        for c in range(n_col):
                            phi, nrm, vc = collider_contact(col_kind, col_prm, col_pose, sdf, sdf_info,
                                                            c, x[p] + dt * vp, alpha0, alpha1, dt)
                            gap = phi - radius[p]
                            if gap < 0.0:
                                dvn = ti.min(-gap / dt, max_push)
                                vrel = vp - vc
                                vt = vrel - vrel.dot(nrm) * nrm
                                vtn = vt.norm()
                                dvt = vec3(0.0)
                                if col_sticky[c] or vtn <= col_mu[c] * dvn:
                                    dvt = -vt
                                else:
                                    dvt = -(col_mu[c] * dvn / vtn) * vt
                                vp = vp + dvn * nrm + dvt
                                contact_id[p] = c
                        if contact_id[p] >= 0:
                            J = mass[p] * (vp - v0)
                            free = 0.0
                            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                                idx = ((base[0] + i) * ny + base[1] + j) * nz + base[2] + k
                                wi = w[i][0] * w[j][1] * w[k][2]
                                grid_dp[idx] = grid_dp[idx] + wi * J
                                if not pinned(grid_m, grid_mk, idx):
                                    free += wi
                            impulse[p] += free * J


@ti.func
def contact_apply(ncell: ti.template(), ox: ti.template(), oy: ti.template(),
        oz: ti.template(), ny: ti.template(), nz: ti.template(), dx: ti.template(),
        grid_v: ti.template(), grid_m: ti.template(), grid_mk: ti.template(),
        grid_dp: ti.template(), walls: ti.template(), n_walls: ti.template()):
    """Add the scattered contact momentum to free nodes (not pinned, walls kept)."""
    for idx in range(ncell):
        m = grid_m[idx]
        dp = grid_dp[idx]
        if m > 0.0 and not pinned(grid_m, grid_mk, idx) and dp.norm_sqr() > 0.0:
            k = idx % nz
            j = (idx // nz) % ny
            i = idx // (ny * nz)
            xi = ti.Vector([ox + i, oy + j, oz + k], ti.f32) * dx
            dv = dp / m
            for w in range(n_walls):
                ax = ti.cast(walls[w, 0], ti.i32)
                if walls[w, 2] * (xi[ax] - walls[w, 1]) <= 1e-9:
                    dv[ax] = 0.0
            grid_v[idx] = grid_v[idx] + dv


@ti.kernel
def reduce_contact(active: NDI, n: ti.i32, x: NDV, impulse: NDV, contact_id: NDI,
                   col_pose: NDF2, col_impulse: NDF2):
    """Sum per-particle contact impulses into each collider's reaction (deterministic)."""
    ti.loop_config(serialize=True)
    for ii in range(n):
        p = active[ii]
        c = contact_id[p]
        if c >= 0:
            J = -impulse[p]  # what the particle exerted on the collider
            t1 = ti.Vector([col_pose[c, 7], col_pose[c, 8], col_pose[c, 9]])
            tq = (x[p] - t1).cross(J)
            for d in ti.static(range(3)):
                col_impulse[c, d] += J[d]
                col_impulse[c, 3 + d] += tq[d]


@ti.kernel
def place_kinematic(kin: NDI, n: ti.i32, x: NDV, v: NDV, C: NDM, X0: NDV, link: NDI,
                    link_poses: NDF2, dt: ti.f32):
    """Put kinematic particles on their link's pose at the end of the control step (the
    substeps place them at each substep's start, one substep behind the link)."""
    kinematic_update(kin, n, x, v, C, X0, link, link_poses, 1.0, 1.0 + 1e-6, dt)


@ti.kernel
def follow_links(active: NDI, n: ti.i32, v: NDV, C: NDM, x: NDV, kind: NDI, link: NDI, group: NDI,
                 group_qs: NDI, twist_change: NDF2):
    """Carry quasi-static particles through their link's change of rigid velocity.

    A pad's pseudo-mass must resist only its deformation, not the hand's acceleration.
    Link motion is piecewise uniform (constant linear and angular velocity within a
    control step), so the link accelerates only between steps; there each dynamic
    particle of a quasi-static group takes the change of the link's rigid velocity
    field, Δv(x) = Δv_o + Δω × (x - o), and its APIC gradient the change [Δω]×.
    ``twist_change`` rows: (Δv_o xyz, Δω xyz, o xyz), o the link origin.
    The solver skips the call after a step with collider contact: there the jump would
    reach the object as a pseudo-mass impulse.
    """
    for ii in range(n):
        p = active[ii]
        l = link[p]
        if kind[p] == DYNAMIC and l >= 0 and group_qs[group[p]] > 0:
            dv = ti.Vector([twist_change[l, 0], twist_change[l, 1], twist_change[l, 2]])
            dw = ti.Vector([twist_change[l, 3], twist_change[l, 4], twist_change[l, 5]])
            o = ti.Vector([twist_change[l, 6], twist_change[l, 7], twist_change[l, 8]])
            v[p] += dv + dw.cross(x[p] - o)
            C[p] += ti.Matrix([[0.0, -dw[2], dw[1]], [dw[2], 0.0, -dw[0]], [-dw[1], dw[0], 0.0]])


@ti.kernel
def reset_contact(active: NDI, n: ti.i32, impulse: NDV, contact_id: NDI):
    for ii in range(n):
        p = active[ii]
        impulse[p] = vec3(0.0)
        contact_id[p] = -1


@ti.kernel
def chunk_health(active: NDI, n: ti.i32, x: NDV, v: NDV, F: NDM, kind: NDI, nchunk: ti.i32,
                 first_bad: NDI, vmax: NDF):
    """Per chunk: first particle with a non-finite x, v or F (or -1), and max |v|."""
    ti.loop_config(block_dim=1)
    for c in range(nchunk):
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
def energies(active: NDI, n: ti.i32, v: NDV, F: NDM, Jp: NDF, kind: NDI, matid: NDI,
             mass: NDF, vol: NDF, mat_table: NDF2, out: NDF):
    """out[0] = kinetic energy [J] of dynamic particles, out[1] = elastic energy [J]."""
    out[0] = 0.0
    out[1] = 0.0
    for ii in range(n):
        p = active[ii]
        if kind[p] == DYNAMIC:
            mi = matid[p]
            out[0] += 0.5 * mass[p] * v[p].norm_sqr()
            out[1] += vol[p] * mat.strain_energy_density(
                F[p], Jp[p], mat_table[mi, 0], mat_table[mi, 1],
                ti.cast(mat_table[mi, 2], ti.i32), mat_table[mi, 5])


# --------------------------------------------------------------------------- fused substep
# Taichi spends ~10 µs per kernel argument on the Python side; a substep is therefore
# two launches: `prepare` (returns the active box by value) and `advance`.

BOX = ti.types.vector(8, ti.i32)


@ti.kernel
def prepare(active: NDI, n: ti.i32, kin: NDI, n_kin: ti.i32, x: NDV, v: NDV, C: NDM,
            X0: NDV, link: NDI, link_poses: NDF2,
            alpha0: ti.f32, alpha1: ti.f32, dt: ti.f32, inv_dx: ti.f32, margin: ti.i32,
            bounds: NDI2, slab_of: NDI, slab_start: NDI, cursor: NDI, order: NDI, slab_cap: ti.i32) -> BOX:
    """Move kinematic particles, find the active box, sort particles into slabs.

    Returns (origin xyz, dims xyz, number of slabs, slab axis); number of slabs is
    -1 if it would exceed ``slab_cap`` (nothing is sorted then).
    """
    kinematic_update(kin, n_kin, x, v, C, X0, link, link_poses, alpha0, alpha1, dt)
    chunk_bounds(active, n, x, inv_dx, NCHUNK, bounds)
    lo = ti.Vector([BIG, BIG, BIG])
    hi = ti.Vector([-BIG, -BIG, -BIG])
    for c in ti.static(range(NCHUNK)):  # tiny reduction, unrolled (serial)
        for d in ti.static(range(3)):
            lo[d] = ti.min(lo[d], bounds[c, d])
            hi[d] = ti.max(hi[d], bounds[c, 3 + d])
    dims = hi - lo + 3 + 2 * margin
    axis = 0
    if dims[1] > dims[axis]:
        axis = 1
    if dims[2] > dims[axis]:
        axis = 2
    n_slabs = (hi[axis] - lo[axis]) // 2 + 1
    if n_slabs + 1 > slab_cap:
        n_slabs = -1
    else:
        sort_into_slabs(active, n, x, inv_dx, axis, lo[axis], n_slabs, slab_of, slab_start, cursor, order)
    o = lo - margin
    return ti.Vector([o[0], o[1], o[2], dims[0], dims[1], dims[2], n_slabs, axis])


@ti.kernel
def advance(order: NDI, slab_start: NDI, n_slabs: ti.i32, n: ti.i32,
            x: NDV, v: NDV, C: NDM, F: NDM, tau: NDM, Jp: NDF,
            mass: NDF, vol: NDF, radius: NDF, kind: NDI, link: NDI, matid: NDI, mat_table: NDF2,
            impulse: NDV, contact_id: NDI,
            ox: ti.i32, oy: ti.i32, oz: ti.i32, nx: ti.i32, ny: ti.i32, nz: ti.i32,
            dx: ti.f32, dt: ti.f32, gravity: ti.math.vec3, damping: ti.f32, relax: ti.f32,
            group: NDI, group_qs: NDI,
            grid_v: NDV, grid_m: NDF, grid_mk: NDF, grid_mq: NDF, grid_link: NDI, grid_dp: NDV,
            grid_vol: ti.types.ndarray(dtype=ti.math.vec2, ndim=1), fbar: ti.template(),
            link_poses: NDF2, group_bind: NDF2, alpha0: ti.f32, alpha1: ti.f32, walls: NDF2, n_walls: ti.i32,
            contact_mode: ti.template(), nh_only: ti.template(), n_col: ti.i32, col_kind: NDI, col_prm: NDF2, col_pose: NDF2,
            col_mu: NDF, col_sticky: NDI, sdf: NDF, sdf_info: NDI2, col_impulse: NDF2,
            max_push: ti.f32, reach: ti.f32):
    """One MLS-MPM substep: clear grid, P2G, grid update + BCs, contact, G2P.

    ``contact_mode``: 0 no colliders, 1 particle-detected (grid-applied), 2 grid nodes.
    """
    inv_dx = 1.0 / dx
    ncell = nx * ny * nz
    clear_grid(ncell, grid_v, grid_m, grid_mk, grid_mq, grid_dp, grid_vol)
    p2g(gravity, order, slab_start, n_slabs, x, v, C, tau, mass, vol, kind, link, matid, mat_table,
        group, group_qs, ox, oy, oz, ny, nz, inv_dx, dt, grid_v, grid_m, grid_mk, grid_mq, grid_link)
    grid_update(ncell, ox, oy, oz, ny, nz, dx, dt, gravity[0], gravity[1], gravity[2], damping, relax,
                grid_v, grid_m, grid_mk, grid_mq, grid_link, link_poses, alpha0, alpha1, walls, n_walls,
                1 if ti.static(contact_mode == 2) else 0, n_col, col_kind, col_prm, col_pose, col_mu, col_sticky,
                sdf, sdf_info, col_impulse)
    if ti.static(contact_mode == 1):
        contact_scatter(order, slab_start, n_slabs, x, kind, mass, radius, impulse, contact_id,
                        ox, oy, oz, ny, nz, inv_dx, dt, grid_v, grid_m, grid_mk, grid_dp, n_col, col_kind, col_prm,
                        col_pose, col_mu, col_sticky, sdf, sdf_info, alpha0, alpha1, max_push, reach)
        contact_apply(ncell, ox, oy, oz, ny, nz, dx, grid_v, grid_m, grid_mk, grid_dp, walls, n_walls)
    g2p(nh_only, order, n, x, v, C, F, tau, Jp, kind, matid, mat_table, link, group, link_poses, group_bind,
        alpha0, alpha1, ox, oy, oz, ny, nz, inv_dx, dt, grid_v, grid_m, grid_mk, fbar)
    if ti.static(fbar):
        volume_scatter(order, slab_start, n_slabs, x, F, vol, kind, ox, oy, oz, ny, nz, inv_dx, grid_vol)
        fbar_stress(nh_only, order, n, x, F, tau, Jp, matid, mat_table, ox, oy, oz, ny, nz, inv_dx, grid_vol)
