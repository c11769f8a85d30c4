"""Contact in a substep: particle-detected collider contact applied on the grid, and contact
between the two velocity fields.

Two velocity fields (multi-field MPM, Bardenhagen et al. 2000, J. Comput. Phys. 160:235,
written here from the paper's algorithm; compiled in with ``two_field``): field 0 the pads,
field 1 soft objects, each transferred, stressed and bounded on its own box copy, so a pad and a
sponge are two bodies; :func:`field_contact` exchanges momentum where they meet.
"""
import taichi as ti

from ...geometry.kinematics import frame_at
from ..colliders import collider_contact
from .grid import field_offset, node_position, pinned, slip_walls
from .layout import DYNAMIC, FIELD_MU, FILL, RECOVERY, SHARE, vec3
from .slabs import add_to, scatter_particles
from .transfer import stencil

@ti.func
def mass_gradient(G: ti.template(), B: ti.template(), idx):
    """Direction of the nodal mass gradient at node idx (central differences; it points
    into the body). The active box keeps >= 2 empty cells around every node with mass,
    so the neighbours exist."""
    g = ti.Vector([G.grid_m[idx + B.ny * B.nz] - G.grid_m[idx - B.ny * B.nz],
                   G.grid_m[idx + B.nz] - G.grid_m[idx - B.nz], G.grid_m[idx + 1] - G.grid_m[idx - 1]])
    return g / ti.max(g.norm(), 1e-30)


@ti.func
def field_contact(G: ti.template(), S: ti.template(), B: ti.template()):
    """Contact between the two velocity fields (multi-field MPM, Bardenhagen et al. 2000).

    At a node where both fields have mass, the contact normal n (from body 0 into
    body 1) is the difference of the two unit mass gradients. The bodies touch there when
    the node lies at both surfaces, each deformed volume V_f = Σ w V0 J ≥ SHARE dx³, and
    together they fill its cell, V_0 + V_1 ≥ FILL dx³. Without this test the B-spline
    supports make bodies meet up to 1.5 cells early; with it, a gap under 0.2 cells
    (1D estimate for these constants) still counts as contact. If they approach,
    (v_0 - v_1)·n > 0, the impulse P on body 0 stops their normal approach and resists
    the slip with Coulomb friction μ (``S.consts[FIELD_MU]``):

        P = -m* [(v_r·n) n + min(1, μ (v_r·n)/|v_t|) v_t],   v_r = v_0 - v_1,

    m* = m0 m1/(m0 + m1), or the free body's mass where the other node is pinned to its
    link (it is then rigid). Body 0 takes +P, body 1 -P: momentum is conserved, and no
    pulling (adhesive) force can arise. Field 0's velocity change P/m0 is kept in
    ``grid_ds``: :func:`g2p` turns it into the pad particles' contact impulses.
    Field 1's copy of node i0 is node i0 + envs × ncell (every env's box of field 0, then
    every env's box of field 1).
    """
    # μ and the stride are read where they are used: a local held across the loop compiles to
    # other (fast-math) arithmetic, other bits
    for i0 in range(B.ncell * B.n_env):
        i1 = i0 + B.ncell * B.n_env
        m0 = G.grid_m[i0]
        m1 = G.grid_m[i1]
        V0, V1, cell = G.grid_vc[i0], G.grid_vc[i1], B.dx * B.dx * B.dx
        if m0 > 0.0 and m1 > 0.0 and ti.min(V0, V1) >= SHARE * cell and V0 + V1 >= FILL * cell:
            pin0 = pinned(G, i0)
            pin1 = pinned(G, i1)
            if not (pin0 and pin1):
                n = mass_gradient(G, B, i1) - mass_gradient(G, B, i0)
                if n.norm() > 1e-6:
                    n = n.normalized()
                    vr = G.grid_v[i0] - G.grid_v[i1]
                    vn = vr.dot(n)
                    if vn > 0.0:
                        m_eff = m1 if pin0 else (m0 if pin1 else m0 * m1 / (m0 + m1))
                        vt = vr - vn * n
                        vtn = vt.norm()
                        stick = 1.0 if vtn <= S.consts[FIELD_MU] * vn else S.consts[FIELD_MU] * vn / vtn
                        P = -m_eff * (vn * n + stick * vt)
                        if not pin0:
                            G.grid_v[i0] = G.grid_v[i0] + P / m0
                            G.grid_ds[i0] = P / m0
                        if not pin1:
                            G.grid_v[i1] = G.grid_v[i1] - P / m1


@ti.func
def beyond_bound(S: ti.template(), c, x, reach):
    """World point x lies more than ``reach`` [m] beyond collider c's bounding sphere (radius
    ``S.col_bound[c]`` about its origin at the substep's end): nothing of c is within ``reach``, and
    its signed distance there exceeds ``reach`` (a mesh's SDF too: its grid lies inside the sphere
    and is positive on its border), so it need not be evaluated."""
    _R0, _t0, _R1, t1 = frame_at(S.col_frames, c)
    return (x - t1).norm() - S.col_bound[c] > reach


