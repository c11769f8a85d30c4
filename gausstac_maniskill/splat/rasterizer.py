"""3D Gaussian Splatting forward rasterizer (Taichi; one code path for CPU and CUDA).

The algorithm is the forward pass of Kerbl et al. (2023), written tile-first so
that it runs well on a CPU:

1. **Project** (one thread per camera × Gaussian): optionally move the Gaussian
   out of its frame (see *Frames* below), world -> camera, cull z <= near or
   z >= far, then cull Gaussians whose screen box cannot reach the image (a
   bound from the trace of the covariance, checked before the covariance is
   formed), EWA splatting Σ' = J W Σ Wᵀ Jᵀ (Zwicker et al. 2002) with the
   perspective Jacobian J evaluated at x/z, y/z clamped to 1.3 × the half field
   of view, + 0.3 px² on the diagonal (anti-aliasing dilation), conic = Σ'⁻¹,
   SH colour for the view direction, and the pixel box of the Gaussian's support
   (see *Support* below). Everything the later stages read about a Gaussian is
   written to one 16-float record (one 64-byte cache line) per camera.
2. **Bin**: count the 16×16 tiles each box touches, exclusive prefix sum,
   emit one 64-bit key ``(camera·tiles + tile) << 32 | float_bits(depth)`` per
   (Gaussian, tile) with a value (the Gaussian and the part of its box inside
   the tile), a single stable ``torch.sort``, then each tile's [start, end)
   range in the sorted list (``torch.searchsorted`` of the tile numbers). On the
   CPU, PyTorch sorts 1-D integers from ``RADIX_SORT_FROM`` elements on with a radix
   sort (FBGEMM's, stable) and below that with a comparison sort, 3.3× slower at
   32 000 keys; from ``RADIX_PAD_FROM`` keys the list is padded up to that size with
   keys past the last tile (sorted to the end, never read).
3. **Rasterise** (one thread per camera × tile): the tile walks its Gaussians
   front to back. A Gaussian whose box part covers no unfinished pixel (a 16-bit
   mask per row) is passed over without reading its record; otherwise the rows
   of its box part that still have unfinished pixels are drawn. Per pixel, the
   exponent ``power = -½ dᵀ Σ'⁻¹ d`` is compared with the support bound
   ``-ln(255 o)`` before any exponential is taken. T and the colour sums of the
   tile's 256 pixels live in thread-local arrays.
   Per pixel: α = min(0.99, o·exp(power)); α < 1/255 is skipped; if
   T·(1-α) < 1e-4 the pixel is finished *without* this Gaussian (as in the
   INRIA code); otherwise C += α·T·c, D += α·T·z, T *= 1-α. The tile stops
   when all its pixels are finished.

Conventions
-----------
* Cameras are pinhole, OpenCV convention: camera x right, y down, z forward.
  ``viewmats`` [C, 4, 4] map world -> camera (``x_cam = R x_world + t``);
  ``Ks`` [C, 3, 3] are ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels.
  Pixel (u, v) covers [u, u+1) × [v, v+1); its centre is (u + 0.5, v + 0.5), so
  ``cx = W/2`` puts the principal point at the image centre (SAPIEN's
  convention). See :func:`sapien_pose_to_opencv_extrinsic` for SAPIEN poses.
* ``depth`` is the camera-space z (metres, not the ray length).
* Outputs: ``rgb`` = Σ wᵢ cᵢ + T·background, ``alpha`` = 1 - T,
  ``depth`` = Σ wᵢ zᵢ with wᵢ = αᵢ Tᵢ, **not** normalised by alpha (it is 0
  where nothing was drawn); :meth:`RenderOutput.normalized_depth` divides by
  alpha, :meth:`RenderOutput.composited_depth` adds T × background depth.

Frames
------
With ``frames`` [F, 3, 4] (affine maps ``x -> M_f x + t_f``) and ``frame_ids``
[N], Gaussian g's mean and covariance are given in frame f = frame_ids[g] and
the projection kernel poses it: μ = M μ⁰ + t, Σ = M Σ⁰ Mᵀ, its SH evaluated at
``R_fᵀ · view_dir`` with ``frame_rotations`` [F, 3, 3] (identity if omitted).
A rigid link is a frame with M = R_f = its rotation; an MPM particle is a frame
with M = F_p (deformation gradient), t = x_p and R_f = polar(F_p). Only the F
frames change from one picture to the next, so the Gaussians' own arrays are
neither rebuilt nor copied per frame (see
:class:`~gausstac_maniskill.splat.deform.FramedGaussians`).

Support
-------
A Gaussian can only contribute where α ≥ 1/255, i.e. inside the ellipse
dᵀΣ'⁻¹d ≤ k² with k = sqrt(2 ln(255·o)) (opacity-aware extent; k = 3.33 for
o = 1, k < 3 for o < 0.35, no pixels at all for o < 1/255). The box is the
exact axis-aligned bounding box of that ellipse, ±k·sqrt(Σ'ₓₓ), ±k·sqrt(Σ'ᵧᵧ)
(never larger than the isotropic radius k·sqrt(λ_max) of the INRIA code).
Unlike a fixed 3σ cut-off this box drops only pixels that the α ≥ 1/255 rule
drops anyway, so the image does not depend on the tiling and equals a dense
"every Gaussian at every pixel" evaluation (up to float rounding).

Lighting
--------
With ``lighting`` (a :class:`~gausstac_maniskill.splat.lighting.Lighting`: ambient plus
directional lights) every Gaussian with a non-zero normal (``normals`` [N, 3], in its
frame) is shaded in the projection kernel, per camera: n = cof(M)·n⁰ normalised and
turned towards the camera, colour c = (A + Σᵢ Eᵢ/π · max(0, n·lᵢ)) · c_SH written as
c^(1/γ) — the diffuse part of SAPIEN's shaders, with the SH colour as linear albedo. A
Gaussian with the zero normal keeps its SH colour (a captured scene's baked lighting). See
:mod:`gausstac_maniskill.splat.lighting`.

Back faces
----------
A Gaussian marked ``one_sided`` lies on a closed surface whose outward normal is its
``normals[g]``, sign included (surfaces sampled from closed, outward-wound meshes, e.g. a
hand asset's links). Behind a closed opaque surface there is always a front side nearer the
camera, so such a Gaussian is culled in the projection when it faces away:
n·v > :data:`BACKFACE_COS` |n||v|, with n = cof(M)·n⁰ and v the view ray (camera to
Gaussian). The bound leaves those near the silhouette (n nearly perpendicular to v) drawn.
Roughly half of a closed surface faces away: its keys are neither sorted nor visited by the
tiles (BENCHMARKS.md, issue 13). Gaussians that are not ``one_sided`` are always drawn.

Batches
-------
With ``gaussian_ranges`` [C, 2], camera c sees only Gaussians [start, stop): B envs' scenes
concatenated into one set, each env's cameras seeing their own env's range, render in one
call of three launches (its records and keys are per camera and local to the range, so a
camera's picture equals that of its range rendered alone, bit for bit). ``lighting`` may
then differ per camera (each env's scene lights). With [C, 2, 2] a camera sees two ranges,
the first then the second (a scene's shared Gaussians and one level of detail of its hand:
``render.Detail``); its picture equals that of the two ranges' Gaussians, in that order,
rendered alone.

Device
------
The kernels run on the Taichi arch in use (``GAUSSTAC_ARCH``); inputs are moved to its
torch device (``backend.torch_device()``) and the outputs lie there.

Depth-aware compositing
-----------------------
With ``background_depth`` [C, H, W] (e.g. a mesh render's depth), a pixel is
finished at the first Gaussian (in depth order) that reaches it (α ≥ 1/255)
with its z beyond the background depth there (every later Gaussian lies
deeper still); the background colour is then composited with the remaining T.
"""
# no `from __future__ import annotations`: Taichi reads the kernels' annotations at runtime

