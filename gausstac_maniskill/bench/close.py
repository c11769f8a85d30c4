"""``python -m gausstac_maniskill.bench close [--dx 1e-3] [--steps 30] [--reaction [explicit]] [--sim-freq 100]``
— the whole hand closed hard on a fixed cube.

``GaussTac-PressCube-v1`` with every joint driven towards closing. Prints per control step each
pad's normal force [N], how deep each pad link's rigid core lies inside the cube [mm], the range
of the particles' volume ratio J and principal stretches, the fastest pad link's speed [m/s] and
the wall time. ``--reaction`` applies the pads' reaction to their links (folded into the joint
drives, or ``explicit``: forces one SAPIEN step late); a ``SimulationError`` ends the run and is
printed.
"""
from __future__ import annotations

import time

import numpy as np

from .common import cli, write_report


def core_depth_in_cube(env, link: str, vertices: np.ndarray) -> float:
    """How deep [m] the deepest of ``vertices`` ([N, 3], link ``link``'s frame: its rigid
    core) lies inside PressCube's cube now (<= 0: outside it). ``env``: the unwrapped
    ``GaussTac-PressCube-v1``, env 0."""
    from ..transforms import vec7_to_matrix
    from ..tasks.press_cube import CUBE_HALF

    T = env._pose_source.all_link_poses()[0, env._pose_source.link_names.index(link)].double().numpy()
    C = vec7_to_matrix(env.block.pose.raw_pose)[0].double().numpy()
    local = (vertices @ T[:3, :3].T + T[:3, 3] - C[:3, 3]) @ C[:3, :3]
    return float(np.min(np.asarray(CUBE_HALF) - np.abs(local), axis=1).max())  # > 0: inside, by this much


def main(argv: list[str] | None = None) -> int:
    ap = cli("close", __doc__)
    ap.add_argument("--dx", type=float, default=1e-3, help="MPM grid spacing [m] (default 1 mm, the tasks')")
    ap.add_argument("--steps", type=int, default=30, help="control steps (default 30)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sim-freq", type=int, default=100, help="SAPIEN steps per second (default 100, ManiSkill's)")
    ap.add_argument("--reaction", nargs="?", const="implicit", choices=("implicit", "explicit"), default=None,
                    help="apply the pads' reaction to their links: implicit contact springs (default) or explicit "
                         "forces one SAPIEN step late")
    ap.add_argument("--out", default="out/bench_close", help="folder for the report")
    args = ap.parse_args(argv)
    import gymnasium as gym
    from tqdm import tqdm

    import gausstac_maniskill  # noqa: F401  (registers the tasks)
    from ..agents.base import core_meshes
    from ..errors import SimulationError

    env = gym.make("GaussTac-PressCube-v1", sim_backend="physx_cpu", obs_mode="state_dict", mpm_dx=args.dx,
                   pad_reaction=args.reaction or False, sim_config=dict(sim_freq=args.sim_freq))
    env.reset(seed=args.seed)
    u = env.unwrapped
    specs = u.agent.gausstac_pads
    cores = {link: np.concatenate([c.vertices for c in pieces]) for link, pieces in core_meshes(type(u.agent)).items()}
    action = np.ones(env.action_space.shape, np.float32)
    links = [u.agent.robot.links_map[s.link] for s in specs]
    lines = [f"GaussTac-PressCube-v1, whole hand closing (action +1), dx = {args.dx * 1e3:g} mm, seed {args.seed}, "
             f"SAPIEN at {args.sim_freq} Hz, pad reaction on the links {args.reaction or 'off'}",
             "",
             "| step | " + " | ".join(f"{s.name} [N]" for s in specs) + " | deepest core vertex in the cube [mm] "
             "| J min..max | stretch min..max | fastest pad link [m/s] | wall [s] |",
             "|" + "---|" * (len(specs) + 6)]
    peak = {s.name: 0.0 for s in specs}
    fastest = 0.0
    try:
        for k in tqdm(range(args.steps), desc="close", leave=False):
            t0 = time.perf_counter()
            try:
                env.step(action)
            except SimulationError as e:
                lines.append(f"| {k} | SimulationError: {str(e)[:160]} |")
                break
            wall = time.perf_counter() - t0
            deepest = max(core_depth_in_cube(u, link, v) for link, v in cores.items())
            F = {s.name: u.pad_force(s.name).item() for s in specs}
            for n, f in F.items():
                peak[n] = max(peak[n], f)
            st = u.cosims[0].flat_state()
            Fd = st["p_F"].reshape(-1, 3, 3)
            J, sv = np.linalg.det(Fd), np.linalg.svd(Fd, compute_uv=False)
            speed = max(float(np.linalg.norm(link.get_linear_velocity()[0].numpy())) for link in links)
            fastest = max(fastest, speed)
            lines.append(f"| {k} | " + " | ".join(f"{F[s.name]:.1f}" for s in specs)
                         + f" | {max(deepest, 0.0) * 1e3:.2f} | {J.min():.2f}..{J.max():.2f} "
                           f"| {sv.min():.2f}..{sv.max():.2f} | {speed:.2f} | {wall:.2f} |")
    finally:
        env.close()
    lines += ["", "peak force [N]: " + ", ".join(f"{n} {v:.1f}" for n, v in peak.items())
              + f"; fastest pad link {fastest:.2f} m/s"]
    text = "\n".join(lines)
    print(text)
    tag = f"_{args.sim_freq}Hz_{args.reaction}" if args.reaction else ""
    write_report(args.out, f"close_dx{args.dx * 1e3:g}mm{tag}.md", text)
    return 0
