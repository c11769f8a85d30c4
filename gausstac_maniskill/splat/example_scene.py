"""The example captured scene shipped with the package: a wooden table top in front of a
tiled backdrop and a painted side wall, as a 3DGS capture would hand it over.

It is made from three procedurally textured meshes sampled into flat Gaussians
(:mod:`.surface`), with a degree-1 SH sheen on the table, and stored in its own frame (y up,
arbitrary units, origin at the table top's centre), so it needs :data:`EXAMPLE_PLACEMENT` to
sit under the hand of the GaussTac tasks (table top at z = -0.10 m)::

    from gausstac_maniskill.splat.example_scene import EXAMPLE_PLACEMENT, EXAMPLE_SCENE
    env = gym.make("GaussTac-PressCube-v1", scene_ply=EXAMPLE_SCENE, scene_pose=EXAMPLE_PLACEMENT)

Regenerate it (deterministic): ``python -m gausstac_maniskill.splat.example_scene [OUT.ply]``.
Units: metres in the world layout; colours RGB in [0, 1].
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import torch

from ..assets import asset_path
from .capture import Similarity, transform_gaussians
from .gaussians import GaussianSet, save_ply
from .sh import SH_C1
from .surface import colored_mesh, gaussians_from_surface, sample_surface_blue_noise

__all__ = ["EXAMPLE_SCENE", "EXAMPLE_PLACEMENT", "build_example_scene", "write_example_scene", "main"]

#: the shipped capture (package data)
EXAMPLE_SCENE: Path = asset_path("tabletop_scene", "gaussians.ply")

#: capture frame -> world: 1 capture unit = 0.4 m, capture y (up) -> world z, origin at the
#: table top's centre, which sits at (-0.07, 0.10, -0.10) m in the world
EXAMPLE_PLACEMENT = Similarity(scale=0.4, rotation=(math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0),
                               translation=(-0.07, 0.10, -0.10))

# world layout [m]: the table top and the two walls behind the hand as the task cameras see it
TABLE_X, TABLE_Y, TABLE_Z = (-0.45, 0.31), (-0.25, 0.45), -0.10
WALL_TOP = 0.45
TABLE_SPACING, WALL_SPACING = 0.011, 0.015     # Gaussian spacing [m]: ~8 k Gaussians, < 1 MB
SHEEN = 0.08                                   # degree-1 colour change along SHEEN_DIR
SHEEN_DIR = (0.0, 0.96, -0.28)                 # brighter looking towards the backdrop
TEXTURE_PX = 512


def _smooth_noise(rng: np.random.Generator, shape, cells: int) -> np.ndarray:
    """Value noise in [0, 1]: a cells×cells random grid, bilinearly upsampled to ``shape``."""
    grid = rng.random((cells + 1, cells + 1))
    y = np.linspace(0, cells, shape[0], endpoint=False)
    x = np.linspace(0, cells, shape[1], endpoint=False)
    y0, x0 = y.astype(int), x.astype(int)
    fy, fx = (y - y0)[:, None], (x - x0)[None, :]
    g = grid
    return ((g[y0][:, x0] * (1 - fx) + g[y0][:, x0 + 1] * fx) * (1 - fy)
            + (g[y0 + 1][:, x0] * (1 - fx) + g[y0 + 1][:, x0 + 1] * fx) * fy)


def _wood(rng, size_m) -> np.ndarray:
    """[H, W, 3] wood planks along u: plank seams, per-plank tint, wavy grain."""
    n = TEXTURE_PX
    v, u = np.meshgrid(np.linspace(0, size_m[1], n), np.linspace(0, size_m[0], n), indexing="ij")
    w = 0.12  # plank width [m]; features are wider than the Gaussian spacing
    plank = np.floor(v / w).astype(int)
    tint = rng.uniform(-0.1, 0.1, plank.max() + 1)[plank]
    wobble = 0.01 * np.sin(u * 7.0 + plank * 1.7) + 0.02 * _smooth_noise(rng, (n, n), 6)
    grain = 0.5 + 0.5 * np.sin(2 * np.pi * (v + wobble) / 0.035)
    base = np.array([0.58, 0.40, 0.24]) + tint[..., None]
    img = base * (0.75 + 0.25 * grain[..., None])
    seam = np.abs(v / w - np.round(v / w)) * w < 0.004
    img[seam] *= 0.4
    return np.clip(img[::-1], 0, 1)  # image row 0 is v = 1


def _tiles(rng, size_m) -> np.ndarray:
    """[H, W, 3] square tiles (10 cm) with grout lines, glazes varying tile by tile."""
    n, t = TEXTURE_PX, 0.10
    v, u = np.meshgrid(np.linspace(0, size_m[1], n), np.linspace(0, size_m[0], n), indexing="ij")
    iu, iv = np.floor(u / t).astype(int), np.floor(v / t).astype(int)
    palette = np.array([[0.36, 0.58, 0.62], [0.85, 0.86, 0.82], [0.30, 0.50, 0.56], [0.78, 0.80, 0.76]])
    pick = rng.integers(0, len(palette), (iv.max() + 1, iu.max() + 1))
    img = palette[pick[iv, iu]] * (0.95 + 0.1 * _smooth_noise(rng, (n, n), 24))[..., None]
    grout = (np.minimum(u % t, t - u % t) < 0.006) | (np.minimum(v % t, t - v % t) < 0.006)
    img[grout] = (0.62, 0.60, 0.56)
    return np.clip(img[::-1], 0, 1)


def _paint(rng, size_m) -> np.ndarray:
    """[H, W, 3] warm paint with a darker band (a dado rail) and soft mottling."""
    n = TEXTURE_PX
    v = np.linspace(0, size_m[1], n)[:, None] * np.ones((1, n))
    img = np.array([0.86, 0.80, 0.70]) * (0.93 + 0.07 * _smooth_noise(rng, (n, n), 8))[..., None]
    band = (v > 0.16) & (v < 0.20)
    img[band] = (0.45, 0.30, 0.22)
    return np.clip(img[::-1], 0, 1)


def _textured_quad(corner, edge_u, edge_v, image: np.ndarray):
    """A two-triangle rectangle ``corner + a·edge_u + b·edge_v`` (a, b in [0, 1]) with UVs
    (a, b) and ``image`` as its texture; normal along edge_u × edge_v."""
    import trimesh
    from PIL import Image

    c, eu, ev = (np.asarray(x, dtype=np.float64) for x in (corner, edge_u, edge_v))
    verts = np.array([c, c + eu, c + eu + ev, c + ev])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    mesh = trimesh.Trimesh(verts, [[0, 1, 2], [0, 2, 3]], process=False)
    tex = Image.fromarray((image * 255 + 0.5).astype(np.uint8))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=tex)
    return mesh


def build_example_scene(seed: int = 0) -> GaussianSet:
    """The example scene in the **world** frame (metres, z up), SH degree 1.

    Returns:
        ≈ 8 k flat Gaussians: the table top (z = ``TABLE_Z``) with a degree-1 sheen, the
        tiled backdrop (y = ``TABLE_Y[1]``, facing -y) and the painted side wall
        (x = ``TABLE_X[0]``, facing +x). Deterministic for ``seed``.
    """
    rng = np.random.default_rng(seed)
    (x0, x1), (y0, y1), z0 = TABLE_X, TABLE_Y, TABLE_Z
    h = WALL_TOP - z0
    table = _textured_quad((x0, y0, z0), (x1 - x0, 0, 0), (0, y1 - y0, 0), _wood(rng, (x1 - x0, y1 - y0)))
    back = _textured_quad((x0, y1, z0), (x1 - x0, 0, 0), (0, 0, h), _tiles(rng, (x1 - x0, h)))
    side = _textured_quad((x0, y0, z0), (0, y1 - y0, 0), (0, 0, h), _paint(rng, (y1 - y0, h)))
    sets = []
    for mesh, spacing, sheen in ((table, TABLE_SPACING, True), (back, WALL_SPACING, False),
                                 (side, WALL_SPACING, False)):
        p, n, rgb = sample_surface_blue_noise([colored_mesh(mesh)], spacing, rng)
        g = gaussians_from_surface(p, n, rgb, spacing)
        sh = torch.zeros(len(g), 4, 3)
        sh[:, :1] = g.sh
        if sheen:  # colour += SHEEN (d · SHEEN_DIR), d the view direction; basis (-C1 y, C1 z, -C1 x)
            L = np.asarray(SHEEN_DIR) / np.linalg.norm(SHEEN_DIR)
            sh[:, 1:] = torch.tensor([-L[1], L[2], -L[0]], dtype=torch.float32)[:, None] * (SHEEN / SH_C1)
        sets.append(g.replace(sh=sh))
    return GaussianSet.cat(sets)


def write_example_scene(path=None, seed: int = 0) -> Path:
    """Build the scene, move it into its capture frame (``EXAMPLE_PLACEMENT.inverse()``)
    and write it as an INRIA ``.ply`` (default: the packaged :data:`EXAMPLE_SCENE`)."""
    path = Path(EXAMPLE_SCENE if path is None else path)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_ply(path, transform_gaussians(build_example_scene(seed), EXAMPLE_PLACEMENT.inverse()))
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gausstac_maniskill.splat.example_scene",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="?", default=None, help=f"output .ply (default {EXAMPLE_SCENE})")
    args = parser.parse_args(argv)
    path = write_example_scene(args.out)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
