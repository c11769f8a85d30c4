"""``python -m gausstac_maniskill.bench hold [--mass 0.01 0.05 0.5 1.0] [--dx 2e-3]`` — the statics of a
held object: do the pads' MPM forces carry the cube's weight, and only that?

1. Two pads on one free 10 g box (no MPM, one PGS step, no gravity): the box's motion under each
   coupling (each pad's PhysX soft limit alone, one per pad, one
   :class:`~gausstac_maniskill.tasks.contact_spring.ObjectSpring` per object) against the implicit
   balance ``(F1 - F2) / (m/dt² + K1 + K2)``.
2. The ``GaussTac-GraspLiftCube-v1`` expert holding cubes of each ``--mass``: each pad's force on
   the cube, their sum against the cube's weight, and the cube's largest speed over the last
   second of the hold.
"""
from __future__ import annotations

import time

import numpy as np
import sapien

from .common import cli, write_report

#: the pads of the pinch and their links (Allegro)
PADS = {"thumb": "link_15.0_tip", "index": "link_3.0_tip"}
#: the thumb's and the index pad's force [N] and indentation [m] on the held 10 g cube at
#: dx = 2 mm with one PhysX spring per pad
PINCH = ((0.115, 0.10e-3), (1.897, 0.57e-3))


def _pinch_scene(dt: float):
    """A PGS scene without gravity, a free 10 g box at the origin and two kinematic pads
    5 cm either side along y; returns (scene, box, [thumb, index] rigid components)."""
    config = sapien.physx.PhysxSceneConfig()
    config.gravity = np.zeros(3)
    config.enable_tgs = False
    sapien.physx.set_scene_config(config)
    scene = sapien.Scene()
    scene.set_timestep(dt)
    b = scene.create_actor_builder()
    b.add_box_collision(half_size=[0.01] * 3, density=0.01 / 8e-6)
    box = b.build(name="box")
    pads = []
    for side in (-1.0, 1.0):
        a = scene.create_actor_builder()
        a.add_box_collision(half_size=[0.005] * 3)
        pad = a.build_kinematic(name="pad")
        pad.set_pose(sapien.Pose([0.0, 0.05 * side, 0.0]))
        pads.append(pad)
    return scene, box, pads


def _per_pad_limits(scene, box, pads, which=(0, 1)):
    """One PhysX D6 soft limit per pad in ``which`` (the per-pad coupling), preloaded with its
    force. Returns the drives (a dropped drive is removed)."""
    from ..tasks.contact_spring import OBJECT_GAIN, frame_along
    from ..transforms import matrix_to_quat

    drives = []
    for i in which:
        (f, depth), n = PINCH[i], np.array([0.0, 1.0 if i == 0 else -1.0, 0.0])
        k = OBJECT_GAIN * f / depth
        d = scene.create_drive(pads[i], sapien.Pose(), box, sapien.Pose())
        d.set_inv_mass_scales(0.0, 1.0)
        d.set_inv_inertia_scales(0.0, 1.0)
        frame = sapien.Pose((-0.01 * n).astype(np.float32), matrix_to_quat(frame_along(n)).astype(np.float32))
        d.set_pose_in_child(box.pose.inv() * frame)
        d.set_pose_in_parent(pads[i].pose.inv() * frame)
        d.set_limit_x(f / k, float(d.get_limit_x()[1]), k, 0.0)
        drives.append(d)
    return drives


def _object_spring(scene, box, pads):
    """One :class:`ObjectSpring` for both pads (returned: a dropped drive is removed)."""
    from ..tasks.contact_spring import ObjectSpring

    rows = []
    for pad, (f, depth), n in zip(pads, PINCH, ([0.0, 1.0, 0.0], [0.0, -1.0, 0.0])):
        link = pad.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
        force, point = f * np.asarray(n), -0.01 * np.asarray(n)  # on the box, at its face
        on_link = -force
        origin = np.asarray(pad.pose.p, np.float64)
        rows.append((np.concatenate([on_link, np.cross(point - origin, on_link), [depth]]), link))
    spring = ObjectSpring(scene, box)
    spring.take(rows, friction=0.0)
    return spring


