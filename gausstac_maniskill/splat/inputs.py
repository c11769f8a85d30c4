"""The rasterizer's arguments checked (``ConfigError`` on a wrong shape, NaN/inf or bad value)
and converted into the contiguous float32/int32 arrays its kernels read, on the Taichi arch's
torch device: the Gaussians (:class:`_Inputs`, kept by :class:`~.deform.FramedGaussians`
across pictures), frames, background, per-camera ranges, lights and camera constants."""

from dataclasses import dataclass, field

import numpy as np
import torch

from .. import backend
from ..errors import ConfigError
from .kernels.common import BACKFACE_COS, FOV_CLAMP, NEVER_CULLED, SUPPORT_SLACK
from .sh import SH_C0, sh_degree_from_coeffs


def _check_finite(name: str, t: torch.Tensor) -> None:
    # fast path: a sum of finite floats is finite (barring overflow, which the
    # exact check below then clears); one pass, no boolean temporary
    if t.numel() == 0 or torch.isfinite(t.sum()):
        return
    if not torch.isfinite(t).all():
        bad = (~torch.isfinite(t)).nonzero()[0].tolist()
        raise ConfigError(f"{name} contains NaN or inf (first at index {bad})")


def _check_shape(name: str, t, shape: tuple, text: str) -> torch.Tensor:
    if not isinstance(t, torch.Tensor):
        raise ConfigError(f"{name} must be a torch.Tensor of shape {text}, got {type(t).__name__}")
    if t.dim() != len(shape) or any(s is not None and s != ts for s, ts in zip(shape, t.shape)):
        raise ConfigError(f"{name} has shape {list(t.shape)}, expected {text}")
    _check_finite(name, t)
    return t


def _cov6(covars: torch.Tensor) -> torch.Tensor:
    """[..., 3, 3] symmetric -> [..., 6] (xx, xy, xz, yy, yz, zz)."""
    i, j = (0, 0, 0, 1, 1, 2), (0, 1, 2, 1, 2, 2)
    return covars[..., i, j]

_DUMMIES: dict = {}


def _dummy(shape: tuple, dtype, device) -> torch.Tensor:
    """A small zero array for a kernel argument that the chosen code path does not read."""
    key = (shape, dtype, str(device))
    if key not in _DUMMIES:
        _DUMMIES[key] = torch.zeros(shape, dtype=dtype, device=device)
    return _DUMMIES[key]


@dataclass
class _Inputs:
    """The Gaussians' arrays as the projection kernel reads them (checked, contiguous float32).

    ``use_cov``: covariances in ``cov6`` [N, 6] (else ``quats``/``scales``); ``frame_id``
    [N] int32 or None (world coordinates); ``rot_mode``: 0 no SH rotation, 1 per Gaussian
    (``sh_rot`` [N, 3, 3]); per-frame rotations come with the frames
    (:func:`~.rasterizer._rasterize`); ``normals`` [N, 3] (in the Gaussians' frames, zero
    rows: not lit) or None (none lit).
    ``one_sided`` [N] bool or None: Gaussians culled when their normal faces away (see
    ``one_sided`` of :func:`~.rasterizer.rasterize`; needs ``normals``).
    ``opacity`` [N, 4]: the opacity o and the terms of the opacity-aware support (see
    :mod:`.kernels.project`), which depend on o alone: ln(255 o) and k = sqrt(2 ln(255 o)),
    the latter 0.1 % larger so that the box never clips a pixel that the α test would keep
    (rounding); ``max(ln(255 o), 0)`` under the root (o < 1/255 is culled anyway); then the
    back-face bound: :data:`BACKFACE_COS` for a one-sided Gaussian, :data:`NEVER_CULLED`
    otherwise.
    """

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    cov6: torch.Tensor
    use_cov: bool
    opacities: torch.Tensor
    sh: torch.Tensor
    degree: int
    sh_rot: torch.Tensor
    rot_mode: int
    frame_id: torch.Tensor | None
    n_frames: int
    normals: torch.Tensor | None = None
    one_sided: torch.Tensor | None = None
    _albedo_pow: dict = field(default_factory=dict, repr=False)
    opacity: torch.Tensor = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # (in float64, rounded once: torch's vectorised float32 log rounds a tensor's tail
        # otherwise than its body, so a Gaussian's terms would depend on the set it sits in;
        # a batch of envs' scenes must give each env's picture exactly)
        o = self.opacities.double()
        ln255o = torch.log(o * 255.0)
        k = torch.sqrt(2.0 * ln255o.clamp_min(0.0)) * SUPPORT_SLACK
        bound = torch.full_like(o, NEVER_CULLED)
        if self.one_sided is not None:
            bound[self.one_sided.to(o.device)] = BACKFACE_COS
        self.opacity = torch.stack([o, ln255o, k, bound], 1).float().contiguous()

    def __len__(self) -> int:
        return self.means.shape[0]

    def albedo_pow(self, exponent: float) -> torch.Tensor:
        """[N, 3] float32 SH degree-0 colours (linear albedo, clamped at 0) to the power
        ``exponent`` (1/gamma), kept per exponent (the arrays must not change)."""
        if exponent not in self._albedo_pow:
            albedo = torch.clamp(SH_C0 * self.sh[:, 0] + 0.5, min=0.0)  # (as the kernel: float32)
            self._albedo_pow[exponent] = (albedo.double() ** exponent).float().contiguous()  # (see __post_init__)
        return self._albedo_pow[exponent]


