"""``python -m gausstac_maniskill.bench splat [--quick] [--skip-speed] [--skip-quality] [--out DIR]`` —
speed and quality of the 3DGS camera.

Speed: ms per frame of the three stages of :func:`~gausstac_maniskill.splat.rasterize` for
50k/100k/300k Gaussians at 128×128, 320×240 and 640×480, in an ``object`` scene (a lumpy sphere
covering about 1/3 of the view) and a ``full`` one (a wall filling the view, 20 % floaters).
Quality: a textured cube rendered by SAPIEN (ambient light only, anti-aliased) against Gaussians
sampled on its surface, PSNR and MS-SSIM over a sweep of Gaussians per cm².
"""
from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time

import numpy as np
import torch

__all__ = ["main", "object_scene", "full_scene", "textured_cube", "cube_gaussians"]

GAMMA = 2.2  # SAPIEN's camera output: colour = linear^(1/2.2)


# --------------------------------------------------------------------------- scenes
def _disc_gaussians(points, normals, spacing, gen, sh_degree=3, opacity_mean=2.0):
    """Flat Gaussians on a surface: tangent scales ~ spacing, normal scale 5 %."""
    from gausstac_maniskill.splat import GaussianSet, rotmat_to_quat

    n = points.shape[0]
    helper = torch.where(normals[:, :1].abs() < 0.9, torch.tensor([[1.0, 0, 0]]),
                         torch.tensor([[0.0, 1, 0]]))
    t1 = torch.nn.functional.normalize(torch.linalg.cross(normals, helper), dim=1)
    t2 = torch.linalg.cross(normals, t1)
    quats = rotmat_to_quat(torch.stack([t1, t2, normals], -1))
    scales = torch.tensor([spacing, spacing, 0.05 * spacing]).expand(n, 3)
    scales = scales * (0.7 + 0.6 * torch.rand(n, 3, generator=gen))
    sh = torch.randn(n, (sh_degree + 1) ** 2, 3, generator=gen) * 0.1
    sh[:, 0] = torch.randn(n, 3, generator=gen) * 0.6
    return GaussianSet.create(points, quats, scales.log(),
                              opacity_mean + torch.randn(n, generator=gen), sh)


def _camera(width, height, fovy=math.radians(45)):
    from gausstac_maniskill.splat import intrinsics_from_fov
    return intrinsics_from_fov(width, height, fovy)[None]


def object_scene(n: int, width: int, height: int, seed: int = 0):
    """(GaussianSet, viewmats [1,4,4], Ks [1,3,3]): a lumpy sphere covering ~1/3 of the image."""
    from gausstac_maniskill.splat import look_at

    gen = torch.Generator().manual_seed(seed)
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen), dim=1)
    r0 = 0.1
    r = r0 * (1 + 0.1 * torch.sin(5 * d[:, 0]) * torch.cos(4 * d[:, 2]))
    g = _disc_gaussians(d * r[:, None], d, math.sqrt(4 * math.pi * r0 * r0 / n), gen)
    K = _camera(width, height)
    # silhouette radius in pixels so that pi r_px^2 = W H / 3
    r_px = math.sqrt(width * height / (3 * math.pi))
    dist = math.hypot(K[0, 1, 1].item() * r0 / r_px, r0)
    return g, look_at([0.0, -dist, 0.02], [0, 0, 0])[None], K


def full_scene(n: int, width: int, height: int, seed: int = 0):
    """(GaussianSet, viewmats, Ks): a wavy wall filling the view + 20 % floaters in front."""
    from gausstac_maniskill.splat import GaussianSet, look_at

    gen = torch.Generator().manual_seed(seed)
    K = _camera(width, height)
    dist = 1.0
    half_w = 1.1 * dist * 0.5 * width / K[0, 0, 0].item()
    half_h = 1.1 * dist * 0.5 * height / K[0, 1, 1].item()
    n_wall = int(0.8 * n)
    u = (torch.rand(n_wall, generator=gen) * 2 - 1) * half_w
    v = (torch.rand(n_wall, generator=gen) * 2 - 1) * half_h
    bump = 0.05 * torch.sin(8 * u) * torch.cos(6 * v)
    pts = torch.stack([u, bump, v], -1)  # wall in the x-z plane at y = 0, camera at y = -1
    normals = torch.nn.functional.normalize(torch.stack([-0.4 * torch.cos(8 * u) * torch.cos(6 * v),
                                                         -torch.ones_like(u),
                                                         0.3 * torch.sin(8 * u) * torch.sin(6 * v)],
                                                        -1), dim=1)
    wall = _disc_gaussians(pts, normals, math.sqrt(4 * half_w * half_h / n_wall), gen)
    n_fl = n - n_wall
    depth = 0.2 + 0.7 * torch.rand(n_fl, generator=gen)  # distance from the camera
    fl = torch.stack([(torch.rand(n_fl, generator=gen) * 2 - 1) * half_w * depth,
                      -depth, (torch.rand(n_fl, generator=gen) * 2 - 1) * half_h * depth], -1)
    floaters = GaussianSet.create(
        fl, torch.nn.functional.normalize(torch.randn(n_fl, 4, generator=gen), dim=1),
        torch.log(0.001 + 0.002 * torch.rand(n_fl, 3, generator=gen)),
        torch.randn(n_fl, generator=gen) - 1.5, torch.randn(n_fl, 16, 3, generator=gen) * 0.3)
    return GaussianSet.cat([wall, floaters]), look_at([0.0, -dist, 0.0], [0, 0, 0])[None], K