def pinch_table(dt: float = 0.01, mass: float = 0.01) -> list[str]:
    """Part 1: the box's motion along the pinch (+y: toward the index) in one step under
    each coupling, against the implicit Euler step of the same springs (table lines)."""
    from ..tasks.contact_spring import OBJECT_GAIN

    k = [OBJECT_GAIN * f / depth for f, depth in PINCH]
    push = [PINCH[0][0], -PINCH[1][0]]  # along +y

    def implicit(which):
        return sum(push[i] for i in which) / (mass / dt ** 2 + sum(k[i] for i in which)) * 1e6

    rows = (("thumb's soft limit alone", lambda *a: _per_pad_limits(*a, which=(0,)), (0,)),
            ("index's soft limit alone", lambda *a: _per_pad_limits(*a, which=(1,)), (1,)),
            ("one PhysX soft limit per pad", _per_pad_limits, (0, 1)),
            ("one ObjectSpring per object", _object_spring, (0, 1)))
    lines = [f"Two pads on a free {mass * 1e3:g} g box, one SAPIEN step of {dt} s (PGS, no gravity): thumb "
             f"{PINCH[0][0]} N at K {k[0]:.0f} N/m, index {PINCH[1][0]} N at K {k[1]:.0f} N/m.", "",
             "| coupling | box along the pinch [µm] | implicit Euler step of the same springs [µm] |", "|---|---|---|"]
    saved = sapien.physx.get_scene_config()
    try:
        for name, couple, which in rows:
            scene, box, pads = _pinch_scene(dt)
            keep = couple(scene, box, pads)  # noqa: F841  (alive while the scene steps)
            scene.step()
            lines.append(f"| {name} | {float(box.pose.p[1]) * 1e6:+.2f} | {implicit(which):+.2f} |")
    finally:
        sapien.physx.set_scene_config(saved)
    return lines


def held_row(mass: float, dx: float, seed: int) -> str:
    """Part 2: one table line for a cube of ``mass`` [kg] held by the expert."""
    import gymnasium as gym

    import gausstac_maniskill.tasks  # noqa: F401  (registers the tasks with ManiSkill)

    from .common import run_expert_episode

    env = gym.make("GaussTac-GraspLiftCube-v1", sim_backend="physx_cpu", obs_mode="state",
                   control_mode="pd_joint_pos", mpm_dx=dx, cube_mass=mass)
    speeds = []
    try:
        u = env.unwrapped
        t0 = time.perf_counter()
        _, info, done, timing, _ = run_expert_episode(
            env, seed, f"hold {mass * 1e3:g} g", each_step=lambda info, a: speeds.append(float(info["cube_speed"][0])))
        seconds = time.perf_counter() - t0
        pads = {p: -u.cosims[0].link_contacts(link).get("cube", np.zeros(7))[:3] for p, link in PADS.items()}
        net = u.object_wrench("cube")[0, :3].numpy().astype(np.float64)
    finally:
        env.close()
    weight = mass * 9.81
    hold = speeds[-int(u.control_freq):]
    cells = " | ".join(f"{np.linalg.norm(f):.3f}" for f in pads.values())
    return (f"| {mass * 1e3:g} | {'yes' if done is not None else 'no'} | {cells} | {np.round(net, 3).tolist()} "
            f"| {weight:.3f} | {np.linalg.norm(net - [0.0, 0.0, weight]) / weight * 100:.1f} "
            f"| {max(hold) * 1e3:.3f} | {seconds / len(timing) * 1e3:.0f} |")


def main(argv: list[str] | None = None) -> int:
    ap = cli("hold", __doc__)
    ap.add_argument("--mass", type=float, nargs="+", default=[0.01, 0.05, 0.5, 1.0], help="cube masses [kg]")
    ap.add_argument("--dx", type=float, default=2e-3, help="MPM grid spacing [m]")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="out/bench_hold", help="folder for the report")
    args = ap.parse_args(argv)
    lines = pinch_table()
    lines += ["", f"GraspLiftCube expert until success (2 s held), dx {args.dx * 1e3:g} mm, seed {args.seed}:", "",
              "| cube [g] | success | thumb force [N] | index force [N] | pads' net force on the cube [N] "
              "| weight [N] | net - weight [% of weight] | max speed, last 1 s [mm/s] | ms per step |",
              "|---|---|---|---|---|---|---|---|---|"]
    lines += [held_row(m, args.dx, args.seed) for m in args.mass]
    text = "\n".join(lines)
    print(text)
    write_report(args.out, "hold.md", text)
    return 0
