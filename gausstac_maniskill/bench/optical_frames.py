"""Optical sensors against real frames: the ``taxim`` package's GelSight data pack (48 frames of
a ball pressed into the gel, each with its touch's centre and radius in pixels).

For each frame, :func:`~gausstac_maniskill.optical.press_sphere` presses the calibration ball
into the preset's flat gel to the depth at which the simulated contact radius equals the frame's
(:func:`match_radius`, once per distinct radius), renders it at the frame's centre, and compares it with
the real frame: PSNR and SSIM in the disc of 1.5x the touch radius and over the whole image.
Baselines, with the same lookup and no-contact frame: the no-contact frame alone, and Taxim's own
height-map approximation of the same press (the ball's geometric cap at the depth whose
intersection circle has the frame's radius, deformed by Taxim's Gaussian pyramid; it needs
``jax``, which ``make bench`` installs; without it the column is empty).

The lookup table was fitted by Taxim on these same frames, so inside the contact the comparison
is in-sample for the colour; what it measures is the surface's shape (the contact and the gel's
skirt around it) and where the model puts it.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

__all__ = ["real_frames", "ssim_map", "frame_metrics", "compare_frames"]


def real_frames(name: str) -> dict:
    """The data pack of preset ``name``: ``imgs`` [N, H, W, 3] uint8 RGB, ``centres`` [N, 2] px
    (column, row), ``radii`` [N] px, ``f0`` [H, W, 3] uint8 RGB (the no-contact frame)."""
    from ..optical import preset

    pack = np.load(os.path.join(preset(name).calibration.folder, "dataPack.npz"))
    return dict(imgs=pack["imgs"][..., ::-1], centres=pack["touch_center"].astype(float),
                radii=pack["touch_radius"].astype(float), f0=pack["f0"][..., ::-1])


def ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[H, W] structural similarity (Wang et al. 2004: Gaussian window σ = 1.5 px, 11 px wide,
    K1 = 0.01, K2 = 0.03) of two uint8 RGB images [H, W, 3], on their luminance."""
    w = torch.tensor([0.299, 0.587, 0.114], dtype=torch.float64)
    x = (torch.from_numpy(a.astype(np.float64)) @ w)[None, None]
    y = (torch.from_numpy(b.astype(np.float64)) @ w)[None, None]
    g = torch.exp(-0.5 * (torch.arange(11, dtype=torch.float64) - 5) ** 2 / 1.5 ** 2)
    g = (g / g.sum())[:, None] * (g / g.sum())[None, :]

    def blur(z):
        return F.conv2d(F.pad(z, (5, 5, 5, 5), mode="reflect"), g[None, None])

    mx, my = blur(x), blur(y)
    vx, vy, cxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return s[0, 0].numpy()


