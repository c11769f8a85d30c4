"""Kernels that change one group's particle rows in place on the device, for the events
between steps that need no rebuild of the world: a pad falling asleep, waking up, or put
back on its rest shape (:meth:`MPMWorld.set_awake`, :meth:`MPMWorld.rest_group`). Doing
them on the host would copy the whole particle state down and back up for every event;
with B envs whose pads wake at different steps that is nearly every step.
"""

import taichi as ti

from .kernels import NDV, Particles

vec3 = ti.math.vec3
mat3 = ti.math.mat3


@ti.func
def forget_row(P: ti.template(), p):
    """No contact impulse, no collider touched, no static-friction anchor."""
    P.impulse[p] = vec3(0.0)
    P.contact_id[p] = -1
    P.anchor[p] = ti.math.vec4(0.0, 0.0, 0.0, -1.0)


@ti.kernel
def forget_contact(P: Particles, start: ti.i32, stop: ti.i32):
    """Clear the contact state of rows [start, stop)."""
    for p in range(start, stop):
        forget_row(P, p)


@ti.kernel
def move_rigidly(P: Particles, start: ti.i32, stop: ti.i32, R: mat3, t: vec3):
    """Move rows [start, stop) by the rigid motion x -> R x + t (a sleeping pad's link moved):
    positions and velocities turn with it, and so do C and τ (R · Rᵀ) and F (R ·)."""
    for p in range(start, stop):
        P.x[p] = R @ P.x[p] + t
        P.v[p] = R @ P.v[p]
        P.C[p] = R @ P.C[p] @ R.transpose()
        P.tau[p] = R @ P.tau[p] @ R.transpose()
        P.F[p] = R @ P.F[p]


@ti.kernel
def put_at_rest(P: Particles, X0: NDV, start: ti.i32, stop: ti.i32, R: mat3, t: vec3, F_rest: mat3):
    """Rows [start, stop) on their rest place X0 (link frame) on the link pose (R, t), still,
    unstressed, with deformation gradient ``F_rest`` (the link's turn from its binding pose), no contact."""
    for p in range(start, stop):
        P.x[p] = R @ X0[p] + t
        P.v[p] = vec3(0.0)
        P.C[p] = mat3(0.0)
        P.tau[p] = mat3(0.0)
        P.Jp[p] = 1.0
        P.F[p] = F_rest
        forget_row(P, p)