def _gaussian_inputs(means, quats, scales, opacities, sh, covars, sh_rotations,
                     frame_ids=None, n_frames: int = 0, frame_rotations: bool = False,
                     normals=None, one_sided=None) -> _Inputs:
    """Check and convert the per-Gaussian arguments of :func:`~.rasterizer.rasterize`
    (ConfigError if bad); ``frame_rotations``: whether per-frame SH rotations will come with
    the frames."""
    if not isinstance(means, torch.Tensor) or means.dim() != 2 or means.shape[1] != 3:
        raise ConfigError(f"means has shape {list(getattr(means, 'shape', []))}, expected [N, 3]")
    n = means.shape[0]
    dev = backend.torch_device()  # the kernels run on the Taichi arch, whatever the inputs' device
    f32 = dict(dtype=torch.float32, device=dev)
    means = _check_shape("means", means, (n, 3), "[N, 3]").to(**f32).contiguous()
    opacities = _check_shape("opacities", opacities, (n,), "[N]").to(**f32).contiguous()
    if n and (opacities.min() < 0 or opacities.max() > 1):
        raise ConfigError("opacities must lie in [0, 1] (pass sigmoid(opacity_logits))")
    if not isinstance(sh, torch.Tensor) or sh.dim() != 3 or sh.shape[0] != n or sh.shape[2] != 3:
        raise ConfigError(f"sh has shape {list(getattr(sh, 'shape', []))}, expected [N, K, 3], "
                          f"K in (1, 4, 9, 16), N={n}")
    degree = sh_degree_from_coeffs(sh.shape[1])
    _check_finite("sh", sh)
    sh = sh.to(**f32).contiguous()
    if covars is not None:
        if quats is not None or scales is not None:
            raise ConfigError("pass either covars or quats+scales, not both")
        if covars.dim() == 3:
            cov6 = _cov6(_check_shape("covars", covars, (n, 3, 3), "[N, 3, 3] or [N, 6]"))
        else:
            cov6 = _check_shape("covars", covars, (n, 6), "[N, 3, 3] or [N, 6]")
        cov6 = cov6.to(**f32).contiguous()
        quats = scales = _dummy((1, 4), torch.float32, dev)
    else:
        if quats is None or scales is None:
            raise ConfigError("quats and scales are required unless covars is given")
        quats = _check_shape("quats", quats, (n, 4), "[N, 4]")
        scales = _check_shape("scales", scales, (n, 3), "[N, 3]")
        if n and (quats.abs().amax(dim=-1) == 0).any():
            raise ConfigError("quats contains a zero quaternion")
        quats, scales = quats.to(**f32).contiguous(), scales.to(**f32).contiguous()
        cov6 = _dummy((1, 6), torch.float32, dev)
    rot_mode = 0
    sh_rot = _dummy((1, 3, 3), torch.float32, dev)
    if sh_rotations is not None:
        if frame_rotations:
            raise ConfigError("pass either sh_rotations (per Gaussian) or frame_rotations, not both")
        sh_rot = _check_shape("sh_rotations", sh_rotations, (n, 3, 3), "[N, 3, 3]")
        sh_rot, rot_mode = sh_rot.to(**f32).contiguous(), 1
    if frame_ids is not None:
        if not isinstance(frame_ids, torch.Tensor) or tuple(frame_ids.shape) != (n,) \
                or frame_ids.dtype.is_floating_point:
            raise ConfigError(f"frame_ids must be an integer tensor of shape [N] = [{n}], got "
                              f"{getattr(frame_ids, 'dtype', type(frame_ids).__name__)} "
                              f"{list(getattr(frame_ids, 'shape', []))}")
        if n and (int(frame_ids.min()) < 0 or int(frame_ids.max()) >= n_frames):
            raise ConfigError(f"frame_ids must lie in [0, {n_frames}) for {n_frames} frames, got "
                              f"[{int(frame_ids.min())}, {int(frame_ids.max())}]")
        frame_ids = frame_ids.to(device=dev, dtype=torch.int32).contiguous()
    if normals is not None:
        normals = _check_shape("normals", normals, (n, 3), "[N, 3]").to(**f32).contiguous()
    if one_sided is not None:
        if normals is None:
            raise ConfigError("one_sided needs normals (each one-sided Gaussian's outward normal)")
        one_sided = _check_shape("one_sided", one_sided, (n,), "[N] bool")
        if one_sided.dtype != torch.bool:
            raise ConfigError(f"one_sided must be a bool tensor, got {one_sided.dtype}")
        one_sided = one_sided.to(dev) if bool(one_sided.any()) else None
    return _Inputs(means, quats, scales, cov6, covars is not None, opacities, sh, degree, sh_rot,
                   rot_mode, frame_ids, n_frames, normals, one_sided)


