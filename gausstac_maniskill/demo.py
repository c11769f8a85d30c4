"""``gausstac demo``: the Allegro hand touches a cube and squeezes a sponge.

MuJoCo gives the poses of ManiSkill's Allegro right hand (the hand base is moved
through space; the fingers hold a fixed posture). The index fingertip presses a
rigid cube, slides across its top face, lifts, and the hand then comes down on
an elastoplastic foam sponge glued to the table, squeezing it between the
fingertips and the table. Every control step (50 ms) the co-simulator solves
the four soft fingertip pads at equilibrium (the default pads) and steps the
MLS-MPM sponge; the 3D Gaussian Splatting camera renders the hand (rigid
Gaussians following their links), the pads and the sponge (soft Gaussians
following their deformation gradient) and the cube.

Writes ``out/demo/demo.mp4`` (camera image next to the index pad's depth map
with shear arrows, the middle pad's depth map, and the normal force per pad)
and ``out/demo/demo_strip.png`` (four key frames), and prints timings.

Part 2 runs the ManiSkill plugin: one scripted-expert episode of each registered
task (``GaussTac-Gesture/PressCube/SlideCube/SqueezeSponge/GraspLiftCube-v1``: the last
one a floating hand that pinches a free cube, lifts it and holds it) with the splat render
camera and the four pads' depth maps, to ``out/demo/tasks/<task>.mp4/.png``.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

from . import backend, environment
from .assets import asset_path

INDEX, MIDDLE = "link_3.0_tip", "link_7.0_tip"
ASSET_DIR = asset_path("allegro_hand_right")


def _rotation_between(a, b) -> np.ndarray:
    """Smallest rotation taking unit vector a onto unit vector b."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    if np.linalg.norm(v) < 1e-9:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1 + c)


def load_hand_gaussians(asset_dir: Path = ASSET_DIR):
    """The hand's Gaussians (link-local), their link names and the closed links (whose
    Gaussians face out: the camera skips those facing away), built on first use."""
    from .splat.asset import load_hand_closed_links
    from .splat.asset import load_hand_gaussians as load

    if not (asset_dir / "gaussians.ply").exists() or not (asset_dir / "links.json").exists():
        from .splat import build

        print(f"[demo] building the hand Gaussians asset in {asset_dir} (first run only)")
        build.main(["--out", str(asset_dir)])
    hand, names = load(str(asset_dir))
    return hand, names, load_hand_closed_links(str(asset_dir))


