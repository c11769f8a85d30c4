"""3D Gaussian Splatting forward rasterizer: :func:`rasterize` (tensors in, images out) and
:func:`render` (a :class:`~.gaussians.GaussianSet`), one code path for Taichi's CPU and CUDA.

:func:`rasterize` checks its arguments (:mod:`.inputs`) and runs three stages: projection of
every Gaussian into every camera (:mod:`.kernels.project`), binning of the (Gaussian, tile)
pairs sorted by tile and depth (:mod:`.kernels.tiles` and one ``torch.sort``), and
front-to-back compositing per tile (:mod:`.kernels.composite`). Camera matrices:
:mod:`.cameras`.

The algorithm is the forward pass of Kerbl et al. (2023), written tile-first so that it runs
well on a CPU: one thread per camera × 16×16 tile owns its pixels (no atomics,
deterministic) and keeps their transmittance and colour sums in thread-local arrays; a
Gaussian whose box covers none of the tile's unfinished pixels is passed over without its
record being read, and each record is one 64-byte cache line. The support box is the exact
bound of where α ≥ 1/255, so the picture does not depend on the tiling and equals a dense
"every Gaussian at every pixel" evaluation up to float rounding.
"""

import contextlib
import time
from dataclasses import dataclass, field

import taichi as ti
import torch

from .. import backend
from ..errors import ConfigError
# (the camera helpers are part of this module's API)
from .cameras import _CV_FROM_SAPIEN, intrinsics_from_fov, look_at, sapien_pose_to_opencv_extrinsic  # noqa: F401
from .gaussians import GaussianSet
from .inputs import (_background_tensor, _camera_constants, _camera_lights, _camera_ranges, _check_shape, _dummy,
                     _frame_inputs, _gaussian_inputs, _Inputs)
# (the rules of the picture, importable from here too)
from .kernels.common import (ALPHA_MAX, ALPHA_MIN, B_TILES, BACKFACE_COS, DILATION, FOV_CLAMP, K_MAX,  # noqa: F401
                             NEVER_CULLED, REC, SUPPORT_SLACK, T_MIN, TILE, TILE_BITS)
from .kernels.composite import _rasterize_tiles
from .kernels.project import _project
from .kernels.tiles import _emit_keys

__all__ = [
    "TILE",
    "RenderOutput",
    "rasterize",
    "render",
    "intrinsics_from_fov",
    "look_at",
    "sapien_pose_to_opencv_extrinsic",
]

# On the CPU, PyTorch sorts 1-D integers with a radix sort (FBGEMM's, stable) from
# RADIX_SORT_FROM elements on and with a comparison sort below, 3.3× slower at 32 000 keys:
# from RADIX_PAD_FROM keys on, the list is padded up to RADIX_SORT_FROM with keys past the
# last tile (sorted to the end, never read).
RADIX_SORT_FROM = 32768  #: (CPU) PyTorch's 1-D integer sort is a radix sort from this many elements on
RADIX_PAD_FROM = 10_000  #: (CPU) key counts from which padding to RADIX_SORT_FROM is faster


@dataclass
class RenderOutput:
    """Images rendered for C cameras of H × W pixels (float32 torch tensors).

    Attributes:
        rgb: [C, H, W, 3] colour, Gaussians composited over the background.
        depth: [C, H, W] Σ wᵢ zᵢ, camera-space z in metres weighted by each
            Gaussian's blending weight wᵢ = αᵢTᵢ; *not* normalised by alpha.
        alpha: [C, H, W] accumulated opacity 1 - T_final (= Σ wᵢ).
        stats: timings (ms: ``project``, ``bin_sort``, ``raster``) when asked
            for, and ``n_keys`` (Gaussian-tile pairs).
    """

    rgb: torch.Tensor
    depth: torch.Tensor
    alpha: torch.Tensor
    stats: dict = field(default_factory=dict)

    def normalized_depth(self, eps: float = 1e-6) -> torch.Tensor:
        """[C, H, W] expected depth Σ wᵢ zᵢ / alpha of the Gaussians (0 where alpha <= eps)."""
        return torch.where(self.alpha > eps, self.depth / self.alpha.clamp_min(eps),
                           torch.zeros_like(self.depth))

    def composited_depth(self, background_depth: torch.Tensor) -> torch.Tensor:
        """[C, H, W] Σ wᵢ zᵢ + T·background_depth (depth matching the composited rgb), on the
        outputs' device (``background_depth`` [C, H, W] m may be on any)."""
        return self.depth + (1.0 - self.alpha) * torch.as_tensor(background_depth, device=self.depth.device)