def frame_metrics(sim: np.ndarray, real: np.ndarray, centre, radius: float) -> dict:
    """PSNR [dB] and mean SSIM of ``sim`` against ``real`` (uint8 RGB [H, W, 3]) in the disc of
    1.5 ``radius`` [px] about ``centre`` (column, row) and over the whole image."""
    h, w = real.shape[:2]
    yy, xx = np.mgrid[:h, :w]
    disc = (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 <= (1.5 * radius) ** 2
    err = (sim.astype(np.float64) - real.astype(np.float64)) ** 2
    s = ssim_map(sim, real)

    def psnr(m):
        return 10 * math.log10(255.0 ** 2 / max(float(err[m].mean()), 1e-12))

    return dict(psnr_disc=psnr(disc), ssim_disc=float(s[disc].mean()), psnr_all=psnr(np.ones_like(disc)),
                ssim_all=float(s.mean()))


def match_radius(sensor, radius_px: float, model: str = "linear", tol_px: float = 0.25, step: float = 0.15e-3,
                 path: list | None = None, iterations: int = 10, **kwargs):
    """The :class:`~gausstac_maniskill.optical.PressedGel` whose contact radius is nearest
    ``radius_px``, and that radius [px]. The press deepens by ``step`` [m] from the last one
    solved (each warm-started from the one before: finite strain needs the continuation) until
    its radius passes ``radius_px``, then the depth is bisected in that last step to within
    ``tol_px``. ``path``: the presses solved so far, ``[(depth, radius, gel)]`` deepening (kept
    by the caller, so that radii matched in increasing order march once). A depth the model
    cannot solve (an element inverts) ends the march."""
    from ..errors import SimulationError
    from ..optical import image, press_gel

    path = [] if path is None else path
    limit = min(sensor.ball_radius, sensor.gel.thickness) * 0.995

    def solve(depth, warm):
        gel = press_gel(sensor, None, depth, model=model, warm=warm, **kwargs)
        return gel, image(gel, sensor, markers=False).contact_radius_px

    while (not path or path[-1][1] < radius_px) and (path[-1][0] if path else 0.0) + step < limit:
        depth = (path[-1][0] if path else 0.0) + step
        try:
            gel, r = solve(depth, path[-1][2] if path else None)
        except SimulationError:
            break
        path.append((depth, r, gel))
    if not path:
        raise SimulationError(f"optical frames: no press of {model!r} could be solved")
    above = next((i for i, p in enumerate(path) if p[1] >= radius_px), None)
    best = min(path, key=lambda p: abs(p[1] - radius_px))
    if above is None or abs(best[1] - radius_px) <= tol_px:
        return best[2], best[1]
    (lo, _, warm), hi = (path[above - 1] if above else (0.0, 0.0, None)), path[above][0]
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        try:
            gel, r = solve(mid, warm)
        except SimulationError:
            hi = mid
            continue
        if abs(r - radius_px) < abs(best[1] - radius_px):
            best = (mid, r, gel)
        if abs(r - radius_px) <= tol_px:
            break
        if r < radius_px:
            lo, warm = mid, gel
        else:
            hi = mid
    return best[2], best[1]


_TAXIM: dict = {}  # preset name -> taxim's JAX simulator


def taxim_depth(name: str, centre, radius_px: float):
    """[H, W] indentation [m] of Taxim's own approximation of the calibration ball pressed to
    the depth whose intersection with the gel has radius ``radius_px``; None without ``jax``."""
    try:
        import jax  # noqa: F401
        from taxim import Taxim
    except ImportError:
        return None
    from ..optical import preset

    sensor = preset(name)
    if name not in _TAXIM:
        _TAXIM[name] = Taxim(Path(sensor.calibration.folder), backend="jax")
    sim = _TAXIM[name]
    mm = sensor.calibration.mm_per_px
    R, a = sensor.ball_radius * 1e3, radius_px * mm  # [mm]
    depth = R - math.sqrt(max(R * R - a * a, 0.0))
    h, w = sensor.calibration.height, sensor.calibration.width
    yy, xx = np.mgrid[:h, :w]
    r2 = ((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) * mm * mm
    height = np.where(r2 < R * R, R - np.sqrt(np.clip(R * R - r2, 0, None)), R)  # the ball's surface [mm]
    shifted = sim._TaximJax__get_shifted_height_map(depth, np.asarray(height, np.float32))
    deformed, _ = sim._TaximJax__compute_gel_pad_deformation(shifted)
    gel = sim._TaximJax__get_gel_map((h, w))
    return np.asarray(gel - deformed, np.float64) * 1e-3



def compare_frames(name: str = "gelsight", model: str = "linear", element: float = 0.25e-3, limit=None,
                   progress: bool = True, half_width: float | None = None, keep_images=(0, 1, 2)) -> dict:
    """Every frame of preset ``name``'s data pack against its simulated press (``model``,
    ``element``, ``half_width``: :func:`~gausstac_maniskill.optical.press_gel`) and the two
    baselines. Returns ``rows`` (one dict per frame), ``images`` (for the frames in
    ``keep_images``: index -> (real, simulated, taxim or None) uint8 RGB), ``centres`` [N, 2] px
    and ``matched`` (touch radius -> (depth [m], simulated radius [px], normal force [N]))."""
    from ..optical import image, preset, render_rgb
    from .common import progress_bar

    sensor = preset(name)
    data = real_frames(name)
    n = len(data["imgs"]) if limit is None else min(limit, len(data["imgs"]))
    matched, path = {}, []
    for r in sorted(set(data["radii"][:n].tolist())):  # deepening: one march for them all
        matched[r] = match_radius(sensor, r, model=model, element=element, half_width=half_width, path=path)
    rows, images = [], {}
    bar = progress_bar(n, f"optical frames ({name})", progress)
    for i in range(n):
        real, c, r = data["imgs"][i], data["centres"][i], data["radii"][i]
        gel, got = matched[r]
        sim = image(gel, sensor, c, markers=False).rgb
        row = dict(frame=i, radius_px=r, sim_radius_px=got, depth_mm=gel.press_depth * 1e3, force_n=gel.force[2])
        row.update({f"sim_{k}": v for k, v in frame_metrics(sim, real, c, r).items()})
        row.update({f"f0_{k}": v for k, v in frame_metrics(data["f0"], real, c, r).items()})
        tx = taxim_depth(name, c, r)
        tx_img = None
        if tx is not None:
            tx_img = render_rgb(torch.from_numpy(tx).float()[None], sensor)[0].numpy()
            row.update({f"taxim_{k}": v for k, v in frame_metrics(tx_img, real, c, r).items()})
        rows.append(row)
        if i in keep_images:
            images[i] = (real, sim, tx_img)
        bar.update(1)
    bar.close()
    return dict(rows=rows, images=images, centres=data["centres"],
                matched={r: (g.press_depth, got, float(g.force[2])) for r, (g, got) in matched.items()})


def summary_lines(result: dict, name: str, model: str) -> list[str]:
    """The markdown table of :func:`compare_frames`' result: mean and worst frame of each metric,
    per method, and the share of frames where the simulation beats both baselines in the disc."""
    rows = result["rows"]
    methods = [("sim", f"press_sphere ({model})"), ("taxim", "Taxim's height map"), ("f0", "no-contact frame")]
    lines = [f"{name}: {len(rows)} real frames; the disc is 1.5x the touch radius", "",
             "| method | PSNR disc mean / worst [dB] | SSIM disc mean / worst | PSNR image mean [dB] | SSIM image mean |",
             "|---|---|---|---|---|"]
    for key, label in methods:
        if f"{key}_psnr_disc" not in rows[0]:
            lines.append(f"| {label} | (needs jax) | | | |")
            continue
        col = {m: np.array([r[f"{key}_{m}"] for r in rows]) for m in ("psnr_disc", "ssim_disc", "psnr_all", "ssim_all")}
        lines.append(f"| {label} | {col['psnr_disc'].mean():.2f} / {col['psnr_disc'].min():.2f} | "
                     f"{col['ssim_disc'].mean():.3f} / {col['ssim_disc'].min():.3f} | {col['psnr_all'].mean():.2f} | "
                     f"{col['ssim_all'].mean():.3f} |")
    base = [k for k in ("taxim", "f0") if f"{k}_psnr_disc" in rows[0]]
    wins = [all(r["sim_psnr_disc"] > r[f"{k}_psnr_disc"] and r["sim_ssim_disc"] > r[f"{k}_ssim_disc"] for k in base)
            for r in rows]
    err = np.array([r["sim_radius_px"] - r["radius_px"] for r in rows])
    lines += ["", f"Frames where the simulation beats {' and '.join(base)} in the disc (PSNR and SSIM): "
              f"{sum(wins)}/{len(rows)}. Contact-radius error [px]: mean {np.abs(err).mean():.2f}, "
              f"worst {err[np.argmax(np.abs(err))]:+.2f}.", "",
              "| touch radius [px] | frames | press depth [mm] | simulated radius [px] | normal force [N] |",
              "|---|---|---|---|---|"]
    counts = {}
    for r in rows:
        counts[r["radius_px"]] = counts.get(r["radius_px"], 0) + 1
    for r, (depth, got, force) in sorted(result["matched"].items()):
        lines.append(f"| {r:.0f} | {counts.get(r, 0)} | {depth * 1e3:.3f} | {got:.2f} | {force:.3f} |")
    return lines


def write_frames_figure(out_dir: str, result: dict, frames=(0, 1, 2)) -> str:
    """``out_dir/optical_frames.png``: for three frames the real, simulated and Taxim images and
    the simulated error (|sim − real| summed over channels), cropped about the touch, and the
    radial profile of the luminance about the touch's centre, simulated against real."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = {r["frame"]: r for r in result["rows"]}
    fig, ax = plt.subplots(len(frames), 5, figsize=(15, 3.1 * len(frames)))
    lum = np.array([0.299, 0.587, 0.114])
    for k, i in enumerate(frames):
        real, sim, tx = result["images"][i]
        row = rows[i]
        data_c = result["centres"][i]
        cx, cy, w = int(data_c[0]), int(data_c[1]), int(2 * row["radius_px"])
        crop = (slice(max(cy - w, 0), cy + w), slice(max(cx - w, 0), cx + w))
        err = np.abs(sim.astype(int) - real.astype(int)).sum(-1)
        panels = [(real, "real"), (sim, f"simulated, {row['sim_psnr_disc']:.1f} dB"),
                  (tx, "Taxim" + (f", {row['taxim_psnr_disc']:.1f} dB" if tx is not None else " (needs jax)")),
                  (err, "|sim - real|")]
        for j, (im, title) in enumerate(panels):
            if im is not None:
                ax[k, j].imshow(im[crop], cmap="magma" if im.ndim == 2 else None, vmin=0, vmax=120 if im.ndim == 2 else None)
            ax[k, j].set_title(f"frame {i}: {title}" if j == 0 else title, fontsize=9)
            ax[k, j].axis("off")
        h, wd = real.shape[:2]
        yy, xx = np.mgrid[:h, :wd]
        rr = np.hypot(xx - data_c[0], yy - data_c[1]).astype(int)
        for im, label in [(real, "real"), (sim, "simulated")] + ([(tx, "Taxim")] if tx is not None else []):
            prof = np.bincount(rr.ravel(), (im @ lum).ravel()) / np.maximum(np.bincount(rr.ravel()), 1)
            ax[k, 4].plot(prof[:int(2.5 * row["radius_px"])], label=label)
        ax[k, 4].axvline(row["radius_px"], color="gray", lw=0.8, ls="--")
        ax[k, 4].set_xlabel("radius [px]")
        ax[k, 4].set_ylabel("mean luminance")
        ax[k, 4].legend(fontsize=8)
    fig.tight_layout()
    path = os.path.join(out_dir, "optical_frames.png")
    os.makedirs(out_dir, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path

