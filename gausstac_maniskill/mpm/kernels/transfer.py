"""Particle-grid transfers (APIC, quadratic B-splines): P2G, G2P, the F-bar volume scatter and
the stress a particle carries into P2G."""
import taichi as ti

from ...geometry.kinematics import frame_at
from .. import materials as mat
from .grid import field_offset, pinned
from .layout import BOND_STRETCH, DYNAMIC, KINEMATIC, MAX_STRETCH, SOFT_CONTACT, vec3
from .slabs import add_to, scatter_particles

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
def p2g(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), B: ti.template(),
        flags: ti.template()):
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
    mostly its read-modify-writes, and a record of 4 or 6 floats is one of them.
    With ``fbar`` the stress τ_p is first evaluated here, on the same stencil, from the
    nodal volume change that :func:`volume_scatter` and :func:`nodal_volume_change` left in ``grid_vol``.
    With ``cellp``, a particle whose λ ln J term is solved on cells (:func:`pressure_solve`)
    adds (V0, V0 ln J, V0 λ) to its cell's ``cell_a`` and V0 ∇w_ip to the cell's operator
    ``cell_G`` (the cell holds 4³ nodes, those of its particles' stencils). Its cell lies
    between nodes floor(x/dx) and floor(x/dx) + 1, inside the stencil: the slab colouring holds.
    """
    scatter_particles(P, G, S, O, B, flags, p2g_particle)


@ti.func
def p2g_particle(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), B: ti.template(),
        flags: ti.template(), p, origin):
    """Particle p's part of :func:`p2g` (``origin``: the active box's corner, in cells)."""
    base, fx, w = stencil(P.x[p], B.inv_dx, origin)
    off = field_offset(P, S, B, p)
    if ti.static(flags.fbar or flags.cellp):
        P.tau[p] = stress_at(flags, False, P.F[p], P.Jp[p], P.matid[p], S, G, B, base, w, off)
    slot = -1
    cell = ti.Vector([0, 0, 0])
    if ti.static(flags.cellp):
        if S.mat_table[P.matid[p], mat.CELL_P] > 0.0:
            cell = ti.cast(ti.floor(P.x[p] * B.inv_dx - origin), ti.i32)
            slot = G.cell_slot[off + (cell[0] * B.ny + cell[1]) * B.nz + cell[2]]
            if slot >= 0:
                lnJ = ti.log(ti.max(P.F[p].determinant(), mat.MIN_J))
                add_to(G.cell_a, slot,
                       P.vol[p] * ti.Vector([1.0, lnJ, S.mat_table[P.matid[p], 1], 0.0]), flags.atomic)
    vj = 0.0
    if ti.static(flags.two_field):
        vj = P.vol[p] * P.F[p].determinant()
    m = P.mass[p]
    # the affine momentum less the stress impulse, Δt V0 (4/dx²) τ
    affine = m * P.C[p] - (B.dt * P.vol[p] * 4.0 * B.inv_dx * B.inv_dx) * P.tau[p]
    # momentum plus this substep's weight impulse; weight is the physical mass
    # ρ V0 (a quasi-static group's pseudo-mass slows its inertia, not its weight)
    mv = m * P.v[p] + (B.dt * P.vol[p] * S.mat_table[P.matid[p], 6]) * B.gravity
    is_kin = P.kind[p] == KINEMATIC
    is_qs = (not is_kin) and S.group_qs[P.group[p]] > 0
    lk = P.link[p]
    bn = ti.Vector([P.bond[p][0], P.bond[p][1], P.bond[p][2]])
    bond_d = P.bond[p][3]
    bonded = 0.0  # 1 for a bound particle that knows the bond surface
    if is_kin and bn.norm_sqr() > 0.0:
        R0, _t0, _R1, _t1 = frame_at(S.link_frames, lk)  # the pose kinematic_update placed it at
        bn = R0 @ bn
        bonded = 1.0
    for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
        dpos = (ti.Vector([i, j, k]) - fx) / B.inv_dx  # x_i - x_p [m]
        weight = w[i][0] * w[j][1] * w[k][2]
        idx = off + ((base[0] + i) * B.ny + base[1] + j) * B.nz + base[2] + k
        mom = mv + affine @ dpos
        add_to(G.grid_pm, idx, weight * ti.Vector([mom[0], mom[1], mom[2], m]), flags.atomic)
        if ti.static(flags.cellp):
            if slot >= 0:  # V0 ∇w_ip, ∇w_ip = (4/dx²) w_ip (x_i - x_p) (MLS)
                lcl = base + ti.Vector([i, j, k]) - cell + 1
                add_to(G.cell_G, slot * 64 + (lcl[0] * 4 + lcl[1]) * 4 + lcl[2],
                       (P.vol[p] * 4.0 * B.inv_dx * B.inv_dx * weight) * dpos, flags.atomic)
        if ti.static(flags.two_field):
            add_to(G.grid_vc, idx, weight * vj, flags.atomic)
        if is_kin:
            wm = weight * m
            add_to(G.grid_kin, idx, ti.Vector([wm * bn[0], wm * bn[1], wm * bn[2],
                                               wm * (bond_d + bn.dot(dpos)), wm * bonded, wm]),
                   flags.atomic)
            G.grid_link[idx] = lk
        elif is_qs:
            add_to(G.grid_mq, idx, weight * m, flags.atomic)
            G.grid_link[idx] = lk


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
def g2p(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), B: ti.template(),
        flags: ti.template()):
    """Gather velocity and its gradient, update F (and plasticity) and stress, advect.

    Bound (kinematic) particles keep their link-given position and velocity, but strain
    with the grid like the material they belong to: F = Q1 (I + Δt Q0ᵀ(∇v - ∇v_link) Q0) Q0ᵀ F,
    Q the link's rotation from its binding pose (rigid motion exactly, no drift). Their stress
    completes the quadrature of the free nodes next to the bond, so the soft layer is held
    where its bound particles are, not a cell deeper (``bench thinlayer``). Where every
    node of the stencil is pinned, F is the rotation Q1 and the stress zero.
    With ``fbar`` or ``cellp`` the stress is left to the next :func:`p2g` (:func:`stress_at`).
    With two fields a particle gathers from its own field, and a dynamic particle of
    field 0 records its share m_p Σ w_ip Δv_i of the other field's contact impulse
    (:func:`field_contact`) in ``impulse``, with ``contact_id`` SOFT_CONTACT where no
    collider touched it.
    """
    origin = ti.Vector([B.ox, B.oy, B.oz])
    for ii in range(B.n):
        p = O.order[ii]
        is_kin = P.kind[p] == KINEMATIC
        base, fx, w = stencil(P.x[p], B.inv_dx, origin)
        off = field_offset(P, S, B, p)
        # velocity v = Σ w_i v_i and APIC gradient C = (4/dx²) Σ w_i v_i (x_i - x_p)ᵀ
        #   = (4/dx) [Σ w_i v_i (i, j, k)ᵀ - v fxᵀ]: the node offsets (i, j, k) are the
        # stencil's own integers, so the moment sums only add (no product per node)
        new_v = vec3(0.0)
        moment = ti.Matrix.zero(ti.f32, 3, 3)  # columns Σ w_i v_i i, Σ w_i v_i j, Σ w_i v_i k
        soft_dv = vec3(0.0)
        for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
            weight = w[i][0] * w[j][1] * w[k][2]
            idx = off + ((base[0] + i) * B.ny + base[1] + j) * B.nz + base[2] + k
            wv = weight * G.grid_v[idx]
            new_v += wv
            for d, o in ti.static(enumerate((i, j, k))):
                if ti.static(o > 0):
                    moment[:, d] += wv if ti.static(o == 1) else 2.0 * wv
            if ti.static(flags.two_field):
                soft_dv += weight * G.grid_ds[idx]
        new_C = (4.0 * B.inv_dx) * (moment - new_v.outer_product(fx))
        all_pinned = is_kin
        if is_kin:
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                all_pinned = all_pinned and pinned(G, off + ((base[0] + i) * B.ny + base[1] + j) * B.nz + base[2] + k)
        mi = P.matid[p]
        if ti.static(flags.two_field):
            if S.group_field[P.group[p]] == 0 and not is_kin and soft_dv.norm_sqr() > 0.0:
                P.impulse[p] += P.mass[p] * soft_dv
                if P.contact_id[p] == -1:
                    P.contact_id[p] = SOFT_CONTACT
        if not is_kin:
            # deformation gradient: F <- (I + Δt ∇v) F, kept in the stretch range the explicit
            # step can carry (limit_stretch), then the material's return map
            Fn = limit_stretch((ti.Matrix.identity(ti.f32, 3) + B.dt * new_C) @ P.F[p], MAX_STRETCH)
            jp = P.Jp[p]
            if ti.static(not flags.nh_only):
                if ti.cast(S.mat_table[mi, 2], ti.i32) == mat.FOAM:
                    Fn, jp = mat.plastic_return(Fn, jp, S.mat_table[mi, 3], S.mat_table[mi, 4])
            if ti.static(not (flags.fbar or flags.cellp)):
                P.tau[p] = elastic_stress(flags.nh_only, Fn, jp, mi, S.mat_table)
            P.v[p] = new_v
            P.C[p] = new_C
            P.F[p] = Fn
            P.Jp[p] = jp
            P.x[p] = P.x[p] + B.dt * new_v  # advect
        else:
            Q0, _o0, Q1, _o1 = frame_at(S.group_frames, P.group[p])
            if all_pinned:
                P.F[p] = Q1
                P.tau[p] = ti.Matrix.zero(ti.f32, 3, 3)
            else:
                # P.C[p] is the link's rigid velocity gradient (kinematic_update)
                strain_rate = Q0.transpose() @ (new_C - P.C[p]) @ Q0
                Fn = limit_stretch(Q1 @ (ti.Matrix.identity(ti.f32, 3) + B.dt * strain_rate) @ Q0.transpose() @ P.F[p],
                                   BOND_STRETCH)
                P.F[p] = Fn
                if ti.static(not (flags.fbar or flags.cellp)):
                    P.tau[p] = elastic_stress(flags.nh_only, Fn, P.Jp[p], mi, S.mat_table)


@ti.func
def limit_stretch(F, bound: ti.template()):
    """F with its principal stretches clamped to [1/bound, bound]: a numerical safeguard far
    outside a silicone pad's working range, where the explicit step fails.

    A pad closed hard on an object is crushed to a quarter of its thickness against its
    rigid core and dragged along (PressCube with the whole hand closed): the last cells shear
    without bound, and a stretch of 70× makes the stress (μ F Fᵀ), the wave speed and then the
    pad blow up. Clamped, the excess is lost like plastic flow (the layer tears). A bound
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
def volume_scatter(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), B: ti.template(),
        flags: ti.template()):
    """F-bar, step 1: each node gathers the rest volume Σ w V0 and the deformed volume
    Σ w V0 J of the particles around it into ``G.grid_vol`` (slab-ordered like :func:`p2g`; per
    field, so two bodies that touch do not average their volume change). Particles whose volume
    term is solved on cells (``mat.CELL_P``) take no part."""
    scatter_particles(P, G, S, O, B, flags, volume_particle)


