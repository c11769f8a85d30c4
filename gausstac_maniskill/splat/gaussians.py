"""A set of 3D Gaussians (:class:`GaussianSet`) and its INRIA-3DGS ``.ply`` file format.

The parameterisation is Kerbl et al.'s (2023), so that scenes trained with any 3DGS code
load unchanged: means [N, 3] m, unit quaternions (w, x, y, z), log standard deviations
(log-metres), opacity logits, SH colour [N, K, 3], K = (degree + 1)², degree 0..3; plus our
``link_id`` and ``group`` labels. Σ = R S Sᵀ Rᵀ with S = diag(exp(log_scales)), m². File
layout (binary little endian, one ``vertex`` element, the INRIA code's property order)::

    x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 f_rest_0 ... f_rest_{3(K-1)-1}
    opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3 [link_id group]

``f_rest`` is channel-major (``f_rest_{c*(K-1)+k}`` is SH coefficient k+1 of channel c);
``opacity`` is the logit, ``scale_*`` the log-scales; normals are written as zeros and
ignored; a plain INRIA file loads with link_id = 0 and group = -1.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Iterable

import numpy as np
import torch

from ..errors import AssetError, ConfigError
from ..transforms import quat_multiply, quat_to_rotmat, rotmat_to_quat
# SH helpers live in .sh; re-exported here, where GaussianSet users have imported them from
from .sh import SH_C0, num_sh_coeffs, rgb_to_sh_dc, sh_dc_to_rgb, sh_degree_from_coeffs

__all__ = [
    "GaussianSet",
    "SH_C0",
    "rgb_to_sh_dc",
    "sh_dc_to_rgb",
    "num_sh_coeffs",
    "sh_degree_from_coeffs",
    "quat_to_rotmat",
    "quat_multiply",
    "rotmat_to_quat",
    "covariance_from_scale_rotation",
    "load_ply",
    "save_ply",
]


def covariance_from_scale_rotation(quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """Σ = R S Sᵀ Rᵀ.

    Args:
        quats: [..., 4] quaternions (w, x, y, z) (normalised here).
        scales: [..., 3] standard deviations along the Gaussian's axes, metres
            (already exponentiated, *not* log-scales).

    Returns:
        [..., 3, 3] covariance matrices, m².
    """
    M = quat_to_rotmat(quats) * scales.unsqueeze(-2)  # R S: column j scaled by s_j
    return M @ M.transpose(-1, -2)


# --------------------------------------------------------------------------- GaussianSet
@dataclass
class GaussianSet:
    """N 3D Gaussians with SH colour and link/group labels (all torch tensors).

    Attributes:
        means: [N, 3] float32 centres, metres.
        quats: [N, 4] float32 unit quaternions (w, x, y, z).
        log_scales: [N, 3] float32 log standard deviations, log-metres.
        opacity_logits: [N] float32, opacity = sigmoid(logit).
        sh: [N, K, 3] float32 SH coefficients, K = (sh_degree + 1)^2.
        link_id: [N] int64 rigid link each Gaussian follows (default 0).
        group: [N] int64 free label (default -1).

    Construct with :meth:`create` to fill defaults and cast dtypes; the plain
    constructor validates shapes (``ConfigError`` names the tensor).
    """

    means: torch.Tensor
    quats: torch.Tensor
    log_scales: torch.Tensor
    opacity_logits: torch.Tensor
    sh: torch.Tensor
    link_id: torch.Tensor
    group: torch.Tensor

    def __post_init__(self) -> None:
        n = self.means.shape[0] if self.means.dim() == 2 else -1
        expect = {
            "means": (n, 3), "quats": (n, 4), "log_scales": (n, 3),
            "opacity_logits": (n,), "link_id": (n,), "group": (n,),
        }
        for name, shape in expect.items():
            t = getattr(self, name)
            if not isinstance(t, torch.Tensor):
                raise ConfigError(f"GaussianSet.{name} must be a torch.Tensor, "
                                  f"got {type(t).__name__}")
            if tuple(t.shape) != shape or n < 0:
                want = "[N, 3]" if name == "means" else str(list(shape)).replace(str(n), "N")
                raise ConfigError(f"GaussianSet.{name} has shape {list(t.shape)}, expected {want}"
                                  + (f" with N = {n}" if n >= 0 else ""))
        if self.sh.dim() != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3:
            raise ConfigError(f"GaussianSet.sh has shape {list(self.sh.shape)}, expected [N, K, 3] "
                              f"with N = {n}")
        if self.sh.shape[1] not in (1, 4, 9, 16):
            raise ConfigError(f"GaussianSet.sh has K = {self.sh.shape[1]} coefficients per "
                              "channel; expected (degree+1)^2 = 1, 4, 9 or 16")
        for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
            if not getattr(self, name).is_floating_point():
                raise ConfigError(f"GaussianSet.{name} must be a floating-point tensor")
        for name in ("link_id", "group"):
            if getattr(self, name).is_floating_point():
                raise ConfigError(f"GaussianSet.{name} must be an integer tensor")

    # ---------------------------------------------------------------- construction
    @classmethod
    def create(cls, means, quats=None, log_scales=None, opacity_logits=None, sh=None, *,
               link_id=None, group=None, sh_degree: int = 0,
               device: torch.device | str | None = None) -> "GaussianSet":
        """Build a set from array-likes, filling defaults and casting to float32/int64.

        Defaults: identity rotation, log-scale log(0.01) (1 cm), opacity logit 0
        (o = 0.5), grey colour (SH zeros) of degree ``sh_degree``, link 0, group -1.
        """
        means = torch.as_tensor(means, dtype=torch.float32, device=device).reshape(-1, 3)
        n, dev = means.shape[0], means.device

        def f32(x, default):
            return default if x is None else torch.as_tensor(x, dtype=torch.float32, device=dev)

        def i64(x, fill):
            if x is None:
                return torch.full((n,), fill, dtype=torch.int64, device=dev)
            return torch.as_tensor(x, dtype=torch.int64, device=dev).reshape(-1)

        quats = f32(quats, torch.tensor([1.0, 0, 0, 0], device=dev).repeat(n, 1))
        log_scales = f32(log_scales, torch.full((n, 3), math.log(0.01), device=dev))
        opacity_logits = f32(opacity_logits, torch.zeros(n, device=dev))
        sh = f32(sh, torch.zeros(n, num_sh_coeffs(sh_degree), 3, device=dev))
        return cls(means, quats, log_scales, opacity_logits.reshape(-1), sh,
                   i64(link_id, 0), i64(group, -1))

    @classmethod
    def empty(cls, sh_degree: int = 0, device=None) -> "GaussianSet":
        """A set with N = 0."""
        return cls.create(torch.zeros(0, 3), sh_degree=sh_degree, device=device)

    @staticmethod
    def cat(sets: Iterable["GaussianSet"]) -> "GaussianSet":
        """Concatenate sets; lower SH degrees are zero-padded to the highest."""
        sets = list(sets)
        if not sets:
            raise ConfigError("GaussianSet.cat needs at least one set")
        k = max(s.sh.shape[1] for s in sets)
        sh = [torch.nn.functional.pad(s.sh, (0, 0, 0, k - s.sh.shape[1])) for s in sets]
        out = {f.name: torch.cat([getattr(s, f.name) for s in sets]) for f in fields(GaussianSet)
               if f.name != "sh"}
        return GaussianSet(sh=torch.cat(sh), **out)

    # ---------------------------------------------------------------- derived quantities
    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        """SH degree 0..3 (from K)."""
        return sh_degree_from_coeffs(self.sh.shape[1])

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def scales(self) -> torch.Tensor:
        """[N, 3] standard deviations, metres (exp of ``log_scales``)."""
        return self.log_scales.exp()

    @property
    def opacities(self) -> torch.Tensor:
        """[N] peak opacities in (0, 1) (sigmoid of ``opacity_logits``)."""
        return torch.sigmoid(self.opacity_logits)

    def covariances(self) -> torch.Tensor:
        """[N, 3, 3] covariance Σ = R S Sᵀ Rᵀ, m²."""
        return covariance_from_scale_rotation(self.quats, self.scales)

    def __getitem__(self, index) -> "GaussianSet":
        """Select Gaussians by a boolean mask, index tensor or slice."""
        return GaussianSet(**{f.name: getattr(self, f.name)[index] for f in fields(self)})

    def to(self, device) -> "GaussianSet":
        """Copy of the set on ``device``."""
        return GaussianSet(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})

    def clone(self) -> "GaussianSet":
        return GaussianSet(**{f.name: getattr(self, f.name).clone() for f in fields(self)})

    def replace(self, **changes) -> "GaussianSet":
        """Copy with some tensors replaced (``dataclasses.replace``)."""
        return replace(self, **changes)

    def has_labels(self) -> bool:
        """True when any ``link_id`` != 0 or ``group`` != -1 (i.e. labels carry data)."""
        return bool((self.link_id != 0).any() or (self.group != -1).any())


# --------------------------------------------------------------------------- PLY I/O
_BASE_FIELDS = ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2")
_TAIL_FIELDS = ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
_LABEL_FIELDS = ("link_id", "group")


def _property_names(sh_rest: int) -> list[str]:
    return [*_BASE_FIELDS, *(f"f_rest_{i}" for i in range(sh_rest)), *_TAIL_FIELDS]


def save_ply(path: str | os.PathLike, gaussians: GaussianSet, *,
             labels: bool | None = None) -> None:
    """Write ``gaussians`` as an INRIA 3DGS ``.ply`` (binary little endian).

    Args:
        path: output file (parent directory must exist).
        gaussians: the set (moved to the CPU for writing).
        labels: write the extra ``int`` properties ``link_id`` and ``group``.
            ``None`` (default) writes them only when they carry data
            (:meth:`GaussianSet.has_labels`), so plain scenes stay plain INRIA files.
    """
    from plyfile import PlyData, PlyElement

    g = gaussians.to("cpu")
    n, k = len(g), g.sh.shape[1]
    if labels is None:
        labels = g.has_labels()
    names = _property_names(3 * (k - 1))
    cols = [g.means.numpy(), np.zeros((n, 3), np.float32), g.sh[:, 0, :].numpy(),
            # channel-major f_rest: [N, K-1, 3] -> [N, 3, K-1] -> [N, 3(K-1)]
            g.sh[:, 1:, :].transpose(1, 2).reshape(n, -1).numpy(),
            g.opacity_logits[:, None].numpy(), g.log_scales.numpy(), g.quats.numpy()]
    data = np.concatenate(cols, axis=1).astype(np.float32, copy=False)
    dtype = [(name, "<f4") for name in names]
    if labels:
        dtype += [(name, "<i4") for name in _LABEL_FIELDS]
    rec = np.empty(n, dtype=dtype)
    for i, name in enumerate(names):
        rec[name] = data[:, i]
    if labels:
        for name in _LABEL_FIELDS:
            values = getattr(g, name)
            if values.numel() and (values.abs().max() > np.iinfo(np.int32).max):
                raise ConfigError(f"GaussianSet.{name} does not fit in int32 for the .ply file")
            rec[name] = values.numpy().astype(np.int32)
    PlyData([PlyElement.describe(rec, "vertex")], text=False, byte_order="<").write(str(path))


def load_ply(path: str | os.PathLike, *, device: torch.device | str | None = None,
             max_gaussians: int | None = None) -> GaussianSet:
    """Read an INRIA 3DGS ``.ply`` (see the module docstring for the layout).

    The SH degree (0..3) is inferred from the number of ``f_rest_*`` properties.
    Quaternions are normalised (INRIA files store them unnormalised); every other
    value is kept bit-exact, so ``save_ply`` -> ``load_ply`` is lossless.

    Args:
        path: the ``.ply`` file.
        device: torch device of the returned tensors.
        max_gaussians: refuse files with more vertices than this (checked from the
            header, before any column is read); ``None``: no limit.

    Raises:
        AssetError: the file is missing, truncated or unreadable, or a required
            vertex property is missing, is a list, is not numeric, holds
            non-finite values, or the ``f_rest`` count is not 3((d+1)^2-1) for
            d in 0..3, or the file has more than ``max_gaussians`` vertices. The
            message names the file and the property (or the count).
    """
    from plyfile import PlyData, PlyElementParseError

    path = Path(path)
    name = path.name
    if not path.is_file():
        raise AssetError(f"{path}: Gaussian .ply file not found")
    try:
        ply = PlyData.read(str(path))
    except PlyElementParseError as exc:
        raise AssetError(_element_error_message(path, exc)) from None
    except Exception as exc:  # header errors, wrong magic, ...
        raise AssetError(f"{name}: unreadable .ply ({type(exc).__name__}: {exc})") from None
    if "vertex" not in [e.name for e in ply.elements]:
        raise AssetError(f"{name}: element 'vertex' missing")
    vertex = ply["vertex"]
    props = {p.name: p for p in vertex.properties}
    n = vertex.count
    if max_gaussians is not None and n > max_gaussians:
        raise AssetError(f"{name}: element 'vertex' holds {n:,} Gaussians, more than "
                         f"max_gaussians={max_gaussians:,}; prune or downsample the capture, "
                         "or raise max_gaussians")

    def column(field: str, integer: bool = False) -> np.ndarray:
        prop = props.get(field)
        if prop is None:
            raise AssetError(f"{name}: vertex property '{field}' missing")
        if hasattr(prop, "len_dtype"):
            raise AssetError(f"{name}: vertex property '{field}' is a list, expected a scalar")
        values = np.asarray(vertex[field])
        if values.dtype.kind not in "fiu":
            raise AssetError(f"{name}: vertex property '{field}' has non-numeric type "
                             f"{values.dtype}")
        if integer:
            if values.dtype.kind == "f":
                raise AssetError(f"{name}: vertex property '{field}' must be an integer type")
            return values.astype(np.int64)
        values = values.astype(np.float32)
        bad = ~np.isfinite(values)
        if bad.any():
            raise AssetError(f"{name}: vertex property '{field}' has non-finite values "
                             f"(vertex {int(np.argmax(bad))})")
        return values

    rest = sorted(int(p[7:]) for p in props if p.startswith("f_rest_") and p[7:].isdigit())
    n_rest = len(rest)
    k = n_rest // 3 + 1
    if n_rest % 3 or k not in (1, 4, 9, 16):
        raise AssetError(f"{name}: vertex property 'f_rest_*' count is {n_rest}; expected "
                         "0, 9, 24 or 45 (SH degree 0..3)")
    for i in range(n_rest):  # names must be f_rest_0 .. f_rest_{n_rest-1}
        if i >= len(rest) or rest[i] != i:
            raise AssetError(f"{name}: vertex property 'f_rest_{i}' missing")

    means = np.stack([column(f) for f in ("x", "y", "z")], axis=1)
    dc = np.stack([column(f"f_dc_{c}") for c in range(3)], axis=1)
    if n_rest:
        f_rest = np.stack([column(f"f_rest_{i}") for i in range(n_rest)], axis=1)
        f_rest = f_rest.reshape(n, 3, k - 1).transpose(0, 2, 1)  # channel-major -> [N, K-1, 3]
    else:
        f_rest = np.zeros((n, 0, 3), np.float32)
    sh = np.concatenate([dc[:, None, :], f_rest], axis=1)
    opacity = column("opacity")
    log_scales = np.stack([column(f"scale_{i}") for i in range(3)], axis=1)
    quats = np.stack([column(f"rot_{i}") for i in range(4)], axis=1)
    qn = np.linalg.norm(quats, axis=1, keepdims=True)
    if (qn == 0).any():
        raise AssetError(f"{name}: vertex property 'rot_0..3' is a zero quaternion "
                         f"(vertex {int(np.argmax(qn[:, 0] == 0))})")
    # normalise only quaternions that are not already unit, to keep round trips bit-exact
    unit = np.abs(qn - 1) < 1e-6
    quats = np.where(unit, quats, quats / qn).astype(np.float32)
    link_id = column("link_id", integer=True) if "link_id" in props else None
    group = column("group", integer=True) if "group" in props else None
    return GaussianSet.create(means, quats, log_scales, opacity, sh.astype(np.float32),
                              link_id=link_id, group=group, device=device)


def _element_error_message(path: Path, exc) -> str:
    """AssetError text for a plyfile element error, naming the row and property.

    For a truncated binary file plyfile names the row only; the property at
    which the data ends is then found from the file size and the row layout.
    """
    element = getattr(exc.element, "name", "?")
    prop = exc.prop.name if exc.prop is not None else None
    if prop is None and exc.element is not None and exc.row is not None:
        prop = _cut_property(path, exc.element, exc.row)
    where = f"{element} {exc.row}" if exc.row is not None else element
    what = f", property '{prop}'" if prop else ""
    return f"{path.name}: {exc.message} at {where}{what} (file truncated or malformed)"


def _cut_property(path: Path, element, row: int) -> str | None:
    """The property of ``element``'s ``row`` at which a binary file ends."""
    raw = path.read_bytes()
    end = raw.find(b"end_header")
    if end < 0:
        return None
    data_start = raw.index(b"\n", end) + 1
    sizes = [np.dtype(p.val_dtype).itemsize for p in element.properties]
    # bytes of this element's data present in the file (assumes it is the first element)
    rem = len(raw) - data_start - row * sum(sizes)
    for prop, size in zip(element.properties, sizes):
        if rem < size:
            return prop.name
        rem -= size
    return element.properties[-1].name
