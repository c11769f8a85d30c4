"""Consistent look: the hand's Gaussians against SAPIEN's lit render of the same hand.

``python -m gausstac_maniskill.bench look [--sizes 128x128 320x240] [--out DIR]``

For each gesture of ``GaussTac-Gesture-v1`` the gesture expert drives the hand there (same seed)
in envs that differ only in the camera: ``camera="sapien"`` and ``camera="splat"`` with each
``splat_lighting`` mode (``"baked"``, ``"scene"``). Prints the PSNR [dB] over the hand's pixels,
MS-SSIM over its bounding box and the splat camera's time per frame; writes a side-by-side PNG
per size.
"""
from __future__ import annotations

import math
import os
import time

import numpy as np
import torch

from .common import cli, write_report

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


MODES = ("baked", "scene")  #: the splat camera's ``lighting`` settings compared


def _frame_ms(envs: dict, repeats: int = 7) -> dict:
    """Median wall time [ms] of one splat camera frame (capture + rgb/depth) of each env at its
    current state, the envs taking turns (so that load from other processes falls on all).
    SAPIEN's background is reused (nothing in it moved) and the co-simulator's posed scene too
    (posed once per step), so this is the splat render with its camera bookkeeping."""
    times = {name: [] for name in envs}
    for _ in range(repeats):
        for name, env in envs.items():
            cam = env.unwrapped._sensors[CAMERA]
            t0 = time.perf_counter()
            cam.capture()
            cam.get_obs(rgb=True, depth=True, position=False, segmentation=False)
            times[name].append(time.perf_counter() - t0)
    return {name: 1e3 * float(np.median(t)) for name, t in times.items()}


def _scores(img: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor) -> dict:
    """PSNR [dB] on the ``mask`` pixels and MS-SSIM over their bounding box (background equal)."""
    from pytorch_msssim import ms_ssim

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
    return dict(psnr=10 * math.log10(1.0 / max(mse, 1e-12)),
                msssim=float(ms_ssim(a, b, data_range=1.0, win_size=win)))


def compare(size: tuple[int, int], seed: int = 0, gestures=None, modes=MODES, timing: bool = True
            ) -> tuple[list[dict], np.ndarray]:
    """Per gesture (default: all six): PSNR and MS-SSIM of the splat image against SAPIEN's on
    hand pixels, and the splat camera's ms per frame, for each lighting mode in ``modes``.
    Returns (rows ``{gesture, size, pixels, <mode>: {psnr, msssim, ms}}``, strip image
    [H', W', 3] uint8: SAPIEN | one splat image per mode | 4×|difference| per mode)."""
    import gymnasium as gym

    from .. import register
    from ..tasks.gesture import GESTURES

    register()
    kw = dict(sim_backend="physx_cpu", control_mode="pd_joint_delta_pos", splat_size=size)
    envs = {"sapien": gym.make("GaussTac-Gesture-v1", camera="sapien", obs_mode="rgb+segmentation", **kw)}
    for mode in modes:
        envs[mode] = gym.make("GaussTac-Gesture-v1", camera="splat", obs_mode="rgb", splat_lighting=mode, **kw)
    rows, tiles = [], []
    try:
        for g in gestures or sorted(GESTURES):
            obs = {name: _reach(env, g, seed) for name, env in envs.items()}
            mask = _hand_mask(envs["sapien"], obs["sapien"])
            images = {name: o["sensor_data"][CAMERA]["rgb"][0, ..., :3].cpu().float() / 255.0
                      for name, o in obs.items()}
            ref = images["sapien"]
            row = dict(gesture=g, size=size, pixels=int(mask.sum()))
            ms = _frame_ms({m: envs[m] for m in modes}) if timing else {}
            for mode in modes:
                row[mode] = _scores(images[mode], ref, mask)
                row[mode]["ms"] = ms.get(mode, float("nan"))
            rows.append(row)
            diffs = [((images[m] - ref).abs() * 4).clamp(0, 1) * mask[..., None] for m in modes]
            tiles.append(torch.cat([ref, *(images[m] for m in modes), *diffs], dim=1))
    finally:
        for env in envs.values():
            env.close()
    strip = (torch.cat(tiles, dim=0).numpy() * 255 + 0.5).astype(np.uint8)
    return rows, strip


def format_table(rows: list[dict]) -> str:
    """Markdown table: per gesture and size, each mode's PSNR, MS-SSIM and ms per frame side by
    side, then the means per size."""
    modes = [k for k, v in rows[0].items() if isinstance(v, dict)]
    head = ["size", "gesture", "hand pixels"]
    for key, label in (("psnr", "PSNR [dB]"), ("msssim", "MS-SSIM"), ("ms", "splat ms/frame")):
        head += [f"{label} {m}" for m in modes]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def cells(vals: dict, bold: bool = False) -> list[str]:
        fmt = {"psnr": "{:.1f}", "msssim": "{:.3f}", "ms": "{:.1f}"}
        b = "**" if bold else ""
        return [f"{b}{fmt[k].format(vals[m][k])}{b}" for k in ("psnr", "msssim", "ms") for m in modes]

    for r in rows:
        out.append("| " + " | ".join([f"{r['size'][0]}x{r['size'][1]}", r["gesture"], str(r["pixels"])]
                                     + cells(r)) + " |")
    for size in sorted({r["size"] for r in rows}):
        sel = [r for r in rows if r["size"] == size]
        mean = {m: {k: float(np.mean([r[m][k] for r in sel])) for k in ("psnr", "msssim", "ms")} for m in modes}
        out.append("| " + " | ".join([f"{size[0]}x{size[1]}", "**mean**", ""] + cells(mean, bold=True)) + " |")
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