@contextlib.contextmanager
def one_torch_thread():
    """Run the enclosed torch operations on one intra-op thread (restored afterwards).

    The camera's torch steps are small (sorting 10⁴-10⁵ keys, a few image-sized
    element-wise ops). With two OpenMP threads on a two-core machine they are no
    faster, and whenever another process holds a core each parallel region spins until
    the descheduled thread returns: a 128×128 frame measured 0.3-2 s instead of 10-30 ms.
    Taichi's kernels keep using every core.
    """
    n = torch.get_num_threads()
    if n == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


def _rasterize(g: _Inputs, frames: torch.Tensor | None, frame_rotations: torch.Tensor | None,
               viewmats, Ks, width, height, background, background_depth, near, far,
               timings: bool, lighting=None, gaussian_ranges=None) -> RenderOutput:
    """Camera checks and the three stages; ``g`` (and ``frames``) are already checked."""
    with one_torch_thread():
        return _rasterize_stages(g, frames, frame_rotations, viewmats, Ks, width, height, background,
                                 background_depth, near, far, timings, lighting, gaussian_ranges)


def _rasterize_stages(g: _Inputs, frames, frame_rotations, viewmats, Ks, width, height, background,
                      background_depth, near, far, timings: bool, lighting=None,
                      gaussian_ranges=None) -> RenderOutput:
    t_start = time.perf_counter()
    if int(width) != width or int(height) != height or not (0 < width < 32768 and 0 < height < 32768):
        raise ConfigError(f"image size width={width!r}, height={height!r} must be ints in [1, 32767]")
    width, height = int(width), int(height)
    n = len(g)
    dev = g.means.device  # the Taichi arch's (_gaussian_inputs)
    f32 = dict(dtype=torch.float32, device=dev)
    viewmats = _check_shape("viewmats", viewmats, (None, 4, 4), "[C, 4, 4]").to(**f32).contiguous()
    C = viewmats.shape[0]
    Ks = _check_shape("Ks", Ks, (C, 3, 3), f"[C, 3, 3] with C={C}").to(**f32).contiguous()
    bg, bg_is_image = _background_tensor(background, C, height, width, dev)
    if background_depth is not None:
        if not isinstance(background_depth, torch.Tensor) or \
                tuple(background_depth.shape) != (C, height, width):
            raise ConfigError(f"background_depth has shape "
                              f"{list(getattr(background_depth, 'shape', []))}, expected "
                              f"[C, H, W] = [{C}, {height}, {width}]")
        if torch.isnan(background_depth).any():
            raise ConfigError("background_depth contains NaN (use inf for empty pixels)")
        bg_depth = background_depth.to(**f32).contiguous()
    else:
        bg_depth = _dummy((1, 1, 1), torch.float32, dev)
    if not (0 < near < far):
        raise ConfigError(f"need 0 < near < far, got near={near}, far={far}")
    framed = g.frame_id is not None
    if framed and frames is None:
        raise ConfigError("frame_ids need frames")
    rot_mode, sh_rot = g.rot_mode, g.sh_rot
    if frame_rotations is not None:
        rot_mode, sh_rot = 2, frame_rotations
    if g.degree == 0:
        rot_mode = 0  # a constant colour does not depend on the view direction
    frame_id = g.frame_id if framed else _dummy((1,), torch.int32, dev)
    frames = frames if framed else _dummy((1, 3, 4), torch.float32, dev)
    seen, n_seen = _camera_ranges(gaussian_ranges, C, n, dev)
    lit = lighting is not None and g.normals is not None
    cull = g.one_sided is not None
    lights, grey = _dummy((1, 1, 6), torch.float32, dev), False
    if lighting is not None:
        lights, scenes = _camera_lights(lighting, C, dev)
        # grey lights of one gamma on constant colours: the kernel takes one power per
        # Gaussian (see _shade)
        grey = lit and g.degree == 0 and all(x.is_grey and x.gamma == scenes[0].gamma for x in scenes)
    normals = g.normals if lit or cull else _dummy((1, 3), torch.float32, dev)
    albedo_pow = g.albedo_pow(1.0 / scenes[0].gamma) if grey else _dummy((1, 3), torch.float32, dev)

    tiles_x = (width + TILE - 1) // TILE
    tiles_y = (height + TILE - 1) // TILE
    n_tile_total = C * tiles_x * tiles_y
    sync = ti.sync if timings else (lambda: None)

    # 1. project: one record per (camera, Gaussian) ------------------------------------
    # only entries of Gaussians that touch a tile are written and ever read
    rec = torch.empty(C, max(n_seen, 1), REC, **f32)
    bins = torch.empty(C, n_seen, 4, dtype=torch.int32, device=dev)
    cams = _camera_constants(viewmats, Ks, width, height)  # (checks Ks)
    if n_seen:
        _project(g.means, g.quats, g.scales, g.cov6, g.opacity, g.sh, g.degree, sh_rot, frame_id, frames,
                 normals, lights, albedo_pow, viewmats, cams, seen, width, height, float(near), float(far),
                 g.use_cov, framed, rot_mode, lit, grey, cull, C == 1, rec, bins)
    sync()
    t_proj = time.perf_counter()

    # 2. bin: one key per (Gaussian, tile), sort, per-tile ranges ---------------------
    ends = torch.cumsum(bins[:, :, B_TILES].reshape(-1), 0, dtype=torch.int64)
    n_keys = int(ends[-1]) if n_seen else 0
    if n_keys:
        n_sort = RADIX_SORT_FROM if dev.type == "cpu" and RADIX_PAD_FROM <= n_keys < RADIX_SORT_FROM else n_keys
        keys = torch.empty(n_sort, dtype=torch.int64, device=dev)
        vals = torch.empty(n_sort, dtype=torch.int64, device=dev)
        keys[n_keys:] = n_tile_total << 32  # padding: past the last tile
        _emit_keys(ends, bins, tiles_x, tiles_x * tiles_y, keys, vals, C == 1)
        keys, order = torch.sort(keys, stable=True)
        vals = vals.index_select(0, order)  # (a quarter of the time of vals[order])
        # tile t's entries are [starts[t], starts[t + 1]) of the sorted list
        starts = torch.searchsorted(keys >> 32, torch.arange(n_tile_total + 1, device=dev))
    else:
        vals = _dummy((1,), torch.int64, dev)
        starts = torch.zeros(n_tile_total + 1, dtype=torch.int64, device=dev)
    sync()
    t_bin = time.perf_counter()

    # 3. rasterise ----------------------------------------------------------------------
    out_rgb = torch.empty(C, height, width, 3, **f32)
    out_depth = torch.empty(C, height, width, **f32)
    out_alpha = torch.empty(C, height, width, **f32)
    spread = 256 if backend.current_arch() == "cpu" else 1
    _rasterize_tiles(starts, vals, rec, bg, bg_is_image, bg_depth, background_depth is not None,
                     tiles_x, spread, C == 1, out_rgb, out_depth, out_alpha)
    sync()
    t_end = time.perf_counter()
    stats = {"n_keys": n_keys}
    if timings:
        stats.update(project=1e3 * (t_proj - t_start), bin_sort=1e3 * (t_bin - t_proj),
                     raster=1e3 * (t_end - t_bin), total=1e3 * (t_end - t_start))
    return RenderOutput(out_rgb, out_depth, out_alpha, stats)


