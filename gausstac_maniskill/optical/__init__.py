"""Vision-based tactile sensors (GelSight, GelSight Mini): RGB images and marker motion from a
gel's solved surface.

* :mod:`.calibration` — a sensor's calibration in Taxim's folder format (``polycalib.npz``,
  the no-contact frame, ``params.json``), read and checked once.
* :mod:`.presets` — the shipped sensors, from the data of the ``taxim`` package, with their
  gel, camera and marker grid.
* :mod:`.render` — surface height [B, H, W] → normals → the calibrated lookup → RGB over the
  no-contact frame; markers moved by the surface's displacement and drawn as dark dots.
* :mod:`.press` — a ball pressed into (or slid over) a flat gel, solved by the pad model and
  imaged: the scene of the calibration frames (:func:`press_sphere`).
* :mod:`.pad` — a sensor looking at a hand's pad: its image from the pad's tactile maps.
"""
from .calibration import Calibration, load_calibration
from .presets import Camera, Gel, MarkerGrid, Preset, preset
from .pad import pad_images, pad_preset
from .press import Press, PressedGel, image, press_gel, press_sphere, slide_gel
from .render import marker_positions, render_rgb, shading

__all__ = ["Calibration", "load_calibration", "Camera", "Gel", "MarkerGrid", "Preset", "preset",
           "shading", "render_rgb", "marker_positions", "Press", "PressedGel", "press_gel", "slide_gel", "image",
           "press_sphere", "pad_preset", "pad_images"]