import contextlib
import math
import time
from dataclasses import dataclass, field

import numpy as np
import taichi as ti
import torch

from .. import backend
from ..errors import ConfigError
from ..mpm.kinematics import quat_to_mat
from .gaussians import GaussianSet
from .sh import SH_C0, SH_C1, SH_C2, SH_C3, sh_degree_from_coeffs

__all__ = [
    "TILE",
    "RenderOutput",
    "rasterize",
    "render",
    "intrinsics_from_fov",
    "look_at",
    "sapien_pose_to_opencv_extrinsic",
]

TILE_BITS = 4  #: log2 of the tile edge
TILE = 1 << TILE_BITS  #: tile edge in pixels (16); tile of pixel x >= 0: x >> TILE_BITS
ALPHA_MIN = 1.0 / 255.0  #: contributions below this α are skipped
ALPHA_MAX = 0.99  #: α clamp (keeps T > 0)
T_MIN = 1e-4  #: a pixel is finished when T would fall below this
DILATION = 0.3  #: px² added to the 2D covariance's diagonal (anti-aliasing)
FOV_CLAMP = 1.3  #: the Jacobian is evaluated at x/z clamped to 1.3 tan(fov/2)
K_MAX = math.sqrt(2.0 * math.log(255.0))  #: support radius (in σ) of an opaque Gaussian
SUPPORT_SLACK = 1.001  #: the support radius k is taken this much larger (rounding; the α test decides)
#: a one-sided Gaussian is culled when n·v > BACKFACE_COS |n||v| (see *Back faces*)
BACKFACE_COS = 0.0
NEVER_CULLED = 2.0  #: the cosine bound of a Gaussian that is not one-sided (n·v <= |n||v| < 2|n||v|)

# One record per (camera, Gaussian), written by _project, read by the tiles: screen centre,
# conic (Σ'⁻¹: a, b, c), opacity, depth z, colour and the support bound -ln(255 o) on the
# exponent (padded to 16 floats: one 64-byte cache line). Binning reads a separate 16-byte
# entry: number of tiles touched (0: culled), x0 | x1 << 16, y0 | y1 << 16 (the pixel box
# [x0, x1) × [y0, y1)) and the depth's bits.
REC = 16
RADIX_SORT_FROM = 32768  #: (CPU) PyTorch's 1-D integer sort is a radix sort from this many elements on
RADIX_PAD_FROM = 10_000  #: (CPU) key counts from which padding to RADIX_SORT_FROM is faster (BENCHMARKS.md, 2026-11-25)
R_U, R_V, R_A, R_B, R_C, R_O, R_Z, R_R, R_G, R_BL, R_THR = range(11)
B_TILES, B_X, B_Y, B_Z = range(4)

_f32_1 = ti.types.ndarray(dtype=ti.f32, ndim=1)
_f32_2 = ti.types.ndarray(dtype=ti.f32, ndim=2)
_f32_3 = ti.types.ndarray(dtype=ti.f32, ndim=3)
_f32_4 = ti.types.ndarray(dtype=ti.f32, ndim=4)
_i32_1 = ti.types.ndarray(dtype=ti.i32, ndim=1)
_i32_2 = ti.types.ndarray(dtype=ti.i32, ndim=2)
_i32_3 = ti.types.ndarray(dtype=ti.i32, ndim=3)
_i64_1 = ti.types.ndarray(dtype=ti.i64, ndim=1)


