"""Pictures of tactile maps: depth with shear arrows per pad, as an RGB array, PNG or MP4."""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np


def maps_figure(maps: Mapping[str, Mapping], pads: Sequence[str] | None = None, depth_max: float = 2e-3,
                shear_scale: float = 6e-3, title: str = "") -> np.ndarray:
    """Depth maps (colour, mm) with shear arrows, pads side by side; returns uint8 RGB [H, W, 3].

    Args:
        maps: ``{pad: {"depth": [R, C] m, "shear": [R, C, 2] m, ...}}`` (torch or numpy).
        pads: which pads, in order (default: all).
        depth_max: top of the colour scale [m].
        shear_scale: shear [m] drawn as an arrow one taxel grid wide.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pads = list(pads or maps)
    fig, axes = plt.subplots(1, len(pads), figsize=(3.2 * len(pads), 3.0), dpi=100, squeeze=False)
    for ax, name in zip(axes[0], pads):
        d = _host(maps[name]["depth"]) * 1e3
        s = _host(maps[name]["shear"]) * 1e3
        im = ax.imshow(d, cmap="magma", vmin=0.0, vmax=depth_max * 1e3, origin="lower")
        yy, xx = np.mgrid[0:d.shape[0], 0:d.shape[1]]
        step = max(1, d.shape[0] // 8)
        ax.quiver(xx[::step, ::step], yy[::step, ::step], s[::step, ::step, 0], s[::step, ::step, 1],
                  color="cyan", angles="xy", scale_units="width", scale=shear_scale * 1e3, width=0.006)
        ax.set_title(name, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, fraction=0.046, label="depth [mm]")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return img


def save_maps_png(path: str, maps: Mapping[str, Mapping], **kwargs) -> None:
    """Write :func:`maps_figure` to a PNG file."""
    import imageio.v2 as imageio

    imageio.imwrite(path, maps_figure(maps, **kwargs))


def write_video(path: str, frames: Sequence[np.ndarray], fps: int = 10) -> None:
    """Write uint8 RGB frames [H, W, 3] to an MP4 (H.264, via imageio-ffmpeg)."""
    import imageio.v2 as imageio

    with imageio.get_writer(path, fps=fps, macro_block_size=1) as w:
        for f in frames:
            w.append_data(np.asarray(f))


def _host(a) -> np.ndarray:
    """A map as a NumPy array on the host (torch tensors on any device, or arrays)."""
    return a.detach().cpu().numpy() if hasattr(a, "detach") else np.asarray(a)
