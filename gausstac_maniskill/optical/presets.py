"""The shipped optical sensors: a calibration (Taxim's format) with the gel, camera and marker
grid it belongs to. ``preset("gelsight")`` and ``preset("gelsight_mini")`` read the calibration
data that the ``taxim`` package ships (real frames of the GelSight and of the GelSight Mini);
``preset(folder)`` reads a user's own calibration folder with the GelSight's gel and markers.

A DIGIT preset is not shipped: Taxim's repository holds a DIGIT ``polycalib.npz``, but its
no-contact frame (``real_bg.npy``) and data pack are not in the stored copy this was built from.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from pathlib import Path

from ..errors import ConfigError
from .calibration import Calibration, load_calibration

__all__ = ["Gel", "Camera", "MarkerGrid", "Preset", "preset", "PRESETS"]


@dataclass(frozen=True)
class Gel:
    """The elastomer: ``size`` (x, y) [m] seen by the camera, ``thickness`` [m], ``curvature_radius``
    [m] of its dome (None: flat), Young's modulus ``E`` [Pa] and Poisson's ratio ``nu``."""

    size: tuple[float, float]
    thickness: float
    curvature_radius: float | None
    E: float
    nu: float


@dataclass(frozen=True)
class Camera:
    """The sensor camera: ``width`` × ``height`` pixels, ``mm_per_px`` on the gel at that
    resolution, and its ``distance`` [m] from the gel surface (a surface pushed towards it by
    δ looks larger by d / (d − δ): the markers' motion with the surface's normal motion)."""

    width: int
    height: int
    mm_per_px: float
    distance: float


@dataclass(frozen=True)
class MarkerGrid:
    """Printed dots on the gel: a square grid of ``spacing`` [m] centred on the image, dots of
    ``radius`` [m] that darken the image by ``darkness`` (0: invisible, 1: black)."""

    spacing: float
    radius: float
    darkness: float = 0.8


@dataclass(frozen=True)
class Preset:
    """One optical sensor. ``ball_radius`` [m]: the radius of the ball its calibration frames
    were pressed with."""

    name: str
    calibration: Calibration
    gel: Gel
    camera: Camera
    markers: MarkerGrid
    ball_radius: float

    def at_resolution(self, width: int, height: int) -> "Preset":
        """The same sensor imaged at ``width`` × ``height`` pixels (same field of view)."""
        if width < 8 or height < 8:
            raise ConfigError(f"optical preset {self.name!r}: resolution {width}x{height} must be at least 8x8")
        scale = self.calibration.width / width
        return replace(self, camera=replace(self.camera, width=int(width), height=int(height),
                                            mm_per_px=self.calibration.mm_per_px * scale))


def _taxim_folder(name: str) -> Path:
    try:
        from taxim import CALIB_GELSIGHT, CALIB_GELSIGHT_MINI
    except ImportError:  # pragma: no cover - taxim is a dependency
        raise ConfigError("optical presets need the 'taxim' package (pip install taxim)") from None
    return {"gelsight": CALIB_GELSIGHT, "gelsight_mini": CALIB_GELSIGHT_MINI}[name]


#: Shipped presets: their gel, markers and calibration ball. The ball is Taxim's (Basics/
#: sensorParams.py of CMURoboTouch/Taxim: ball_radius = 4.00/2 mm); the GelSight Mini's data
#: pack does not say its ball, so the same 2 mm radius is assumed. The gel thicknesses, moduli
#: and camera distances are typical values, not part of the calibration data.
PRESETS = {
    "gelsight": dict(thickness=4e-3, curvature_radius=None, E=0.15e6, nu=0.48, distance=0.030,
                     markers=MarkerGrid(spacing=1.2e-3, radius=0.15e-3), ball_radius=2e-3),
    "gelsight_mini": dict(thickness=3e-3, curvature_radius=None, E=0.15e6, nu=0.48, distance=0.025,
                          markers=MarkerGrid(spacing=1.0e-3, radius=0.12e-3), ball_radius=2e-3),
}


@functools.lru_cache(maxsize=8)
def _load(key: str) -> Preset:
    if key in PRESETS:
        folder, spec = _taxim_folder(key), PRESETS[key]
    else:
        folder, spec = Path(key), PRESETS["gelsight"]
    cal = load_calibration(folder)
    mm = cal.mm_per_px
    gel = Gel(size=(cal.width * mm * 1e-3, cal.height * mm * 1e-3), thickness=spec["thickness"],
              curvature_radius=spec["curvature_radius"], E=spec["E"], nu=spec["nu"])
    camera = Camera(width=cal.width, height=cal.height, mm_per_px=mm, distance=spec["distance"])
    name = key if key in PRESETS else Path(key).name
    return Preset(name, cal, gel, camera, spec["markers"], spec["ball_radius"])


def preset(name) -> Preset:
    """The optical sensor ``name``: ``"gelsight"``, ``"gelsight_mini"``, or the path of a
    calibration folder in Taxim's format (:func:`~.calibration.load_calibration`; the gel and
    markers are the GelSight's: give your own with ``dataclasses.replace(preset(folder),
    gel=Gel(...), markers=MarkerGrid(...), ball_radius=...)``). Read once and kept."""
    if isinstance(name, Preset):
        return name
    key = str(name)
    if key not in PRESETS and not Path(key).exists():
        raise ConfigError(f"optical preset {key!r}: not a preset name ({', '.join(PRESETS)}) "
                          "nor an existing calibration folder")
    return _load(key if key in PRESETS else str(Path(key).resolve()))