def _frame_inputs(frames, frame_rotations, n_frames: int | None, device) -> tuple:
    """Check ``frames`` [F, 3, 4] or [F, 4, 4] and ``frame_rotations`` [F, 3, 3] (or None)."""
    if not isinstance(frames, torch.Tensor) or frames.dim() != 3 or frames.shape[1] not in (3, 4) \
            or frames.shape[2] != 4 or (n_frames is not None and frames.shape[0] != n_frames):
        want = "F" if n_frames is None else str(n_frames)
        raise ConfigError(f"frames has shape {list(getattr(frames, 'shape', []))}, expected "
                          f"[{want}, 3, 4] or [{want}, 4, 4]")
    _check_finite("frames", frames)
    frames = frames[:, :3, :].to(dtype=torch.float32, device=device).contiguous()
    if frame_rotations is not None:
        frame_rotations = _check_shape("frame_rotations", frame_rotations, (frames.shape[0], 3, 3),
                                       f"[F, 3, 3] with F={frames.shape[0]}")
        frame_rotations = frame_rotations.to(dtype=torch.float32, device=device).contiguous()
    return frames, frame_rotations


def _background_tensor(background, C: int, H: int, W: int, device) -> tuple[torch.Tensor, int]:
    """Background as [C, 1, 1, 3] (constant) or [C, H, W, 3] (image) + the is-image flag."""
    if background is None:
        background = 0.0
    bg = torch.as_tensor(background, dtype=torch.float32, device=device)
    _check_finite("background", bg)
    if bg.dim() == 0:
        return bg.expand(C, 1, 1, 3).contiguous(), 0
    if bg.shape == (3,):
        return bg.expand(C, 1, 1, 3).contiguous(), 0
    if bg.shape == (C, 3):
        return bg.reshape(C, 1, 1, 3).contiguous(), 0
    if bg.shape == (C, H, W, 3):
        return bg.contiguous(), 1
    raise ConfigError(f"background has shape {list(bg.shape)}, expected a scalar, [3], "
                      f"[C, 3] or [C, H, W, 3] with C={C}, H={H}, W={W}")