@ti.func
def volume_particle(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), B: ti.template(),
        flags: ti.template(), p, origin):
    """Particle p's part of :func:`volume_scatter` (``origin``: the active box's corner, in cells)."""
    if P.kind[p] == DYNAMIC and S.mat_table[P.matid[p], mat.CELL_P] <= 0.0:
        base, fx, w = stencil(P.x[p], B.inv_dx, origin)
        off = field_offset(P, S, B, p)
        vj = P.vol[p] * ti.Vector([1.0, P.F[p].determinant()])
        for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
            idx = off + ((base[0] + i) * B.ny + base[1] + j) * B.nz + base[2] + k
            add_to(G.grid_vol, idx, (w[i][0] * w[j][1] * w[k][2]) * vj, flags.atomic)


@ti.func
def stress_at(flags: ti.template(), report: ti.template(), Fp, jp, mi, S: ti.template(), G: ti.template(),
        B: ti.template(), base, w, off):
    """Kirchhoff stress [Pa] of a particle (deformation gradient Fp, plastic J jp, material row
    mi, stencil (base, w), box copy offset off) as the substep uses it: for a material whose
    λ ln J term is solved on cells, μ(F Fᵀ - I) (with ``report``, for readings after a step, the
    whole Neo-Hookean stress); else the F-bar stress (:func:`fbar_stress_at`) or the plain
    elastic stress."""
    tau = ti.Matrix.zero(ti.f32, 3, 3)
    on_cells = False
    if ti.static(flags.cellp):
        on_cells = S.mat_table[mi, mat.CELL_P] > 0.0
    if on_cells:
        tau = mat.neo_hookean_shear(Fp, S.mat_table[mi, 0])
        if ti.static(report):
            tau += S.mat_table[mi, 1] * ti.log(ti.max(Fp.determinant(), mat.MIN_J)) * ti.Matrix.identity(ti.f32, 3)
    else:
        if ti.static(flags.fbar):
            tau = fbar_stress_at(flags, Fp, jp, mi, S, G, B, base, w, off)
        else:
            tau = elastic_stress(flags.nh_only, Fp, jp, mi, S.mat_table)
    return tau


