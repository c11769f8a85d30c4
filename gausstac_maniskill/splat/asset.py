"""Reading a hand Gaussians folder (``gaussians.ply`` + ``links.json``, written by ``gausstac
build-asset``, :mod:`.build`): the Gaussians and link names, the coarser level of detail, and
the links whose surfaces are closed. One reader for the tasks, the agents and the demo; it
needs no ManiSkill. Every function is cached per process and raises
:class:`~gausstac_maniskill.errors.AssetError` naming the file and the field.
"""
from __future__ import annotations

import json
import os
from functools import lru_cache

from ..errors import AssetError

__all__ = ["load_hand_gaussians", "load_hand_closed_links", "load_hand_lod"]


@lru_cache(maxsize=8)
def _links_json(folder: str) -> tuple[str, dict, list]:
    """(path of ``links.json``, its object, its link names), read once per process; both
    files of the folder must exist."""
    ply, links = os.path.join(folder, "gaussians.ply"), os.path.join(folder, "links.json")
    for path in (ply, links):
        if not os.path.isfile(path):
            raise AssetError(f"{path}: hand Gaussians file not found (GaussTacAgent.gausstac_gaussians); "
                             "build it with `gausstac build-asset --urdf <hand.urdf> --out <folder>`")
    try:
        with open(links) as f:
            meta = json.load(f)
        names = list(meta["link_names"])
    except (ValueError, KeyError, TypeError) as e:
        raise AssetError(f"{links}: expected a JSON object with a 'link_names' list ({e})") from None
    return links, meta, names


@lru_cache(maxsize=8)
def load_hand_gaussians(folder: str):
    """``(GaussianSet, link names)`` of a hand Gaussians folder (cached per process)."""
    from .gaussians import load_ply

    _, _, names = _links_json(folder)
    return load_ply(os.path.join(folder, "gaussians.ply")), names


@lru_cache(maxsize=8)
def load_hand_closed_links(folder: str) -> tuple:
    """The links of a hand Gaussians folder whose Gaussians lie on closed surfaces with their
    normals pointing out (``links.json``'s ``closed_links``, written by ``gausstac build-asset``;
    empty if absent): the splat camera skips those facing away. Cached per process."""
    links, meta, names = _links_json(folder)
    closed = meta.get("closed_links", [])
    if not isinstance(closed, list) or not all(isinstance(n, str) for n in closed):
        raise AssetError(f"{links}: 'closed_links' must be a list of link names, got {closed!r}")
    unknown = sorted(set(closed) - set(names))
    if unknown:
        raise AssetError(f"{links}: closed_links {unknown} are not in link_names")
    return tuple(closed)


@lru_cache(maxsize=8)
def load_hand_lod(folder: str):
    """The coarser level of a hand Gaussians folder, or None: ``(fine spacing [m], coarse
    spacing [m], coarse GaussianSet)`` from ``links.json``'s ``spacing`` and ``coarse`` entry
    (``{"file": ..., "spacing": ...}``; the same link names and frames as ``gaussians.ply``).
    A camera whose pixels at the hand are at least the coarse spacing draws the coarse set
    (:class:`gausstac_maniskill.render.SceneGaussians`). Cached per process."""
    from .gaussians import load_ply

    links, meta, names = _links_json(folder)
    coarse = meta.get("coarse")
    if coarse is None:
        return None
    try:
        fine, spacing, ply = float(meta["spacing"]), float(coarse["spacing"]), os.path.join(folder, coarse["file"])
    except (KeyError, TypeError, ValueError) as e:
        raise AssetError(f"{links}: 'coarse' needs 'file' and 'spacing' [m], and the file 'spacing' ({e!r})") from None
    if not 0 < fine < spacing:
        raise AssetError(f"{links}: coarse.spacing={spacing} must exceed spacing={fine} (metres)")
    if not os.path.isfile(ply):
        raise AssetError(f"{ply}: coarse hand Gaussians file not found ({links}: coarse.file)")
    gs = load_ply(ply)
    if len(gs) and int(gs.link_id.max()) >= len(names):
        raise AssetError(f"{ply}: link ids reach {int(gs.link_id.max())}, but {links} names {len(names)} links")
    return fine, spacing, gs