# =========================================================================== kernels
@ti.func
def _sh_to_rgb(sh: ti.template(), g: ti.i32, degree: ti.i32, d: ti.math.vec3) -> ti.math.vec3:
    """Colour of Gaussian g for unit view direction d: Σ_lm c_lm Y_lm(d) + 0.5, clamped >= 0."""
    x, y, z = d[0], d[1], d[2]
    rgb = ti.math.vec3(0.0)
    for ch in ti.static(range(3)):
        v = SH_C0 * sh[g, 0, ch]
        if degree >= 1:
            v += SH_C1 * (-y * sh[g, 1, ch] + z * sh[g, 2, ch] - x * sh[g, 3, ch])
        if degree >= 2:
            xx, yy, zz = x * x, y * y, z * z
            v += (SH_C2[0] * x * y * sh[g, 4, ch]
                  + SH_C2[1] * y * z * sh[g, 5, ch]
                  + SH_C2[2] * (2.0 * zz - xx - yy) * sh[g, 6, ch]
                  + SH_C2[3] * x * z * sh[g, 7, ch]
                  + SH_C2[4] * (xx - yy) * sh[g, 8, ch])
            if degree >= 3:
                v += (SH_C3[0] * y * (3.0 * xx - yy) * sh[g, 9, ch]
                      + SH_C3[1] * x * y * z * sh[g, 10, ch]
                      + SH_C3[2] * y * (4.0 * zz - xx - yy) * sh[g, 11, ch]
                      + SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * sh[g, 12, ch]
                      + SH_C3[4] * x * (4.0 * zz - xx - yy) * sh[g, 13, ch]
                      + SH_C3[5] * z * (xx - yy) * sh[g, 14, ch]
                      + SH_C3[6] * x * (xx - 3.0 * yy) * sh[g, 15, ch])
        rgb[ch] = ti.max(v + 0.5, 0.0)
    return rgb


@ti.func
def _cofactor_times(M: ti.math.mat3, n0: ti.math.vec3) -> ti.math.vec3:
    """cof(M)·n⁰ = det(M) M⁻ᵀ n⁰: a normal carried by the frame x -> M x + t (the normal of the
    plane pushed forward by M); the columns of cof(M) are m1×m2, m2×m0, m0×m1."""
    m0 = ti.math.vec3(M[0, 0], M[1, 0], M[2, 0])
    m1 = ti.math.vec3(M[0, 1], M[1, 1], M[2, 1])
    m2 = ti.math.vec3(M[0, 2], M[1, 2], M[2, 2])
    return n0[0] * m1.cross(m2) + n0[1] * m2.cross(m0) + n0[2] * m0.cross(m1)


@ti.func
def _shade(albedo: ti.math.vec3, n0: ti.math.vec3, M: ti.math.mat3, view: ti.math.vec3,
           lights: ti.template(), c: ti.i32, albedo_pow: ti.template(), g: ti.i32,
           grey: ti.template()) -> ti.math.vec3:
    """Diffuse shading of a Gaussian of linear albedo ``albedo`` and normal ``n0`` in the
    frame whose linear map is M, seen along ``view`` (camera -> Gaussian, world):
    (A + Σᵢ Eᵢ/π · max(0, n·lᵢ))·albedo, written as c^(1/gamma). ``lights[c]`` (camera c's
    scene) rows: (A, 1/gamma, 0, 0), then (lᵢ toward the light, Eᵢ/π). ``grey``: the ambient and every light are grey,
    so the light is one number L and c^(1/gamma) = albedo^(1/gamma) · L^(1/gamma), with
    albedo^(1/gamma) of Gaussian g read from ``albedo_pow`` (one power instead of three)."""
    n = _cofactor_times(M, n0)  # (normals move with cof(M))
    rgb = albedo
    len2 = n.norm_sqr()
    if len2 > 0.0:  # (a singular frame has no normal: the colour is left as it is)
        n *= ti.rsqrt(len2)
        if n.dot(view) > 0.0:
            n = -n  # two-sided: the side facing the camera
        light = ti.math.vec3(lights[c, 0, 0], lights[c, 0, 1], lights[c, 0, 2])  # ambient
        for i in range(1, lights.shape[1]):
            l_dir = ti.math.vec3(lights[c, i, 0], lights[c, i, 1], lights[c, i, 2])
            light += ti.math.vec3(lights[c, i, 3], lights[c, i, 4], lights[c, i, 5]) * ti.max(n.dot(l_dir), 0.0)
        if ti.static(grey):
            rgb = ti.math.vec3(albedo_pow[g, 0], albedo_pow[g, 1], albedo_pow[g, 2]) * light[0] ** lights[c, 0, 3]
        else:
            rgb = (albedo * light) ** lights[c, 0, 3]
    return rgb


@ti.func
def _quat_scale_to_cov(q: ti.math.vec4, s: ti.math.vec3) -> ti.math.mat3:
    """Σ = R S Sᵀ Rᵀ from a quaternion (w, x, y, z) and standard deviations s."""
    R = quat_to_mat(q.normalized())
    M = R @ ti.Matrix([[s[0], 0.0, 0.0], [0.0, s[1], 0.0], [0.0, 0.0, s[2]]])
    return M @ M.transpose()


@ti.func
def _box_1d(centre: ti.f32, radius: ti.f32, size: ti.i32):
    """Pixels [lo, hi) whose centre (i + 0.5) lies within centre ± radius, clipped to [0, size)."""
    lo = ti.max(ti.cast(ti.ceil(centre - radius - 0.5), ti.i32), 0)
    hi = ti.min(ti.cast(ti.floor(centre + radius - 0.5), ti.i32) + 1, size)
    return lo, hi


@ti.func
def _split(i: ti.i32, n: ti.i32, one_camera: ti.template()):
    """(camera, item) of the flat index i over cameras × n items; with ``one_camera`` it is
    (0, i) without the integer division, which costs as much as a small loop body."""
    c, k = 0, i
    if ti.static(not one_camera):
        c, k = ti.raw_div(i, n), ti.raw_mod(i, n)  # (i >= 0: no floor correction)
    return c, k


