"""Rigid (link) and soft (MPM particle) deformation of Gaussians."""
import math

import pytest
import torch

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.splat import (GaussianSet, SoftBinding, intrinsics_from_fov, look_at,
                                      polar_rotation, pose_gaussians, quat_to_rotmat, rasterize,
                                      render,
                                      rigid_transform, soft_deform)

W, H = 64, 48


def rot_z(theta):
    c, s = math.cos(theta), math.sin(theta)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose(R, t):
    T = torch.eye(4)
    T[:3, :3] = R
    T[:3, 3] = torch.as_tensor(t)
    return T


def random_rotation(seed):
    q = torch.nn.functional.normalize(torch.randn(4, generator=torch.Generator().manual_seed(seed)),
                                      dim=0)
    return quat_to_rotmat(q)


def camera():
    return (look_at([0.0, -1.5, 0.6], [0, 0, 0])[None],
            intrinsics_from_fov(W, H, math.radians(50))[None])


def test_rotated_link_moves_its_gaussians_exactly():
    means = torch.tensor([[0.1, 0.0, 0.0], [0.0, 0.2, 0.05], [0.3, -0.1, 0.2]])
    quats = torch.tensor([[1.0, 0, 0, 0]] * 3)
    link_id = torch.tensor([1, 1, 0])
    poses = torch.stack([torch.eye(4), pose(rot_z(math.pi / 2), [1.0, 2.0, 3.0])])
    m, q = rigid_transform(means, quats, link_id, poses)
    # 90° about z: (x, y, z) -> (-y, x, z), then + t; link 0 is the identity
    expected = torch.tensor([[1.0, 2.1, 3.0], [0.8, 2.0, 3.05], [0.3, -0.1, 0.2]])
    assert torch.allclose(m, expected, atol=1e-6)
    s = math.sqrt(0.5)
    assert torch.allclose(q[:2], torch.tensor([[s, 0, 0, s]] * 2), atol=1e-6)
    assert torch.allclose(q[2], torch.tensor([1.0, 0, 0, 0]))


def test_rigid_rotation_composes_quaternions_and_batches():
    gen = torch.Generator().manual_seed(0)
    n = 50
    means = torch.randn(n, 3, generator=gen)
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=1)
    link_id = torch.randint(0, 3, (n,), generator=gen)
    poses = torch.stack([torch.stack([pose(random_rotation(10 * b + l),
                                           torch.randn(3, generator=gen)) for l in range(3)])
                         for b in range(2)])  # [B=2, L=3]
    m, q = rigid_transform(means, quats, link_id, poses)
    assert m.shape == (2, n, 3) and q.shape == (2, n, 4)
    for b in range(2):
        T = poses[b, link_id]
        R = T[:, :3, :3]
        assert torch.allclose(m[b], (R @ means[:, :, None])[..., 0] + T[:, :3, 3], atol=1e-5)
        assert torch.allclose(quat_to_rotmat(q[b]), R @ quat_to_rotmat(quats), atol=1e-5)
    with pytest.raises(ConfigError, match="link_id"):
        rigid_transform(means, quats, link_id + 5, poses)
    with pytest.raises(ConfigError, match=r"\[L, 4, 4\]"):
        rigid_transform(means, quats, link_id, torch.eye(4))


def test_polar_rotation_is_proper():
    gen = torch.Generator().manual_seed(1)
    R = torch.stack([random_rotation(i) for i in range(20)])
    S = torch.randn(20, 3, 3, generator=gen)
    S = S @ S.transpose(1, 2) + 0.5 * torch.eye(3)  # symmetric positive definite
    assert torch.allclose(polar_rotation(R @ S), R, atol=1e-4)
    # an inverted element (det F < 0) still gives a rotation
    F = torch.diag(torch.tensor([1.0, 1.0, -0.5]))
    Rf = polar_rotation(F)
    assert torch.linalg.det(Rf).item() == pytest.approx(1.0, abs=1e-6)
    assert torch.allclose(Rf @ Rf.T, torch.eye(3), atol=1e-6)


