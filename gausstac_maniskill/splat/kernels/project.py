"""Stage 1 of the rasterizer: EWA projection of 3D Gaussians to 2D conics (one thread per
camera × Gaussian).

:func:`_project` poses the Gaussian with its frame (μ = M μ⁰ + t, Σ = M Σ⁰ Mᵀ, if framed),
maps it world -> camera, culls z <= near or z >= far (and one-sided Gaussians facing away),
then Gaussians whose screen box cannot reach the image (a bound from the trace of Σ, checked
before Σ is formed). It forms Σ' = J W Σ Wᵀ Jᵀ (Zwicker et al. 2002) with the perspective
Jacobian J at x/z, y/z clamped to 1.3 × the half field of view, + 0.3 px² on the diagonal
(anti-aliasing), conic = Σ'⁻¹, the SH colour for the view direction (shaded, if lit), and
the pixel box of the support. A Gaussian can only contribute where α ≥ 1/255, i.e. inside
dᵀΣ'⁻¹d ≤ k², k = sqrt(2 ln(255·o)); the box is that ellipse's exact axis-aligned bound
±k·sqrt(Σ'ₓₓ), ±k·sqrt(Σ'ᵧᵧ), so it drops only pixels the α test drops anyway. Everything
the later stages read about a Gaussian goes into one 16-float record per camera.
"""
# no `from __future__ import annotations`: Taichi reads the kernels' annotations at runtime

import taichi as ti

from ...geometry.kinematics import quat_to_mat
from ..sh import SH_C0, SH_C1, SH_C2, SH_C3
from .common import (ALPHA_MIN, B_TILES, B_X, B_Y, B_Z, DILATION, K_MAX, R_A, R_B, R_BL, R_C, R_G, R_O, R_R,
                     R_THR, R_U, R_V, R_Z, TILE_BITS, _f32_2, _f32_3, _i32_1, _i32_2, _i32_3, _split)


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
    writes rec[c, j] and bins[c, j] (bins[c, j, B_TILES] = 0 if culled or past the range).

    ``use_cov``: covariances from ``cov6`` (else from ``quats``/``scales``); ``framed``:
    means and covariances lie in ``frames[frame_id[g]]``; ``rot_mode``: SH frames not
    rotated (0), rotated per Gaussian by ``sh_rot[g]`` (1) or per frame by
    ``sh_rot[frame_id[g]]`` (2); ``lit``: Gaussians with a non-zero ``normals[g]`` (in
    their frame) are shaded with ``lights`` [C, 1 + L, 6]; ``grey``: grey lights and
    ``albedo_pow`` [N, 3] holds each Gaussian's albedo^(1/gamma) (see :func:`_shade`).
    ``opac`` [N, 4]: each Gaussian's opacity, support terms and back-face bound (see
    ``splat.inputs._Inputs.opacity``); ``cull``: some Gaussians are one-sided (bound < 1):
    culled when their normal n = cof(M)·``normals[g]`` faces away from the view ray v
    (camera -> Gaussian): n·v > bound·|n||v|. ``cams`` [C, 12]: the per-camera constants of
    ``splat.inputs._camera_constants``. Only entries of Gaussians that touch a tile are written.
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
