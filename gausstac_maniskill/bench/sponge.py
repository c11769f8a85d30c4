"""``python -m gausstac_maniskill.bench sponge [--dx 2e-3] [--nu 0.2 0.45] [--obs-mode rgb]`` — the
grasp-and-squeeze expert on the free sponge.

``GaussTac-GraspSqueezeSponge-v1`` with its scripted expert, per grid spacing and sponge Poisson
ratio: success and its control step, the compression reached against the target, the sponge's
height [mm], the thumb's and index pad's normal force [N], the sponge's volume change against
linear elasticity's bound (1 − 2ν)·c, the smallest det F, the MPM substeps per SAPIEN step, and
the wall time per control step split into physics, MPM, tactile and render [ms]; with ``rgb``
the last frame is written to ``sponge_<dx>_<nu>.png``.
"""
from __future__ import annotations

import os

import numpy as np

from .common import cli, run_expert_episode, split_cells, step_split_ms, write_report


def main(argv: list[str] | None = None) -> int:
    ap = cli("sponge", __doc__)
    ap.add_argument("--dx", type=float, nargs="+", default=[2e-3], help="MPM grid spacings [m]")
    ap.add_argument("--nu", type=float, nargs="+", default=[0.2, 0.45], help="sponge Poisson's ratios")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--obs-mode", default="rgb", help="ManiSkill obs mode (rgb: the splat camera renders)")
    ap.add_argument("--out", default="out/bench_sponge", help="folder for the report and the pictures")
    args = ap.parse_args(argv)
    import gymnasium as gym
    import imageio.v3 as iio

    import gausstac_maniskill.tasks  # noqa: F401  (registers the tasks with ManiSkill)

    env_id = "GaussTac-GraspSqueezeSponge-v1"
    os.makedirs(args.out, exist_ok=True)
    lines = [f"{env_id}, scripted expert, seed {args.seed}, pd_joint_pos, SAPIEN 100 Hz, obs_mode {args.obs_mode}",
             "", "| dx [mm] | nu | particles | success at step | compression / target | height [mm] "
             "| thumb / index [N] | mean det F - 1 | bound (1-2nu) c | min det F | substeps per SAPIEN step "
             "| ms/step: physics | mpm | tactile | render | total |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for dx in args.dx:
        for nu in args.nu:
            env = gym.make(env_id, sim_backend="physx_cpu", obs_mode=args.obs_mode, control_mode="pd_joint_pos",
                           mpm_dx=dx, sponge_nu=nu)
            try:
                u = env.unwrapped
                substeps = []
                obs, info, done, timing, _ = run_expert_episode(
                    env, args.seed, f"sponge dx {dx * 1e3:g} mm nu {nu:g}",
                    lambda info, action: substeps.append(u.cosims[0].world.last_step.substeps))
                sim = u.cosims[0]
                c = float(info["compression"][0])
                J = np.linalg.det(sim.object_deformation_gradients("sponge"))
                f = (u.touch_force("thumb").item(), u.touch_force("index").item())
                lines.append(f"| {dx * 1e3:g} | {nu:g} | {len(J)} | {'-' if done is None else done} "
                             f"| {c:.3f} / {float(u.target_compression[0]):.3f} "
                             f"| {float(info['height'][0]) * 1e3:.1f} | {f[0]:.3f} / {f[1]:.3f} "
                             f"| {J.mean() - 1:+.4f} | {(1 - 2 * nu) * c:.4f} | {J.min():.3f} "
                             f"| {np.median(substeps):.0f} | {split_cells(step_split_ms(timing))} |")
                rgb = obs.get("sensor_data", {}).get("splat_camera", {}).get("rgb") if isinstance(obs, dict) else None
                if rgb is not None:
                    iio.imwrite(os.path.join(args.out, f"sponge_{dx * 1e3:g}mm_nu{nu:g}.png"),
                                rgb[0].cpu().numpy().astype(np.uint8))
            finally:
                env.close()
    text = "\n".join(lines)
    print(text)
    write_report(args.out, "sponge.md", text)
    return 0
