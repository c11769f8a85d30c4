"""Which pads of a scene an object nears over a control step (:func:`update_sleep`): those are
simulated, the others sleep and cost nothing. Units: metres."""
from __future__ import annotations

import numpy as np

from ..geometry.colliders import Collider
from ..transforms import turn_angle


def update_sleep(sim) -> None:
    """Wake the pads of scene ``sim`` (a :class:`~.scene.GaussTacSim`) near an object (collider
    or soft group), put the others to sleep.

    A pad is near when the region it sweeps over the coming step, relative to an object,
    comes within ``sleep_margin`` of that object; both move from their start poses (where
    the pad's particles are, where the collider was) to their end poses. Seen from the
    object's end pose, the pad's bounding-sphere centre travels from its start position
    (carried along with the object's motion) to its end position; the region lies inside
    spheres on that segment, at most the pad's radius apart, grown by half their spacing and
    by the centre's departure from the segment (at most each body's turn angle times the
    centre's distance from that body's origin). A pad that crosses an object within one
    step, or an object that crosses a pad, therefore wakes the pad, although both end poses
    may be clear. Soft objects are taken where their particles are."""
    soft_boxes = []
    if sim._soft:
        for g in sim._soft:
            x = sim.world.positions(sim._w(g))
            soft_boxes.append((x.min(0), x.max(0)))
    for name, pad in sim.pads.items():
        T = sim._link_pose[pad.spec.link]
        c_local, r = pad.bounding_sphere()
        c = T[:3, :3] @ c_local + T[:3, 3]
        S = sim.world.link_pose(sim._w(pad.spec.link))  # the step's start pose
        c0 = S[:3, :3] @ c_local + S[:3, 3]
        r += float(turn_angle(S, T)) * float(np.linalg.norm(c_local))
        near = False
        for idx in sim._objects.values():
            col = sim.world.colliders[idx]
            O0, O1 = sim.world.collider_start_pose(idx), col.pose
            start = O1[:3, :3] @ (O0[:3, :3].T @ (c0 - O0[:3, 3])) + O1[:3, 3]  # c0 as the object sees it
            grown = r + float(turn_angle(O0, O1)) * float(np.linalg.norm(c0 - O0[:3, 3]))  # the object's turn
            centres, reach = _sweep(start, c, grown)
            near |= min(_distance(col, p) for p in centres) - reach < sim.sleep_margin
        if soft_boxes:
            centres, reach = _sweep(c0, c, r)
            for lo, hi in soft_boxes:
                d = float(np.linalg.norm(np.maximum(np.maximum(lo - centres, centres - hi), 0.0), axis=1).min())
                near |= d - reach < sim.sleep_margin
        sim.pad_solver_of(name).set_near(name, near)


def _sweep(a: np.ndarray, b: np.ndarray, radius: float) -> tuple[np.ndarray, float]:
    """Spheres that hold a sphere of ``radius`` [m] moved along the segment a -> b: centres
    at most ``radius`` apart on it ([n + 1, 3]) and their radius, grown by half the spacing."""
    length = float(np.linalg.norm(b - a))
    n = max(1, int(np.ceil(length / max(radius, 1e-9))))
    return a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a), radius + 0.5 * length / n


def _distance(collider: Collider, point: np.ndarray) -> float:
    """Signed distance [m] from ``point`` to ``collider`` (exact for analytic shapes, a
    bounding-sphere lower bound for meshes), in numpy: cheap enough for every step."""
    from ..geometry import colliders as col

    T = collider.pose
    q = (point - T[:3, 3]) @ T[:3, :3]
    if collider.kind == col.SPHERE:
        return float(np.linalg.norm(q) - collider.radius)
    if collider.kind == col.BOX:
        d = np.abs(q) - np.asarray(collider.half_extents)
        return float(np.linalg.norm(np.maximum(d, 0.0)) + min(d.max(), 0.0))
    if collider.kind == col.CAPSULE:
        z = np.clip(q[2], -collider.half_length, collider.half_length)
        return float(np.linalg.norm(q - [0.0, 0.0, z]) - collider.radius)
    if collider.kind == col.HALFSPACE:
        return float(q[2])
    lo, hi = collider.mesh.bounds
    return float(np.linalg.norm(np.maximum(np.maximum(lo - q, q - hi), 0.0)))
