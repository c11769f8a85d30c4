"""Consistent look: the hand's Gaussians against SAPIEN's lit render of the same hand.

``python -m gausstac_maniskill.bench look [--sizes 128x128 320x240] [--out DIR]`` (about 3 min on 2 cores)

For each of the six gestures of ``GaussTac-Gesture-v1`` the gesture expert drives the hand to
its gesture (same seed) in two envs that differ only in the camera: ``camera="sapien"`` (SAPIEN's
rasterizer, the task's lighting) and ``camera="splat"`` (our Gaussians over SAPIEN's render of
the rest of the scene). Both images come from the task's default camera at the same pose and
intrinsics. The hand's pixels are those SAPIEN's segmentation gives to the robot's links;
PSNR [dB] is over those pixels, MS-SSIM (pytorch-msssim, window 7 at 128 px) over the
hand's bounding box with the background made equal in both images. Writes a side-by-side
PNG per size (SAPIEN | splat | |difference| × 4) to ``--out``.

This measures the issue's point 3 as it stands: the hand's Gaussians carry colours baked from
its meshes, unlit, while SAPIEN shades the meshes with the scene's lights.
"""
from __future__ import annotations

import math
import os
import time

import numpy as np
import torch

from . import cli, write_report

CAMERA = "splat_camera"


def _hand_mask(env, obs) -> torch.Tensor:
    """[H, W] bool: pixels SAPIEN's segmentation gives to the robot's links."""
    seg = obs["sensor_data"][CAMERA]["segmentation"][0, ..., 0].cpu()
    robot = env.unwrapped.agent.robot
    ids = [int(k) for k, v in env.unwrapped.segmentation_id_map.items()
           if getattr(v, "articulation", None) is robot or v in getattr(robot, "links", [])]
    return torch.isin(seg, torch.tensor(ids, dtype=seg.dtype))


def _reach(env, gesture: str, seed: int):
    """Reset with ``gesture`` fixed and drive the hand there with the expert (<= 40 steps)."""
    from ..experts import make_expert

    env.unwrapped.fixed_gesture = gesture
    obs, _ = env.reset(seed=seed)
    expert = make_expert(env.unwrapped)
    expert.reset()
    for _ in range(40):
        obs, _, _, _, info = env.step(expert.act(obs))
        if bool(info["success"].all()):
            break
    return obs


def compare(size: tuple[int, int], seed: int = 0, gestures=None) -> tuple[list[dict], np.ndarray]:
    """Per gesture (default: all six): PSNR and MS-SSIM of the splat image against SAPIEN's,
    on hand pixels. Returns (rows, strip image [H', W', 3] uint8)."""
    import gymnasium as gym
    from pytorch_msssim import ms_ssim

    from .. import register
    from ..tasks.gesture import GESTURES

    register()
    kw = dict(sim_backend="physx_cpu", control_mode="pd_joint_delta_pos", splat_size=size)
    envs = {cam: gym.make("GaussTac-Gesture-v1", camera=cam, obs_mode=mode, **kw)
            for cam, mode in (("sapien", "rgb+segmentation"), ("splat", "rgb"))}
    rows, tiles = [], []
    try:
        for g in gestures or sorted(GESTURES):
            obs = {cam: _reach(env, g, seed) for cam, env in envs.items()}
            mask = _hand_mask(envs["sapien"], obs["sapien"])
            ref = obs["sapien"]["sensor_data"][CAMERA]["rgb"][0, ..., :3].cpu().float() / 255.0
            img = obs["splat"]["sensor_data"][CAMERA]["rgb"][0, ..., :3].cpu().float() / 255.0
            mse = float(((img - ref) ** 2)[mask].mean()) if mask.any() else float("nan")
            ys, xs = torch.nonzero(mask, as_tuple=True)
            y0, y1, x0, x1 = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
            a = torch.where(mask[..., None], img, ref)[y0:y1, x0:x1].permute(2, 0, 1)[None]
            b = ref[y0:y1, x0:x1].permute(2, 0, 1)[None]
            side = min(a.shape[-2:])
            win = 7 if side >= 7 * 16 else (5 if side >= 5 * 16 else 3)
            pad = max(0, win * 16 + 1 - side)  # MS-SSIM's 4 downsamplings need a minimum size
            if pad:
                a, b = (torch.nn.functional.pad(t, (0, pad, 0, pad), mode="replicate") for t in (a, b))
            rows.append(dict(gesture=g, size=size, pixels=int(mask.sum()),
                             psnr=10 * math.log10(1.0 / max(mse, 1e-12)),
                             msssim=float(ms_ssim(a, b, data_range=1.0, win_size=win))))
            diff = ((img - ref).abs() * 4).clamp(0, 1) * mask[..., None]
            tiles.append(torch.cat([ref, img, diff], dim=1))
    finally:
        for env in envs.values():
            env.close()
    strip = (torch.cat(tiles, dim=0).numpy() * 255 + 0.5).astype(np.uint8)
    return rows, strip


def format_table(rows: list[dict]) -> str:
    out = ["| size | gesture | hand pixels | PSNR on hand pixels [dB] | MS-SSIM (hand box) |", "|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['size'][0]}x{r['size'][1]} | {r['gesture']} | {r['pixels']} | {r['psnr']:.1f} | "
                   f"{r['msssim']:.3f} |")
    for size in sorted({r["size"] for r in rows}):
        sel = [r for r in rows if r["size"] == size]
        out.append(f"| {size[0]}x{size[1]} | **mean** | | **{np.mean([r['psnr'] for r in sel]):.1f}** | "
                   f"**{np.mean([r['msssim'] for r in sel]):.3f}** |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = cli("look", __doc__)
    ap.add_argument("--sizes", nargs="+", default=["128x128", "320x240"], help="WxH of the camera")
    ap.add_argument("--out", default="out/bench_look", help="folder for look.md and the PNG strips")
    args = ap.parse_args(argv)
    import imageio.v3 as iio

    os.makedirs(args.out, exist_ok=True)
    t0 = time.perf_counter()
    rows = []
    for s in args.sizes:
        w, h = (int(v) for v in s.lower().split("x"))
        r, strip = compare((w, h))
        rows += r
        iio.imwrite(os.path.join(args.out, f"look_{w}x{h}.png"), strip)
    text = f"total {time.perf_counter() - t0:.0f} s\n\n" + format_table(rows)
    print(text)
    write_report(args.out, "look.md", text)
    return 0