# --------------------------------------------------------------------------- speed
def bench_speed(sizes, resolutions, scenes, repeats):
    from gausstac_maniskill.splat import render

    rows = []
    header = (f"{'scene':<7} {'N':>7} {'resolution':>10} {'project':>8} {'bin+sort':>9} "
              f"{'raster':>8} {'total':>8} {'keys':>9}")
    print("\nSpeed: ms/frame, median of", repeats, "renders after 2 warm-up renders")
    print(header)
    print("-" * len(header))
    for scene in scenes:
        for n in sizes:
            for (w, h) in resolutions:
                g, V, K = (object_scene if scene == "object" else full_scene)(n, w, h)
                for _ in range(2):
                    render(g, V, K, w, h, timings=True)
                stats = [render(g, V, K, w, h, timings=True).stats for _ in range(repeats)]
                med = {k: statistics.median(s[k] for s in stats)
                       for k in ("project", "bin_sort", "raster", "total")}
                row = dict(scene=scene, n=n, res=f"{w}x{h}", keys=stats[0]["n_keys"], **med)
                rows.append(row)
                print(f"{scene:<7} {n:>7} {row['res']:>10} {med['project']:>8.1f} "
                      f"{med['bin_sort']:>9.1f} {med['raster']:>8.1f} {med['total']:>8.1f} "
                      f"{row['keys']:>9}", flush=True)
    return rows


