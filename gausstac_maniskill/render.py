"""The co-simulated scene as 3D Gaussians, posed every frame for the splat camera.

:class:`SceneGaussians` gathers

* the hand's rigid Gaussians (link-local, from ``assets/<hand>/gaussians.ply``),
  minus those that sit where a soft pad replaces the rigid link surface;
* rigid objects' Gaussians (in the object frame), following the object's pose;
* soft Gaussians on the surface particles of the pads and soft objects, bound to
  those particles (Σ = F Σ0 Fᵀ, SH view direction rotated by polar(F)ᵀ).

and renders them with :func:`gausstac_maniskill.splat.rasterize`. Gaussians the
co-simulator does not move (a captured background, captured objects on SAPIEN actors) join
as :class:`RigidLayer` s, splatted in the same pass and depth-sorted with the hand's.
The hand's, objects' and soft Gaussians carry albedo and normals, shaded by a ``lighting``
(:mod:`gausstac_maniskill.splat.lighting`); a layer keeps its colours unless ``lit=True``.
All are kept once as one :class:`~gausstac_maniskill.splat.FramedGaussians` in their frames:
posing the scene gathers only the F frames ([F, 3, 4]). Units: metres.
"""
from __future__ import annotations

from typing import Callable, Mapping, Sequence

import numpy as np
import torch

from .errors import ConfigError
from .owner import Owner
from .splat import FramedGaussians, GaussianSet, PosedGaussians, SoftBinding, pose_gaussians
from .splat.deform import polar_rotation, rigid_frames

__all__ = ["SceneGaussians", "PosedScene", "BatchScene", "RigidLayer", "box_gaussians", "particle_gaussians"]

PAD_RGB = (0.55, 0.62, 0.78)      # translucent-looking blue-grey silicone (albedo, linear)
SOFT_RGB = (0.95, 0.80, 0.25)     # foam yellow (albedo, linear)


def box_gaussians(half_extents, spacing: float, link_id: int = 0) -> GaussianSet:
    """Checkered flat Gaussians on the surface of a box (box frame, metres)."""
    import trimesh

    from .splat.surface import gaussians_from_surface

    mesh = trimesh.creation.box(extents=2 * np.asarray(half_extents, float))
    pts, face = trimesh.sample.sample_surface_even(mesh, max(int(mesh.area / spacing ** 2), 1), seed=0)
    check = (np.floor(pts / 0.01).astype(int).sum(1) % 2).astype(float)
    rgb = np.stack([0.75 - 0.35 * check, 0.25 + 0.1 * check, 0.2 + 0.05 * check], 1)
    return gaussians_from_surface(pts, mesh.face_normals[face], rgb, spacing, link_id=link_id)


def particle_gaussians(sim) -> tuple[GaussianSet, np.ndarray]:
    """Soft Gaussians on the outer particles of every pad and soft object of ``sim``,
    in the world rest frame; returns them and the particle row of each (the rows of
    :meth:`GaussTacSim.particles <gausstac_maniskill.cosim.GaussTacSim.particles>`)."""
    from .splat.surface import gaussians_from_surface

    x0 = sim.rest_positions()
    h = sim.settings.particle_spacing
    pts, nrm, rgb, idx = [], [], [], []
    for name, pad in sim.pads.items():
        start, _ = sim.particle_rows(name)
        T = sim._link_pose[pad.spec.link]
        sel = np.flatnonzero(pad.surface)
        n = pad.normal[sel] @ T[:3, :3].T
        pts.append(x0[start + sel] + 0.5 * pad.spacing * n)
        nrm.append(n)
        rgb.append(np.tile(PAD_RGB, (len(sel), 1)))
        idx.append(start + sel)
    for name in sim._soft:
        start, stop = sim.particle_rows(name)
        p = x0[start:stop]
        lo, hi = p.min(0), p.max(0)
        outer = np.any((p < lo + h) | (p > hi - h), axis=1)
        n = np.zeros((int(outer.sum()), 3))
        q = p[outer]
        for d in range(3):
            n[q[:, d] > hi[d] - h, d] = 1.0
            n[q[:, d] < lo[d] + h, d] = -1.0
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        shade = 0.08 * np.random.default_rng(1).standard_normal((len(q), 1))
        pts.append(q + 0.5 * h * n)
        nrm.append(n)
        rgb.append(np.clip(np.asarray(SOFT_RGB) + shade, 0, 1))
        idx.append(start + np.flatnonzero(outer))
    if not pts:
        return GaussianSet.empty(), np.zeros(0, np.int64)
    pts, nrm, rgb = np.concatenate(pts), np.concatenate(nrm), np.concatenate(rgb)
    gs = gaussians_from_surface(pts, nrm, rgb, h, link_id=0, group=np.zeros(len(pts), np.int64))
    return gs, np.concatenate(idx)


