"""Moving Gaussians with the simulation: rigid links and MPM particles (torch, vectorised).

Both bindings pose a Gaussian by a *frame*, an affine map ``x -> M x + t`` with an SH
rotation R: μ = M μ⁰ + t, Σ = M Σ⁰ Mᵀ, and the SH are evaluated at Rᵀ d.

* **Rigid** — Gaussian g with ``link_id[g] = l`` is stored in link l's frame (rest mean μ⁰,
  rotation q⁰); its frame is the link's world pose: M = R = R_l, t = t_l (q = q_l ⊗ q⁰).
* **Soft** — Gaussian g is bound to one MPM particle p (:meth:`SoftBinding.from_nearest`),
  with the rest offset o_g = μ⁰_g − X_p as its local mean; its frame is M = F_p (the
  deformation gradient), t = x_p, R = polar(F_p): μ_g = x_p + F_p o_g, Σ_g = F_p Σ⁰_g F_pᵀ.

:func:`pose_gaussians` gives world-space :class:`PosedGaussians` (full covariances, rendered
through ``rasterize``'s ``covars`` and ``sh_rotations``); :class:`FramedGaussians` keeps the
Gaussians in their frames and lets the rasterizer's projection kernel pose them, so a picture
only needs the [F, 3, 4] frames. Lit Gaussians keep a normal in their frame, moved by cof(M)
(:mod:`.lighting`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import ConfigError
from .gaussians import GaussianSet, covariance_from_scale_rotation, quat_multiply, rotmat_to_quat

__all__ = [
    "rigid_transform",
    "polar_rotation",
    "SoftBinding",
    "soft_deform",
    "PosedGaussians",
    "pose_gaussians",
    "FramedGaussians",
    "rigid_frames",
    "particle_frames",
]


def _check_poses(link_poses: torch.Tensor, link_id: torch.Tensor) -> torch.Tensor:
    if not isinstance(link_poses, torch.Tensor) or link_poses.dim() not in (3, 4) \
            or link_poses.shape[-2:] != (4, 4):
        raise ConfigError(f"link_poses has shape {list(getattr(link_poses, 'shape', []))}, "
                          "expected [L, 4, 4] or [B, L, 4, 4]")
    if not torch.isfinite(link_poses).all():
        raise ConfigError("link_poses contains NaN or inf")
    n_links = link_poses.shape[-3]
    if link_id.numel() and (link_id.min() < 0 or link_id.max() >= n_links):
        raise ConfigError(f"link_id values must lie in [0, {n_links}) for {n_links} link poses, "
                          f"got range [{int(link_id.min())}, {int(link_id.max())}]")
    return link_poses


def rigid_transform(means: torch.Tensor, quats: torch.Tensor, link_id: torch.Tensor,
                    link_poses: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Move link-local Gaussians to the world with their links' poses.

    Args:
        means: [N, 3] link-local (rest) centres, metres.
        quats: [N, 4] link-local rotations (w, x, y, z).
        link_id: [N] int, index of each Gaussian's link in ``link_poses``.
        link_poses: [L, 4, 4] or [B, L, 4, 4] link -> world transforms.

    Returns:
        (means [..., N, 3] = R_l μ⁰ + t_l, quats [..., N, 4] = q_l ⊗ q⁰), with
        the leading batch dimension B when ``link_poses`` has one.
    """
    link_poses = _check_poses(link_poses, link_id)
    T = link_poses.to(means.dtype)[..., link_id, :, :]  # [..., N, 4, 4]
    R, t = T[..., :3, :3], T[..., :3, 3]
    world_means = (R @ means.unsqueeze(-1)).squeeze(-1) + t
    q_link = rotmat_to_quat(R)
    return world_means, quat_multiply(q_link, quats.expand_as(q_link))