def soft_scene(n=300, seed=0):
    """A blob of Gaussians (all soft: group 0) and a particle lattice through it."""
    gen = torch.Generator().manual_seed(seed)
    g = GaussianSet.create(torch.randn(n, 3, generator=gen) * 0.15,
                           torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=1),
                           torch.log(torch.rand(n, 3, generator=gen) * 0.03 + 0.01),
                           torch.randn(n, generator=gen) + 1.0,
                           torch.randn(n, 9, 3, generator=gen) * 0.4,
                           group=torch.zeros(n, dtype=torch.int64))
    ax = torch.linspace(-0.5, 0.5, 11)
    X = torch.stack(torch.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
    return g, X


def test_binding_maps_each_gaussian_to_its_nearest_particle():
    g, X = soft_scene()
    b = SoftBinding.from_nearest(g, X)
    assert len(b) == len(g)
    d = torch.cdist(g.means, X)
    assert torch.equal(b.particle_index, d.argmin(dim=1))
    assert torch.allclose(b.rest_offset, g.means - X[b.particle_index])
    with pytest.raises(ConfigError, match="max_distance"):
        SoftBinding.from_nearest(g, X + 10.0, max_distance=0.1)


def test_identity_F_leaves_image_unchanged():
    g, X = soft_scene()
    b = SoftBinding.from_nearest(g, X)
    posed = pose_gaussians(g, soft=b, x=X.clone(), F=torch.eye(3).expand(len(X), 3, 3))
    assert torch.allclose(posed.means, g.means, atol=1e-6)
    assert torch.allclose(posed.covars, g.covariances(), atol=1e-9)
    V, K = camera()
    a = render(g, V, K, W, H, background=0.2)
    d = posed.render(V, K, W, H, background=0.2)
    print("F = I: max |Δrgb| =", (a.rgb - d.rgb).abs().max().item())
    assert a.alpha.max() > 0.5
    assert (a.rgb - d.rgb).abs().max() < 1e-4 and (a.depth - d.depth).abs().max() < 1e-4


def test_pure_rotation_F_equals_rigid_path():
    """x_p = R X_p + t and F_p = R for all particles must equal moving a link by [R | t]."""
    g, X = soft_scene(seed=2)
    R, t = random_rotation(5), torch.tensor([0.05, -0.02, 0.1])
    b = SoftBinding.from_nearest(g, X)
    soft = pose_gaussians(g, soft=b, x=X @ R.T + t, F=R.expand(len(X), 3, 3))
    rigid = pose_gaussians(g.replace(group=torch.full((len(g),), -1)),
                           link_poses=pose(R, t)[None])
    assert torch.allclose(soft.means, rigid.means, atol=1e-5)
    assert torch.allclose(soft.covars, rigid.covars, atol=1e-7)
    assert torch.allclose(soft.sh_rotations, rigid.sh_rotations, atol=1e-5)
    V, K = camera()
    a, c = soft.render(V, K, W, H), rigid.render(V, K, W, H)
    assert a.alpha.max() > 0.5
    assert (a.rgb - c.rgb).abs().max() < 1e-3
    # the SH frame matters: without rotating the view direction (SH degree 2) the
    # image differs, so the agreement above checks the SH rotation too
    wrong = rasterize(rigid.means, None, None, rigid.opacities, rigid.sh, V, K, W, H,
                      covars=rigid.covars)
    assert (wrong.rgb - c.rgb).abs().max() > 1e-2


def test_soft_deform_closed_form_shear():
    g, X = soft_scene(n=20)
    b = SoftBinding.from_nearest(g, X)
    F = torch.tensor([[1.0, 0.3, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.8]])
    x = X + torch.tensor([0.0, 0.0, 0.01])
    means, covs, rots = soft_deform(b, x, F.expand(len(X), 3, 3))
    p = b.particle_index
    assert torch.allclose(means, x[p] + b.rest_offset @ F.T, atol=1e-6)
    assert torch.allclose(covs, F @ g.covariances() @ F.T, atol=1e-8)
    assert torch.allclose(rots, polar_rotation(F).expand(20, 3, 3), atol=1e-6)
    # batched particles [B, P, 3]
    mb, cb, rb = soft_deform(b, torch.stack([x, X]), torch.stack([F, torch.eye(3)])[:, None]
                             .expand(2, len(X), 3, 3))
    assert torch.allclose(mb[0], means) and torch.allclose(mb[1], g.means, atol=1e-6)
    with pytest.raises(ConfigError, match="particle F"):
        soft_deform(b, x, torch.eye(3).expand(len(X) - 1, 3, 3))
    bad = F.expand(len(X), 3, 3).clone()
    bad[0, 0, 0] = float("nan")
    with pytest.raises(ConfigError, match="NaN"):
        soft_deform(b, x, bad)


def test_mixed_rigid_and_soft_with_batched_links():
    g, X = soft_scene(n=40)
    group = torch.where(torch.arange(40) < 20, -1, 0)
    g = g.replace(group=group, link_id=torch.where(group < 0, 1, 0))
    b = SoftBinding.from_nearest(g, X)
    assert torch.equal(b.gaussian_index, torch.arange(20, 40))
    poses = torch.stack([torch.eye(4).expand(2, 4, 4), torch.stack([torch.eye(4),
                         pose(rot_z(0.3), [0, 0, 1.0])])])  # [B=2, L=2]
    posed = pose_gaussians(g, link_poses=poses, soft=b, x=X, F=torch.eye(3).expand(len(X), 3, 3))
    assert posed.means.shape == (2, 40, 3)
    assert torch.allclose(posed.means[:, 20:], g.means[20:].expand(2, 20, 3), atol=1e-6)
    assert torch.allclose(posed.means[0, :20], g.means[:20])
    assert torch.allclose(posed.means[1, :20], g.means[:20] @ rot_z(0.3).T
                          + torch.tensor([0, 0, 1.0]), atol=1e-6)
    V, K = camera()
    out = posed[1].render(V, K, W, H)
    assert out.rgb.shape == (1, H, W, 3)
    with pytest.raises(ConfigError, match="x and gradients F"):
        pose_gaussians(g, soft=b)


def test_moving_scene_and_camera_together_changes_nothing():
    """Invariance: moving a link by T and the camera by T leaves the image unchanged.

    This pins down the SH convention independently of the rasterizer's code: the
    view direction in the Gaussian's own frame is the same before and after.
    """
    g, _ = soft_scene(seed=3)
    g = g.replace(group=torch.full((len(g),), -1))
    T = pose(random_rotation(9), [0.2, -0.1, 0.3])
    V, K = camera()
    before = render(g, V, K, W, H, background=0.1)
    posed = pose_gaussians(g, link_poses=T[None])
    after = posed.render(V @ torch.linalg.inv(T), K, W, H, background=0.1)
    assert before.alpha.max() > 0.5
    assert (before.rgb - after.rgb).abs().max() < 1e-3
    assert (before.depth - after.depth).abs().max() < 1e-3


def test_framed_gaussians_render_like_the_posed_world_set():
    """Rigid links and MPM particles as frames posed by the rasterizer's kernel give the
    image of pose_gaussians' world-space set (rigid part: links; soft part: particles with
    a shearing F, SH rotated by polar(F))."""
    from gausstac_maniskill.splat import FramedGaussians, particle_frames, rigid_frames

    g, X = soft_scene(n=120, seed=4)
    rigid = g[torch.arange(60)].replace(group=torch.full((60,), -1), link_id=torch.arange(60) % 2)
    soft = g[torch.arange(60, 120)]
    both = GaussianSet.cat([rigid, soft])
    b = SoftBinding.from_nearest(both, X, gaussian_index=torch.arange(60, 120))
    links = torch.stack([pose(random_rotation(1), [0.1, 0.0, 0.05]), pose(rot_z(0.4), [-0.1, 0.05, 0.0])])
    gen = torch.Generator().manual_seed(7)
    F = torch.eye(3) + 0.15 * torch.randn(len(X), 3, 3, generator=gen)
    x = X + 0.01 * torch.randn(len(X), 3, generator=gen)
    world = pose_gaussians(both, links, b, x, F)

    soft_framed, particles = FramedGaussians.from_binding(both, b)
    assert torch.equal(particles, torch.unique(b.particle_index))
    framed = FramedGaussians.cat([FramedGaussians.from_gaussians(rigid, n_frames=2), soft_framed])
    assert len(framed) == 120 and framed.n_frames == 2 + len(particles)
    lf, lr = rigid_frames(links)
    pf, pr = particle_frames(x[particles], F[particles])
    frames, rots = torch.cat([lf, pf]), torch.cat([lr, pr])

    V, K = camera()
    a = framed.render(frames, rots, V, K, W, H, background=0.2)
    c = world.render(V, K, W, H, background=0.2)
    assert c.alpha.max() > 0.5
    for name in ("rgb", "depth", "alpha"):
        assert (getattr(a, name) - getattr(c, name)).abs().max() < 1e-4, name
    # the world-space view of the same frames
    back = framed.posed(frames, rots)
    assert torch.allclose(back.means, world.means, atol=1e-6)
    assert torch.allclose(back.covars, world.covars, atol=1e-8)
    assert torch.allclose(back.sh_rotations, world.sh_rotations, atol=1e-5)
    # the SH rotations matter here (SH degree 2): leaving them out changes the colours
    plain = framed.render(frames, None, V, K, W, H, background=0.2)
    assert (plain.rgb - a.rgb).abs().max() > 1e-2
    with pytest.raises(ConfigError, match="frames has shape"):
        framed.render(frames[:-1], None, V, K, W, H)
