"""Shared fixtures for the splat tests: a dense pure-torch reference renderer and scenes.

The reference evaluates *every* Gaussian at *every* pixel in float64, with the
same rules as the Taichi rasterizer (EWA projection with the 1.3·tan(fov/2)
clamp, 0.3 px² dilation, α = min(0.99, o·exp(-½dᵀΣ⁻¹d)), skip α < 1/255, stop
before T < 1e-4, depth order with ties broken by index). It has no tiles, boxes
or sort keys, so agreement shows that the tiling drops nothing.
"""
from __future__ import annotations

import math

import pytest
import torch


@pytest.fixture(autouse=True)
def _torch_single_thread():
    """Small torch ops with 2 OpenMP threads are 10-50x slower when another process
    (or Taichi's pool) holds a core: the reference renderer's many tiny ops then
    dominate the suite. One thread is as fast here and immune to that."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


# --- spherical harmonics, written out per basis function (independent of the kernel) ---
def _sh_basis(d: torch.Tensor, degree: int) -> torch.Tensor:
    """[M, K] real SH basis (3DGS sign convention) at unit directions d [M, 3]."""
    x, y, z = d.unbind(-1)
    one = torch.ones_like(x)
    b = [0.28209479177387814 * one]
    if degree >= 1:
        c1 = 0.4886025119029199
        b += [-c1 * y, c1 * z, -c1 * x]
    if degree >= 2:
        b += [1.0925484305920792 * x * y, -1.0925484305920792 * y * z,
              0.31539156525252005 * (2 * z * z - x * x - y * y),
              -1.0925484305920792 * x * z, 0.5462742152960396 * (x * x - y * y)]
    if degree >= 3:
        b += [-0.5900435899266435 * y * (3 * x * x - y * y),
              2.890611442640554 * x * y * z,
              -0.4570457994644658 * y * (4 * z * z - x * x - y * y),
              0.3731763325901154 * z * (2 * z * z - 3 * x * x - 3 * y * y),
              -0.4570457994644658 * x * (4 * z * z - x * x - y * y),
              1.445305721320277 * z * (x * x - y * y),
              -0.5900435899266435 * x * (x * x - 3 * y * y)]
    return torch.stack(b, dim=-1)


def reference_rasterize(means, covars, opacities, sh, viewmats, Ks, width, height, *,
                        sh_rotations=None, background=0.0, background_depth=None,
                        near=0.01, far=1e4):
    """Dense float64 reference. covars [N,3,3]; returns (rgb [C,H,W,3], depth, alpha)."""
    f = dict(dtype=torch.float64)
    means, covars, opacities, sh = (t.to(**f) for t in (means, covars, opacities, sh))
    viewmats, Ks = viewmats.to(**f), Ks.to(**f)
    degree = int(round(math.sqrt(sh.shape[1]))) - 1
    C, N = viewmats.shape[0], means.shape[0]
    bg = torch.as_tensor(background, **f)
    if bg.dim() <= 1:
        bg = bg.expand(C, height, width, 3)
    ys, xs = torch.meshgrid(torch.arange(height, **f) + 0.5, torch.arange(width, **f) + 0.5,
                            indexing="ij")
    rgbs, depths, alphas = [], [], []
    for c in range(C):
        R, t = viewmats[c, :3, :3], viewmats[c, :3, 3]
        fx, fy, cx, cy = Ks[c, 0, 0], Ks[c, 1, 1], Ks[c, 0, 2], Ks[c, 1, 2]
        p = means @ R.T + t
        # Jacobian of (fx x/z + cx, fy y/z + cy), x/z and y/z clamped to 1.3 tan(fov/2)
        tanx, tany = 0.5 * width / fx, 0.5 * height / fy
        u_ = (p[:, 0] / p[:, 2]).clamp(-(cx / fx + 0.3 * tanx), (width - cx) / fx + 0.3 * tanx)
        v_ = (p[:, 1] / p[:, 2]).clamp(-(cy / fy + 0.3 * tany), (height - cy) / fy + 0.3 * tany)
        J = torch.zeros(N, 2, 3, **f)
        J[:, 0, 0] = fx / p[:, 2]
        J[:, 0, 2] = -fx * u_ / p[:, 2]
        J[:, 1, 1] = fy / p[:, 2]
        J[:, 1, 2] = -fy * v_ / p[:, 2]
        S2 = J @ R @ covars @ R.T @ J.transpose(1, 2) + 0.3 * torch.eye(2, **f)
        conic = torch.linalg.inv(S2)
        mu2 = torch.stack([fx * p[:, 0] / p[:, 2] + cx, fy * p[:, 1] / p[:, 2] + cy], -1)
        cam = -R.T @ t
        d = torch.nn.functional.normalize(means - cam, dim=-1)
        if sh_rotations is not None:
            d = torch.einsum("nji,nj->ni", sh_rotations.to(**f), d)  # Rᵀ d
        col = (torch.einsum("nk,nkc->nc", _sh_basis(d, degree), sh) + 0.5).clamp_min(0)
        keep = (p[:, 2] > near) & (p[:, 2] < far) & (torch.linalg.det(S2) > 0) \
            & (opacities >= 1 / 255)
        order = torch.sort(p[:, 2], stable=True).indices
        T = torch.ones(height, width, **f)
        acc = torch.zeros(height, width, 3, **f)
        dep = torch.zeros(height, width, **f)
        active = torch.ones(height, width, dtype=torch.bool)
        for g in order.tolist():
            if not keep[g]:
                continue
            if background_depth is not None:
                active &= ~(p[g, 2] > background_depth[c].to(**f))
            dx, dy = xs - mu2[g, 0], ys - mu2[g, 1]
            power = -0.5 * (conic[g, 0, 0] * dx * dx + conic[g, 1, 1] * dy * dy) \
                - conic[g, 0, 1] * dx * dy
            alpha = (opacities[g] * torch.exp(power)).clamp(max=0.99)
            hit = active & (alpha >= 1 / 255)
            T_next = T * (1 - alpha)
            stop = hit & (T_next < 1e-4)
            active &= ~stop
            hit &= ~stop
            w = torch.where(hit, alpha * T, torch.zeros_like(T))
            acc += w[..., None] * col[g]
            dep += w * p[g, 2]
            T = torch.where(hit, T_next, T)
        rgbs.append(acc + T[..., None] * bg[c])
        depths.append(dep)
        alphas.append(1 - T)
    return torch.stack(rgbs).float(), torch.stack(depths).float(), torch.stack(alphas).float()


@pytest.fixture
def reference():
    return reference_rasterize


@pytest.fixture
def sh_basis_reference():
    """The written-out SH basis above: ``fn(d [M, 3] tensor, degree) -> [M, K]``."""
    return _sh_basis


def random_rigid(rng, max_deg: float = 30.0, max_t: float = 0.05):
    """A [4, 4] rigid transform: ``max_deg`` degrees about a random axis, a shift of up
    to ``max_t`` metres per axis."""
    from gausstac_maniskill.transforms import make_pose, rotation_about

    R = rotation_about(rng.normal(size=3), math.radians(max_deg))
    return make_pose(rng.uniform(-max_t, max_t, 3), R)


@pytest.fixture
def rigid_motion():
    """:func:`random_rigid`."""
    return random_rigid


PLATE_URDF = """<?xml version="1.0"?>
<robot name="plate">
  <material name="blue"><color rgba="0.2 0.6 0.9 1"/></material>
  <link name="plate">
    <visual>
      <origin xyz="0 0 0.01" rpy="0 0 0"/>
      <geometry><box size="0.04 0.04 0.004"/></geometry>
      <material name="blue"/>
    </visual>
  </link>
  {extra}
