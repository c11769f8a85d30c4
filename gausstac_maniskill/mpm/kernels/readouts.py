"""Reductions read back after a step: contact impulses per collider and link, energies, drift
from the links' rigid motion, torn layers, health (non-finite state, speed)."""
import taichi as ti

from ...geometry.kinematics import pose_at
from ...kernel_launch import NDF, NDF2, NDI, NDV, cached_kernel
from .. import materials as mat
from .layout import DYNAMIC, Particles, Reduction
from .slabs import TASK_SPREAD, spread_item, spread_tasks

@cached_kernel
@ti.kernel
def chunk_health(P: Particles, active: NDI, n: ti.i32, nchunk: ti.i32, first_bad: NDI, vmax: NDF):
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
                s = P.x[p].sum() + P.v[p].sum() + P.F[p].sum()
                if bad < 0 and not (s == s and ti.abs(s) < 1e30):
                    bad = p
                if P.kind[p] == DYNAMIC:
                    vm = ti.max(vm, P.v[p].norm())
            first_bad[c] = bad
            vmax[c] = vm


@ti.kernel
def energies(P: Particles, active: NDI, n: ti.i32, mat_table: NDF2, dx: ti.f32, out: NDF):
    """out[0] = kinetic energy [J] of dynamic particles, out[1] = elastic energy [J]. The kinetic
    energy is APIC's, ½ m (|v|² + tr(C D Cᵀ)) with D = (Δx²/4) I for quadratic B-splines
    (Jiang et al. 2015): the velocity's variation over a particle's stencil carries energy too,
    and the grid holds it after P2G."""
    out[0] = 0.0
    out[1] = 0.0
    for ii in range(n):
        p = active[ii]
        if P.kind[p] == DYNAMIC:
            mi = P.matid[p]
            out[0] += 0.5 * P.mass[p] * (P.v[p].norm_sqr() + 0.25 * dx * dx * (P.C[p] * P.C[p]).sum())
            out[1] += P.vol[p] * mat.strain_energy_density(
                P.F[p], P.Jp[p], mat_table[mi, 0], mat_table[mi, 1],
                ti.cast(mat_table[mi, 2], ti.i32), mat_table[mi, 5])


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
