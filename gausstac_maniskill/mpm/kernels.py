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
BIG = 1 << 29


@ti.func
def bspline_weights(fx):
    """Quadratic B-spline weights for the 3 nodes of a stencil (fx in [0.5, 1.5))."""
    return [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]


@ti.kernel
def kinematic_update(kin: NDI, n: ti.i32, x: NDV, v: NDV, C: NDM, F: NDM, tau: NDM,
                     X0: NDV, link: NDI, group: NDI, link_poses: NDF2, group_bind: NDF2,
                     alpha0: ti.f32, alpha1: ti.f32, dt: ti.f32):
    """Place kinematic particles on their link at fraction alpha0 of the control step.

    Their velocity is the finite difference of the link transform over this substep
    applied to the rest coordinate X0 (link frame); C is the matching velocity gradient
    (R1 - R0) R0ᵀ / Δt and F the link rotation relative to the binding rotation.
    """
    for ii in range(n):
        p = kin[ii]
        l = link[p]
        R0, t0 = pose_at(link_poses, l, alpha0)
        R1, t1 = pose_at(link_poses, l, alpha1)
        g = group[p]
        Rb = quat_to_mat(ti.Vector([group_bind[g, 0], group_bind[g, 1], group_bind[g, 2], group_bind[g, 3]]))
        x0 = R0 @ X0[p] + t0
        x[p] = x0
        v[p] = (R1 @ X0[p] + t1 - x0) / dt
        C[p] = (R1 - R0) @ R0.transpose() / dt
        F[p] = R0 @ Rb.transpose()
        tau[p] = ti.Matrix.zero(ti.f32, 3, 3)


@ti.kernel
def chunk_bounds(active: NDI, n: ti.i32, x: NDV, inv_dx: ti.f32, nchunk: ti.i32, out: NDI2):
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


@ti.kernel
def sort_into_slabs(active: NDI, n: ti.i32, x: NDV, inv_dx: ti.f32, axis: ti.i32, lo_axis: ti.i32,
                    n_slabs: ti.i32, slab_of: NDI, slab_start: NDI, cursor: NDI, order: NDI):
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


@ti.kernel
def clear_grid(ncell: ti.i32, grid_v: NDV, grid_m: NDF, grid_mk: NDF):
    for i in range(ncell):
        grid_v[i] = vec3(0.0)
        grid_m[i] = 0.0
        grid_mk[i] = 0.0