def polar_rotation(F: torch.Tensor) -> torch.Tensor:
    """Rotation R of the polar decomposition F = R S (S symmetric positive), [..., 3, 3].

    Via the SVD F = U Σ Vᵀ: R = U Vᵀ, with the sign of U's last column flipped
    when det(U Vᵀ) < 0 so that R is a proper rotation (det R = +1) even for
    inverted elements.
    """
    U, _, Vh = torch.linalg.svd(F.to(torch.float64))
    det = torch.linalg.det(U @ Vh)
    U = U.clone()
    U[..., :, 2] *= torch.where(det < 0, -1.0, 1.0).to(U.dtype).unsqueeze(-1)
    return (U @ Vh).to(F.dtype)


@dataclass
class SoftBinding:
    """Which MPM particle carries each soft Gaussian (Gaussian -> particle map).

    Attributes:
        gaussian_index: [G] int64, indices (into the GaussianSet) of the soft Gaussians.
        particle_index: [G] int64, p(g): the particle each of them follows.
        rest_offset: [G, 3] o_g = μ⁰_g − X_p(g), metres (world rest frame).
        rest_covariance: [G, 3, 3] Σ⁰_g, m² (world rest frame).
    """

    gaussian_index: torch.Tensor
    particle_index: torch.Tensor
    rest_offset: torch.Tensor
    rest_covariance: torch.Tensor

    @classmethod
    def from_nearest(cls, gaussians: GaussianSet, particle_rest: torch.Tensor,
                     gaussian_index: torch.Tensor | None = None,
                     max_distance: float | None = None) -> "SoftBinding":
        """Bind each selected Gaussian to its nearest particle at rest (scipy cKDTree).

        Args:
            gaussians: the set; its means/quats/scales are the rest state, in
                the same (world rest) frame as ``particle_rest``.
            particle_rest: [P, 3] rest positions X of the MPM particles, metres.
            gaussian_index: [G] indices of the soft Gaussians; default all of
                them with ``group >= 0``.
            max_distance: raise ConfigError if a Gaussian is farther than this
                (metres) from every particle (a binding error, e.g. wrong frame).
        """
        from scipy.spatial import cKDTree

        if gaussian_index is None:
            gaussian_index = torch.nonzero(gaussians.group >= 0).flatten()
        gaussian_index = torch.as_tensor(gaussian_index, dtype=torch.int64).flatten()
        X = torch.as_tensor(particle_rest, dtype=torch.float32)
        if X.dim() != 2 or X.shape[1] != 3 or X.shape[0] == 0:
            raise ConfigError(f"particle_rest has shape {list(X.shape)}, expected [P, 3], P > 0")
        mu0 = gaussians.means[gaussian_index].detach().cpu()
        dist, idx = cKDTree(X.cpu().numpy()).query(mu0.numpy().astype(np.float64))
        if max_distance is not None and len(dist) and dist.max() > max_distance:
            g = int(np.argmax(dist))
            raise ConfigError(f"soft Gaussian {int(gaussian_index[g])} is {dist[g]:.4g} m from the "
                              f"nearest particle (max_distance={max_distance})")
        idx = torch.as_tensor(idx, dtype=torch.int64)
        dev = gaussians.device
        sub = gaussians[gaussian_index.to(dev)]
        return cls(gaussian_index.to(dev), idx.to(dev),
                   (mu0 - X[idx]).to(dev), sub.covariances())

    def __len__(self) -> int:
        return self.gaussian_index.shape[0]


