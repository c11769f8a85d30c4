"""The grid of a substep: clearing, momentum to velocity with its boundary conditions
(pinned nodes, quasi-static relaxation, slip walls, grid-node contact), the bond's ghost nodes."""
import taichi as ti

from ...geometry.kinematics import frame_at
from ..colliders import collider_contact
from .layout import BOND_REACH, PIN_FRACTION, vec3, vec4

@ti.func
def link_motion_at(S: ti.template(), l, xi, dt):
    """Rigid motion of link ``l`` over the substep at world point xi:
    (velocity [m/s], angular velocity ω [rad/s], link origin at the substep's start)."""
    R0, t0, R1, t1 = frame_at(S.link_frames, l)
    W = R1 @ R0.transpose()
    omega = 0.5 / dt * ti.Vector([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]])
    return (R1 @ (R0.transpose() @ (xi - t0)) + t1 - xi) / dt, omega, t0


@ti.func
def field_offset(P: ti.template(), S: ti.template(), B: ti.template(), p):
    """Offset of particle p's box copy in the grid arrays: its env's box of its velocity
    field (``Scene.group_copy``; 0 with one env and one field)."""
    return S.group_copy[P.group[p]] * B.ncell


@ti.func
def clear_grid(G: ti.template(), B: ti.template(), flags: ti.template()):
    """Zero P2G's sums on every box copy (and mark no cell numbered, with ``flags.cellp``)."""
    for i in range(B.ntot):
        if ti.static(flags.cellp):
            G.cell_slot[i] = 0
        G.grid_pm[i] = vec4(0.0)
        G.grid_kin[i] = ti.Vector([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        G.grid_dp[i] = vec3(0.0)
        G.grid_vol[i] = ti.Vector([0.0, 0.0])
        G.grid_mq[i] = 0.0
        if ti.static(flags.two_field):
            G.grid_vc[i] = 0.0
            G.grid_ds[i] = vec3(0.0)


@ti.func
def grid_update(G: ti.template(), S: ti.template(), B: ti.template(), flags: ti.template()):
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
    * With grid contact (``flags.contact_mode == 2``), colliders are enforced here on nodes
      with φ < 0 (unilateral, Coulomb friction; only the node's own env's) and their reaction
      impulse is accumulated.
    Every box copy (``B.ntot`` = fields × envs × ``ncell``; copy = field · n_env + env) is
    updated alike.
    """
    for idx in range(B.ntot):
        pm = G.grid_pm[idx]
        m = pm[3]
        G.grid_m[idx] = m
        vel = vec3(0.0)
        if m > 0.0:
            env = (idx // B.ncell) % B.n_env
            relax = ti.exp(-S.env_relax[env] * B.dt)
            xi = node_position(idx, B, B.dx)
            vel = ti.Vector([pm[0], pm[1], pm[2]]) / m
            vel *= B.damping
            if pinned(G, idx):
                vel, _omega, _t0 = link_motion_at(S, G.grid_link[idx], xi, B.dt)
            else:
                if G.grid_mq[idx] >= 0.5 * m:
                    # the link's rigid velocity here, and its centripetal acceleration
                    # ω × (ω × r): the pseudo-mass must not turn a spinning hand into a load
                    v_link, omega, t0 = link_motion_at(S, G.grid_link[idx], xi, B.dt)
                    vel += B.dt * omega.cross(omega.cross(xi - t0))
                    vel = v_link + relax * (vel - v_link)
                vel = slip_walls(S, B, xi, vel)
                if ti.static(flags.contact_mode == 2):
                    for c in range(B.n_col):
                        if S.col_env[c] != env:
                            continue
                        phi, nrm, vc = collider_contact(S, c, xi, B.dt)
                        if phi < 0.0:
                            vrel = vel - vc
                            vn = vrel.dot(nrm)
                            if vn < 0.0:
                                vt = vrel - vn * nrm
                                vtn = vt.norm()
                                if S.col_friction[c, 1] > 0.0 or vtn <= -S.col_friction[c, 0] * vn:
                                    vt = vec3(0.0)
                                else:
                                    vt *= 1.0 + S.col_friction[c, 0] * vn / vtn
                                new_vel = vc + vt
                                dp = m * (new_vel - vel)
                                ti.atomic_add(S.col_impulse[c, 0], -dp[0])
                                ti.atomic_add(S.col_impulse[c, 1], -dp[1])
                                ti.atomic_add(S.col_impulse[c, 2], -dp[2])
                                _R0, _t0, _R1, t1 = frame_at(S.col_frames, c)
                                tq = (xi - t1).cross(-dp)
                                ti.atomic_add(S.col_impulse[c, 3], tq[0])
                                ti.atomic_add(S.col_impulse[c, 4], tq[1])
                                ti.atomic_add(S.col_impulse[c, 5], tq[2])
                                vel = new_vel
        G.grid_v[idx] = vel


@ti.func
def node_position(idx, B: ti.template(), dx):
    """World position [m] of grid node ``idx`` of box B at spacing ``dx`` (of either velocity
    field and any env: idx modulo ncell)."""
    cell = idx % B.ncell
    i, j, k = cell // (B.ny * B.nz), (cell // B.nz) % B.ny, cell % B.nz
    return ti.Vector([B.ox + i, B.oy + j, B.oz + k], ti.f32) * dx


@ti.func
def slip_walls(S: ti.template(), B: ti.template(), xi, v):
    """The vector v with its normal component dropped on every slip wall (symmetry plane,
    bilateral; ``S.walls`` rows) that node position xi [m] lies on or beyond."""
    out = v
    for w in range(B.n_walls):
        ax = ti.cast(S.walls[w, 0], ti.i32)
        if S.walls[w, 2] * (xi[ax] - S.walls[w, 1]) <= 1e-9:
            out[ax] = 0.0
    return out


@ti.func
def pinned(G: ti.template(), idx):
    """A node is held by its link when kinematic particles bring at least PIN_FRACTION of
    its mass (Dirichlet): it moves rigidly with the link (:func:`grid_update`), or, where its
    bound particles know the bond surface, as :func:`bond_ghosts` sets it."""
    return G.grid_kin[idx][5] >= PIN_FRACTION * G.grid_m[idx]


@ti.func
def bond_ghosts(G: ti.template(), S: ti.template(), B: ti.template()):
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
    Visits ``B.n_bond`` nodes: every box copy with a bond, none without.
    """
    for idx in range(B.n_bond):
        m = G.grid_m[idx]
        b = G.grid_kin[idx]
        if m > 0.0 and b[4] > 0.0 and pinned(G, idx) and b[4] >= 0.999 * b[5]:
            nrm = ti.Vector([b[0], b[1], b[2]])
            if nrm.norm() > 1e-3 * b[4]:
                nrm = nrm.normalized()
                d = b[3] / b[4]
                reach = BOND_REACH * B.dx
                xi = node_position(idx, B, B.dx)
                xm = xi + (reach - d) * nrm
                off = idx - idx % B.ncell
                # trilinear mean of the free nodes of the cell around xm
                g = xm / B.dx - ti.Vector([B.ox, B.oy, B.oz], ti.f32)
                base = ti.cast(ti.floor(g), ti.i32)
                f = g - base
                vsum = vec3(0.0)
                wsum = 0.0
                for a, c, e in ti.static(ti.ndrange(2, 2, 2)):
                    q = base + ti.Vector([a, c, e])
                    if 0 <= q[0] < B.nx and 0 <= q[1] < B.ny and 0 <= q[2] < B.nz:
                        j = off + (q[0] * B.ny + q[1]) * B.nz + q[2]
                        if G.grid_m[j] > 0.0 and not pinned(G, j):
                            wt = (f[0] if a else 1.0 - f[0]) * (f[1] if c else 1.0 - f[1]) * (f[2] if e else 1.0 - f[2])
                            vsum += wt * G.grid_v[j]
                            wsum += wt
                if wsum > 0.25:
                    lk = G.grid_link[idx]
                    v_i, _w0, _t0 = link_motion_at(S, lk, xi, B.dt)
                    v_m, _w1, _t1 = link_motion_at(S, lk, xm, B.dt)
                    ratio = ti.max(-1.0, ti.min(1.0, d / reach))
                    G.grid_v[idx] = v_i + ratio * (vsum / wsum - v_m)


@ti.func
def free_node(G: ti.template(), idx):
    """A node that carries mass and is not held by a link (its velocity is an unknown)."""
    return G.grid_m[idx] > 0.0 and not pinned(G, idx)
