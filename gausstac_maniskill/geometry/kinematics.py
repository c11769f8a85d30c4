"""Rigid motion inside Taichi kernels: quaternions (w, x, y, z) and pose interpolation.

A pose row holds 14 floats: the pose at the start of the control step
(position 0:3, quaternion 3:7) and at its end (position 7:10, quaternion 10:14).
Within a control step a substep at fraction α ∈ [0, 1] uses the linear
interpolation of positions and the slerp of rotations, so a link's motion is
spread over the substeps and kinematic particles/colliders never jump.

The interpolation is done once per substep and per row (:func:`write_frames`), not per
particle or node: a *frame* row holds the rigid transform at the substep's start and end,
R0 (0:9), t0 (9:12), R1 (12:21), t1 (21:24), read back with :func:`frame_at`.
"""

import taichi as ti


@ti.func
def quat_to_mat(q):
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ti.Matrix([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


@ti.func
def slerp(q0, q1, alpha):
    """Shortest-arc spherical interpolation of unit quaternions."""
    d = q0.dot(q1)
    qb = q1
    if d < 0.0:
        qb = -q1
        d = -d
    out = ti.Vector([0.0, 0.0, 0.0, 0.0])
    if d > 0.9995:  # nearly parallel: normalised lerp is exact to float precision
        out = (1.0 - alpha) * q0 + alpha * qb
    else:
        theta = ti.acos(d)
        s = ti.sin(theta)
        out = (ti.sin((1.0 - alpha) * theta) / s) * q0 + (ti.sin(alpha * theta) / s) * qb
    return out.normalized()


@ti.func
def pose_at(poses: ti.template(), row, alpha):
    """(R, t) of pose row ``row`` at fraction ``alpha`` of the control step."""
    p0 = ti.Vector([poses[row, 0], poses[row, 1], poses[row, 2]])
    p1 = ti.Vector([poses[row, 7], poses[row, 8], poses[row, 9]])
    q0 = ti.Vector([poses[row, 3], poses[row, 4], poses[row, 5], poses[row, 6]])
    q1 = ti.Vector([poses[row, 10], poses[row, 11], poses[row, 12], poses[row, 13]])
    q = slerp(q0, q1, alpha)
    return quat_to_mat(q), (1.0 - alpha) * p0 + alpha * p1


FRAME = 24  # floats per frame row: R0, t0, R1, t1 (rotations row-major)


@ti.func
def write_frames(poses: ti.template(), n, alpha0, alpha1, frames: ti.template(), serial: ti.template()):
    """Frame rows of pose rows 0..n-1 over the substep [alpha0, alpha1] of the control step.
    ``serial``: in one thread (the CPU: a few dozen rows cost less than handing a loop to its
    threads); a GPU keeps the loop parallel (a batch has thousands of rows)."""
    ti.loop_config(serialize=serial)
    for r in range(n):
        R0, t0 = pose_at(poses, r, alpha0)
        R1, t1 = pose_at(poses, r, alpha1)
        for a, b in ti.static(ti.ndrange(3, 3)):
            frames[r, 3 * a + b] = R0[a, b]
            frames[r, 12 + 3 * a + b] = R1[a, b]
        for a in ti.static(range(3)):
            frames[r, 9 + a] = t0[a]
            frames[r, 21 + a] = t1[a]


@ti.func
def frame_at(frames: ti.template(), r):
    """(R0, t0, R1, t1) of frame row r: the rigid transform at the substep's start and end."""
    R0 = ti.Matrix([[frames[r, 3 * a + b] for b in ti.static(range(3))] for a in ti.static(range(3))])
    R1 = ti.Matrix([[frames[r, 12 + 3 * a + b] for b in ti.static(range(3))] for a in ti.static(range(3))])
    t0 = ti.Vector([frames[r, 9 + a] for a in ti.static(range(3))])
    t1 = ti.Vector([frames[r, 21 + a] for a in ti.static(range(3))])
    return R0, t0, R1, t1