def rasterize(means: torch.Tensor, quats: torch.Tensor | None, scales: torch.Tensor | None,
              opacities: torch.Tensor, sh: torch.Tensor, viewmats: torch.Tensor,
              Ks: torch.Tensor, width: int, height: int, *,
              covars: torch.Tensor | None = None,
              sh_rotations: torch.Tensor | None = None,
              frames: torch.Tensor | None = None, frame_ids: torch.Tensor | None = None,
              frame_rotations: torch.Tensor | None = None,
              normals: torch.Tensor | None = None, one_sided: torch.Tensor | None = None,
              lighting=None, background=None, background_depth: torch.Tensor | None = None,
              gaussian_ranges: torch.Tensor | None = None,
              near: float = 0.01, far: float = 1e4,
              timings: bool = False) -> RenderOutput:
    """Render N Gaussians into C pinhole cameras.

    Cameras follow OpenCV (camera x right, y down, z forward). Pixel (u, v) covers
    [u, u+1) × [v, v+1) and its centre is (u + 0.5, v + 0.5), so ``cx = W/2`` puts the
    principal point at the image centre (SAPIEN's convention; see
    :func:`sapien_pose_to_opencv_extrinsic` for SAPIEN poses). Each pixel composites the
    Gaussians front to back by camera-space z: rgb = Σ wᵢ cᵢ + T·background, alpha = 1 - T,
    depth = Σ wᵢ zᵢ with wᵢ = αᵢ Tᵢ (see :class:`RenderOutput`).

    Args:
        means: [N, 3] centres, metres (world, or in their frames with ``frames``).
        quats: [N, 4] rotations (w, x, y, z), normalised here. ``None`` with ``covars``.
        scales: [N, 3] standard deviations along the Gaussian axes, metres
            (exponentiated, not log-scales). ``None`` with ``covars``.
        opacities: [N] peak opacities in [0, 1] (sigmoid of the logits).
        sh: [N, K, 3] SH colour coefficients, K = (degree+1)², degree 0..3.
        viewmats: [C, 4, 4] world -> camera transforms (``x_cam = R x_world + t``).
        Ks: [C, 3, 3] pinhole intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, pixels.
        width, height: image size W, H in pixels.
        covars: optional precomputed covariances, [N, 3, 3] or [N, 6]
            (xx, xy, xz, yy, yz, zz), m²; replaces ``quats``/``scales``.
        sh_rotations: optional [N, 3, 3] rotation of each Gaussian's SH frame
            (e.g. polar(F) of a deformed Gaussian): the SH are evaluated at
            ``Rᵀ · view_dir``.
        frames: optional [F, 3, 4] (or [F, 4, 4]) affine frame -> world maps
            ``x -> M x + t``; Gaussian g's mean and covariance are then given in
            frame ``frame_ids[g]`` and posed by the projection kernel (μ = M μ⁰ + t,
            Σ = M Σ⁰ Mᵀ). A rigid link is a frame with M = its rotation, an MPM particle one
            with M = F_p (deformation gradient) and t = x_p; only the F frames change from
            one picture to the next (see :class:`~gausstac_maniskill.splat.deform.FramedGaussians`).
        frame_ids: [N] integer frame of each Gaussian (with ``frames``).
        frame_rotations: optional [F, 3, 3] rotation R_f of the SH frames of each frame's
            Gaussians (instead of ``sh_rotations``; a link's rotation, polar(F_p) for a
            particle): the SH are evaluated at ``R_fᵀ · view_dir``.
        normals: optional [N, 3] normals (world, or in the Gaussians' frames with
            ``frames``, where they move with cof(M); any length), the zero vector for a
            Gaussian that is not to be lit; see
            :func:`~gausstac_maniskill.splat.lighting.surface_normals`.
        one_sided: optional [N] bool: Gaussians on closed surfaces (sampled from closed,
            outward-wound meshes) whose ``normals`` point outward, sign included. Such a
            Gaussian is culled in the projection when it faces away from the camera,
            n·v > :data:`BACKFACE_COS` |n||v| (n = cof(M)·n⁰, v the view ray, camera ->
            Gaussian): a nearer front side always hides it; those near the silhouette stay
            drawn. The others are always drawn. Needs ``normals``.
        lighting: optional :class:`~gausstac_maniskill.splat.lighting.Lighting` (every
            camera), or a sequence of C of them (camera c's scene's). A Gaussian with a
            non-zero normal is shaded per camera: n = cof(M)·n⁰ normalised and turned
            towards the camera, c = (A + Σᵢ Eᵢ/π · max(0, n·lᵢ)) · c_SH written as c^(1/γ)
            (the diffuse part of SAPIEN's shaders, the SH colour as linear albedo); one with
            the zero normal keeps its SH colour (a captured scene's baked lighting). Needs
            ``normals``; see :mod:`gausstac_maniskill.splat.lighting`.
        background: colour behind the Gaussians: scalar, [3], [C, 3] or an
            image [C, H, W, 3]. Default black.
        background_depth: optional [C, H, W] camera-z depth (metres) of the background
            image (e.g. a mesh render's depth) for depth-aware compositing: a pixel is
            finished at the first Gaussian that reaches it (α ≥ 1/255) beyond this depth,
            and the background is composited with the remaining T. Use ``inf`` where the
            background is empty.
        gaussian_ranges: optional [C, 2] integers: camera c sees only Gaussians
            [start, stop) (B envs' scenes concatenated into one set, each env's cameras
            seeing their env's range, in one call of three launches; each picture equals
            its range rendered alone, bit for bit; ``lighting`` may differ per camera). Or
            [C, 2, 2]: two such ranges, the first then the second (a scene's shared
            Gaussians and one level of detail of its hand: ``render.Detail``). Default:
            every camera sees all of them.
        near, far: clip distances along camera z, metres.
        timings: record per-stage wall times (ms) in ``RenderOutput.stats``.

    Returns:
        :class:`RenderOutput` with rgb [C, H, W, 3], depth [C, H, W] (m), alpha [C, H, W],
        on the device of the Taichi arch in use (``GAUSSTAC_ARCH``,
        ``backend.torch_device()``); the inputs may lie on any device and are moved there.

    Raises:
        ConfigError: a wrong shape (the message gives the expected one), NaN/inf
            in any input, opacities outside [0, 1], frame ids out of range, or
            non-positive image size.
    """
    if (frames is None) != (frame_ids is None):
        raise ConfigError("frames and frame_ids go together")
    if frame_rotations is not None and frames is None:
        raise ConfigError("frame_rotations need frames and frame_ids")
    if lighting is not None and normals is None:
        raise ConfigError("lighting needs normals (splat.lighting.surface_normals(quats, scales))")
    dev = backend.torch_device()
    with one_torch_thread():  # the input checks are torch reductions too
        n_frames = 0
        if frames is not None:
            frames, frame_rotations = _frame_inputs(frames, frame_rotations, None, dev)
            n_frames = frames.shape[0]
        g = _gaussian_inputs(means, quats, scales, opacities, sh, covars, sh_rotations, frame_ids,
                             n_frames, frame_rotations is not None, normals, one_sided)
        return _rasterize(g, frames, frame_rotations, viewmats, Ks, width, height, background,
                          background_depth, near, far, timings, lighting, gaussian_ranges)


def render(gaussians: GaussianSet, viewmats: torch.Tensor, Ks: torch.Tensor, width: int,
           height: int, **kwargs) -> RenderOutput:
    """Render a :class:`GaussianSet` (activates scales/opacities); kwargs as :func:`rasterize`.
    With ``lighting`` and no ``normals``, its flat Gaussians are lit (:func:`surface_normals
    <gausstac_maniskill.splat.lighting.surface_normals>`)."""
    if kwargs.get("lighting") is not None and kwargs.get("normals") is None:
        from .lighting import surface_normals

        kwargs["normals"] = surface_normals(gaussians.quats, gaussians.scales)
    return rasterize(gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities,
                     gaussians.sh, viewmats, Ks, width, height, **kwargs)
