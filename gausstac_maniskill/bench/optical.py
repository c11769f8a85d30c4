"""Optical sensors (:mod:`gausstac_maniskill.optical`): the cost of one image per pad.

``python -m gausstac_maniskill.bench optical [--presets gelsight gelsight_mini] [--size 320 240]
[--batch 1 4] [--repeats 50] [--frames gelsight] [--model linear] [--limit N] [--out DIR]``

Per preset and batch: the milliseconds per image of the colour lookup over the no-contact frame
(:func:`~gausstac_maniskill.optical.render_rgb`) and of the markers moved and drawn
(:func:`~gausstac_maniskill.optical.marker_positions` and the dots), on a surface with a
Gaussian indentation of 0.5 mm and a uniform 0.2 mm shear, on this process's torch threads.
Writes the table and ``optical.png``: each preset's image of that surface with its markers.

Then the real frames of ``--frames`` (:mod:`.optical_frames`: each pressed with
:func:`~gausstac_maniskill.optical.press_sphere` and compared with the real image and two
baselines; ``optical_frames.png``), and the marker flow of a ball slid over the GelSight's gel
(``optical_slide.png``). ``--frames none`` skips both.

Last, on the hand: PressCube's expert episode with a GelSight Mini on the index pad
(``optical=``), the milliseconds per control step of its image and markers against the pads'
solve in the same steps (``--no-hand`` skips it).
"""
from __future__ import annotations

import time

import numpy as np
import torch

from .common import cli, write_report


def _surface(cam, batch: int):
    yy, xx = np.mgrid[:cam.height, :cam.width].astype(float)
    r2 = ((xx - cam.width / 2) ** 2 + (yy - cam.height / 2) ** 2) * (cam.mm_per_px * 1e-3) ** 2
    depth = torch.tensor(0.5e-3 * np.exp(-r2 / (1.5e-3) ** 2), dtype=torch.float32).expand(batch, -1, -1).contiguous()
    shear = torch.full((batch, cam.height, cam.width, 2), 0.2e-3)
    return depth, shear


def time_point(name: str, size, batch: int, repeats: int) -> dict:
    """Milliseconds per image (batch ``batch``) of the lookup alone and with the markers."""
    from ..optical import marker_positions, preset, render_rgb

    sensor = preset(name).at_resolution(*size)
    depth, shear = _surface(sensor.camera, batch)
    render_rgb(depth, sensor)  # tables built once
    t0 = time.perf_counter()
    for _ in range(repeats):
        render_rgb(depth, sensor)
    t1 = time.perf_counter()
    for _ in range(repeats):
        _, moved = marker_positions(shear, depth, sensor)
        render_rgb(depth, sensor, markers=moved)
    t2 = time.perf_counter()
    per = 1e3 / (repeats * batch)
    return dict(preset=name, batch=batch, lookup_ms=(t1 - t0) * per, with_markers_ms=(t2 - t1) * per,
                markers=int(moved.shape[1]))


def main(argv=None) -> int:
    ap = cli("optical", __doc__)
    ap.add_argument("--presets", nargs="+", default=["gelsight", "gelsight_mini"])
    ap.add_argument("--size", nargs=2, type=int, default=[320, 240], metavar=("W", "H"))
    ap.add_argument("--batch", nargs="+", type=int, default=[1, 4])
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--frames", nargs="+", default=["gelsight"], help="presets whose real frames to compare, or none")
    ap.add_argument("--model", default="linear", choices=["linear", "neo_hookean"], help="the gel's pad model")
    ap.add_argument("--limit", type=int, default=None, help="compare only the first N frames")
    ap.add_argument("--no-hand", dest="hand", action="store_false",
                    help="skip the optical pads on the hand (PressCube's expert, timed against the pad's solve)")
    ap.add_argument("--out", default="out/bench_optical")
    args = ap.parse_args(argv)
    rows = [time_point(p, args.size, b, args.repeats) for p in args.presets for b in args.batch]
    lines = [f"Optical image {args.size[0]}x{args.size[1]}, {torch.get_num_threads()} torch threads", "",
             "| preset | batch | markers | lookup [ms/image] | lookup + markers [ms/image] |", "|---|---|---|---|---|"]
    lines += [f"| {r['preset']} | {r['batch']} | {r['markers']} | {r['lookup_ms']:.2f} | {r['with_markers_ms']:.2f} |"
              for r in rows]
    text = "\n".join(lines)
    print(text)
    print("wrote", write_picture(args.out, args.presets, args.size))
    for name in [f for f in args.frames if f != "none"]:
        from .optical_frames import compare_frames, summary_lines, write_frames_figure

        result = compare_frames(name, model=args.model, limit=args.limit)
        table = "\n".join(summary_lines(result, name, args.model))
        print(table)
        text += "\n\n" + table
        print("wrote", write_frames_figure(args.out, result))
    if args.frames != ["none"]:
        print("wrote", write_slide_picture(args.out))
    if args.hand:
        table = "\n".join(hand_lines(time_on_hand(args.size[0])))
        print(table)
        text += "\n\n" + table
    write_report(args.out, "optical.md", text)
    return 0