@ti.kernel
def _project(means: _f32_2, quats: _f32_2, scales: _f32_2, cov6: _f32_2, opac: _f32_2,
             sh: _f32_3, degree: ti.i32, sh_rot: _f32_3, frame_id: _i32_1, frames: _f32_3,
             normals: _f32_2, lights: _f32_3, albedo_pow: _f32_2,
             viewmats: _f32_3, cams: _f32_2, seen: _i32_2, width: ti.i32, height: ti.i32,
             near: ti.f32, far: ti.f32,
             use_cov: ti.template(), framed: ti.template(), rot_mode: ti.template(),
             lit: ti.template(), grey: ti.template(), cull: ti.template(), one_camera: ti.template(),
             rec: _f32_3, bins: _i32_3):
    """EWA projection of camera c's Gaussians into camera c: the j-th of the Gaussians
    [seen[c, 0], seen[c, 1]) then [seen[c, 2], seen[c, 3]) (all of them, or camera c's env's)
    writes rec[c, j] and
    bins[c, j] (bins[c, j, B_TILES] = 0 if culled or past the range).

    ``use_cov``: covariances from ``cov6`` (else from ``quats``/``scales``); ``framed``:
    means and covariances lie in ``frames[frame_id[g]]``; ``rot_mode``: SH frames not
    rotated (0), rotated per Gaussian by ``sh_rot[g]`` (1) or per frame by
    ``sh_rot[frame_id[g]]`` (2); ``lit``: Gaussians with a non-zero ``normals[g]`` (in
    their frame) are shaded with ``lights`` [C, 1 + L, 6] (see *Lighting*); ``grey``: grey lights and
    ``albedo_pow`` [N, 3] holds each Gaussian's albedo^(1/gamma) (see :func:`_shade`).
    ``opac`` [N, 4]: each Gaussian's opacity, support terms and back-face bound (see
    :attr:`_Inputs.opacity`); ``cull``: some Gaussians are one-sided (bound < 1): culled when
    their normal (``normals[g]``, in their frame) faces away (see *Back faces*).
    ``cams`` [C, 12]: the per-camera constants of :func:`_camera_constants`. Only entries
    of Gaussians that touch a tile are written.
    """
    for i in range(viewmats.shape[0] * bins.shape[1]):
        c, j = _split(i, bins.shape[1], one_camera)
        bins[c, j, B_TILES] = 0
        g = seen[c, 0] + j  # the Gaussian (of the first range, then the second); its entries are [c, j]
        if g >= seen[c, 1]:
            g = seen[c, 2] + g - seen[c, 1]
            if g >= seen[c, 3]:
                continue
        W = ti.Matrix([[viewmats[c, i, j] for j in ti.static(range(3))]
                       for i in ti.static(range(3))])  # world -> camera rotation
        t = ti.math.vec3(viewmats[c, 0, 3], viewmats[c, 1, 3], viewmats[c, 2, 3])
        mu = ti.math.vec3(means[g, 0], means[g, 1], means[g, 2])
        f = 0
        M = ti.Matrix.identity(ti.f32, 3)  # frame -> world linear map
        if ti.static(framed):
            f = frame_id[g]
            M = ti.Matrix([[frames[f, i, j] for j in ti.static(range(3))]
                           for i in ti.static(range(3))])
            mu = M @ mu + ti.math.vec3(frames[f, 0, 3], frames[f, 1, 3], frames[f, 2, 3])
        p = W @ mu + t  # camera-space centre
        o = opac[g, 0]
        view = mu - ti.math.vec3(cams[c, 8], cams[c, 9], cams[c, 10])  # camera centre -> Gaussian, world
        drawn = p.z > near and p.z < far and o >= ALPHA_MIN
        if ti.static(cull):
            bound = opac[g, 3]
            if drawn and bound < 1.0:  # one-sided: culled when its outward normal faces away
                n = ti.math.vec3(normals[g, 0], normals[g, 1], normals[g, 2])
                if ti.static(framed):
                    n = _cofactor_times(M, n)  # (det M > 0: links and deformation gradients)
                if n.dot(view) > bound * ti.sqrt(n.norm_sqr() * view.norm_sqr()):
                    drawn = False
        if drawn:
            fx, fy, cx, cy = cams[c, 0], cams[c, 1], cams[c, 2], cams[c, 3]
            # perspective Jacobian at the centre, with x/z, y/z clamped to 1.3 tan(fov/2)
            # (the half-fov measured from the principal point on each side)
            lim_xn, lim_xp, lim_yn, lim_yp = cams[c, 4], cams[c, 5], cams[c, 6], cams[c, 7]
            iz = 1.0 / p.z
            tx = ti.math.clamp(p.x * iz, -lim_xn, lim_xp) * p.z
            ty = ti.math.clamp(p.y * iz, -lim_yn, lim_yp) * p.z
            J = ti.Matrix([[fx * iz, 0.0, -fx * tx * iz * iz],
                           [0.0, fy * iz, -fy * ty * iz * iz]])
            T = J @ W
            if ti.static(framed):
                T = T @ M  # frame -> screen: Σ' = (J W M) Σ⁰ (J W M)ᵀ
            u = fx * p.x * iz + cx
            v = fy * p.y * iz + cy
            # cheap cull first: Σ'ₓₓ = T₀ᵀ Σ T₀ <= tr(Σ) |T₀|² and k <= K_MAX, so this box
            # contains the exact one (empty -> culled before the covariance is formed)
            trace = 0.0
            if ti.static(use_cov):
                trace = cov6[g, 0] + cov6[g, 3] + cov6[g, 5]
            else:
                trace = scales[g, 0] ** 2 + scales[g, 1] ** 2 + scales[g, 2] ** 2
            rxb = K_MAX * 1.01 * ti.sqrt(trace * (T[0, 0] ** 2 + T[0, 1] ** 2 + T[0, 2] ** 2) + DILATION)
            ryb = K_MAX * 1.01 * ti.sqrt(trace * (T[1, 0] ** 2 + T[1, 1] ** 2 + T[1, 2] ** 2) + DILATION)
            bx0, bx1 = _box_1d(u, rxb, width)
            by0, by1 = _box_1d(v, ryb, height)
            if bx0 < bx1 and by0 < by1:
                S = ti.Matrix.zero(ti.f32, 3, 3)  # covariance (in its frame), m²
                if ti.static(use_cov):
                    S = ti.Matrix([[cov6[g, 0], cov6[g, 1], cov6[g, 2]],
                                   [cov6[g, 1], cov6[g, 3], cov6[g, 4]],
                                   [cov6[g, 2], cov6[g, 4], cov6[g, 5]]])
                else:
                    S = _quat_scale_to_cov(
                        ti.math.vec4(quats[g, 0], quats[g, 1], quats[g, 2], quats[g, 3]),
                        ti.math.vec3(scales[g, 0], scales[g, 1], scales[g, 2]))
                S2 = T @ S @ T.transpose()  # EWA: 2D screen-space covariance, px²
                a = S2[0, 0] + DILATION
                b = S2[0, 1]
                d = S2[1, 1] + DILATION
                det = a * d - b * b
                if det > 0.0:
                    # opacity-aware support: o·exp(-k²/2) = 1/255, i.e. k = sqrt(2 ln(255 o))
                    # (kept per Gaussian with ln(255 o), see _Inputs.opacity)
                    ln255o, k = opac[g, 1], opac[g, 2]
                    x0, x1 = _box_1d(u, k * ti.sqrt(a), width)
                    y0, y1 = _box_1d(v, k * ti.sqrt(d), height)
                    if x0 < x1 and y0 < y1:
                        # (shifts, not //: Taichi's floor division of ints costs a branch each)
                        bins[c, j, B_TILES] = (((x1 - 1) >> TILE_BITS) - (x0 >> TILE_BITS) + 1) \
                            * (((y1 - 1) >> TILE_BITS) - (y0 >> TILE_BITS) + 1)
                        bins[c, j, B_X], bins[c, j, B_Y] = x0 | (x1 << 16), y0 | (y1 << 16)
                        bins[c, j, B_Z] = ti.bit_cast(p.z, ti.i32)
                        rec[c, j, R_U], rec[c, j, R_V] = u, v
                        rec[c, j, R_A], rec[c, j, R_B], rec[c, j, R_C] = d / det, -b / det, a / det
                        rec[c, j, R_O], rec[c, j, R_Z] = o, p.z
                        # the exponent's support bound, with slack: the α test decides
                        rec[c, j, R_THR] = -ln255o - 1e-4
                        # view direction (camera centre -> Gaussian), world frame; a rotated
                        # SH frame (link, polar(F)) R is evaluated at Rᵀ dir
                        dirn = view
                        if degree > 0:  # (a constant colour needs no direction)
                            dirn = view.normalized()
                        if ti.static(rot_mode > 0):
                            r = f
                            if ti.static(rot_mode == 1):
                                r = g
                            Rs = ti.Matrix([[sh_rot[r, i, j] for j in ti.static(range(3))]
                                            for i in ti.static(range(3))])
                            dirn = Rs.transpose() @ dirn
                        rgb = _sh_to_rgb(sh, g, degree, dirn)
                        if ti.static(lit):
                            n0 = ti.math.vec3(normals[g, 0], normals[g, 1], normals[g, 2])
                            if n0.norm_sqr() > 0.0:
                                rgb = _shade(rgb, n0, M, view, lights, c, albedo_pow, g, grey)
                        rec[c, j, R_R], rec[c, j, R_G], rec[c, j, R_BL] = rgb[0], rgb[1], rgb[2]