@ti.func
def contact_scatter(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), B: ti.template(),
        flags: ti.template()):
    """Particle-detected contact, applied as momentum on the grid (of the particle's field).

    For each dynamic particle near a collider, its free velocity v* is gathered
    from the grid and its end-of-substep position x + Δt v* is tested against the
    collider's surface inflated by the particle radius (the material's surface lies
    half a particle spacing beyond the centres). If it would penetrate, the velocity
    change Δv that puts it on the surface (normal part, capped at ``B.max_push``) with
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
    substep and a loaded contact creeps at a speed proportional to its shear load (a
    held, sheared pad lets go of most of its tangential force within 0.4 s, whatever μ; the
    plate slide of ``python -m gausstac_maniskill.bench pad`` shows it). With the anchor the
    drift the partial impulses leave is taken back in the next substep, like the normal
    penetration. Where
    |d_t|/Δt exceeds μ times the normal velocity change the particle slides (Coulomb),
    its friction opposes the drift, and its anchor moves to where it is predicted to end
    the substep. A particle that leaves contact forgets its anchor.
    Slab-ordered like :func:`p2g` (atomic-free and deterministic), or atomic.
    """
    scatter_particles(P, G, S, O, B, flags, contact_particle)


@ti.func
def contact_particle(P: ti.template(), G: ti.template(), S: ti.template(), O: ti.template(), B: ti.template(),
        flags: ti.template(), p, origin):
    """Particle p's part of :func:`contact_scatter` (``origin``: the active box's corner, in cells)."""
    if P.kind[p] == DYNAMIC:
        env = S.group_env[P.group[p]]  # a particle touches only its own env's colliders
        near = False
        for c in range(B.n_col):
            if S.col_env[c] == env and not beyond_bound(S, c, P.x[p], P.radius[p] + B.reach):
                phi, nrm, vc = collider_contact(S, c, P.x[p], B.dt)
                if phi - P.radius[p] < B.reach:
                    near = True
        stuck_to = -1  # collider whose anchor the particle keeps after this substep
        slid = False
        if near:
            base, fx, w = stencil(P.x[p], B.inv_dx, origin)
            off = field_offset(P, S, B, p)
            v0 = vec3(0.0)  # the free velocity v*, gathered
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                v0 += w[i][0] * w[j][1] * w[k][2] * G.grid_v[off + ((base[0] + i) * B.ny + base[1] + j)
                                                              * B.nz + base[2] + k]
            vp = v0
            for c in range(B.n_col):
                if S.col_env[c] != env or beyond_bound(S, c, P.x[p] + B.dt * vp, P.radius[p]):
                    continue  # (not this env's, or too far to touch)
                phi, nrm, vc = collider_contact(S, c, P.x[p] + B.dt * vp, B.dt)
                gap = phi - P.radius[p]
                if gap < 0.0:
                    vrel = vp - vc
                    # stop the approach, and take back an older penetration by at most
                    # RECOVERY cells per substep: the push stays in the particle's velocity
                    approach = ti.max(-vrel.dot(nrm), 0.0)
                    dvn = ti.min(-gap / B.dt, approach + RECOVERY / (B.inv_dx * B.dt), B.max_push)
                    want = -(vrel - vrel.dot(nrm) * nrm)  # stop the slip (first contact)
                    anchored = ti.cast(P.anchor[p][3], ti.i32) == c
                    if anchored:  # back onto the anchor
                        _R0, _t0, R1, t1 = frame_at(S.col_frames, c)
                        a = ti.Vector([P.anchor[p][0], P.anchor[p][1], P.anchor[p][2]])
                        drift = P.x[p] + B.dt * vp - (R1 @ a + t1)
                        want = -(drift - drift.dot(nrm) * nrm) / B.dt
                    wn = want.norm()
                    if wn > B.max_push:  # a jump of the anchor (a teleported collider) is not a load
                        want *= B.max_push / wn
                        wn = B.max_push
                    dvt = want
                    slides = S.col_friction[c, 1] <= 0.0 and wn > S.col_friction[c, 0] * dvn
                    if slides:  # Coulomb
                        dvt = (S.col_friction[c, 0] * dvn / wn) * want
                    vp = vp + dvn * nrm + dvt
                    P.contact_id[p] = c
                    # sliding or a new contact: anchor where it ends this substep
                    slid = slid or slides or not anchored
                    stuck_to = c
            if stuck_to >= 0 and slid:
                _R0, _t0, R1, t1 = frame_at(S.col_frames, stuck_to)
                a = R1.transpose() @ (P.x[p] + B.dt * vp - t1)
                P.anchor[p] = ti.Vector([a[0], a[1], a[2], ti.cast(stuck_to, ti.f32)])
            if P.contact_id[p] >= 0:
                J = P.mass[p] * (vp - v0)  # the contact impulse m_p Δv
                free = 0.0
                for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                    idx = off + ((base[0] + i) * B.ny + base[1] + j) * B.nz + base[2] + k
                    wi = w[i][0] * w[j][1] * w[k][2]
                    add_to(G.grid_dp, idx, wi * J, flags.atomic)
                    if not pinned(G, idx):
                        free += wi
                P.impulse[p] += free * J
        if stuck_to < 0:
            P.anchor[p][3] = -1.0


@ti.func
def contact_apply(G: ti.template(), S: ti.template(), B: ti.template()):
    """Add the scattered contact momentum ``G.grid_dp`` to free nodes (not pinned, walls kept)."""
    for idx in range(B.ntot):
        m = G.grid_m[idx]
        dp = G.grid_dp[idx]
        if m > 0.0 and not pinned(G, idx) and dp.norm_sqr() > 0.0:
            xi = node_position(idx, B, B.dx)
            G.grid_v[idx] = G.grid_v[idx] + slip_walls(S, B, xi, dp / m)
