"""How PhysX settles a fingertip pressed by its joint drives into a spring, per coupling scheme.

``python -m gausstac_maniskill.bench drive_contact [--stiffness 6e3 1e5] [--sim-freq 100]`` (no MPM).

ManiSkill's Allegro hand drives its index finger 0.01 rad past where the tip touches a one-sided
spring of stiffness K. The reference is the static balance of drives and spring,
``kp (q* - q) = Jᵀ F``, solved from the Jacobian; the table gives the spring force after 0.05,
0.2 and 1 s and the wall time per SAPIEN step, per scheme: ``fold`` (the spring folded into the
joint drives, :class:`~gausstac_maniskill.tasks.joint_contact.JointContact`), ``d6`` (a PhysX D6
joint with a soft linear limit) and ``explicit`` (the last step's force applied), and per solver.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

__all__ = ["main", "press"]


def press(scheme: str, tgs: bool, iterations: int, stiffness: float, sim_freq: int = 100,
          seconds: float = 1.0, offset: float = 0.01) -> dict:
    """One run (see the module docstring). Returns the spring force [N] per SAPIEN step,
    the static balance [N] and the mean wall time per step [s]."""
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401
    import sapien

    from ..tasks.contact_spring import GAIN, frame_along
    from ..tasks.joint_contact import JointContact
    from ..transforms import matrix_to_quat

    env = gym.make("Empty-v1", robot_uids="allegro_hand_right", sim_backend="physx_cpu",
                   sim_config=dict(sim_freq=sim_freq, scene_config=dict(enable_tgs=tgs,
                                                                         solver_position_iterations=iterations)))
    try:
        env.reset(seed=0)
        robot = env.unwrapped.agent.robot
        art, scene = robot._objs[0], env.unwrapped.scene.sub_scenes[0]
        joints = art.get_active_joints()
        names = [j.name[j.name.index("joint_"):] for j in joints]
        flex = [names.index(f"joint_{k}.0") for k in (1, 2, 3)]
        tip = robot.links_map["link_3.0_tip"]._objs[0]
        hand = JointContact(art, [tip])
        limits = np.array([j.get_limit()[0] for j in joints], np.float64)  # a posture inside every joint's range
        q0 = np.clip(art.qpos.astype(np.float64), limits[:, 0] + 0.05, limits[:, 1] - 0.05)
        art.set_qpos(q0.astype(np.float32))
        art.set_qvel(np.zeros(len(q0), np.float32))
        for j, t in zip(joints, q0):
            j.set_drive_target(float(t))
        hand.model.compute_full_jacobian(q0)
        J = hand.jacobian(q0, 0)
        closing = np.zeros_like(q0)
        closing[flex] = 1.0
        n = -(J[:3] @ closing)
        n /= np.linalg.norm(n)  # the spring pushes back against the closing
        anchor = np.asarray(tip.entity_pose.p, np.float64)
        target = q0 + offset * closing
        for j, t in zip(joints, target):
            j.set_drive_target(float(t))
        if scheme == "d6":
            frame = sapien.Pose(anchor.astype(np.float32), matrix_to_quat(frame_along(n)).astype(np.float32))
            spring = scene.create_drive(None, frame, tip.entity, tip.entity_pose.inv() * frame)
            spring.set_limit_x(0.0, 1.0e30, stiffness, 0.0)
        kp = np.array([j.stiffness for j in joints])
        forces, wall = [], 0.0
        for _ in range(int(round(seconds * sim_freq))):
            origin = np.asarray(tip.entity_pose.p, np.float64)
            depth = max(-float((origin - anchor) @ n), 0.0)
            force = stiffness * depth * n
            t0 = time.perf_counter()
            if scheme == "fold":
                row = np.zeros((1, 1, 7))
                row[0, 0, :3], row[0, 0, 6] = force, GAIN * depth  # secant stiffness GAIN |F| / δ = K
                hand.fold(row)
            elif scheme == "explicit" and depth > 0.0:
                com = np.asarray((tip.entity_pose * tip.cmass_local_pose).p, np.float64)
                tip.add_force_torque(force.astype(np.float32), np.cross(origin - com, force).astype(np.float32))
            scene.step()
            wall += time.perf_counter() - t0
            forces.append(stiffness * max(-float((np.asarray(tip.entity_pose.p) - anchor) @ n), 0.0))
        a = J[:3].T @ n  # static balance of drives and spring, linearised at the touch
        dq = np.linalg.solve(np.diag(kp) + stiffness * np.outer(a, a), kp * (target - q0))
        return dict(forces=np.array(forces), balance=stiffness * max(-float(a @ dq), 0.0),
                    wall=wall / max(len(forces), 1))
    finally:
        env.close()


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="bench drive_contact", description=__doc__.splitlines()[0])
    p.add_argument("--stiffness", type=float, nargs="+", default=[6.0e3, 1.0e5], help="spring K [N/m]")
    p.add_argument("--sim-freq", type=int, default=100)
    args = p.parse_args(argv)
    runs = [("fold", False, 15), ("fold", True, 15), ("d6", False, 15), ("d6", False, 255), ("d6", True, 15),
            ("explicit", False, 15)]
    rows = []
    for K in args.stiffness:
        for scheme, tgs, it in runs:
            r = press(scheme, tgs, it, K, args.sim_freq)
            f, hz = r["forces"], args.sim_freq
            at = [f[min(int(round(s * hz)) - 1, len(f) - 1)] for s in (0.05, 0.2, 1.0)]
            ok = np.all(np.isfinite(f))
            rows.append([f"{K:g}", scheme, ("TGS" if tgs else "PGS") + f" {it}", *(f"{v:.3g}" for v in at),
                         f"{r['balance']:.3g}", f"{100 * (at[2] / r['balance'] - 1):+.1f} %" if ok else "NaN",
                         f"{f.max():.3g}", f"{1e3 * r['wall']:.2f}"])
    head = ["K [N/m]", "scheme", "solver iters", "0.05 s", "0.2 s", "1 s", "balance", "error at 1 s", "peak",
            "ms/step"]
    print(f"Index tip pressed 0.01 rad into a spring, SAPIEN at {args.sim_freq} Hz (spring force [N] after t)\n")
    print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
    print("\n".join("| " + " | ".join(r) + " |" for r in rows))
    return 0
