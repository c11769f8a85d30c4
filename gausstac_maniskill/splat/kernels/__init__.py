"""The rasterizer's Taichi kernels, one module per stage: :mod:`.project` (3D Gaussians to
2D conics), :mod:`.tiles` (tile binning keys), :mod:`.composite` (front-to-back compositing
per tile); :mod:`.common` holds what they share. Called by ``splat.rasterizer``."""