class RigidLayer:
    """Gaussians outside the co-simulator that a :class:`SceneGaussians` splats with its own.

    Args:
        gaussians: the set. With ``poses=None`` its means are world coordinates (a captured
            background; posed once and cached). Otherwise each Gaussian lies in the frame
            ``link_id[g]`` indexes in ``poses()`` (captured objects in their actors' frames).
        poses: ``None`` or a function returning the current ``[L, 4, 4]`` frame -> world
            rigid transforms (metres); called every time the scene is posed.
        lit: shade the layer's flat Gaussians with the scene lighting (colours are albedo);
            default False: a capture has its lighting baked into its colours.
    """

    def __init__(self, gaussians: GaussianSet, poses: Callable[[], object] | None = None, lit: bool = False):
        self.gaussians = gaussians
        self.poses = poses
        self.lit = bool(lit)
        self._static: PosedGaussians | None = None
        self._framed: FramedGaussians | None = None

    def __len__(self) -> int:
        return len(self.gaussians)

    def posed(self) -> PosedGaussians:
        """World-space Gaussians (full covariances) for the current poses."""
        if self.poses is None:
            if self._static is None:
                self._static = pose_gaussians(self.gaussians)
            return self._static
        return pose_gaussians(self.gaussians, self._pose_matrices())

    def _pose_matrices(self) -> torch.Tensor:
        T = torch.as_tensor(np.asarray(self.poses(), dtype=np.float64), dtype=torch.float32)
        if T.dim() != 3 or T.shape[1:] != (4, 4):
            raise ConfigError(f"RigidLayer: poses() returned shape {list(T.shape)}, expected [L, 4, 4]")
        return T

    def framed(self) -> FramedGaussians:
        """The layer in its frames (built once): one identity frame for a world-space layer,
        otherwise one per pose of ``poses()`` (whose number must not change)."""
        if self._framed is None:
            n_frames = 1 if self.poses is None else self._pose_matrices().shape[0]
            ids = torch.zeros(len(self.gaussians), dtype=torch.int64) if self.poses is None else None
            self._framed = FramedGaussians.from_gaussians(self.gaussians, ids, n_frames, lit=self.lit)
        return self._framed

    def frames(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Current (frames [F, 3, 4], SH rotations [F, 3, 3]) of :meth:`framed`."""
        if self.poses is None:
            return rigid_frames(torch.eye(4)[None])
        return rigid_frames(self._pose_matrices())


def _levels_of(hand_lod) -> list:
    """The ((spacing [m], GaussianSet), ...) of ``hand_lod`` (``splat.asset.load_hand_lod``'s
    form), checked: ConfigError unless the spacings grow from level to level."""
    try:
        _, levels = hand_lod
        levels = [(float(sp), g) for sp, g in levels]
    except (TypeError, ValueError):
        raise ConfigError("hand_lod must be (fine spacing [m], ((spacing [m], GaussianSet), ...)) as "
                          f"splat.asset.load_hand_lod returns it; got {type(hand_lod).__name__} of "
                          f"{len(hand_lod) if hasattr(hand_lod, '__len__') else '?'} items") from None
    spacings = [sp for sp, _ in levels]
    if not levels or any(not isinstance(g, GaussianSet) for _, g in levels) \
            or not all(0 < a < b for a, b in zip(spacings, spacings[1:])) or spacings[0] <= 0:
        raise ConfigError(f"hand_lod: the levels must be GaussianSets with spacings that grow from level to "
                          f"level, got spacings {spacings}")
    return levels


class Detail:
    """A scene's levels of detail of the hand (:class:`SceneGaussians` with ``hand_lod``).

    The scene's Gaussians are laid out [fine hand | everything else | level 1 | level 2 | ...]
    (levels coarser and coarser). A camera draws the fine hand and the rest, one range
    [0, n_fine + n_rest), or the rest and level k, two ranges. It draws the coarsest level
    whose splats are no wider than its pixel at the hand: ``IN_PLANE_SCALE · spacing``, the
    splats' in-plane σ (:mod:`gausstac_maniskill.splat.surface`), at most z / fx (z: the hand's
    root link in the camera, fx: the focal length in pixels). There the picture keeps its look
    and its depth (``bench look``: at 1.09 spacings per pixel the hand's mean depth error
    grows by 0.26 mm, at 1.3 its median by 1 mm)."""

    def __init__(self, n_fine: int, n_rest: int, levels: Sequence[tuple[int, int, float]]):
        """``levels``: (start, stop, spacing [m]) of each coarser level, finest first."""
        from .splat.surface import IN_PLANE_SCALE

        self.fine = (0, n_fine + n_rest)
        self.rest = (n_fine, n_fine + n_rest)
        self.levels = [(int(a), int(b)) for a, b, _ in levels]
        self.sigmas = torch.tensor([IN_PLANE_SCALE * s for _, _, s in levels], dtype=torch.float64)

    def level(self, viewmats: torch.Tensor, Ks: torch.Tensor, anchor: np.ndarray) -> torch.Tensor:
        """[C] the level each camera draws: 0 the fine hand, k > 0 ``levels[k - 1]``;
        ``anchor``: the hand root's world position [m]."""
        V = torch.as_tensor(viewmats, dtype=torch.float64).cpu()
        z = V[:, 2, :3] @ torch.as_tensor(anchor, dtype=torch.float64) + V[:, 2, 3]
        pixel = z / torch.as_tensor(Ks, dtype=torch.float64).cpu()[:, 0, 0]  # metres per pixel at the hand
        return (self.sigmas[None, :] <= pixel[:, None]).sum(1)  # the σ grow with k

    def ranges(self, viewmats: torch.Tensor, Ks: torch.Tensor, anchor: np.ndarray) -> torch.Tensor:
        """[C, 2, 2] the two ranges [start, stop) each camera draws (see :meth:`level`)."""
        table = torch.tensor([[self.fine, (self.fine[1], self.fine[1])]]
                             + [[self.rest, lv] for lv in self.levels], dtype=torch.int64)
        return table[self.level(viewmats, Ks, anchor)]