# --------------------------------------------------------------------------- quality
def make_texture(size: int = 128) -> np.ndarray:
    """[6, size, size, 3] float32 linear albedo in [0, 1]: one pattern per cube face
    (checkers of three sizes, stripes, rings and a colour gradient, each with a hue)."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    hues = np.array([[0.9, 0.3, 0.2], [0.2, 0.7, 0.3], [0.25, 0.35, 0.9],
                     [0.9, 0.8, 0.2], [0.7, 0.3, 0.8], [0.2, 0.8, 0.85]], np.float32)
    pats = [
        ((np.floor(x * 4) + np.floor(y * 4)) % 2),
        ((np.floor(x * 8) + np.floor(y * 8)) % 2),
        0.5 + 0.5 * np.sin(2 * np.pi * 6 * x),
        0.5 + 0.5 * np.cos(2 * np.pi * 5 * np.hypot(x - 0.5, y - 0.5)),
        ((np.floor(x * 16) + np.floor(y * 16)) % 2),
        x * (1 - y),
    ]
    tex = np.stack([0.15 + 0.8 * p[..., None] * h[None, None] + 0.05 * (1 - p[..., None])
                    for p, h in zip(pats, hues)])
    return np.clip(tex, 0, 1).astype(np.float32)


def textured_cube(side: float):
    """Cube geometry: 6 faces of (origin corner, u axis, v axis, outward normal), metres."""
    h = side / 2
    faces = []
    for axis in range(3):
        for sign in (1.0, -1.0):
            nrm = np.zeros(3, np.float32)
            nrm[axis] = sign
            a, b = [i for i in range(3) if i != axis]
            u = np.zeros(3, np.float32)
            v = np.zeros(3, np.float32)
            u[a], v[b] = side, side
            if np.dot(np.cross(u, v), nrm) < 0:  # keep (u, v, n) right-handed
                u, v = v, u
            corner = -h * np.ones(3, np.float32)
            corner[axis] = sign * h
            faces.append((corner, u, v, nrm))
    return faces


def cube_gaussians(side: float, texture: np.ndarray, per_face_grid: int, seed: int = 0):
    """Gaussians on a jittered grid of m×m cells per cube face, colour averaged per cell."""
    from gausstac_maniskill.splat import GaussianSet, rgb_to_sh_dc, rotmat_to_quat

    rng = np.random.default_rng(seed)
    m = per_face_grid
    size = texture.shape[1]
    spacing = side / m
    display = texture ** (1.0 / GAMMA)
    pts, nrms, rots, cols = [], [], [], []
    for f, (corner, u, v, nrm) in enumerate(textured_cube(side)):
        iu, iv = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
        s = (iu.ravel() + 0.5 + rng.uniform(-0.2, 0.2, m * m)) / m
        t = (iv.ravel() + 0.5 + rng.uniform(-0.2, 0.2, m * m)) / m
        pts.append(corner + s[:, None] * u + t[:, None] * v)
        # cell-average of the display colour (box prefilter), 4×4 samples per cell
        sub = (np.arange(4) + 0.5) / 4
        ss = (iu.ravel()[:, None, None] + sub[None, :, None]) / m
        tt = (iv.ravel()[:, None, None] + sub[None, None, :]) / m
        px = np.clip((ss * size).astype(int), 0, size - 1)
        py = np.clip((tt * size).astype(int), 0, size - 1)
        cols.append(display[f][py, px].reshape(m * m, 16, 3).mean(1))
        R = np.stack([u / side, v / side, nrm], axis=1)  # columns: tangent, bitangent, normal
        rots.append(np.repeat(R[None], m * m, 0))
    pts, rots, cols = (np.concatenate(a).astype(np.float32) for a in (pts, rots, cols))
    n = len(pts)
    quats = rotmat_to_quat(torch.from_numpy(rots))
    scales = torch.tensor([0.6 * spacing, 0.6 * spacing, 1e-3 * spacing]).expand(n, 3)
    sh = rgb_to_sh_dc(torch.from_numpy(cols))[:, None, :]
    return GaussianSet.create(pts, quats, scales.log(), torch.full((n,), 4.0), sh)


def sapien_render(side, texture, viewmat, K, width, height, supersample=4):
    """SAPIEN render of the textured cube (ambient 1, unlit), box-downsampled. [H, W, 3]."""
    import sapien
    from sapien import render as R

    from gausstac_maniskill.splat.rasterizer import _CV_FROM_SAPIEN

    scene = sapien.Scene()
    scene.set_ambient_light([1.0, 1.0, 1.0])
    body = R.RenderBodyComponent()
    for f, (corner, u, v, nrm) in enumerate(textured_cube(side)):
        verts = np.stack([corner, corner + u, corner + u + v, corner + v]).astype(np.float32)
        tri = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
        uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
        rgba = np.concatenate([texture[f], np.ones(texture.shape[1:3] + (1,), np.float32)], -1)
        # texture row = v (t), column = u (s), as sampled in cube_gaussians (index [t, s])
        tex = R.RenderTexture2D(np.ascontiguousarray(rgba), "R32G32B32A32Sfloat",
                                filter_mode="nearest")
        mat = R.RenderMaterial(base_color=[1, 1, 1, 1], specular=0.0, roughness=1.0,
                               metallic=0.0)
        mat.base_color_texture = tex
        body.attach(R.RenderShapeTriangleMesh(verts, tri, np.tile(nrm, (4, 1)), uv, mat))
    ent = sapien.Entity()
    ent.add_component(body)
    scene.add_entity(ent)
    ss = supersample
    fovy = 2 * math.atan(0.5 * height / K[1, 1].item())
    cam = scene.add_camera("cam", width * ss, height * ss, fovy, 0.01, 10.0)
    # OpenCV world->camera -> SAPIEN entity pose (camera->world, x fwd, y left, z up)
    inv = torch.linalg.inv(viewmat.double())
    pose = np.eye(4)
    pose[:3, :3] = (inv[:3, :3] @ _CV_FROM_SAPIEN.double()).numpy()
    pose[:3, 3] = inv[:3, 3].numpy()
    cam.entity.set_pose(sapien.Pose(pose))
    scene.update_render()
    cam.take_picture()
    img = torch.from_numpy(cam.get_picture("Color")[..., :3].copy())
    seg = torch.from_numpy(cam.get_picture("Segmentation")[..., 1].astype(np.float32).copy())
    img = img.reshape(height, ss, width, ss, 3).mean((1, 3))
    cover = (seg > 0).float().reshape(height, ss, width, ss).mean((1, 3))
    return img.clamp(0, 1), cover


def bench_quality(out_dir, width=320, height=240, grids=(8, 16, 32, 64, 128)):
    from pytorch_msssim import ms_ssim

    from gausstac_maniskill.splat import intrinsics_from_fov, look_at, render

    side = 0.1
    texture = make_texture()
    V = look_at([0.17, -0.21, 0.15], [0, 0, 0])
    K = intrinsics_from_fov(width, height, math.radians(40))
    print(f"\nQuality vs SAPIEN: textured cube ({side} m), {width}x{height}, ambient light 1, "
          "no other lights; SAPIEN 4x supersampled")
    try:
        ref, cover = sapien_render(side, texture, V, K, width, height)
    except Exception as exc:  # noqa: BLE001 - no Vulkan device, ...
        print(f"SKIPPED: SAPIEN cannot render here ({type(exc).__name__}: {exc})")
        return []
    # SAPIEN's empty pixels: read the background off a fully empty corner
    bg = ref[cover == 0].median(dim=0).values if (cover == 0).any() else torch.zeros(3)
    header = (f"{'grid/face':>9} {'N':>7} {'G/cm^2':>7} {'PSNR dB':>8} {'PSNR obj':>8} "
              f"{'MS-SSIM':>8} {'ms/frame':>8}")
    print(f"background colour (from SAPIEN's empty pixels): {bg.tolist()}")
    print(header)
    print("-" * len(header))
    rows = []
    for m in grids:
        g = cube_gaussians(side, texture, m)
        render(g, V[None], K[None], width, height, background=bg)  # warm-up
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            out = render(g, V[None], K[None], width, height, background=bg)
            times.append(1e3 * (time.perf_counter() - t0))
        img = out.rgb[0].clamp(0, 1)
        mse = ((img - ref) ** 2).mean().item()
        obj = cover > 0.5
        mse_obj = ((img - ref)[obj] ** 2).mean().item()
        psnr = 10 * math.log10(1.0 / max(mse, 1e-12))
        psnr_obj = 10 * math.log10(1.0 / max(mse_obj, 1e-12))
        msssim = ms_ssim(img.permute(2, 0, 1)[None], ref.permute(2, 0, 1)[None],
                         data_range=1.0).item()
        density = len(g) / (6 * side * side * 1e4)
        rows.append(dict(grid=m, n=len(g), density=density, psnr=psnr, psnr_obj=psnr_obj,
                         ms_ssim=msssim, ms=statistics.median(times)))
        print(f"{m:>9} {len(g):>7} {density:>7.1f} {psnr:>8.2f} {psnr_obj:>8.2f} "
              f"{msssim:>8.4f} {statistics.median(times):>8.1f}", flush=True)
        if out_dir:
            import imageio.v3 as iio
            side_by_side = torch.cat([ref, img, (img - ref).abs() * 4], dim=1)
            iio.imwrite(os.path.join(out_dir, f"splat_vs_sapien_grid{m}.png"),
                        (side_by_side.clamp(0, 1) * 255).round().byte().numpy())
    if out_dir:
        print(f"images (SAPIEN | Gaussians | 4x abs difference) in {out_dir}/")
    return rows


# --------------------------------------------------------------------------- main
def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m gausstac_maniskill.bench splat",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="small subset: 50k/100k at 320x240 and a short quality sweep")
    parser.add_argument("--out", default="out/bench_splat",
                        help="directory for the PNG comparisons (default out/bench_splat; "
                             "'' = none)")
    parser.add_argument("--repeats", type=int, default=7, help="timed renders per configuration")
    parser.add_argument("--skip-speed", action="store_true")
    parser.add_argument("--skip-quality", action="store_true")
    parser.add_argument("--arch", default=None, help="cpu | cuda | auto (default: $GAUSSTAC_ARCH)")
    parser.add_argument("--torch-threads", type=int, default=1,
                        help="torch intra-op threads (default 1: the pipeline's torch ops are "
                             "small, and 2 OpenMP threads spin 10-50x slower whenever another "
                             "process holds a core; 0 = leave torch's default)")
    args = parser.parse_args(argv)
    if args.torch_threads > 0:
        torch.set_num_threads(args.torch_threads)

    from gausstac_maniskill import backend
    arch = backend.init(args.arch) if args.arch else backend.ensure_init()
    print(f"gausstac splat benchmark: Taichi arch={arch}, torch {torch.__version__}, "
          f"{os.cpu_count()} CPU cores, torch threads {torch.get_num_threads()}")
    if args.out:
        os.makedirs(args.out, exist_ok=True)
    if not args.skip_speed:
        if args.quick:
            bench_speed([50_000, 100_000], [(320, 240)], ["object", "full"], args.repeats)
        else:
            bench_speed([50_000, 100_000, 300_000], [(128, 128), (320, 240), (640, 480)],
                        ["object", "full"], args.repeats)
    if not args.skip_quality:
        bench_quality(args.out, grids=(8, 32, 64) if args.quick else (8, 16, 32, 64, 128))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
