"""Hand Gaussians assets: built from a URDF's visual meshes, or aligned from a scan.

An asset is a folder with ``gaussians.ply`` (an INRIA 3DGS file, :mod:`.gaussians`, whose
Gaussians lie in the local frames of their links, posed at run time by
:func:`~gausstac_maniskill.splat.deform.rigid_transform`; extra integer properties
``link_id``, an index into ``link_names``, and ``group``, -1 rigid or k >= 0 inside pad
region k) and ``links.json`` (link names in ``link_id`` order, the source URDF, Gaussians per
link, the spacing, pad names in ``group`` order and, for URDF builds, the ``closed_links``
whose meshes bound solids with outward normals, :func:`.surface.closed_outward`).

:func:`build_from_urdf` puts one flat Gaussian on every blue-noise sample of each link's
visual surface (:mod:`.surface`). :func:`build_from_scan` aligns a point cloud or Gaussian
scene to the URDF hand at a reference pose (:mod:`.align`), gives every point the link of the
nearest posed link surface and moves it into that link's frame (means, rotations, SH).
Units: metres; the URDF root link is the world frame of the reference pose.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np
import torch

from ..errors import AssetError, ConfigError
from ..transforms import transform_points
from ..urdf import URDFModel, default_hand_urdf, parse_urdf
from .align import ScanAlignment, align_point_clouds, assign_links, load_scan
from .gaussians import GaussianSet, quat_to_rotmat, rotmat_to_quat, save_ply
from .sh import rotate_sh
from .surface import (IN_PLANE_SCALE, NORMAL_SCALE, OPACITY_LOGIT, closed_outward, gaussians_from_points,
                      gaussians_from_surface, load_link_meshes, sample_surface_blue_noise)

__all__ = [
    "DEFAULT_SPACING",
    "HandAsset",
    "build_from_urdf",
    "sample_posed_hand",
    "build_from_scan",
    "save_asset",
    "main",
]

DEFAULT_SPACING = 1.5e-3  #: target sample spacing, metres

#: link name -> ``fn(points_local [n, 3]) -> bool mask [n]`` of the pad region
PadRegions = Mapping[str, Callable[[np.ndarray], np.ndarray]]


def _pad_groups(pad_regions: PadRegions | None, link: str, local_points: np.ndarray,
                pad_names: list[str]) -> np.ndarray:
    """[n] ``group`` labels of a link's points: the pad's index inside its region, else -1."""
    group = np.full(len(local_points), -1, dtype=np.int64)
    if pad_regions and link in pad_regions:
        mask = np.asarray(pad_regions[link](local_points), dtype=bool).reshape(-1)
        if mask.shape[0] != len(local_points):
            raise ConfigError(f"pad_regions[{link!r}] returned {mask.shape[0]} values for "
                              f"{len(local_points)} points")
        group[mask] = pad_names.index(link)
    return group


def _check_pads(pad_regions: PadRegions | None, links: Sequence[str]) -> list[str]:
    """Pad names in ``group`` order, after checking each names a built link and is callable."""
    if not pad_regions:
        return []
    for name, fn in pad_regions.items():
        if name not in links:
            raise ConfigError(f"pad_regions names link {name!r}, which has no Gaussians "
                              f"(links: {', '.join(links)})")
        if not callable(fn):
            raise ConfigError(f"pad_regions[{name!r}] must be callable(points_local) -> mask")
    return list(pad_regions)


@dataclass
class HandAsset:
    """Hand Gaussians in link frames, plus what ``links.json`` records.

    Attributes:
        gaussians: link-local Gaussians with ``link_id`` / ``group`` labels.
        link_names: link names in ``link_id`` order.
        pad_names: link names of the pads in ``group`` order.
        meta: extra ``links.json`` fields (source, spacing, ...).
    """

    gaussians: GaussianSet
    link_names: list[str]
    pad_names: list[str] = field(default_factory=list)
    meta: dict = field(default_factory=dict)

    def counts(self) -> dict[str, int]:
        """Gaussians per link."""
        c = torch.bincount(self.gaussians.link_id, minlength=len(self.link_names))
        return {n: int(c[i]) for i, n in enumerate(self.link_names)}


def _progress(iterable, enabled: bool, desc: str):
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, disable=not enabled, leave=False)


def build_from_urdf(urdf: str | os.PathLike | None = None, spacing: float = DEFAULT_SPACING,
                    links: Sequence[str] | None = None, pad_regions: PadRegions | None = None,
                    seed: int = 0, progress: bool = True) -> HandAsset:
    """Gaussians on every link's visual surface, in link frames.

    Args:
        urdf: URDF file; default ManiSkill's Allegro right hand.
        spacing: target sample spacing, metres (≈ area / spacing² Gaussians).
        links: links to build (default every link with a visual, URDF order);
            their order is the ``link_id`` order.
        pad_regions: link name -> ``fn(points_local [n, 3]) -> bool mask [n]``;
            Gaussians of that link where the mask is true get ``group`` = the
            index of the link in ``pad_regions`` (insertion order), others -1.
        seed: sampling seed (the result is deterministic for a seed).
        progress: show a tqdm bar over links.
    """
    if not (isinstance(spacing, (int, float)) and 0 < spacing < 1 and math.isfinite(spacing)):
        raise ConfigError(f"spacing={spacing!r} must be a positive length in metres (< 1)")
    model = parse_urdf(default_hand_urdf() if urdf is None else urdf)
    links = model.visual_links if links is None else list(links)
    if not links:
        raise AssetError(f"{model.path.name}: no link has visual geometry")
    pad_names = _check_pads(pad_regions, links)
    rng = np.random.default_rng(seed)
    meshes = load_link_meshes(model, links)
    sets, sources = [], {}
    closed = [name for name in links if closed_outward(meshes[name])]
    for i, name in enumerate(_progress(links, progress, "gaussians per link")):
        p, nm, c = sample_surface_blue_noise(meshes[name], spacing, rng)
        group = _pad_groups(pad_regions, name, p, pad_names)
        sets.append(gaussians_from_surface(p, nm, c, spacing, link_id=i, group=group))
        sources[name] = sorted({m.source for m in meshes[name]})
    meta = {"source": "urdf", "spacing": float(spacing), "seed": int(seed),
            "colour_sources": sources, "closed_links": closed,
            "splat": {"in_plane_sigma": IN_PLANE_SCALE * spacing,
                      "normal_sigma": NORMAL_SCALE * spacing,
                      "opacity_logit": OPACITY_LOGIT}}
    return HandAsset(GaussianSet.cat(sets), links, pad_names,
                     {"urdf": model.path.name, "robot": model.name, **meta})


# =========================================================================== scans
def sample_posed_hand(model: URDFModel, spacing: float, q=None,
                      links: Sequence[str] | None = None, seed: int = 0,
                      meshes: dict | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area-uniform samples of the hand's visual surface in the world at joints ``q``.

    Args:
        model: the parsed URDF.
        spacing: ≈ one sample per spacing² of surface, metres.
        q: joint positions, as :meth:`URDFModel.joint_map` takes them.
        links: links to sample (default :attr:`URDFModel.visual_links`).
        seed: sampling seed.
        meshes: :func:`.surface.load_link_meshes` of ``links`` if already loaded.

    Returns:
        (points [n, 3] metres, unit normals [n, 3], link index [n] into ``links``),
        in the URDF root frame.
    """
    import trimesh

    links = model.visual_links if links is None else list(links)
    meshes = load_link_meshes(model, links) if meshes is None else meshes
    fk = model.forward_kinematics(q)
    rng = np.random.default_rng(seed)
    P, N, L = [], [], []
    for i, name in enumerate(links):
        T = fk[name]
        for cm in meshes[name]:
            n = max(1, int(round(cm.mesh.area / spacing ** 2)))
            p, fi = trimesh.sample.sample_surface(cm.mesh, n, seed=int(rng.integers(2 ** 31)))
            P.append(transform_points(T, p))
            N.append(np.asarray(cm.mesh.face_normals)[fi] @ T[:3, :3].T)
            L.append(np.full(n, i))
    return np.concatenate(P), np.concatenate(N), np.concatenate(L)