class PosedScene:
    """A :class:`SceneGaussians` posed at one instant: its Gaussians in their frames and the
    frames' current poses ([F, 3, 4]) and SH rotations ([F, 3, 3] or None); with ``detail``
    (a :class:`Detail`) and ``anchor`` (the hand root's world position [m]), each camera draws
    the hand at the level its pixel size calls for."""

    def __init__(self, gaussians: FramedGaussians, frames: torch.Tensor, rotations: torch.Tensor | None,
                 detail: Detail | None = None, anchor: np.ndarray | None = None):
        self.gaussians, self.frames, self.rotations = gaussians, frames, rotations
        self.detail, self.anchor = detail, anchor

    def ranges(self, viewmats, Ks) -> torch.Tensor:
        """[C, 2, 2] the two ranges [start, stop) of Gaussians each camera draws (all of them,
        and an empty one, without levels of detail)."""
        if self.detail is None:
            n = len(self.gaussians)
            return torch.tensor([[[0, n], [n, n]]]).expand(len(viewmats), 2, 2)
        return self.detail.ranges(viewmats, Ks, self.anchor)

    def render(self, viewmats, Ks, width: int, height: int, **kwargs):
        """Render (see :meth:`FramedGaussians.render`); ``viewmats`` [C, 4, 4], ``Ks`` [C, 3, 3]."""
        viewmats, Ks = torch.as_tensor(viewmats, dtype=torch.float32), torch.as_tensor(Ks, dtype=torch.float32)
        ranges = None if self.detail is None else self.ranges(viewmats, Ks)
        return self.gaussians.render(self.frames, self.rotations, viewmats, Ks, width, height,
                                     gaussian_ranges=ranges, **kwargs)

    def world(self) -> PosedGaussians:
        """The same Gaussians in world space (full covariances)."""
        return self.gaussians.posed(self.frames, self.rotations)