def soft_deform(binding: SoftBinding, x: torch.Tensor, F: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Deform soft Gaussians with their particles.

    Args:
        binding: the Gaussian -> particle map.
        x: [P, 3] or [B, P, 3] current particle positions, metres.
        F: [P, 3, 3] or [B, P, 3, 3] particle deformation gradients.

    Returns:
        (means [..., G, 3] = x_p + F_p o_g, covariances [..., G, 3, 3] = F Σ⁰ Fᵀ,
        sh_rotations [..., G, 3, 3] = polar(F_p)).
    """
    if x.dim() not in (2, 3) or x.shape[-1] != 3:
        raise ConfigError(f"particle x has shape {list(x.shape)}, expected [P, 3] or [B, P, 3]")
    if F.shape != x.shape + (3,):
        raise ConfigError(f"particle F has shape {list(F.shape)}, expected {list(x.shape) + [3]}")
    for name, t in (("particle x", x), ("particle F", F)):
        if not torch.isfinite(t).all():
            raise ConfigError(f"{name} contains NaN or inf")
    p = binding.particle_index
    if len(binding) and int(p.max()) >= x.shape[-2]:
        raise ConfigError(f"binding refers to particle {int(p.max())} but x has "
                          f"{x.shape[-2]} particles")
    Fp = F[..., p, :, :]
    means = x[..., p, :] + (Fp @ binding.rest_offset.unsqueeze(-1)).squeeze(-1)
    covs = Fp @ binding.rest_covariance @ Fp.transpose(-1, -2)
    return means, covs, polar_rotation(Fp)


@dataclass
class PosedGaussians:
    """Gaussians in world space with full covariances, ready for the rasterizer.

    Attributes:
        means: [..., N, 3] world centres, metres.
        covars: [..., N, 3, 3] world covariances, m².
        sh_rotations: [..., N, 3, 3] rotation of each Gaussian's SH frame.
        opacities: [N] in (0, 1).
        sh: [N, K, 3] SH coefficients (in each Gaussian's own frame).

    The optional leading dimension is the batch B of the poses.
    """

    means: torch.Tensor
    covars: torch.Tensor
    sh_rotations: torch.Tensor
    opacities: torch.Tensor
    sh: torch.Tensor

    @staticmethod
    def cat(parts) -> "PosedGaussians":
        """Concatenate posed sets (same leading batch shape) into one, so that a single
        :meth:`render` sorts all of them by depth together; lower SH degrees are
        zero-padded to the highest."""
        parts = list(parts)
        if not parts:
            raise ConfigError("PosedGaussians.cat needs at least one set")
        batch = {tuple(p.means.shape[:-2]) for p in parts}
        if len(batch) > 1:
            raise ConfigError(f"PosedGaussians.cat: leading batch shapes differ: {sorted(batch)}")
        k = max(p.sh.shape[1] for p in parts)
        sh = [torch.nn.functional.pad(p.sh, (0, 0, 0, k - p.sh.shape[1])) for p in parts]
        return PosedGaussians(torch.cat([p.means for p in parts], dim=-2),
                              torch.cat([p.covars for p in parts], dim=-3),
                              torch.cat([p.sh_rotations for p in parts], dim=-3),
                              torch.cat([p.opacities for p in parts]), torch.cat(sh))

    def __getitem__(self, b: int) -> "PosedGaussians":
        """The poses of batch element (environment) ``b``."""
        if self.means.dim() != 3:
            raise ConfigError("PosedGaussians has no batch dimension to index")
        return PosedGaussians(self.means[b], self.covars[b], self.sh_rotations[b],
                              self.opacities, self.sh)

    def render(self, viewmats, Ks, width, height, **kwargs):
        """Render (unbatched) with :func:`rasterize`; kwargs as there."""
        from .rasterizer import rasterize

        if self.means.dim() != 2:
            raise ConfigError("PosedGaussians.render needs one pose; index the batch first")
        return rasterize(self.means, None, None, self.opacities, self.sh, viewmats, Ks, width,
                         height, covars=self.covars, sh_rotations=self.sh_rotations, **kwargs)


def pose_gaussians(gaussians: GaussianSet, link_poses: torch.Tensor | None = None,
                   soft: SoftBinding | None = None, x: torch.Tensor | None = None,
                   F: torch.Tensor | None = None) -> PosedGaussians:
    """World-space Gaussians for the current link poses and particle state.

    Gaussians listed in ``soft`` follow their particles (needs ``x`` and ``F``);
    all others follow their link (``link_poses``; if ``None`` they stay where
    they are, i.e. their means are already world coordinates).

    Args:
        gaussians: rest state (rigid Gaussians in link-local frames, soft ones
            in the world rest frame of the particles).
        link_poses: [L, 4, 4] or [B, L, 4, 4] link -> world transforms.
        soft: Gaussian -> particle binding.
        x: [P, 3] or [B, P, 3] particle positions; F: [P, 3, 3] or [B, P, 3, 3].

    Returns:
        :class:`PosedGaussians` (batched when the poses or particles are).
    """
    n = len(gaussians)
    Rg = None
    if link_poses is not None:
        means, quats = rigid_transform(gaussians.means, gaussians.quats, gaussians.link_id,
                                       link_poses)
        Rg = link_poses.to(means.dtype)[..., gaussians.link_id, :3, :3]
    else:
        means, quats = gaussians.means, gaussians.quats
        Rg = torch.eye(3, dtype=means.dtype, device=means.device).expand(n, 3, 3)
    covars = covariance_from_scale_rotation(quats, gaussians.scales.expand(quats.shape[:-1] + (3,)))
    if soft is not None and len(soft):
        if x is None or F is None:
            raise ConfigError("soft Gaussians need particle positions x and gradients F")
        s_means, s_covs, s_rot = soft_deform(soft, x.to(means.dtype), F.to(means.dtype))
        batch = torch.broadcast_shapes(means.shape[:-2], s_means.shape[:-2])
        means = means.expand(batch + (n, 3)).clone()
        covars = covars.expand(batch + (n, 3, 3)).clone()
        Rg = Rg.expand(batch + (n, 3, 3)).clone()
        i = soft.gaussian_index
        means[..., i, :] = s_means.expand(batch + s_means.shape[-2:])
        covars[..., i, :, :] = s_covs.expand(batch + s_covs.shape[-3:])
        Rg[..., i, :, :] = s_rot.expand(batch + s_rot.shape[-3:])
    return PosedGaussians(means, covars, Rg.contiguous(), gaussians.opacities, gaussians.sh)


def rigid_frames(poses: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Frames of rigid poses [F, 4, 4] (link -> world): (frames [F, 3, 4], SH rotations [F, 3, 3])."""
    poses = torch.as_tensor(poses, dtype=torch.float32)
    return poses[:, :3, :], poses[:, :3, :3]


def particle_frames(x: torch.Tensor, F: torch.Tensor, rotations: bool = True
                    ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Frames of MPM particles: M = F_p, t = x_p ([P, 3, 4]) and SH rotations polar(F_p)
    ([P, 3, 3], or None with ``rotations=False``, when no bound Gaussian's colour depends
    on the view direction)."""
    x = torch.as_tensor(x, dtype=torch.float32)
    F = torch.as_tensor(F, dtype=torch.float32)
    frames = torch.cat([F, x.unsqueeze(-1)], dim=-1)
    return frames, (polar_rotation(F) if rotations else None)


@dataclass(eq=False)
class FramedGaussians:
    """Gaussians stored in F moving frames, posed inside the rasterizer (see the module docstring).

    The per-Gaussian arrays are checked and converted once, at construction; a picture then
    only needs the frames (do not modify the arrays in place afterwards).

    Attributes:
        means: [N, 3] centres in their frames, metres.
        covars: [N, 6] covariances in their frames (xx, xy, xz, yy, yz, zz), m².
        frame_ids: [N] integer frame of each Gaussian, in [0, n_frames).
        opacities: [N] in [0, 1].
        sh: [N, K, 3] SH coefficients (in each Gaussian's own frame).
        n_frames: F.
        normals: [N, 3] normals in their frames, the zero vector for a Gaussian that scene
            lighting leaves as it is, or None (no Gaussian is lit); see
            :mod:`~gausstac_maniskill.splat.lighting`.
        one_sided: [N] bool or None: Gaussians on closed surfaces whose ``normals`` point
            outward, culled when they face away from the camera (needs ``normals``; see
            ``one_sided`` of :func:`~gausstac_maniskill.splat.rasterizer.rasterize`).
    """

    means: torch.Tensor
    covars: torch.Tensor
    frame_ids: torch.Tensor
    opacities: torch.Tensor
    sh: torch.Tensor
    n_frames: int
    normals: torch.Tensor | None = None
    one_sided: torch.Tensor | None = None

    def __post_init__(self) -> None:
        from .inputs import _gaussian_inputs

        self.n_frames = int(self.n_frames)
        self._inputs = _gaussian_inputs(self.means, None, None, self.opacities, self.sh, self.covars, None,
                                        self.frame_ids, self.n_frames, frame_rotations=True,
                                        normals=self.normals, one_sided=self.one_sided)

    def __len__(self) -> int:
        return self.means.shape[0]

    @classmethod
    def from_gaussians(cls, gaussians: GaussianSet, frame_ids=None, n_frames: int | None = None,
                       lit: bool = False, one_sided=None) -> "FramedGaussians":
        """A :class:`GaussianSet` in frames ``frame_ids`` (default: its ``link_id``); ``lit``:
        its flat Gaussians get normals (:func:`~gausstac_maniskill.splat.lighting.surface_normals`),
        i.e. scene lighting shades them (their colours are albedo). ``one_sided`` ([N] bool,
        with ``lit``): Gaussians whose shortest axis, sign included, is the outward normal of a
        closed surface (surfaces sampled from closed meshes, see
        :func:`~gausstac_maniskill.splat.surface.closed_outward`); culled when facing away."""
        from .lighting import surface_normals
        from .inputs import _cov6

        ids = gaussians.link_id if frame_ids is None else torch.as_tensor(frame_ids)
        if n_frames is None:
            n_frames = int(ids.max()) + 1 if len(ids) else 1
        normals = surface_normals(gaussians.quats, gaussians.scales) if lit else None
        if one_sided is not None:
            if not lit:
                raise ConfigError("FramedGaussians.from_gaussians: one_sided needs lit=True (the normals)")
            one_sided = torch.as_tensor(one_sided, dtype=torch.bool) & (normals.norm(dim=1) > 0)
        return cls(gaussians.means, _cov6(gaussians.covariances()), ids, gaussians.opacities, gaussians.sh,
                   n_frames, normals, one_sided)

    @classmethod
    def from_binding(cls, gaussians: GaussianSet, binding: SoftBinding, lit: bool = False
                     ) -> tuple["FramedGaussians", torch.Tensor]:
        """The soft Gaussians of ``binding`` in the frames of their particles: local mean o_g,
        local covariance Σ⁰_g (and, with ``lit``, the rest normals of the flat ones). Returns
        them and the particle index of each frame ([F] int64, ascending; pose the frames with
        :func:`particle_frames` of those particles)."""
        from .lighting import surface_normals
        from .inputs import _cov6

        particles, frame = torch.unique(binding.particle_index, return_inverse=True)
        soft = gaussians[binding.gaussian_index]
        normals = surface_normals(soft.quats, soft.scales) if lit else None
        return cls(binding.rest_offset, _cov6(binding.rest_covariance), frame, soft.opacities, soft.sh,
                   len(particles), normals), particles

    @classmethod
    def cat(cls, parts, frame_offsets=None) -> "FramedGaussians":
        """One set from several, frames numbered on (part 0's frames first, then part 1's, ...),
        or part i's frame f becoming ``frame_offsets[i] + f`` (parts that share frames, e.g. two
        levels of detail of one hand; the frame count is then the largest frame used + 1);
        lower SH degrees are zero-padded to the highest; a part without normals contributes
        zero normals (not lit) when another has some, and is two-sided when another has one-sided ones."""
        parts = list(parts)
        if not parts:
            raise ConfigError("FramedGaussians.cat needs at least one set")
        k = max(p.sh.shape[1] for p in parts)
        offsets = [0]
        for p in parts:
            offsets.append(offsets[-1] + p.n_frames)
        if frame_offsets is not None:
            if len(frame_offsets) != len(parts):
                raise ConfigError(f"FramedGaussians.cat: {len(frame_offsets)} frame offsets for {len(parts)} parts")
            offsets = [int(o) for o in frame_offsets]
            offsets.append(max(o + p.n_frames for o, p in zip(offsets, parts)))
        normals = one_sided = None
        if any(p.normals is not None for p in parts):
            normals = torch.cat([p.normals.to(torch.float32) if p.normals is not None else
                                 torch.zeros(len(p), 3, device=p.means.device) for p in parts])
        if any(p.one_sided is not None for p in parts):
            one_sided = torch.cat([p.one_sided.to(p.means.device) if p.one_sided is not None else
                                   torch.zeros(len(p), dtype=torch.bool, device=p.means.device) for p in parts])
        return cls(torch.cat([p.means for p in parts]), torch.cat([p.covars for p in parts]),
                   torch.cat([p.frame_ids.to(torch.int64) + o for p, o in zip(parts, offsets)]),
                   torch.cat([p.opacities for p in parts]),
                   torch.cat([torch.nn.functional.pad(p.sh, (0, 0, 0, k - p.sh.shape[1])) for p in parts]),
                   offsets[-1], normals, one_sided)

    def render(self, frames: torch.Tensor, frame_rotations: torch.Tensor | None, viewmats, Ks,
               width: int, height: int, *, background=None, background_depth=None, near: float = 0.01,
               far: float = 1e4, timings: bool = False, lighting=None, gaussian_ranges=None):
        """Render with the frames posed at ``frames`` [F, 3, 4] (or [F, 4, 4]) and SH frames
        rotated by ``frame_rotations`` [F, 3, 3] (``None``: not rotated); ``lighting`` (a
        :class:`~gausstac_maniskill.splat.lighting.Lighting`, one per camera, or None) shades
        the Gaussians that have normals; the other arguments as in
        :func:`~gausstac_maniskill.splat.rasterizer.rasterize`. Returns its ``RenderOutput``."""
        from .inputs import _frame_inputs
        from .rasterizer import _rasterize, one_torch_thread

        with one_torch_thread():
            frames, frame_rotations = _frame_inputs(frames, frame_rotations, self.n_frames,
                                                    self._inputs.means.device)
            return _rasterize(self._inputs, frames, frame_rotations, viewmats, Ks, width, height, background,
                              background_depth, near, far, timings, lighting, gaussian_ranges)

    def posed(self, frames: torch.Tensor, frame_rotations: torch.Tensor | None = None) -> PosedGaussians:
        """The same Gaussians in world space (full covariances), e.g. to check a render or
        to hand them to other tools."""
        from .inputs import _frame_inputs

        frames, frame_rotations = _frame_inputs(frames, frame_rotations, self.n_frames, self._inputs.means.device)
        f = self._inputs.frame_id.long()
        M, t = frames[f, :, :3], frames[f, :, 3]
        c = self._inputs.cov6
        S = torch.stack([c[:, [0, 1, 2]], c[:, [1, 3, 4]], c[:, [2, 4, 5]]], dim=1)
        rot = frame_rotations[f] if frame_rotations is not None else \
            torch.eye(3, device=frames.device).expand(len(self), 3, 3)
        return PosedGaussians((M @ self._inputs.means.unsqueeze(-1)).squeeze(-1) + t,
                              M @ S @ M.transpose(-1, -2), rot.contiguous(), self._inputs.opacities,
                              self._inputs.sh)
