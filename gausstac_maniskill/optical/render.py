"""Images of a vision-based tactile sensor from its gel's surface, batched in torch.

The surface is given as its indentation ``depth`` [B, H, W] [m] (positive where the gel is
pushed towards the camera, as the pad's depth map reads it) on the camera's pixel grid (row 0 at
the top, column 0 at the left), and for the markers its tangential displacement ``shear``
[B, H, W, 2] [m] (along the columns, along the rows).

The colour is Taxim's calibrated lookup: each pixel's surface normal, binned by its tilt (in
[0, π/2]) and azimuth (in [−π, π]) as the calibration was, picks six coefficients per channel of a
quadratic in the pixel's place; the change it gives is added to the no-contact frame. The change
the lookup gives a flat surface is taken off, so that an undeformed gel renders as the no-contact
frame itself; so is a tilt within the first bin (under 0.7°), whose azimuth would only pick
the calibration's noise.
"""
from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from ..errors import ConfigError
from .presets import Preset

__all__ = ["shading", "render_rgb", "marker_positions", "marker_rest"]

_TABLES: dict = {}


def _tables(preset: Preset, device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(coefficients [bins², 18] (6 terms × 3 channels per bin), features [H·W, 1, 6], the flat
    surface's colour [H, W, 3] and the background [H, W, 3], float 0–1) at the preset's camera
    resolution, kept per (calibration, resolution, device)."""
    cal, cam = preset.calibration, preset.camera
    key = (str(cal.folder), cam.height, cam.width, str(device))
    if key not in _TABLES:
        bins = cal.bins
        poly = torch.from_numpy(np.array(cal.poly)).permute(1, 2, 3, 0).reshape(bins * bins, 18).to(device)
        y = torch.arange(cam.height, dtype=torch.float32) * (cal.height / cam.height)
        x = torch.arange(cam.width, dtype=torch.float32) * (cal.width / cam.width)
        yy, xx = torch.meshgrid(y, x, indexing="ij")
        feat = torch.stack([xx * xx, yy * yy, xx * yy, xx, yy, torch.ones_like(xx)], -1).reshape(-1, 1, 6).to(device)
        flat = (feat @ poly[(bins - 1) // 2].view(6, 3)).view(cam.height, cam.width, 3)  # tilt 0: a flat surface
        bg = torch.from_numpy(np.array(cal.background)).float().div(255.0).permute(2, 0, 1)[None]
        if (cam.height, cam.width) != (cal.height, cal.width):
            bg = F.interpolate(bg, size=(cam.height, cam.width), mode="bilinear", antialias=True, align_corners=False)
        _TABLES[key] = (poly, feat, flat, bg[0].permute(1, 2, 0).contiguous().to(device))
    return _TABLES[key]


def _check(name: str, x: torch.Tensor, preset: Preset, channels: int | None = None) -> torch.Tensor:
    cam = preset.camera
    want = (cam.height, cam.width) + ((channels,) if channels else ())
    x = torch.as_tensor(x, dtype=torch.float32)
    if x.ndim != len(want) + 1 or tuple(x.shape[1:]) != want:
        raise ConfigError(f"optical sensor {preset.name!r}: {name} has shape {tuple(x.shape)}, expected "
                          f"[B, {', '.join(map(str, want))}] (the camera's {cam.width}x{cam.height} pixels)")
    return x


def _bin_index(depth: torch.Tensor, preset: Preset) -> torch.Tensor:
    """[B, H, W] long: each pixel's normal bin (tilt · bins + azimuth), as Taxim bins it."""
    cal, cam = preset.calibration, preset.camera
    z = depth * (1e3 / cam.mm_per_px)  # towards the camera, in this camera's pixels
    d_row = (z[:, 2:, 1:-1] - z[:, :-2, 1:-1]) * 0.5  # the surface's slopes (central differences)
    d_col = (z[:, 1:-1, 2:] - z[:, 1:-1, :-2]) * 0.5
    tilt = torch.atan(torch.sqrt(d_row * d_row + d_col * d_col))
    azimuth = torch.atan2(d_row, d_col)
    bins = cal.bins
    i_tilt = torch.floor(tilt / (0.5 * math.pi / (bins - 1))).long().clamp_(0, bins - 1)
    i_az = torch.floor((azimuth + math.pi) / (2 * math.pi / (bins - 1))).long().clamp_(0, bins - 1)
    i_az = torch.where(i_tilt == 0, (bins - 1) // 2, i_az)  # within the first tilt bin: flat (no azimuth)
    idx = (i_tilt * bins + i_az).float()[:, None]
    return F.pad(idx, (1, 1, 1, 1), mode="replicate")[:, 0].long()


def shading(depth, preset: Preset) -> torch.Tensor:
    """The colour change [B, H, W, 3] (0–1 units, RGB) that the indentation ``depth``
    [B, H, W] [m] makes on the preset's camera image (zero for an undeformed gel)."""
    depth = _check("depth", depth, preset)
    return _shading(depth, preset, _tables(preset, depth.device))


def _shading(depth: torch.Tensor, preset: Preset, tables) -> torch.Tensor:
    """:func:`shading` of a checked ``depth``, given the preset's :func:`_tables`: each pixel's
    six features times its bin's 6 × 3 coefficients, one small matrix product per pixel."""
    poly, feat, flat, _ = tables
    B, H, W = depth.shape
    coef = poly.index_select(0, _bin_index(depth, preset).reshape(-1)).view(B * H * W, 6, 3)
    colour = torch.bmm(feat.expand(B, -1, -1, -1).reshape(B * H * W, 1, 6), coef)
    return colour.view(B, H, W, 3) - flat


def render_rgb(depth, preset: Preset, markers=None) -> torch.Tensor:
    """The sensor's image [B, H, W, 3] uint8 RGB: the no-contact frame plus :func:`shading` of
    ``depth`` [B, H, W] [m]; with ``markers`` [B, N, 2] (pixel places, column then row) the
    preset's dots drawn dark there."""
    depth = _check("depth", depth, preset)
    tables = _tables(preset, depth.device)
    img = tables[3] + _shading(depth, preset, tables)
    if markers is not None:
        markers = torch.as_tensor(markers, dtype=torch.float32, device=depth.device)
        if markers.ndim != 3 or markers.shape[0] != depth.shape[0] or markers.shape[2] != 2:
            raise ConfigError(f"optical sensor {preset.name!r}: markers has shape {tuple(markers.shape)}, expected "
                              f"[{depth.shape[0]}, N, 2] (pixel places, column then row)")
        img = img * (1.0 - preset.markers.darkness * _dots(markers, preset))[..., None]
    return (img.clamp_(0.0, 1.0) * 255.0 + 0.5).to(torch.uint8)


def _dots(centres: torch.Tensor, preset: Preset) -> torch.Tensor:
    """[B, H, W] coverage in [0, 1] of dots of the preset's radius at ``centres`` [B, N, 2] px."""
    cam = preset.camera
    r = preset.markers.radius * 1e3 / cam.mm_per_px
    k = int(math.ceil(r + 1.0))
    off = torch.arange(-k, k + 1, dtype=torch.float32, device=centres.device)
    oy, ox = torch.meshgrid(off, off, indexing="ij")
    base = torch.floor(centres)  # [B, N, 2]
    px = base[..., None, None, 0] + ox  # [B, N, K, K]
    py = base[..., None, None, 1] + oy
    dist = torch.sqrt((px - centres[..., None, None, 0]) ** 2 + (py - centres[..., None, None, 1]) ** 2)
    cover = (r + 0.5 - dist).clamp(0.0, 1.0)
    inside = (px >= 0) & (px < cam.width) & (py >= 0) & (py < cam.height)
    flat = (py.clamp(0, cam.height - 1) * cam.width + px.clamp(0, cam.width - 1)).long()
    B = centres.shape[0]
    out = torch.zeros(B, cam.height * cam.width, device=centres.device)
    out.scatter_reduce_(1, flat.reshape(B, -1), (cover * inside).reshape(B, -1), reduce="amax")
    return out.reshape(B, cam.height, cam.width)


def marker_rest(preset: Preset) -> torch.Tensor:
    """[N, 2] the markers' rest places in pixels (column, row): the preset's square grid,
    centred on the image, row by row."""
    cam, grid = preset.camera, preset.markers
    pitch = grid.spacing * 1e3 / cam.mm_per_px
    nx, ny = int(cam.width // pitch), int(cam.height // pitch)
    xs = (cam.width - 1) / 2 + (torch.arange(nx) - (nx - 1) / 2) * pitch
    ys = (cam.height - 1) / 2 + (torch.arange(ny) - (ny - 1) / 2) * pitch
    yy, xx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([xx.reshape(-1), yy.reshape(-1)], -1).float()


def marker_positions(shear, depth, preset: Preset) -> tuple[torch.Tensor, torch.Tensor]:
    """The markers moved by the surface: (rest [N, 2], places [B, N, 2]) in pixels (column, row).

    Each marker moves with the tangential displacement ``shear`` [B, H, W, 2] [m] (along the
    columns, along the rows) at its rest place, and looks displaced away from the image centre by
    the surface's push towards the camera ``depth`` [B, H, W] [m] (perspective: a factor
    d / (d − δ) at camera distance d)."""
    shear = _check("shear", shear, preset, channels=2)
    depth = _check("depth", depth, preset)
    cam = preset.camera
    rest = marker_rest(preset).to(shear.device)
    grid = torch.stack([(rest[:, 0] + 0.5) / cam.width * 2 - 1, (rest[:, 1] + 0.5) / cam.height * 2 - 1], -1)
    grid = grid[None, None].expand(shear.shape[0], 1, -1, 2)
    fields = torch.cat([shear.permute(0, 3, 1, 2), depth[:, None]], 1)  # [B, 3, H, W]
    at = F.grid_sample(fields, grid, mode="bilinear", align_corners=False)[:, :, 0].permute(0, 2, 1)  # [B, N, 3]
    moved = rest + at[..., :2] * (1e3 / cam.mm_per_px)
    centre = torch.tensor([(cam.width - 1) / 2, (cam.height - 1) / 2], device=shear.device)
    scale = cam.distance / (cam.distance - at[..., 2:3])
    return rest, centre + (moved - centre) * scale