class SceneGaussians:
    """Gaussians of a :class:`~gausstac_maniskill.cosim.GaussTacSim` scene.

    Args:
        sim: the co-simulator (its pads and soft objects get soft Gaussians).
        hand: rigid hand Gaussians in link-local frames (``link_id`` indexes ``hand_links``).
        hand_links: link names of the hand Gaussians.
        objects: rigid object name -> its Gaussians in the object frame.
        hand_lod: ``(fine spacing [m], ((spacing [m], GaussianSet), ...))``, the same hand
            built coarser (``splat.asset.load_hand_lod``), finest first; a camera whose pixels
            at the hand are as wide as a level's splats draws that level instead
            (:class:`Detail`).
        closed_links: hand links whose Gaussians lie on closed surfaces with their shortest axis
            as the outward normal (``links.json["closed_links"]``, written by ``gausstac
            build-asset`` after :func:`~gausstac_maniskill.splat.surface.closed_outward`):
            they are one-sided, i.e. not drawn when they face away from the camera (a nearer
            front side hides them; ``one_sided`` in :func:`gausstac_maniskill.splat.rasterizer.rasterize`),
            except on links carrying a soft pad, whose surface is open where the pad replaces it.
    """

    sim = Owner()  # the co-simulator whose Gaussians these are

    def __init__(self, sim, hand: GaussianSet | None = None, hand_links: Sequence[str] = (),
                 objects: Mapping[str, GaussianSet] | None = None, hand_lod: tuple | None = None,
                 closed_links: Sequence[str] = ()):
        self.sim = sim  # held weakly (owner.Owner): the simulator owns its scene
        self.hand_links = list(hand_links)
        unknown = sorted(set(closed_links) - set(self.hand_links))
        if unknown:
            raise ConfigError(f"closed_links {unknown} are not among the hand links {self.hand_links}")
        # a link whose surface gives way to a soft pad is open there: only the others stay closed
        padded = {pad.spec.link for pad in sim.pads.values()}
        self._closed = torch.tensor([self.hand_links.index(n) for n in closed_links if n not in padded],
                                    dtype=torch.int64)
        sets = []
        self.n_hand = 0
        self.hand_levels: list[tuple[float, GaussianSet]] = []  # (spacing [m], Gaussians), finest first
        if hand is not None and len(hand):
            sets.append(self._drop_pad_regions(hand))
            self.n_hand = len(sets[0])
            if hand_lod is not None:
                self.hand_levels = [(float(sp), self._drop_pad_regions(g)) for sp, g in _levels_of(hand_lod)]
        self.object_names = list(objects or {})
        for i, name in enumerate(self.object_names):
            if name not in sim._objects:
                raise ConfigError(f"Gaussians given for unknown rigid object {name!r}")
            g = objects[name]
            sets.append(g.replace(link_id=torch.full_like(g.link_id, len(self.hand_links) + i)))
        soft, self.particle_index = particle_gaussians(sim)
        self.n_rigid = sum(len(s) for s in sets)
        sets.append(soft)
        self.gaussians = GaussianSet.cat(sets)
        rest = torch.as_tensor(sim.rest_positions())
        self.binding = SoftBinding.from_nearest(self.gaussians, rest,
                                                gaussian_index=torch.arange(self.n_rigid, len(self.gaussians)))
        self.layers: list[RigidLayer] = []
        self._framed: FramedGaussians | None = None  # built on first use, again after add_layer

    def add_layer(self, layer: RigidLayer) -> None:
        """Splat ``layer`` (e.g. a captured scene or captured objects) with this scene's
        Gaussians from now on, in the same pass (depth-sorted together)."""
        if not isinstance(layer, RigidLayer):
            raise ConfigError(f"add_layer takes a RigidLayer, got {type(layer).__name__}")
        self.layers.append(layer)
        self._framed = None

    def _drop_pad_regions(self, hand: GaussianSet) -> GaussianSet:
        """Remove rigid Gaussians where a soft pad replaces the link's surface."""
        from scipy.spatial import cKDTree

        keep = torch.ones(len(hand), dtype=torch.bool)
        for pad in self.sim.pads.values():
            if pad.spec.link not in self.hand_links:
                continue
            sel = torch.nonzero(hand.link_id == self.hand_links.index(pad.spec.link)).flatten()
            d, _ = cKDTree(pad.rest[~pad.kinematic]).query(hand.means[sel].numpy())
            keep[sel[torch.as_tensor(d < 2.5 * pad.spacing)]] = False
        return hand[torch.nonzero(keep).flatten()]

    def framed(self) -> FramedGaussians:
        """All Gaussians in their frames: links and objects (in that order), the particles
        the soft Gaussians follow, then each layer's frames. Built once."""
        if self._framed is None:
            n_rigid_frames = len(self.hand_links) + len(self.object_names)
            rigid = self.gaussians[torch.arange(self.n_rigid)]
            soft, particles = FramedGaussians.from_binding(self.gaussians, self.binding, lit=True)
            self._particles = particles.numpy()
            self._carry = self.sim.carry_rows(self._particles)
            # the first rows lie on pads solved at equilibrium (posed from their solution), the others in the world
            self._solved = int(np.searchsorted(self._particles, self.sim.solved_rows))
            self._rows_device = None  # (rows, carry) on the arch's device, at the first picture
            # polar(F) is only needed if a soft Gaussian's colour depends on the view direction
            self._soft_rotations = bool(soft.sh.shape[1] > 1 and soft.sh[:, 1:].abs().max() > 0)
            parts = [FramedGaussians.from_gaussians(rigid, rigid.link_id, n_rigid_frames, lit=True,
                                                    one_sided=self._one_sided(rigid, self.n_hand)),
                     soft, *(layer.framed() for layer in self.layers)]
            offsets = None
            self.detail = None
            if self.hand_levels:  # last, in the links' frames (0..): [fine | rest | level 1 | ...]
                offsets = [0]
                for p in parts[:-1]:
                    offsets.append(offsets[-1] + p.n_frames)
                n_rest = sum(len(p) for p in parts) - self.n_hand
                start, levels = self.n_hand + n_rest, []
                for spacing, g in self.hand_levels:
                    parts.append(FramedGaussians.from_gaussians(g, g.link_id, n_rigid_frames, lit=True,
                                                                one_sided=self._one_sided(g, len(g))))
                    offsets.append(0)
                    levels.append((start, start + len(g), spacing))
                    start += len(g)
                self.detail = Detail(self.n_hand, n_rest, levels)
            self._framed = FramedGaussians.cat(parts, frame_offsets=offsets)
        return self._framed

    def _one_sided(self, rigid: GaussianSet, n_hand: int) -> torch.Tensor | None:
        """[len(rigid)] bool: the first ``n_hand`` (hand) Gaussians on a closed link; None if none."""
        if not len(self._closed):
            return None
        mask = torch.isin(rigid.link_id, self._closed)
        mask[n_hand:] = False  # (objects' frames follow the links': their ids are not links)
        return mask

    def soft_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """(the particles [P'] the soft Gaussians ride on, ascending rows of the sim's
        :meth:`~gausstac_maniskill.cosim.GaussTacSim.particles`; each one's row of the sim's
        :meth:`~gausstac_maniskill.cosim.GaussTacSim.pad_carries`, [P'] int32)."""
        self.framed()
        return self._particles, self._carry

    def world_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """The part of :meth:`soft_rows` that lies in the sim's world (the rows after
        :meth:`solved_frames`' ones): (those particles' world indices [P'_w], their carry rows)."""
        self.framed()
        return self._particles[self._solved:] - self.sim.solved_rows, self._carry[self._solved:]

    def solved_frames(self, device) -> torch.Tensor:
        """[k, 3, 4] frames (F | x) on ``device`` of the first k rows of :meth:`soft_rows`, those
        on pads solved at equilibrium (from their solution: :meth:`GaussTacSim.equilibrium_frames`)."""
        self.framed()
        frames = torch.zeros((self._solved, 3, 4), dtype=torch.float32, device=device)
        if self._solved:
            where, solved = self.sim.equilibrium_frames(self._particles[:self._solved])
            frames[torch.as_tensor(where, device=device)] = torch.as_tensor(solved, device=device)
        return frames

    def soft_frames(self) -> torch.Tensor:
        """[P', 3, 4] frames (F_p | x_p) of :meth:`soft_rows`' particles: the world's read on the
        device in one launch (Taichi arch's torch device), sleeping pads carried by their links;
        pads solved at equilibrium from their solution (:meth:`solved_frames`)."""
        from .mpm.gather import read_particle_frames

        self.framed()
        if self._rows_device is None:
            from . import backend

            dev = backend.torch_device()
            rows, carry = self.world_rows()
            self._rows_device = (torch.as_tensor(rows, dtype=torch.int32, device=dev),
                                 torch.as_tensor(carry, device=dev))
        frames = read_particle_frames(self.sim.world, *self._rows_device, self.sim.pad_carries())
        if not self._solved:
            return frames
        return torch.cat([self.solved_frames(frames.device), frames])

    def posed(self, soft: torch.Tensor | None = None) -> PosedScene:
        """The scene at the simulator's current link, object and particle state, with the layers;
        ``soft``: :meth:`soft_frames` when the caller read them (a batch reads every env's at
        once), else read here. The frames lie on the soft frames' device (the Taichi arch's)."""
        sim = self.sim
        framed = self.framed()
        poses = []
        for name in self.hand_links:
            if name not in sim._link_pose:
                raise ConfigError(f"render: no pose for hand link {name!r}; pass every hand link's "
                                  "pose to GaussTacSim.step (link_poses)")
            poses.append(sim._link_pose[name])
        for name in self.object_names:
            poses.append(sim.world.colliders[sim._objects[name]].pose)
        rigid, _ = rigid_frames(np.array(poses) if poses else np.zeros((0, 4, 4)))
        if soft is None:
            soft = self.soft_frames()  # only the particles the soft Gaussians ride on
        # the rigid frames (links, objects, layers) go to the device in one copy
        host = torch.cat([rigid, *(f for f, _ in (layer.frames() for layer in self.layers))]).to(soft.device)
        n = rigid.shape[0]
        frames = torch.cat([host[:n], soft, host[n:]])
        rotations = None  # SH degree 0 everywhere: colours do not depend on the view direction
        if framed.sh.shape[1] > 1:  # a rigid frame's SH turn with its rotation, a particle's with polar(F)
            soft_rot = polar_rotation(soft[:, :, :3]) if self._soft_rotations else \
                torch.eye(3, device=soft.device).expand(len(soft), 3, 3)  # (no soft colour depends on it)
            rotations = torch.cat([host[:n, :, :3], soft_rot, host[n:, :, :3]])
        anchor = sim._link_pose[self.hand_links[0]][:3, 3] if self.detail is not None else None
        return PosedScene(framed, frames, rotations, self.detail, anchor)

    def render(self, viewmats, Ks, width: int, height: int, **kwargs):
        """Render; ``viewmats`` [C, 4, 4] world-to-camera (OpenCV), ``Ks`` [C, 3, 3].
        Keyword arguments go to :func:`~gausstac_maniskill.splat.rasterize` (e.g. ``background``,
        ``lighting``: a :class:`~gausstac_maniskill.splat.lighting.Lighting` shading the lit
        Gaussians; None: every colour as stored)."""
        return self.posed().render(viewmats, Ks, width, height, **kwargs)


