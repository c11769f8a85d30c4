"""``python -m gausstac_maniskill.bench grasp [--masses 0.01 0.05 0.5] [--dx 2e-3] [--obs-mode rgb]`` —
the grasp-and-lift expert on free cubes.

``GaussTac-GraspLiftCube-v1`` (``physx_cpu``, ``pd_joint_pos``, ``pad_reaction=True``, SAPIEN at
100 Hz) with its scripted expert, per cube mass and grid spacing: success and its control step,
the cube's final height [mm], its largest speed over the last second of the hold [mm/s], the
thumb's and index pad's mean normal force against the grip target [N], and the wall time per
control step split into physics, MPM, tactile and render [ms].
"""
from __future__ import annotations

import numpy as np

from .common import cli, run_expert_episode, split_cells, step_split_ms, write_report


def main(argv: list[str] | None = None) -> int:
    ap = cli("grasp", __doc__)
    ap.add_argument("--masses", type=float, nargs="+", default=[0.01, 0.05, 0.5], help="cube masses [kg]")
    ap.add_argument("--dx", type=float, nargs="+", default=[2e-3], help="MPM grid spacings [m]")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--obs-mode", default="rgb", help="ManiSkill obs mode (rgb: the splat camera renders)")
    ap.add_argument("--out", default="out/bench_grasp", help="folder for the report")
    args = ap.parse_args(argv)
    import gymnasium as gym

    import gausstac_maniskill.tasks  # noqa: F401  (registers the tasks with ManiSkill)

    lines = [f"GaussTac-GraspLiftCube-v1, scripted expert, seed {args.seed}, pd_joint_pos, SAPIEN 100 Hz, "
             f"obs_mode {args.obs_mode}", "",
             "| dx [mm] | mass [g] | success at step | height [mm] | max speed, last 1 s [mm/s] | thumb / index "
             "[N] | grip target [N] | ms/step: physics | mpm | tactile | render | total |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for dx in args.dx:
        for mass in args.masses:
            env = gym.make("GaussTac-GraspLiftCube-v1", sim_backend="physx_cpu", obs_mode=args.obs_mode,
                           control_mode="pd_joint_pos", mpm_dx=dx, cube_mass=mass)
            try:
                u = env.unwrapped
                speeds, forces = [], []

                def record(info, action):
                    speeds.append(float(info["cube_speed"][0]))
                    forces.append((u.pad_force("thumb").item(), u.pad_force("index").item()))

                obs, info, done, timing, expert = run_expert_episode(env, args.seed, f"grasp {mass * 1e3:g} g", record)
                last = slice(-min(int(round(u.control_freq)), len(speeds)), None)  # the last second
                f = np.mean(forces[last], axis=0)
                lines.append(f"| {dx * 1e3:g} | {mass * 1e3:g} | {'-' if done is None else done} "
                             f"| {float(info['height'][0]) * 1e3:.1f} | {1e3 * max(speeds[last]):.3f} "
                             f"| {f[0]:.2f} / {f[1]:.2f} | {expert.grip:.2f} | {split_cells(step_split_ms(timing))} |")
            finally:
                env.close()
    text = "\n".join(lines)
    print(text)
    write_report(args.out, "grasp.md", text)
    return 0