@ti.kernel
def _emit_keys(ends: _i64_1, bins: _i32_3, tiles_x: ti.i32, tiles_per_cam: ti.i32, keys: _i64_1,
               vals: _i64_1, one_camera: ti.template()):
    """One key per (Gaussian, touched tile): (camera·tiles + tile) << 32 | depth bits, and
    its value: the part of the Gaussian's box inside the tile (4 bits each: first column,
    last column, first row, last row, tile-local) << 32 | Gaussian index. ``ends`` [C·N]:
    the inclusive prefix sum of the tile counts, so (camera c, Gaussian g) writes from
    ends[c·N + g] - its count on.

    Positive float32 depths compare like their bit patterns read as integers,
    so sorting the keys sorts by tile, then front to back.
    """
    for i in range(bins.shape[0] * bins.shape[1]):
        c, g = _split(i, bins.shape[1], one_camera)
        count = bins[c, g, B_TILES]
        off = ends[c * bins.shape[1] + g] - count
        if count > 0:
            x0, x1 = bins[c, g, B_X] & 0xFFFF, bins[c, g, B_X] >> 16
            y0, y1 = bins[c, g, B_Y] & 0xFFFF, bins[c, g, B_Y] >> 16
            zbits = ti.cast(bins[c, g, B_Z], ti.i64)
            if count == 1:  # (most Gaussians: one entry, no loops)
                _emit_entry(keys, vals, off, c * tiles_per_cam, tiles_x, x0 >> TILE_BITS, y0 >> TILE_BITS,
                            x0, x1, y0, y1, zbits, g)
            else:
                for ty in range(y0 >> TILE_BITS, ((y1 - 1) >> TILE_BITS) + 1):  # pixel boxes are >= 0
                    for tx in range(x0 >> TILE_BITS, ((x1 - 1) >> TILE_BITS) + 1):
                        _emit_entry(keys, vals, off, c * tiles_per_cam, tiles_x, tx, ty, x0, x1, y0, y1, zbits, g)
                        off += 1