@ti.kernel
def p2g(order: NDI, slab_start: NDI, n_slabs: ti.i32, x: NDV, v: NDV, C: NDM, tau: NDM,
        mass: NDF, vol: NDF, kind: NDI, link: NDI,
        ox: ti.i32, oy: ti.i32, oz: ti.i32, ny: ti.i32, nz: ti.i32, inv_dx: ti.f32, dt: ti.f32,
        grid_v: NDV, grid_m: NDF, grid_mk: NDF, grid_link: NDI):
    """Scatter mass and APIC momentum (with the stress impulse) to the grid.

    Momentum to node i: w_ip [m_p v_p + (m_p C_p - Δt V0_p (4/dx²) τ_p)(x_i - x_p)].
    Kinematic particles also scatter their mass to ``grid_mk`` and their link id.
    """
    origin = ti.Vector([ox, oy, oz])
    for color in ti.static(range(2)):
        ti.loop_config(block_dim=1)
        for h in range((n_slabs - color + 1) // 2):
            s = 2 * h + color
            for ii in range(slab_start[s], slab_start[s + 1]):
                p = order[ii]
                Xp = x[p] * inv_dx - origin
                base = ti.cast(ti.floor(Xp - 0.5), ti.i32)
                fx = Xp - base
                w = bspline_weights(fx)
                m = mass[p]
                affine = m * C[p] - (dt * vol[p] * 4.0 * inv_dx * inv_dx) * tau[p]
                mv = m * v[p]
                is_kin = kind[p] == KINEMATIC
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


@ti.kernel
def grid_update(ncell: ti.i32, ox: ti.i32, oy: ti.i32, oz: ti.i32, ny: ti.i32, nz: ti.i32,
                dx: ti.f32, dt: ti.f32, gx: ti.f32, gy: ti.f32, gz: ti.f32, damping: ti.f32,
                grid_v: NDV, grid_m: NDF, grid_mk: NDF, grid_link: NDI,
                link_poses: NDF2, alpha0: ti.f32, alpha1: ti.f32,
                walls: NDF2, n_walls: ti.i32,
                grid_contact: ti.i32, n_col: ti.i32, col_kind: NDI, col_prm: NDF2, col_pose: NDF2,
                col_mu: NDF, col_sticky: NDI, sdf: NDF, sdf_info: NDI2, col_impulse: NDF2):
    """Momentum -> velocity, gravity, damping, then boundary conditions per node.

    * Nodes where kinematic mass is at least half the node mass move exactly with
      their link (Dirichlet), so a kinematic layer is rigid, not a viscous drag.
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
            vel = grid_v[idx] / m + dt * g
            vel *= damping
            if grid_mk[idx] >= 0.5 * m:
                l = grid_link[idx]
                R0, t0 = pose_at(link_poses, l, alpha0)
                R1, t1 = pose_at(link_poses, l, alpha1)
                q = R0.transpose() @ (xi - t0)
                vel = (R1 @ q + t1 - xi) / dt
            else:
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


@ti.kernel
def g2p(order: NDI, n: ti.i32, x: NDV, v: NDV, C: NDM, F: NDM, tau: NDM, Jp: NDF,
        kind: NDI, matid: NDI, mass: NDF, radius: NDF, impulse: NDV, contact_id: NDI,
        mat_table: NDF2,
        ox: ti.i32, oy: ti.i32, oz: ti.i32, ny: ti.i32, nz: ti.i32, inv_dx: ti.f32, dt: ti.f32,
        grid_v: NDV, particle_contact: ti.i32, n_col: ti.i32, col_kind: NDI, col_prm: NDF2,
        col_pose: NDF2, col_mu: NDF, col_sticky: NDI, sdf: NDF, sdf_info: NDI2,
        alpha0: ti.f32, alpha1: ti.f32, max_push: ti.f32):
    """Gather velocity and its gradient, update F (and plasticity), stress, contact, advect.

    Particle contact: a particle whose predicted position x + Δt v lies closer than
    its radius to a collider's surface gets the normal velocity that puts it exactly
    on the surface (capped at ``max_push``), and Coulomb friction on its tangential
    velocity relative to the collider. The velocity change times the particle mass
    is the contact impulse, stored per particle (its negative acts on the collider).
    """
    origin = ti.Vector([ox, oy, oz])
    for ii in range(n):
        p = order[ii]
        if kind[p] == DYNAMIC:
            Xp = x[p] * inv_dx - origin
            base = ti.cast(ti.floor(Xp - 0.5), ti.i32)
            fx = Xp - base
            w = bspline_weights(fx)
            new_v = vec3(0.0)
            new_C = ti.Matrix.zero(ti.f32, 3, 3)
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                dpos = ti.Vector([i, j, k]) - fx
                weight = w[i][0] * w[j][1] * w[k][2]
                gv = grid_v[((base[0] + i) * ny + base[1] + j) * nz + base[2] + k]
                new_v += weight * gv
                new_C += (4.0 * inv_dx * weight) * gv.outer_product(dpos)
            # deformation gradient: F <- (I + Δt ∇v) F, then the material's return map
            Fn = (ti.Matrix.identity(ti.f32, 3) + dt * new_C) @ F[p]
            mi = matid[p]
            model = ti.cast(mat_table[mi, 2], ti.i32)
            jp = Jp[p]
            if model == mat.FOAM:
                Fn, jp = mat.plastic_return(Fn, jp, mat_table[mi, 3], mat_table[mi, 4])
            tau[p] = mat.kirchhoff_stress(Fn, jp, mat_table[mi, 0], mat_table[mi, 1], model, mat_table[mi, 5])
            # contact with rigid colliders (particle mode)
            if particle_contact:
                for c in range(n_col):
                    x_pred = x[p] + dt * new_v
                    phi, nrm, vc = collider_contact(col_kind, col_prm, col_pose, sdf, sdf_info,
                                                    c, x_pred, alpha0, alpha1, dt)
                    gap = phi - radius[p]
                    if gap < 0.0:
                        dvn = ti.min(-gap / dt, max_push)
                        vrel = new_v - vc
                        vn = vrel.dot(nrm)
                        vt = vrel - vn * nrm
                        vtn = vt.norm()
                        if col_sticky[c] or vtn <= col_mu[c] * dvn:
                            vt = vec3(0.0)
                        else:
                            vt *= 1.0 - col_mu[c] * dvn / vtn
                        out_v = vc + (vn + dvn) * nrm + vt
                        impulse[p] += mass[p] * (out_v - new_v)
                        contact_id[p] = c
                        new_v = out_v
            v[p] = new_v
            C[p] = new_C
            F[p] = Fn
            Jp[p] = jp
            x[p] = x[p] + dt * new_v


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