def run(out: str = "out/demo", fast: bool = False, width: int = 320, height: int = 240) -> dict:
    """Run the demo; returns timing statistics (seconds)."""
    from .config import Material
    from .config import SolverSettings
    from .cosim import GaussTacSim
    from .geometry import Box, box_particles
    from .pose import MujocoPoseSource
    from .render import box_gaussians
    from .splat import intrinsics_from_fov, look_at
    from .tactile import allegro_pad_specs
    from .transforms import make_pose

    t_start = time.perf_counter()
    os.makedirs(out, exist_ok=True)
    dx = 2.0e-3 if fast else 1.5e-3
    src = MujocoPoseSource()
    q = np.zeros(len(src.joint_names))
    for j, name in enumerate(src.joint_names):  # a relaxed posture, thumb opposed
        q[j] = {"joint_12.0": 1.2, "joint_13.0": 0.3, "joint_14.0": 0.3}.get(name, 0.15)
    src.set_joint_positions(q)
    # orient the hand so the index pad faces the table (-z), apex 3 mm above z = 0
    pads = allegro_pad_specs()
    pad_links = [p.link for p in pads]
    T_idx = src.link_poses([INDEX])[0, 0].numpy()
    R_b = _rotation_between(T_idx[:3, 0], np.array([0.0, 0.0, -1.0]))
    base0 = make_pose(rotation=R_b)
    src.set_base_pose(base0)

    def hand_at(offset):
        src.set_base_pose(make_pose(base0[:3, 3] + offset, R_b))
        return src.link_poses()[0].numpy()

    names_all = list(src.link_names)
    pad_pose = lambda P: {n: P[names_all.index(n)] for n in pad_links}  # noqa: E731
    settings = SolverSettings(dx=dx)
    from .tactile import build_pad
    from .urdf import default_hand_urdf, link_mesh

    P = hand_at(np.zeros(3))
    S_idx = build_pad(pads[1], link_mesh(default_hand_urdf(), INDEX), settings.particle_spacing,
                      settings.dx).sensor_frame
    apex = P[names_all.index(INDEX)] @ S_idx
    finger_dir = apex[:3, 0] - apex[:3, 0] @ np.array([0, 0, 1.0]) * np.array([0, 0, 1.0])
    finger_dir /= np.linalg.norm(finger_dir)
    side = np.cross([0, 0, 1.0], finger_dir)
    start = -apex[:3, 3] + np.array([0, 0, 3e-3])  # base offset putting the apex 3 mm above z=0
    P = hand_at(start)  # the co-simulation starts there: no jump on the first step
    sim = GaussTacSim(pads, pad_pose(P), settings=settings)
    # scene: a rigid cube below the index tip, a sponge 6 cm to the side
    cube_half = (0.02, 0.02, 0.015)
    cube_pose = make_pose([0, 0, -cube_half[2]])
    sim.add_rigid_object("cube", Box(half_extents=cube_half, pose=cube_pose, friction=0.6))
    sponge_c = 0.06 * side + np.array([0.0, 0.0, 0.0])
    sponge_half = np.array([0.016, 0.016, 0.006]) if fast else np.array([0.018, 0.02, 0.007])
    h = settings.particle_spacing
    sp = box_particles(sponge_c - sponge_half - [0, 0, sponge_half[2]], sponge_c + sponge_half - [0, 0, sponge_half[2]], h)
    sim.world.add_link("table", np.eye(4))
    foam = Material(E=2e4, nu=0.2, density=60.0, model="foam", yield_compression=0.08, hardening=4.0)
    sim.add_soft_object("sponge", sp, foam, link="table", kinematic=sp[:, 2] < sp[:, 2].min() + settings.dx)

    # trajectory of the hand base (offsets from `start`), 50 ms control steps
    path = []
    lin = lambda a, b, n: [a + (b - a) * (k + 1) / n for k in range(n)]  # noqa: E731
    down = np.array([0, 0, -1.0])
    n = 1 if fast else 2
    path += lin(np.zeros(3), down * 4.0e-3, 6 * n)                         # touch + press 1 mm
    path += [path[-1]] * (2 * n)
    path += lin(path[-1], path[-1] + finger_dir * 8e-3, 8 * n)           # slide 8 mm
    path += lin(path[-1], path[-1] - down * 8e-3, 3 * n)                 # lift
    over = sponge_c + np.array([0, 0, 9e-3])
    path += lin(path[-1], over - np.array([0, 0, 3e-3]), 6 * n)           # travel over the sponge
    path += lin(path[-1], path[-1] + down * 13e-3, 10 * n)               # squeeze 4 mm into the foam
    path += [path[-1]] * (2 * n)
    path += lin(path[-1], path[-1] - down * 12e-3, 5 * n)                # release

    # Gaussians: hand (rigid, link-local), cube (object frame), pads + sponge (soft, automatic)
    hand, hand_links, closed = load_hand_gaussians()
    sim.attach_gaussians(hand, hand_links, {"cube": box_gaussians(cube_half, 1.5e-3 if not fast else 2.5e-3)},
                         closed_links=closed)
    n_gauss = len(sim._scene.gaussians)
    target = 0.5 * sponge_c + np.array([0.0, 0.0, 0.005])
    eye = target + 0.20 * finger_dir + 0.09 * np.array([0, 0, 1.0]) - 0.03 * side
    view = look_at(eye, target)
    K = intrinsics_from_fov(width, height, np.deg2rad(50.0))

    frames, log = [], []
    t_sim = t_render = 0.0
    try:
        from tqdm import tqdm

        steps = tqdm(path, desc="demo", unit="step")
    except ImportError:  # pragma: no cover
        steps = path
    for k, off in enumerate(steps):
        P = hand_at(start + off)
        t0 = time.perf_counter()
        maps = sim.step(dict(zip(names_all, P)), 0.05)
        t_sim += time.perf_counter() - t0
        t0 = time.perf_counter()
        img = sim.render(view[None], K[None], width, height, background=(1.0, 1.0, 1.0)).rgb[0]
        t_render += time.perf_counter() - t0
        forces = {nm: sim.pad_pressure_force(nm) for nm in maps}
        log.append(dict(step=k, substeps=sim.world.last_step.substeps, awake=[nm for nm in sim.pads if sim.is_awake(nm)],
                        force_from_stress=forces, sim_s=sim.world.last_step.wall_time,
                        rigid_contact_force={nm: float(m["force"].sum()) for nm, m in maps.items()}))
        frames.append(_panel(img.numpy(), maps, forces, k))
    _write_outputs(out, frames, log)
    stats = dict(steps=len(path), sim_s=t_sim, render_s=t_render, total_s=time.perf_counter() - t_start,
                 gaussians=n_gauss, particles=sim.world.num_particles)
    print(f"[demo] {len(path)} control steps: MPM {t_sim:.1f} s ({1e3 * t_sim / len(path):.0f} ms/step), "
          f"3DGS {t_render:.1f} s ({1e3 * t_render / len(path):.0f} ms/frame, {n_gauss} Gaussians), "
          f"{sim.world.num_particles} particles; total {stats['total_s']:.0f} s")
    peak = max(log, key=lambda r: r["force_from_stress"][INDEX])
    print(f"[demo] peak index-pad force {peak['force_from_stress'][INDEX]:.2f} N (from pad stress) at step "
          f"{peak['step']}; "
          f"wrote {out}/demo.mp4, {out}/demo_strip.png, {out}/demo_log.json")
    return stats