@ti.func
def _emit_entry(keys: ti.template(), vals: ti.template(), off: ti.i64, first_tile: ti.i32, tiles_x: ti.i32,
                tx: ti.i32, ty: ti.i32, x0: ti.i32, x1: ti.i32, y0: ti.i32, y1: ti.i32, zbits: ti.i64, g: ti.i32):
    """Entry ``off`` of :func:`_emit_keys`: Gaussian g's box [x0, x1) × [y0, y1) in tile (tx, ty)."""
    rx0 = ti.max(x0 - tx * TILE, 0)
    rx1 = ti.min(x1 - tx * TILE, TILE) - 1
    ry0 = ti.max(y0 - ty * TILE, 0)
    ry1 = ti.min(y1 - ty * TILE, TILE) - 1
    tile = ti.cast(first_tile + ty * tiles_x + tx, ti.i64)
    keys[off] = (tile << 32) | zbits
    part = rx0 | (rx1 << 4) | (ry0 << 8) | (ry1 << 12)
    vals[off] = (ti.cast(part, ti.i64) << 32) | ti.cast(g, ti.i64)


@ti.kernel
def _rasterize_tiles(starts: _i64_1, vals: _i64_1, rec: _f32_3,
                     background: _f32_4, bg_is_image: ti.i32, bg_depth: _f32_3,
                     use_bg_depth: ti.template(), tiles_x: ti.i32, spread: ti.template(),
                     one_camera: ti.template(), out_rgb: _f32_4, out_depth: _f32_3, out_alpha: _f32_3):
    """Front-to-back α compositing, one thread per (camera, 16×16 tile).

    The tile's transmittance T and colour/depth sums live in thread-local arrays
    (pixel index li = row·16 + column); a finished pixel stores -T (T > 0
    otherwise) and has its bit cleared in its row's mask ``live``. A Gaussian whose
    box (in its key's value) covers no unfinished pixel is skipped without reading its
    record; otherwise it visits only the unfinished pixels of its box, row by row, as the
    set bits of ``live & box`` (lowest column first: each pixel still takes its Gaussians
    in depth order, so the picture is the same as visiting every pixel of the box). Each
    tile owns its pixels: no atomics, deterministic.
    """
    C, H, Wd = out_rgb.shape[0], out_rgb.shape[1], out_rgb.shape[2]
    tiles_y = (H + TILE - 1) // TILE
    # Taichi's CPU backend hands a parallel loop out in blocks of at least 512 iterations
    # (adaptive block size): a loop over the 64 tiles of a 128×128 picture would run on one
    # thread. Each tile is therefore ``spread`` iterations (a power of two) of which the first
    # does the work.
    for i in range(C * tiles_y * tiles_x * spread):
        if i & (spread - 1) != 0:
            continue
        c, tile = _split(i >> ti.static(spread.bit_length() - 1), tiles_y * tiles_x, one_camera)
        px0 = (tile % tiles_x) * TILE
        py0 = (tile // tiles_x) * TILE
        px1 = ti.min(px0 + TILE, Wd)
        py1 = ti.min(py0 + TILE, H)
        trans = ti.Vector([1.0] * (TILE * TILE), dt=ti.f32)  # T; -T once finished
        acc_r = ti.Vector([0.0] * (TILE * TILE), dt=ti.f32)  # Σ w c
        acc_g = ti.Vector([0.0] * (TILE * TILE), dt=ti.f32)
        acc_b = ti.Vector([0.0] * (TILE * TILE), dt=ti.f32)
        acc_z = ti.Vector([0.0] * (TILE * TILE), dt=ti.f32)  # Σ w z
        z_bg = ti.Vector([0.0] * (TILE * TILE), dt=ti.f32)  # the tile's background depth
        if ti.static(use_bg_depth):
            for y, x in ti.ndrange((py0, py1), (px0, px1)):
                z_bg[(y - py0) * TILE + (x - px0)] = bg_depth[c, y, x]
        live = ti.Vector([0] * TILE, dt=ti.u32)  # bit x - px0 of row y - py0: unfinished
        for r in range(py1 - py0):
            live[r] = ti.u32((1 << (px1 - px0)) - 1)
        alive = (px1 - px0) * (py1 - py0)
        j = ti.cast(starts[c * tiles_x * tiles_y + tile], ti.i32)  # the tile's [j, end) in vals
        end = ti.cast(starts[c * tiles_x * tiles_y + tile + 1], ti.i32)
        # the next Gaussian's record is read one step ahead: its cache line is then on
        # its way while this one is drawn (records are visited in depth order, i.e.
        # at random addresses)
        g_next, u_next = 0, 0.0
        if j < end:
            g_next = ti.cast(vals[j], ti.i32)
            u_next = rec[c, g_next, R_U]
        while j < end and alive > 0:  # Gaussians of this tile, front to back
            val = vals[j]
            g, u = g_next, u_next
            j += 1
            if j < end:
                g_next = ti.cast(vals[j], ti.i32)
                u_next = rec[c, g_next, R_U]
            part = ti.cast(val >> 32, ti.i32)  # the Gaussian's box inside this tile
            cx0, cx1 = part & 15, ((part >> 4) & 15) + 1
            cy0, cy1 = (part >> 8) & 15, ((part >> 12) & 15) + 1
            box_bits = ti.u32(((1 << cx1) - 1) & ~((1 << cx0) - 1))
            todo = ti.u32(0)
            for r in range(cy0, cy1):
                todo |= live[r] & box_bits
            if todo != 0:
                v = rec[c, g, R_V]
                A, B, Cc = rec[c, g, R_A], rec[c, g, R_B], rec[c, g, R_C]
                o, z, thr = rec[c, g, R_O], rec[c, g, R_Z], rec[c, g, R_THR]
                cr, cg, cb = rec[c, g, R_R], rec[c, g, R_G], rec[c, g, R_BL]
                half_a = -0.5 * A
                for r in range(cy0, cy1):
                    todo_row = live[r] & box_bits  # the box's unfinished pixels of this row
                    if todo_row != 0:
                        # power = -½(A dx² + C dy²) - B dx dy along the row
                        y = py0 + r
                        dy = y + 0.5 - v
                        lin = -B * dy
                        const = -0.5 * Cc * dy * dy
                        while todo_row != 0:  # each unfinished pixel once, lowest column first
                            low = todo_row & (~todo_row + ti.u32(1))
                            todo_row ^= low
                            col = 31 - ti.math.clz(ti.cast(low, ti.i32))  # CUDA's clz takes i32, not u32
                            dx = px0 + col + 0.5 - u
                            power = (half_a * dx + lin) * dx + const
                            if power >= thr:  # inside the support: o·exp(power) may reach 1/255
                                li = r * TILE + col
                                T = trans[li]  # > 0: its bit in live is set
                                alpha = ti.min(ALPHA_MAX, o * ti.exp(power))
                                if alpha >= ALPHA_MIN:
                                    T_next = T * (1.0 - alpha)
                                    hidden = False
                                    if ti.static(use_bg_depth):
                                        hidden = z > z_bg[li]  # behind the background surface
                                    if hidden or T_next < T_MIN:
                                        # finished *before* this Gaussian
                                        trans[li] = -T
                                        alive -= 1
                                        live[r] &= ~low
                                    else:
                                        w = alpha * T  # blending weight
                                        acc_r[li] += w * cr
                                        acc_g[li] += w * cg
                                        acc_b[li] += w * cb
                                        acc_z[li] += w * z
                                        trans[li] = T_next
        # write out, compositing the background with the remaining transmittance
        for y, x in ti.ndrange((py0, py1), (px0, px1)):
            li = (y - py0) * TILE + (x - px0)
            T = ti.abs(trans[li])
            by, bx = y * bg_is_image, x * bg_is_image
            out_rgb[c, y, x, 0] = acc_r[li] + T * background[c, by, bx, 0]
            out_rgb[c, y, x, 1] = acc_g[li] + T * background[c, by, bx, 1]
            out_rgb[c, y, x, 2] = acc_b[li] + T * background[c, by, bx, 2]
            out_depth[c, y, x] = acc_z[li]
            out_alpha[c, y, x] = 1.0 - T


# =========================================================================== Python API
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
    (``sh_rot`` [N, 3, 3]); per-frame rotations come with the frames (:func:`_rasterize`);
    ``normals`` [N, 3] (in the Gaussians' frames, zero rows: not lit) or None (none lit).
    ``one_sided`` [N] bool or None: Gaussians culled when their normal faces away (see *Back
    faces* in the module docstring; needs ``normals``).
    ``opacity`` [N, 4]: the opacity o and the terms of the opacity-aware support (see *Support*
    in the module docstring), which depend on o alone: ln(255 o) and k = sqrt(2 ln(255 o)),
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
    """Check and convert the per-Gaussian arguments of :func:`rasterize` (ConfigError if bad);
    ``frame_rotations``: whether per-frame SH rotations will come with the frames."""
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


def _rasterize(g: _Inputs, frames: torch.Tensor | None, frame_rotations: torch.Tensor | None,
               viewmats, Ks, width, height, background, background_depth, near, far,
               timings: bool, lighting=None, gaussian_ranges=None) -> RenderOutput:
    """Camera checks and the three stages; ``g`` (and ``frames``) are already checked."""
    with one_torch_thread():
        return _rasterize_stages(g, frames, frame_rotations, viewmats, Ks, width, height, background,
                                 background_depth, near, far, timings, lighting, gaussian_ranges)


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
    """Render N Gaussians into C pinhole cameras (see the module docstring for the rules).

    Args:
        means: [N, 3] centres, metres (world, or in their frames with ``frames``).
        quats: [N, 4] rotations (w, x, y, z), normalised here. ``None`` with ``covars``.
        scales: [N, 3] standard deviations along the Gaussian axes, metres
            (exponentiated, not log-scales). ``None`` with ``covars``.
        opacities: [N] peak opacities in [0, 1] (sigmoid of the logits).
        sh: [N, K, 3] SH colour coefficients, K = (degree+1)², degree 0..3.
        viewmats: [C, 4, 4] world -> camera transforms (OpenCV axes).
        Ks: [C, 3, 3] pinhole intrinsics in pixels.
        width, height: image size W, H in pixels.
        covars: optional precomputed covariances, [N, 3, 3] or [N, 6]
            (xx, xy, xz, yy, yz, zz), m²; replaces ``quats``/``scales``.
        sh_rotations: optional [N, 3, 3] rotation of each Gaussian's SH frame
            (e.g. polar(F) of a deformed Gaussian): the SH are evaluated at
            ``Rᵀ · view_dir``.
        frames: optional [F, 3, 4] (or [F, 4, 4]) affine frame -> world maps
            ``x -> M x + t``; Gaussian g's mean and covariance are then given in
            frame ``frame_ids[g]`` and posed by the kernel (μ = M μ⁰ + t,
            Σ = M Σ⁰ Mᵀ). See *Frames* in the module docstring.
        frame_ids: [N] integer frame of each Gaussian (with ``frames``).
        frame_rotations: optional [F, 3, 3] rotation of the SH frames of each
            frame's Gaussians (instead of ``sh_rotations``).
        normals: optional [N, 3] normals (world, or in the Gaussians' frames with
            ``frames``; any length, sign free), the zero vector for a Gaussian that is
            not to be lit; see :func:`~gausstac_maniskill.splat.lighting.surface_normals`.
        one_sided: optional [N] bool: Gaussians on closed surfaces whose ``normals`` point
            outward; they are culled when they face away from the camera (see *Back faces*
            above). Needs ``normals``.
        lighting: optional :class:`~gausstac_maniskill.splat.lighting.Lighting` (every
            camera), or a sequence of C of them (camera c's scene's); shades the Gaussians
            with a normal (needs ``normals``), see *Lighting* above.
        background: colour behind the Gaussians: scalar, [3], [C, 3] or an
            image [C, H, W, 3]. Default black.
        background_depth: optional [C, H, W] camera-z depth (metres) of the
            background image for depth-aware compositing (Gaussians behind it
            are hidden). Use ``inf`` where the background is empty.
        gaussian_ranges: optional [C, 2] integers: camera c sees only Gaussians
            [start, stop); or [C, 2, 2]: two such ranges (see *Batches* above); default:
            every camera sees all of them.
        near, far: clip distances along camera z, metres.
        timings: record per-stage wall times (ms) in ``RenderOutput.stats``.

    Returns:
        :class:`RenderOutput` with rgb [C, H, W, 3], depth [C, H, W], alpha [C, H, W],
        on the device of the Taichi arch in use (``backend.torch_device()``); the inputs
        may lie on any device and are moved there.

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


# =========================================================================== cameras
def intrinsics_from_fov(width: int, height: int, fovy: float, fovx: float | None = None,
                        device=None) -> torch.Tensor:
    """[3, 3] pinhole K for a vertical field of view ``fovy`` (radians).

    ``fovx`` defaults to square pixels (fx = fy). The principal point is the
    image centre (W/2, H/2), as in SAPIEN's cameras.
    """
    fy = 0.5 * height / math.tan(0.5 * fovy)
    fx = fy if fovx is None else 0.5 * width / math.tan(0.5 * fovx)
    return torch.tensor([[fx, 0.0, 0.5 * width], [0.0, fy, 0.5 * height], [0.0, 0.0, 1.0]],
                        dtype=torch.float32, device=device)


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> torch.Tensor:
    """[4, 4] OpenCV world -> camera matrix for a camera at ``eye`` looking at ``target``.

    Camera z points to the target, x right and y down in the image, with
    ``up`` (world) appearing upwards.
    """
    eye, target, up = (torch.as_tensor(v, dtype=torch.float64) for v in (eye, target, up))
    z = target - eye
    z = z / z.norm()
    x = torch.linalg.cross(z, up)
    if x.norm() < 1e-9:
        raise ConfigError("look_at: viewing direction is parallel to up")
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    R = torch.stack([x, y, z])  # rows: camera axes in world coordinates
    M = torch.eye(4, dtype=torch.float64)
    M[:3, :3] = R
    M[:3, 3] = -R @ eye
    return M.float()


# camera axes (rows) of OpenCV expressed in the other conventions' axes
_CV_FROM_SAPIEN = torch.tensor([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])  # x fwd, y left, z up
_CV_FROM_OPENGL = torch.tensor([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])  # x right, y up, z back


def sapien_pose_to_opencv_extrinsic(pose, convention: str = "sapien") -> torch.Tensor:
    """World -> camera [..., 4, 4] OpenCV extrinsic from a SAPIEN camera pose.

    Args:
        pose: [..., 4, 4] camera -> world transform (array-like or
            ``sapien.Pose``, whose ``to_transformation_matrix()`` is used).
        convention: axes of ``pose``'s camera frame:

            * ``"sapien"`` — the camera entity pose (``camera.entity_pose``,
              ``camera.get_pose()``): x forward, y left, z up;
            * ``"opengl"`` — ``camera.get_model_matrix()``: x right, y up, z backward.

    Returns:
        [..., 4, 4] float32 ``viewmat`` for :func:`rasterize` (x right, y down,
        z forward). Equals SAPIEN's ``camera.get_extrinsic_matrix()`` (3×4) in
        its top three rows.

    The maths: with ``pose = [R | p]`` (camera -> world), the OpenCV axes are
    ``x_cv = -y_s, y_cv = -z_s, z_cv = x_s`` (SAPIEN) or ``x_cv = x_gl,
    y_cv = -y_gl, z_cv = -z_gl`` (OpenGL), i.e. ``R_cv = A`` with rows above;
    extrinsic = ``[A Rᵀ | -A Rᵀ p]``.
    """
    if hasattr(pose, "to_transformation_matrix"):
        pose = pose.to_transformation_matrix()
    pose = torch.as_tensor(pose, dtype=torch.float64)
    if pose.shape[-2:] != (4, 4):
        raise ConfigError(f"pose has shape {list(pose.shape)}, expected [..., 4, 4]")
    if convention == "sapien":
        A = _CV_FROM_SAPIEN
    elif convention == "opengl":
        A = _CV_FROM_OPENGL
    else:
        raise ConfigError(f"convention={convention!r} must be 'sapien' or 'opengl'")
    A = A.to(torch.float64)
    R, p = pose[..., :3, :3], pose[..., :3, 3:]
    Rw = A @ R.transpose(-1, -2)
    out = torch.zeros(pose.shape, dtype=torch.float64)
    out[..., :3, :3] = Rw
    out[..., :3, 3:] = -Rw @ p
    out[..., 3, 3] = 1.0
    return out.float()
