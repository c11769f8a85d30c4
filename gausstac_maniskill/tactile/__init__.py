"""Tactile pads on hand links and the dense maps (depth, shear, force) they produce."""
from .extract import TaxelBinning, tactile_maps
from .readout import TactileReadout
from .pad import (ALLEGRO_TIPS, Pad, allegro_pad_specs, build_pad, pad_core_meshes, pad_geometry, pad_mesh,
                  pad_specs_for_links)
from .visualize import maps_figure, save_maps_png, write_video

__all__ = ["Pad", "build_pad", "pad_core_meshes", "pad_geometry", "pad_mesh", "allegro_pad_specs", "pad_specs_for_links", "ALLEGRO_TIPS", "TaxelBinning",
           "tactile_maps", "TactileReadout", "maps_figure", "save_maps_png", "write_video"]