</robot>
"""


@pytest.fixture
def plate_urdf(tmp_path):
    """``write(extra="") -> Path``: writes ``tmp_path/robot.urdf``, robot "plate" with one
    link "plate" (a 40 x 40 x 4 mm box, colour (0.2, 0.6, 0.9), 10 mm above the link
    origin) and the XML ``extra`` after it."""
    def write(extra: str = ""):
        path = tmp_path / "robot.urdf"
        path.write_text(PLATE_URDF.format(extra=extra))
        return path

    return write


@pytest.fixture(scope="session")
def hand_model():
    """ManiSkill's Allegro right hand, parsed."""
    from gausstac_maniskill.urdf import default_hand_urdf, parse_urdf

    return parse_urdf(default_hand_urdf())


@pytest.fixture(scope="session")
def hand_meshes(hand_model):
    """Coloured visual meshes of every Allegro link with a visual (link frames)."""
    from gausstac_maniskill.splat.surface import load_link_meshes

    return load_link_meshes(hand_model)


def random_scene(n: int, sh_degree: int = 0, seed: int = 0, spread: float = 0.3):
    """A blob of n random Gaussians around the origin (GaussianSet)."""
    from gausstac_maniskill.splat import GaussianSet

    gen = torch.Generator().manual_seed(seed)
    k = (sh_degree + 1) ** 2
    return GaussianSet.create(
        torch.randn(n, 3, generator=gen) * spread,
        torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=1),
        torch.log(torch.rand(n, 3, generator=gen) * 0.08 + 0.01),
        torch.randn(n, generator=gen) * 2.0,
        torch.randn(n, k, 3, generator=gen) * 0.5,
    )


@pytest.fixture
def scene_factory():
    return random_scene
