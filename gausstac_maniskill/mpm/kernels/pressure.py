"""The implicit cell pressure: the λ ln J term of nearly incompressible materials solved per grid
cell by Jacobi-preconditioned conjugate gradients in every substep."""
import taichi as ti

from .. import materials as mat
from .grid import field_offset, free_node, node_position, slip_walls
from .layout import N_ACTIVE, NCHUNK, vec3
from .slabs import TASK_SPREAD, spread_item, spread_tasks

# --------------------------------------------------------------------------- cell pressure
# Nearly incompressible silicone (ν → 0.5) at the shear wave's time step. For a material with
# ``mat.CELL_P`` (SolverSettings.pressure = "implicit") the Neo-Hookean stress splits into
# μ(F Fᵀ - I), kept explicit on the particles, and the volume term λ ln J · I, taken as one
# value per grid cell, π_c = λ mean_(p in c)(ln J_p) (F-bar's idea with the cell as the patch,
# so the volume constraint is not counted once per particle), and solved backward Euler in
# every substep. The cell's operator is built from its particles' own MLS gradients,
# G_ci = Σ_(p in c) V0_p ∇w_ip (4³ nodes i per cell), so the force of the cell pressures,
# f_i = -Σ_c G_ci π_c, and their rate, d(mean ln J)/dt = Σ_i G_ci·v_i / V_c, are exactly
# those of the particles' transfers (trilinear cell gradients would not be, and lose half the
# volume stiffness). Backward Euler,
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
def number_cells(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), B: ti.template()):
    """Number the cells that hold particles of cell-pressure materials: ``G.cell_slot[c]`` = slot
    or -1, ``G.slot_cell[slot]`` = c, ``G.cell_count`` = (slots, 1 if capacity ran out); then
    clear their ``cell_a`` and ``cell_G`` rows. In box order: bit-reproducible."""
    origin = ti.Vector([B.ox, B.oy, B.oz])
    for ii in range(S.counts[N_ACTIVE]):  # mark (every particle of a cell writes the same 1)
        p = O.order[ii]
        if S.mat_table[P.matid[p], mat.CELL_P] > 0.0:
            off = field_offset(P, S, B, p)
            cell = ti.cast(ti.floor(P.x[p] * B.inv_dx - origin), ti.i32)
            G.cell_slot[off + (cell[0] * B.ny + cell[1]) * B.nz + cell[2]] = 1
    G.cell_count[0] = 0
    G.cell_count[1] = 0
    cap = G.slot_cell.shape[0]
    ti.loop_config(serialize=True)
    for c in range(B.ntot):
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
def cell_node(c, l, B: ti.template()):
    """Flat index of the node at offset l ∈ {0..63} (4³, z fastest) from cell c's node c - (1, 1, 1)."""
    return c + ((l // 16 - 1) * B.ny + (l // 4) % 4 - 1) * B.nz + l % 4 - 1


@ti.func
def gather_cells(G: ti.template(), S: ti.template(), B: ti.template(), comp: ti.template(), coef):
    """t_i = M⁻¹ Σ_c G_ci q_c on free nodes, 0 elsewhere, into ``G.grid_t``; q is component
    ``comp`` of ``G.cell_b`` (0: π, 2: the CG direction). Slip walls drop the normal component
    (:func:`slip_walls`, a projection: the operator stays symmetric). coef = (Δt, 1/dx, 1/(1/dx), α)."""
    for idx in range(B.ntot):
        t = vec3(0.0)
        live = True
        if ti.static(comp == 2):  # the CG direction: nothing to do once converged
            live = G.cg_sum[CG_DONE] == 0.0
        if live:
            if free_node(G, idx):
                cc = idx % B.ncell
                node = ti.Vector([cc // (B.ny * B.nz), (cc // B.nz) % B.ny, cc % B.nz])
                for l in range(64):
                    cell = node - ti.Vector([l // 16, (l // 4) % 4, l % 4]) + 1  # node = cell - 1 + offset l
                    if cell.min() >= 0:
                        slot = G.cell_slot[idx - cc + (cell[0] * B.ny + cell[1]) * B.nz + cell[2]]
                        if slot >= 0:
                            t += G.cell_b[slot][comp] * G.cell_G[slot * 64 + l]
                xi = node_position(idx, B, coef[2])
                t = slip_walls(S, B, xi, t / G.grid_m[idx])
        G.grid_t[idx] = t


@ti.func
def slot_sum(step: ti.template(), G: ti.template(), B: ti.template(), coef, atomic: ti.template()):
    """Σ_k step(G, k, B, coef) over the numbered cells (a step may also update its cell):
    in fixed chunks summed in a fixed order on the CPU (bit-reproducible), atomically on GPUs."""
    n = G.cell_count[0]
    total = 0.0
    if ti.static(atomic):
        G.cg_sum[0] = 0.0
        for k in range(n):
            ti.atomic_add(G.cg_sum[0], step(G, k, B, coef))
        total = G.cg_sum[0]
    else:
        ti.loop_config(block_dim=TASK_SPREAD)
        for q in range(spread_tasks(NCHUNK)):  # a thread block per chunk
            ch = spread_item(q)
            if ch >= 0:
                s = 0.0
                for k in range(ch * n // NCHUNK, (ch + 1) * n // NCHUNK):
                    s += step(G, k, B, coef)
                G.cg_sum[ch] = s
        for ch in ti.static(range(NCHUNK)):
            total += G.cg_sum[ch]
    return total


@ti.func
def cell_apply(G: ti.template(), k, B: ti.template(), with_v: ti.template(), t_scale):
    """Σ_i G_ci·u_i over the 4³ nodes of numbered cell k, u = v - t_scale·t with ``with_v``
    (v = ``grid_v``), else u = t (t = ``grid_t``)."""
    c = G.slot_cell[k]
    s = 0.0
    for l in range(64):
        i = cell_node(c, l, B)
        u = G.grid_t[i]
        if ti.static(with_v):
            u = G.grid_v[i] - t_scale * u
        s += G.cell_G[k * 64 + l].dot(u)
    return s


@ti.func
def cg_start(G: ti.template(), k, B: ti.template(), coef):
    """Cell k: the Jacobi diagonal V/λ + Δt² Σ_i |G_ci|²/m_i, and the residual at the guess πⁿ,
    r = Δt Gᵀ(v* - Δt M⁻¹ G πⁿ), z = r / diag, p = z. Returns rᵀz."""
    dt = coef[0]
    a = G.cell_a[k]
    c = G.slot_cell[k]
    diag = a[0] * a[0] / a[2]  # V/λ̄, λ̄ = Σ V0 λ / V
    for l in range(64):
        i = cell_node(c, l, B)
        if free_node(G, i):
            diag += dt * dt * G.cell_G[k * 64 + l].norm_sqr() / G.grid_m[i]
    r = dt * cell_apply(G, k, B, True, dt)
    G.cell_a[k][3] = diag
    G.cell_b[k] = ti.Vector([G.cell_b[k][0], r, r / diag, 0.0])
    return r * r / diag


@ti.func
def cg_apply(G: ti.template(), k, B: ti.template(), coef):
    """Cell k: (A p)_k = (V/λ̄) p_k + Δt² (Gᵀ t)_k with t = M⁻¹ G p; returns p_k (A p)_k."""
    dt = coef[0]
    pAp = 0.0
    if G.cg_sum[CG_DONE] == 0.0:
        a = G.cell_a[k]
        p = G.cell_b[k][2]
        Ap = p * a[0] * a[0] / a[2] + dt * dt * cell_apply(G, k, B, False, 0.0)
        G.cell_b[k][3] = Ap
        pAp = p * Ap
    return pAp


@ti.func
def cg_update(G: ti.template(), k, B: ti.template(), coef):
    """Cell k: π += α p, r -= α A p (α = coef[3]); returns the new rᵀz."""
    b = G.cell_b[k]
    alpha = coef[3]
    r = b[1] - alpha * b[3]
    G.cell_b[k][0] = b[0] + alpha * b[2]
    G.cell_b[k][1] = r
    return r * r / G.cell_a[k][3]


@ti.func
def pressure_solve(G: ti.template(), S: ti.template(), B: ti.template(), flags: ti.template()):
    """The cells' values π⁺ (see the section comment) by at most ``flags.cellp`` Jacobi-PCG
    iterations from πⁿ, then v ← v* - Δt M⁻¹ G π⁺ on free nodes. Expects ``G.cell_a`` = (Σ V0,
    Σ V0 ln J, Σ V0 λ, -) and ``G.cell_G`` of the numbered cells from :func:`p2g`."""
    dt = B.dt
    coef = ti.Vector([dt, B.inv_dx, 1.0 / B.inv_dx, 0.0])
    for k in range(G.cell_count[0]):  # the guess πⁿ = λ̄ mean(ln J)
        a = G.cell_a[k]
        G.cell_b[k] = ti.Vector([a[1] * a[2] / (a[0] * a[0]), 0.0, 0.0, 0.0])
    G.cg_sum[CG_DONE] = 0.0
    gather_cells(G, S, B, 0, coef)  # t = M⁻¹ G πⁿ
    rz = slot_sum(cg_start, G, B, coef, flags.atomic)
    G.cg_sum[CG_RZ0] = rz
    if rz <= 0.0:
        G.cg_sum[CG_DONE] = 1.0
    for _it in ti.static(range(flags.cellp)):
        gather_cells(G, S, B, 2, coef)  # t = M⁻¹ G p
        pAp = slot_sum(cg_apply, G, B, coef, flags.atomic)
        alpha = 0.0
        if G.cg_sum[CG_DONE] == 0.0 and pAp > 0.0:
            alpha = rz / pAp
        coef[3] = alpha
        rz_new = slot_sum(cg_update, G, B, coef, flags.atomic)
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
    gather_cells(G, S, B, 0, coef)  # t = M⁻¹ G π⁺
    for idx in range(B.ntot):
        if free_node(G, idx):
            G.grid_v[idx] = G.grid_v[idx] - dt * G.grid_t[idx]
