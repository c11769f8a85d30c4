"""Reading a hand Gaussians folder (``gaussians.ply`` + ``links.json``, written by ``gausstac
build-asset``, :mod:`.build`): the Gaussians and link names, the coarser levels of detail, and
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
    """The coarser levels of a hand Gaussians folder, or None: ``(fine spacing [m], ((spacing
    [m], GaussianSet), ...))``, finest first, from ``links.json``'s ``spacing`` and its
    ``levels`` list (``[{"file": ..., "spacing": ...}, ...]``; an older folder's single
    ``coarse`` entry is read as a one-level list). Every level is the same hand built at
    another spacing: the same link names and frames as ``gaussians.ply``. A camera draws the
    coarsest level whose splats are no wider than its pixels at the hand
    (:class:`gausstac_maniskill.render.Detail`). Cached per process."""
    from .gaussians import load_ply

    links, meta, names = _links_json(folder)
    levels = meta.get("levels", [meta["coarse"]] if "coarse" in meta else None)
    field = "levels" if "levels" in meta else "coarse"
    if levels is None:
        return None
    if not isinstance(levels, list) or not levels:
        raise AssetError(f"{links}: '{field}' must be a non-empty list of {{'file', 'spacing'}} objects")
    try:
        fine = float(meta["spacing"])
        entries = [(float(e["spacing"]), os.path.join(folder, e["file"])) for e in levels]
    except (KeyError, TypeError, ValueError) as e:
        raise AssetError(f"{links}: each of '{field}' needs 'file' and 'spacing' [m], and the file 'spacing' "
                         f"({e!r})") from None
    spacings = [fine] + [s for s, _ in entries]
    if not all(0 < a < b for a, b in zip(spacings, spacings[1:])):
        raise AssetError(f"{links}: spacing={fine} and {field}[*].spacing={spacings[1:]} must grow from level "
                         "to level (metres)")
    out = []
    for k, (spacing, ply) in enumerate(entries):
        if not os.path.isfile(ply):
            raise AssetError(f"{ply}: hand Gaussians file of a level of detail not found ({links}: {field}[{k}].file)")
        gs = load_ply(ply)
        if len(gs) and int(gs.link_id.max()) >= len(names):
            raise AssetError(f"{ply}: link ids reach {int(gs.link_id.max())}, but {links} names {len(names)} links")
        out.append((spacing, gs))
    return fine, tuple(out)