def write_slide_picture(out_dir: str, depth: float = 0.8e-3, distance: float = 1.5e-3) -> str:
    """``out_dir/optical_slide.png``: the GelSight's image of its calibration ball pressed
    ``depth`` [m] and slid ``distance`` [m] along the columns with friction 1, markers drawn, and
    the markers' motion from rest as arrows (to scale)."""
    import os

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..optical import image, slide_gel

    steps = slide_gel("gelsight", None, depth, distance, steps=6)
    press = image(steps[-1], "gelsight")
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.6))
    ax[0].imshow(press.rgb)
    ax[0].set_title(f"GelSight, ball pressed {depth * 1e3:g} mm, slid {distance * 1e3:g} mm (μ = 1)", fontsize=9)
    d = press.markers - press.marker_rest
    ax[1].imshow(press.rgb, alpha=0.35)
    ax[1].quiver(press.marker_rest[:, 0], press.marker_rest[:, 1], d[:, 0], d[:, 1], color="k", angles="xy",
                 scale_units="xy", scale=1, width=0.002)
    ax[1].set_title(f"marker flow (to scale); largest {np.abs(d).max():.1f} px", fontsize=9)
    for a in ax:
        a.axis("off")
    fig.tight_layout()
    path = os.path.join(out_dir, "optical_slide.png")
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def write_picture(out_dir: str, presets, size) -> str:
    """``out_dir/optical.png``: each preset's image of the bench's surface, with its markers, side by side."""
    import os

    import imageio.v2 as imageio

    from ..optical import marker_positions, preset, render_rgb

    images = []
    for name in presets:
        sensor = preset(name).at_resolution(*size)
        depth, shear = _surface(sensor.camera, 1)
        _, moved = marker_positions(shear * (depth / depth.max())[..., None], depth, sensor)
        images.append(render_rgb(depth, sensor, markers=moved)[0].numpy())
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, "optical.png")
    imageio.imwrite(path, np.concatenate(images, axis=1))
    return path


def time_on_hand(width: int = 320, seed: int = 0) -> dict:
    """PressCube's expert with a GelSight Mini image of ``width`` px on the index pad: per control
    step, the pads' solve [s] (the env's ``step_timing["mpm"]``) and the image with its markers
    [s] (timed on the step's maps, as the observation makes them)."""
    import gymnasium as gym

    from ..experts import make_expert
    from ..optical import pad_images

    env = gym.make("GaussTac-PressCube-v1", obs_mode="state_dict", optical={"index": "gelsight_mini"},
                   optical_width=width)
    try:
        obs, _ = env.reset(seed=seed)
        expert = make_expert(env)
        expert.reset()
        sensor = env.unwrapped.tactile_sensor.config.optical["index"]
        solve, image = [], []
        for _ in range(40):
            obs, _, terminated, truncated, _ = env.step(expert.act(obs))
            solve.append(env.unwrapped.step_timing.get("mpm", 0.0))
            t0 = time.perf_counter()
            pad_images(obs["tactile"]["index"]["depth"], obs["tactile"]["index"]["shear"], sensor)
            image.append(time.perf_counter() - t0)
            if bool(terminated[0]) or bool(truncated[0]):
                break
        cam = sensor.camera
        return dict(width=cam.width, height=cam.height, steps=len(solve), solve_ms=1e3 * float(np.median(solve[1:])),
                    image_ms=1e3 * float(np.median(image[1:])))
    finally:
        env.close()


def hand_lines(r: dict) -> list[str]:
    """The table of :func:`time_on_hand`."""
    return [f"On the hand: PressCube's expert, {r['steps']} control steps, GelSight Mini image "
            f"{r['width']}x{r['height']} on the index pad (medians, first step left out)", "",
            "| pads' solve [ms/step] | index image + markers [ms/step] | image / solve |", "|---|---|---|",
            f"| {r['solve_ms']:.1f} | {r['image_ms']:.1f} | {r['image_ms'] / max(r['solve_ms'], 1e-9):.2f} |"]