def _panel(rgb, maps, forces, step):
    """One video frame: camera | index depth + shear | middle depth | forces."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(12.8, 3.2), dpi=100,
                             gridspec_kw=dict(width_ratios=[1.45, 1, 1, 1]))
    axes[0].imshow(np.clip(rgb, 0, 1))
    axes[0].set_title(f"3DGS camera, step {step}", fontsize=9)
    for ax, name, title in ((axes[1], INDEX, "index pad: depth + shear"), (axes[2], MIDDLE, "middle pad: depth")):
        d = maps[name]["depth"].numpy() * 1e3
        im = ax.imshow(d, cmap="magma", vmin=0, vmax=2.0, origin="lower")
        if name == INDEX:
            s = maps[name]["shear"].numpy() * 1e3
            yy, xx = np.mgrid[0:d.shape[0], 0:d.shape[1]]
            ax.quiver(xx[::2, ::2], yy[::2, ::2], s[::2, ::2, 0], s[::2, ::2, 1], color="cyan",
                      scale=6, width=0.006)
        ax.set_title(title, fontsize=9)
        fig.colorbar(im, ax=ax, fraction=0.046, label="mm")
    names = list(forces)
    axes[3].bar(range(len(names)), [forces[n] for n in names], color="tab:blue")
    axes[3].set_xticks(range(len(names)), [n.replace("link_", "").replace("_tip", "") for n in names])
    axes[3].set_ylim(0, 12)
    axes[3].set_title("normal force per pad (from pad stress) [N]", fontsize=9)
    for ax in axes[:3]:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.canvas.draw()
    frame = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return frame


def _write_outputs(out, frames, log):
    import imageio.v2 as imageio

    from .tactile import write_video

    write_video(os.path.join(out, "demo.mp4"), frames, fps=10)
    keys = np.linspace(0, len(frames) - 1, 4).astype(int)
    imageio.imwrite(os.path.join(out, "demo_strip.png"), np.concatenate([frames[k] for k in keys], 0))
    with open(os.path.join(out, "demo_log.json"), "w") as f:
        json.dump(log, f, indent=1)


#: task -> its gym.make arguments in part 2 (the grasp runs its expert with absolute joint
#: targets on a 2 mm grid: the contact loop steps the co-simulator after every SAPIEN step)
TASKS = {"GaussTac-Gesture-v1": {}, "GaussTac-PressCube-v1": {}, "GaussTac-SlideCube-v1": {},
         "GaussTac-SqueezeSponge-v1": {},
         "GaussTac-GraspLiftCube-v1": dict(control_mode="pd_joint_pos", mpm_dx=2e-3)}


def run_tasks(out: str = "out/demo/tasks", seed: int = 0) -> list[dict]:
    """One scripted-expert episode of each registered GaussTac task in ManiSkill (held for
    five more steps after success): an MP4 per task of the splat render camera with the four
    pads' depth maps and the index pad's GelSight Mini image beside it, and a PNG of its last
    frame. Returns one summary per task."""
    import gymnasium as gym
    import imageio.v2 as imageio
    from mani_skill.utils.registration import REGISTERED_ENVS

    from .experts import make_expert

    os.makedirs(out, exist_ok=True)
    results = []
    for env_id, kwargs in TASKS.items():
        t0 = time.perf_counter()
        env = gym.make(env_id, obs_mode="state_dict", render_mode="rgb_array", sim_backend="physx_cpu",
                       **{"control_mode": "pd_joint_delta_pos", "optical": {"index": "gelsight_mini"}, **kwargs})
        obs, _ = env.reset(seed=seed)
        expert = make_expert(env)
        expert.reset()
        frames, steps, info, done_at = [], 0, {}, None
        for k in range(1, REGISTERED_ENVS[env_id].max_episode_steps + 6):
            obs, _, terminated, truncated, step_info = env.step(expert.act(obs))
            frames.append(_task_frame(env.render()[0].numpy(), obs["tactile"]))
            if done_at is None:
                steps, info = k, step_info
                if bool(terminated[0]) or bool(truncated[0]):
                    done_at = k
            elif k >= done_at + 5:
                break
        env.close()
        name = env_id.split("-")[1].lower()
        from .tactile import write_video

        write_video(os.path.join(out, f"{name}.mp4"), frames, fps=10)
        imageio.imwrite(os.path.join(out, f"{name}.png"), frames[-1])
        r = dict(task=env_id, steps=steps, success=bool(info["success"][0]), seconds=time.perf_counter() - t0)
        results.append(r)
        print(f"[demo] {env_id}: expert {'succeeded' if r['success'] else 'FAILED'} in {steps} steps "
              f"({r['seconds']:.1f} s) -> {out}/{name}.mp4")
    return results


def _task_frame(rgb: np.ndarray, tactile: dict) -> np.ndarray:
    """The render camera image next to the four pads' depth maps (0–0.5 mm, 16×16 taxels) and,
    where the index pad has an optical sensor, its image (scaled to the camera's height)."""
    h = rgb.shape[0]
    cell = h // 4
    col = []
    for pad in ("thumb", "index", "middle", "ring"):
        d = np.clip(tactile[pad]["depth"][0].numpy() / 0.5e-3, 0, 1)
        img = np.stack([d, d ** 0.5, 1 - d], -1)
        img = np.kron(img, np.ones((cell // 16 + 1, cell // 16 + 1, 1)))[:cell, :cell]
        col.append((img * 255).astype(np.uint8))
    panels = [rgb, np.concatenate(col, 0)[:h]]
    if "rgb" in tactile["index"]:
        import cv2

        optical = tactile["index"]["rgb"][0].numpy()
        panels.append(cv2.resize(optical, (round(optical.shape[1] * h / optical.shape[0]), h),
                                 interpolation=cv2.INTER_AREA))
    return np.concatenate(panels, 1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="gausstac demo", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/demo", help="output folder")
    ap.add_argument("--fine", action="store_true",
                    help="1.5 mm grid and twice the steps (default: 2 mm grid)")
    ap.add_argument("--arch", default=environment.read("GAUSSTAC_ARCH"), choices=["cpu", "cuda", "auto"])
    ap.add_argument("--no-tasks", action="store_true",
                    help="skip part 2: one expert episode of each ManiSkill task (out/demo/tasks/, ~40 s)")
    args = ap.parse_args(argv)
    print(f"[demo] Taichi backend: {backend.init(args.arch)}")
    torch.set_num_threads(1)  # small torch ops: one thread avoids contention with Taichi's pool
    run(args.out, fast=not args.fine)
    if not args.no_tasks:
        run_tasks(os.path.join(args.out, "tasks"))
    return 0