@ti.func
def fbar_stress_at(flags: ti.template(), Fp, jp, mi, S: ti.template(), G: ti.template(), B: ti.template(),
        base, w, off):
    """F-bar, step 2 (anti-locking for ν → 0.5): Kirchhoff stress of a particle with
    deformation gradient Fp and stencil (base, w) whose λ (bulk) term is evaluated at the
    grid-smoothed volume change J̄ = Σ_i w_ip J_i, J_i = (Σ w V0 J)_i / (Σ w V0)_i, instead
    of the particle's own J; the μ terms keep the particle's F. One bulk constraint per
    node instead of one per particle, so a nearly incompressible material is not
    over-constrained (volumetric locking). This is the selective form of F-bar / J-bar
    (de Souza Neto et al. 1996; for MPM, Coombs et al. 2018): replacing the whole F by
    (J̄/J)^{1/3} F would let particles trade volume at no cost (a pad creeps after contact);
    the μ terms' own volume stiffness stops that. ``grid_vol`` holds (Σ w V0, J_i) per node
    (:func:`nodal_volume_change`). A Neo-Hookean material takes μ(F Fᵀ - I) + λ ln J̄ I at once
    (its own λ ln J is never formed): P2G is bound by its arithmetic per particle."""
    J = ti.max(Fp.determinant(), mat.MIN_J)
    J_sum, w_sum = 0.0, 0.0
    for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
        gv = G.grid_vol[off + ((base[0] + i) * B.ny + base[1] + j) * B.nz + base[2] + k]
        if gv[0] > 0.0:
            weight = w[i][0] * w[j][1] * w[k][2]
            J_sum += weight * gv[1]  # the node's J_i (nodal_volume_change)
            w_sum += weight
    J_bar = J if w_sum <= 0.0 else J_sum / w_sum
    s_bar = mat.volumetric_stress(flags.nh_only, ti.max(J_bar, mat.MIN_J), jp, mi, S.mat_table)
    tau = ti.Matrix.zero(ti.f32, 3, 3)
    if ti.static(flags.nh_only):  # μ(F Fᵀ - I) + λ ln J̄ I: the particle's own λ ln J is never needed
        tau = mat.neo_hookean_shear(Fp, S.mat_table[mi, 0]) + s_bar * ti.Matrix.identity(ti.f32, 3)
    else:
        dp = s_bar - mat.volumetric_stress(flags.nh_only, J, jp, mi, S.mat_table)
        tau = elastic_stress(flags.nh_only, Fp, jp, mi, S.mat_table) + dp * ti.Matrix.identity(ti.f32, 3)
    return tau


@ti.func
def nodal_volume_change(G: ti.template(), B: ti.template()):
    """F-bar, step 1b: each node's (Σ w V0, Σ w V0 J) becomes (Σ w V0, J_i = Σ w V0 J / Σ w V0): one
    division per node instead of one per particle and stencil node (:func:`fbar_stress_at`)."""
    for idx in range(B.ntot):
        gv = G.grid_vol[idx]
        if gv[0] > 0.0:
            G.grid_vol[idx] = ti.Vector([gv[0], gv[1] / gv[0]])


@ti.func
def report_stress(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), B: ti.template(),
        flags: ti.template()):
    """:func:`stress_at` (whole, with ``report``) for every particle: the stress reported after a step."""
    origin = ti.Vector([B.ox, B.oy, B.oz])
    for ii in range(B.n):
        p = O.order[ii]
        base, _fx, w = stencil(P.x[p], B.inv_dx, origin)
        off = field_offset(P, S, B, p)
        P.tau[p] = stress_at(flags, True, P.F[p], P.Jp[p], P.matid[p], S, G, B, base, w, off)