def _camera_ranges(gaussian_ranges, C: int, n: int, device) -> tuple[torch.Tensor, int]:
    """``gaussian_ranges`` [C, 2] (camera c sees Gaussians [start, stop)) or [C, 2, 2] (two
    such ranges) checked, as [C, 4] int32 (start, stop, start, stop) on ``device``, and the
    most Gaussians a camera sees; None: every camera sees all ``n`` Gaussians."""
    if gaussian_ranges is None:
        return torch.tensor([[0, n, n, n]], dtype=torch.int32, device=device).expand(C, 4).contiguous(), n
    r = torch.as_tensor(gaussian_ranges)
    if r.shape not in ((C, 2), (C, 2, 2)) or r.dtype.is_floating_point:
        raise ConfigError(f"gaussian_ranges must be an integer tensor of shape [C, 2] or [C, 2, 2] (C = {C}), got "
                          f"{r.dtype} {list(r.shape)}")
    r = r.to(torch.int64).cpu()
    if r.dim() == 2:
        r = torch.stack([r, r[:, 1:].expand(C, 2)], 1)  # and an empty second range
    bad = ((r[..., 0] < 0) | (r[..., 1] < r[..., 0]) | (r[..., 1] > n)).any(1)
    if C and bad.any():
        c = int(bad.nonzero()[0])
        raise ConfigError(f"gaussian_ranges[{c}] = {torch.as_tensor(gaussian_ranges)[c].tolist()} is not a range "
                          f"[start, stop) (or two) with 0 <= start <= stop <= N = {n}")
    most = int((r[..., 1] - r[..., 0]).sum(1).max()) if C else 0
    return r.reshape(C, 4).to(device=device, dtype=torch.int32).contiguous(), most


def _camera_lights(lighting, C: int, device) -> tuple[torch.Tensor, list]:
    """Per-camera light rows [C, 1 + L, 6] (see :meth:`Lighting.kernel_array`; a scene with
    fewer lights is padded with dark ones, which add exactly 0) and the C ``Lighting`` s, from
    one ``Lighting`` (every camera) or a sequence of C."""
    from .lighting import Lighting

    lights = [lighting] * C if isinstance(lighting, Lighting) else list(lighting)
    if len(lights) != C or not all(isinstance(x, Lighting) for x in lights):
        raise ConfigError(f"lighting must be a splat.lighting.Lighting, a sequence of C = {C} of them, or "
                          f"None; got {type(lighting).__name__}")
    if not lights:
        return torch.zeros(0, 1, 6, dtype=torch.float32, device=device), lights
    if all(x == lights[0] for x in lights):  # one scene's lights (every env's, as a rule): one copy
        a = lights[0].kernel_array(device)
        return a.expand(C, *a.shape).contiguous(), lights
    arrays = [x.kernel_array(device) for x in lights]
    rows = max(a.shape[0] for a in arrays)
    out = torch.zeros(C, rows, 6, dtype=torch.float32, device=device)
    for c, a in enumerate(arrays):
        out[c, :a.shape[0]] = a
    return out, lights


_CAMERA_CACHE: dict = {}
_CAMERA_CACHE_SIZE = 8  #: cameras whose constants are kept (a picture of a still camera reuses them)


def _camera_constants(viewmats: torch.Tensor, Ks: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """[C, 12] float32 per-camera constants of the projection kernel: fx, fy, cx, cy (px); the
    limits of x/z on the negative and positive side, then of y/z, at which the EWA Jacobian is
    evaluated (1.3 × the half field of view measured from the principal point on each side);
    the camera centre in the world (m); 0. ConfigError unless fx, fy > 0. (numpy: a dozen tiny
    torch ops cost ~0.15 ms.) Kept for the last few cameras, by the values of their matrices."""
    V = viewmats.detach().cpu().numpy()
    K = Ks.detach().cpu().numpy()
    key = (V.tobytes(), K.tobytes(), width, height, str(viewmats.device))
    cached = _CAMERA_CACHE.get(key)
    if cached is not None:
        return cached
    V, K = V.astype(np.float64), K.astype(np.float64)
    fx, fy, cx, cy = K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]
    if (fx <= 0).any() or (fy <= 0).any():
        raise ConfigError("Ks: focal lengths fx, fy must be positive")
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    lims = [cx / fx + (FOV_CLAMP - 1.0) * tan_x, (width - cx) / fx + (FOV_CLAMP - 1.0) * tan_x,
            cy / fy + (FOV_CLAMP - 1.0) * tan_y, (height - cy) / fy + (FOV_CLAMP - 1.0) * tan_y]
    centre = -np.einsum("cji,cj->ci", V[:, :3, :3], V[:, :3, 3])  # x_cam = R x + t = 0
    out = np.concatenate([np.stack([fx, fy, cx, cy, *lims], 1), centre, np.zeros((len(fx), 1))], 1)
    out = torch.from_numpy(out.astype(np.float32)).to(viewmats.device)
    if len(_CAMERA_CACHE) >= _CAMERA_CACHE_SIZE:
        del _CAMERA_CACHE[next(iter(_CAMERA_CACHE))]  # the oldest
    _CAMERA_CACHE[key] = out
    return out

