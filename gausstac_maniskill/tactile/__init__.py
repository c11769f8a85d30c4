"""Tactile pads on hand links and the dense maps (depth, shear, force) they produce."""
from .extract import TaxelBinning, tactile_maps
from .pad import ALLEGRO_TIPS, Pad, allegro_pad_specs, build_pad

__all__ = ["Pad", "build_pad", "allegro_pad_specs", "ALLEGRO_TIPS", "TaxelBinning", "tactile_maps"]