def build_from_scan(scan, urdf: str | os.PathLike | None = None, joint_positions=None,
                    init="pca", links: Sequence[str] | None = None,
                    pad_regions: PadRegions | None = None, max_distance: float | None = 0.01,
                    reference_spacing: float = 1e-3, seed: int = 0,
                    progress: bool = True) -> tuple[HandAsset, ScanAlignment, np.ndarray]:
    """Align a scan to the URDF hand at a reference pose and split it into links.

    Args:
        scan: a file (see :func:`.align.load_scan`), a GaussianSet, or [n, 3] points,
            in an arbitrary frame, of the hand at the reference pose.
        urdf: URDF file; default ManiSkill's Allegro right hand.
        joint_positions: the reference pose (see :meth:`URDFModel.forward_kinematics`);
            default all joints at 0.
        init: initial alignment, see :func:`.align.align_point_clouds`.
        links: links to assign to (default all with visuals); ``link_id`` order.
        pad_regions: as :func:`build_from_urdf`, evaluated on link-local means.
        max_distance: drop scan Gaussians farther than this (metres) from the
            aligned hand surface (background, table); None keeps all.
        reference_spacing: spacing of the hand surface samples used for ICP and
            link assignment, metres.

    Returns:
        (asset with link-local Gaussians, the alignment, link index per
        *input* point (-1 where dropped)).
    """
    if isinstance(scan, GaussianSet):
        g = scan.to("cpu")
        points = g.means.double().numpy()
    elif isinstance(scan, (str, os.PathLike)):
        points, g, rgb = load_scan(scan)
        if g is None:
            g = gaussians_from_points(points, rgb)
    else:
        points = np.asarray(scan, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) < 10:
            raise ConfigError(f"scan points have shape {list(points.shape)}, expected [n>=10, 3]")
        g = gaussians_from_points(points)
    model = parse_urdf(default_hand_urdf() if urdf is None else urdf)
    links = model.visual_links if links is None else list(links)
    pad_names = _check_pads(pad_regions, links)
    meshes = load_link_meshes(model, links)
    ref_p, ref_n, ref_l = sample_posed_hand(model, reference_spacing, joint_positions, links,
                                            seed=seed, meshes=meshes)
    align = align_point_clouds(points, ref_p, ref_n, init=init, seed=seed)
    world = transform_points(align.transform, points)
    fk = model.forward_kinematics(joint_positions)
    label, dist = assign_links(world, ref_p, ref_l, meshes, links, fk)
    if max_distance is not None:
        label[dist > max_distance] = -1
    R_align = align.transform[:3, :3]
    sets = []
    for i, name in enumerate(_progress(links, progress, "assign scan to links")):
        sel = np.nonzero(label == i)[0]
        if len(sel) == 0:
            continue
        Tl = fk[name]
        local = (world[sel] - Tl[:3, 3]) @ Tl[:3, :3]  # R_lᵀ (x - t_l)
        Q = Tl[:3, :3].T @ R_align  # scan axes -> link axes
        sub = g[torch.as_tensor(sel)]
        quats = rotmat_to_quat(torch.as_tensor(Q) @ quat_to_rotmat(sub.quats.double()))
        sh = rotate_sh(sub.sh, R_align.T @ Tl[:3, :3])
        group = _pad_groups(pad_regions, name, local, pad_names)
        sets.append(GaussianSet.create(local, quats, sub.log_scales, sub.opacity_logits, sh,
                                       link_id=np.full(len(sel), i), group=group))
    if not sets:
        raise AssetError("no scan point lies within max_distance of the aligned hand")
    meta = {"urdf": model.path.name, "robot": model.name, "source": "scan",
            "scan": str(scan) if isinstance(scan, (str, os.PathLike)) else None,
            "scan_to_hand": align.transform.tolist(), "icp_rms": align.rms,
            "reference_joint_positions": model.joint_map(joint_positions),
            "dropped": int((label < 0).sum()), "seed": int(seed)}
    return HandAsset(GaussianSet.cat(sets), links, pad_names, meta), align, label


