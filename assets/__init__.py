"""GaussTac's packaged assets: one folder per hand (``allegro_hand_right/gaussians.ply`` +
``links.json``, ``ability_hand_right/finger_L2_hull.obj``) and the example captured scene
(``tabletop_scene/gaussians.ply``, made by :mod:`gausstac_maniskill.splat.example_scene`).
Files generated per user (the pad links' rigid cores) go to GaussTac's disk cache,
:mod:`gausstac_maniskill.cache` (its :func:`cache_path` and :func:`cache_dir`, also importable here).

The repository's top-level ``assets/`` is installed as the package
``gausstac_maniskill.assets`` (``pyproject.toml``: package-dir + package-data), so the
files are found through the package wherever it is installed (editable or from a wheel)::

    from gausstac_maniskill.assets import asset_path
    asset_path("allegro_hand_right", "gaussians.ply")
"""
from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from ..cache import cache_dir, cache_path

__all__ = ["ASSET_ROOT", "asset_path", "cache_path", "cache_dir"]


def _root() -> Path:
    root = files(__name__)
    if not isinstance(root, Path):  # e.g. a zip import: SAPIEN, trimesh and Taichi need real files
        raise RuntimeError(f"gausstac_maniskill.assets is not on the file system ({root!r}); "
                           "install gausstac_maniskill as a regular (unzipped) package")
    return root


#: The folder holding the assets (``.../gausstac_maniskill/assets`` when installed from a wheel,
#: the repository's ``assets/`` in an editable install).
ASSET_ROOT: Path = _root()


def asset_path(*parts: str) -> Path:
    """``ASSET_ROOT / parts...`` (it need not exist: some assets are written on first use)."""
    return ASSET_ROOT.joinpath(*parts)