class BatchScene:
    """B envs' scenes rendered in one rasterizer call (three launches whatever B).

    The envs' Gaussians are concatenated once (rebuilt only when an env's own set changes,
    e.g. a layer is added), each env's frames are concatenated per picture, and every camera
    sees only its env's Gaussians (the rasterizer's ``gaussian_ranges``): each picture equals
    that env's scene rendered alone.
    """

    def __init__(self):
        self._parts: list = []  # the envs' FramedGaussians (or None) that _framed was built of
        self._framed: FramedGaussians | None = None
        self._ranges = torch.zeros(0, 2, dtype=torch.int64)  # [B, 2] each env's Gaussians in _framed

    def _framed_of(self, posed: list) -> tuple[FramedGaussians | None, torch.Tensor]:
        """The envs' Gaussians in one set (built again only when one env's set changed) and
        each env's range [start, stop) in it ([B, 2], empty for an env without Gaussians)."""
        parts = [p.gaussians if p is not None else None for p in posed]
        if len(parts) != len(self._parts) or any(a is not b for a, b in zip(parts, self._parts)):
            some = [g for g in parts if g is not None]
            self._framed = FramedGaussians.cat(some) if some else None
            sizes = torch.tensor([len(g) if g is not None else 0 for g in parts], dtype=torch.int64)
            stops = torch.cumsum(sizes, 0)
            self._ranges = torch.stack([stops - sizes, stops], 1)
            self._parts = parts
        return self._framed, self._ranges

    def render(self, posed: Sequence[PosedScene | None], viewmats, Ks, width: int, height: int,
               camera_env=None, **kwargs):
        """Render camera c of env ``camera_env[c]`` (default: camera b of env b).

        Args:
            posed: per env, its :class:`PosedScene` at the current state, or None for an env
                with nothing to splat (its cameras see the background only).
            viewmats: [C, 4, 4] world -> camera (OpenCV), Ks: [C, 3, 3] pixel intrinsics.
            width, height: image size in pixels.
            camera_env: [C] env index of each camera (default ``arange(B)``, C = B).
            kwargs: as :func:`~gausstac_maniskill.splat.rasterize` (``background`` [C, H, W, 3]
                or a colour, ``background_depth`` [C, H, W], ``lighting``: one
                :class:`~gausstac_maniskill.splat.lighting.Lighting` or one per camera, ...).

        Returns:
            The rasterizer's ``RenderOutput`` (rgb [C, H, W, 3], depth [C, H, W] m, alpha
            [C, H, W]) on the Taichi arch's torch device.
        """
        from .splat.rasterizer import rasterize

        posed = list(posed)
        C, B = len(viewmats), len(posed)
        envs = np.arange(B) if camera_env is None else np.asarray(camera_env, dtype=np.int64).ravel()
        if envs.shape != (C,) or (C and (envs.min() < 0 or envs.max() >= B)):
            raise ConfigError(f"BatchScene.render: camera_env must hold one env index in [0, {B}) per camera "
                              f"({C} cameras), got {envs.tolist()}")
        framed, env_ranges = self._framed_of(posed)
        if framed is None:  # nothing to splat anywhere: an empty set renders the background
            empty = GaussianSet.empty()
            return rasterize(empty.means, empty.quats, empty.scales, empty.opacities, empty.sh,
                             viewmats, Ks, width, height, **kwargs)
        viewmats, Ks = torch.as_tensor(viewmats, dtype=torch.float32), torch.as_tensor(Ks, dtype=torch.float32)
        # each camera's two ranges: its env's, at the level of detail its pixel size calls for
        stops = env_ranges[torch.as_tensor(envs), 1:]
        ranges = torch.stack([env_ranges[torch.as_tensor(envs)], torch.cat([stops, stops], 1)], 1)
        for e in np.unique(envs):
            if posed[e] is not None and posed[e].detail is not None:
                sel = torch.as_tensor(envs == e)
                ranges[sel] = env_ranges[e, 0] + posed[e].ranges(viewmats[sel], Ks[sel])
        frames = torch.cat([p.frames for p in posed if p is not None])
        rotations = None
        if framed.sh.shape[1] > 1:  # some colour depends on the view: every frame needs its rotation
            rotations = torch.cat([p.rotations if p.rotations is not None else
                                   torch.eye(3).expand(p.frames.shape[0], 3, 3)
                                   for p in posed if p is not None])
        return framed.render(frames, rotations, viewmats, Ks, width, height, gaussian_ranges=ranges, **kwargs)