# =========================================================================== output
def save_asset(out_dir: str | os.PathLike, asset: HandAsset) -> tuple[Path, Path]:
    """Write ``gaussians.ply`` and ``links.json`` into ``out_dir`` (created)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ply, js = out / "gaussians.ply", out / "links.json"
    save_ply(ply, asset.gaussians, labels=True)
    info = {"format": "gausstac-hand-gaussians/1",
            "link_names": list(asset.link_names),
            "counts": asset.counts(),
            "num_gaussians": len(asset.gaussians),
            "pad_names": list(asset.pad_names),
            "frames": "link-local: pose with rigid_transform(means, quats, link_id, "
                      "link_poses[link_names])",
            **asset.meta}
    js.write_text(json.dumps(info, indent=2) + "\n")
    return ply, js


# =========================================================================== CLI
def _parse_guess(text: str):
    if text in ("pca", "identity"):
        return text
    p = Path(text)
    if not p.is_file():
        raise ConfigError(f"--scan-frame-guess {text!r} is neither 'pca', 'identity' nor a file")
    T = np.load(p) if p.suffix == ".npy" else np.loadtxt(p)
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise AssetError(f"{p.name}: scan frame guess has shape {list(T.shape)}, expected 4x4")
    return T


def main(argv: list[str] | None = None) -> int:
    """``gausstac build-asset``: write ``gaussians.ply`` + ``links.json``."""
    import time

    ap = argparse.ArgumentParser(
        prog="gausstac build-asset",
        description="Hand Gaussians (gaussians.ply + links.json, link-local frames) from a "
                    "URDF's visual meshes, or from a scan aligned to the URDF.")
    ap.add_argument("--urdf", default=None,
                    help="URDF file (default: ManiSkill's allegro_hand_right.urdf)")
    ap.add_argument("--out", default=None, help="output folder (default assets/<urdf stem>/)")
    ap.add_argument("--spacing", type=float, default=DEFAULT_SPACING,
                    help="sample spacing in metres (default %(default)s)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scan", default=None,
                    help="scan to align instead of sampling meshes: Gaussian .ply, point "
                         ".ply, .xyz or .npy")
    ap.add_argument("--scan-frame-guess", default="pca",
                    help="initial scan->hand alignment: 'pca' (default), 'identity', or a "
                         ".npy/.txt file with a 4x4 matrix")
    ap.add_argument("--ref-q", default=None,
                    help="reference joint positions of the scan: comma-separated radians in "
                         "URDF joint order, or a JSON object name->value (default all 0)")
    ap.add_argument("--max-distance", type=float, default=0.01,
                    help="drop scan points farther than this from the aligned hand (metres)")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    urdf = Path(args.urdf or default_hand_urdf())
    out = Path(args.out) if args.out else Path("assets") / urdf.stem
    t0 = time.perf_counter()
    if args.scan:
        q = None
        if args.ref_q:
            text = args.ref_q.strip()
            try:
                q = json.loads(text) if text.startswith("{") else \
                    [float(v) for v in text.split(",")]
            except ValueError:
                raise ConfigError(f"--ref-q {text!r}: expected comma-separated numbers or a "
                                  "JSON object") from None
        asset, align, _ = build_from_scan(args.scan, urdf, q, init=_parse_guess(
            args.scan_frame_guess), max_distance=args.max_distance, seed=args.seed,
            progress=not args.no_progress)
        print(f"aligned scan: trimmed RMS {align.rms * 1e3:.3f} mm, "
              f"dropped {asset.meta['dropped']} points")
    else:
        asset = build_from_urdf(urdf, args.spacing, seed=args.seed,
                                progress=not args.no_progress)
    ply, js = save_asset(out, asset)
    dt = time.perf_counter() - t0
    print(f"{len(asset.gaussians)} Gaussians on {len(asset.link_names)} links in {dt:.1f} s "
          f"-> {ply} ({ply.stat().st_size / 1e6:.2f} MB), {js}")
    for name, n in asset.counts().items():
        print(f"  {name:16s} {n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
