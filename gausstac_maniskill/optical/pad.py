"""An optical sensor looking at a pad: its image from the pad's tactile maps, batched.

The camera sees the pad's taxel layout (x along the finger = the image's columns, y = its rows;
:class:`~gausstac_maniskill.config.SensorLayout`) at ``width`` pixels across, with square
pixels. The pad's depth and shear maps [B, rows, cols] are interpolated bicubically to those
pixels (taxels are cell-centred), and rendered with the preset's calibrated lookup and markers
(:mod:`.render`): the same surface the tactile maps read, imaged as that sensor would.
"""
from __future__ import annotations

from dataclasses import replace

import torch
import torch.nn.functional as F

from ..errors import ConfigError
from .presets import Preset, preset as _preset
from .render import marker_positions, render_rgb

__all__ = ["pad_preset", "pad_images"]


def pad_preset(sensor, layout, width: int = 320) -> Preset:
    """The optical sensor ``sensor`` (a :class:`~.presets.Preset`, its name or a calibration
    folder) imaging a pad's ``layout`` (size (x, y) [m]) at ``width`` pixels along x, square
    pixels; the lookup keeps its calibration's image coordinates."""
    sensor = _preset(sensor)
    width = int(width)
    size_x, size_y = layout.size
    height = max(8, int(round(width * size_y / size_x)))
    if width < 8 or width > 4096:
        raise ConfigError(f"optical pad image: width={width!r} px must be in 8..4096")
    at = sensor.at_resolution(width, height)
    return replace(at, camera=replace(at.camera, mm_per_px=size_x * 1e3 / width))


def pad_images(depth: torch.Tensor, shear: torch.Tensor, sensor: Preset) -> tuple[torch.Tensor, torch.Tensor]:
    """The sensor's image of a pad's maps: ``depth`` [B, rows, cols] [m] (positive into the
    pad) and ``shear`` [B, rows, cols, 2] [m] (along x, along y) -> (rgb [B, H, W, 3] uint8,
    markers [B, N, 2] px, column then row), for ``sensor`` from :func:`pad_preset`."""
    cam = sensor.camera
    if depth.ndim != 3 or shear.shape != depth.shape + (2,):
        raise ConfigError(f"optical pad image: depth {tuple(depth.shape)} and shear {tuple(shear.shape)} must be "
                          "[B, rows, cols] and [B, rows, cols, 2]")
    fields = torch.cat([depth[:, None], shear.permute(0, 3, 1, 2)], 1).float()
    up = F.interpolate(fields, size=(cam.height, cam.width), mode="bicubic", align_corners=False)
    d, s = up[:, 0].contiguous(), up[:, 1:].permute(0, 2, 3, 1).contiguous()
    _, places = marker_positions(s, d, sensor)
    return render_rgb(d, sensor, markers=places), places
