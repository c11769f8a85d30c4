"""A vision-based tactile sensor's calibration, in the folder format of Taxim (Si and Yuan,
RA-L 2022) and of the ``taxim`` package:

* ``polycalib.npz``: ``grad_r``, ``grad_g``, ``grad_b`` [bins, bins, 6], per bin of the surface
  normal (its tilt in [0, π/2], its azimuth in [−π, π]) the coefficients of a quadratic in the
  pixel's place (x², y², xy, x, y, 1) that gives the colour change from the no-contact frame, in
  0–255 units. As the ``taxim`` package reads them, ``grad_b`` holds the red channel and
  ``grad_r`` the blue one.
* the no-contact frame: ``dataPack.npz`` ``f0`` [H, W, 3] (BGR, as OpenCV wrote it) or
  ``real_bg.npy``.
* ``params.json``: ``sensor`` with ``pixmm`` (mm per pixel), ``num_bins``, ``h`` and ``w``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError

__all__ = ["Calibration", "load_calibration"]


@dataclass(frozen=True)
class Calibration:
    """A sensor's optical calibration (read-only arrays).

    Attributes:
        folder: where it was read.
        poly: [3, bins, bins, 6] float32, RGB: the colour change [0–1] of a pixel per normal bin
            (tilt, azimuth), as coefficients of (x², y², xy, x, y, 1), x and y in pixels of the
            full-resolution image (column, row).
        background: [H, W, 3] uint8 RGB, the no-contact frame.
        mm_per_px: size of a full-resolution pixel on the gel [mm].
    """

    folder: Path
    poly: np.ndarray
    background: np.ndarray
    mm_per_px: float

    @property
    def bins(self) -> int:
        return self.poly.shape[1]

    @property
    def height(self) -> int:
        return self.background.shape[0]

    @property
    def width(self) -> int:
        return self.background.shape[1]


#: polycalib.npz's arrays in the order of the red, green and blue channels (as the taxim package reads them)
_RGB_KEYS = ("grad_b", "grad_g", "grad_r")


def _read(path: Path, what: str):
    if not path.is_file():
        raise ConfigError(f"optical calibration {path.parent}: {path.name} is missing ({what})")
    try:
        if path.suffix == ".json":
            return json.loads(path.read_text())
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, json.JSONDecodeError) as exc:
        raise ConfigError(f"optical calibration {path.parent}: {path.name} cannot be read as {what}: {exc}") from None


def load_calibration(folder) -> Calibration:
    """Read the Taxim-format calibration in ``folder`` (see the module's docstring). Raises
    :class:`~gausstac_maniskill.errors.ConfigError` naming the file that is missing or malformed."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"optical calibration: {folder} is not a folder (expected polycalib.npz, "
                          "dataPack.npz or real_bg.npy, and params.json)")
    params = _read(folder / "params.json", "JSON with sensor.pixmm, sensor.num_bins, sensor.h, sensor.w")
    try:
        sensor = params["sensor"]
        mm_per_px, bins = float(sensor["pixmm"]), int(sensor["num_bins"])
        h, w = int(sensor["h"]), int(sensor["w"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"optical calibration {folder}: params.json lacks sensor.{exc} "
                          "(expected sensor.pixmm, sensor.num_bins, sensor.h, sensor.w)") from None
    if not (mm_per_px > 0 and bins > 1 and h > 0 and w > 0):
        raise ConfigError(f"optical calibration {folder}: params.json sensor values must be positive "
                          f"(pixmm={mm_per_px}, num_bins={bins}, h={h}, w={w})")
    with _read(folder / "polycalib.npz", "an npz of grad_r, grad_g, grad_b") as poly:
        try:
            channels = [np.asarray(poly[k], np.float64) for k in _RGB_KEYS]
        except KeyError as exc:
            raise ConfigError(f"optical calibration {folder}: polycalib.npz lacks {exc} "
                              "(expected grad_r, grad_g, grad_b)") from None
    for c, k in zip(channels, _RGB_KEYS):
        if c.shape != (bins, bins, 6):
            raise ConfigError(f"optical calibration {folder}: polycalib.npz {k} has shape {c.shape}, "
                              f"expected ({bins}, {bins}, 6) (num_bins from params.json)")
    if (folder / "real_bg.npy").is_file():
        bg = np.asarray(_read(folder / "real_bg.npy", "an [H, W, 3] image"))
    else:
        with _read(folder / "dataPack.npz", "an npz with the no-contact frame f0") as pack:
            if "f0" not in pack.files:
                raise ConfigError(f"optical calibration {folder}: dataPack.npz lacks f0 (the no-contact frame)")
            bg = np.asarray(pack["f0"])
    if bg.shape != (h, w, 3):
        raise ConfigError(f"optical calibration {folder}: the no-contact frame has shape {bg.shape}, "
                          f"expected ({h}, {w}, 3) (h and w from params.json)")
    bg = np.ascontiguousarray(np.clip(bg, 0, 255).astype(np.uint8)[..., ::-1])  # BGR -> RGB
    poly_rgb = (np.stack(channels) / 255.0).astype(np.float32)
    for a in (bg, poly_rgb):
        a.setflags(write=False)
    return Calibration(folder=folder, poly=poly_rgb, background=bg, mm_per_px=mm_per_px)
