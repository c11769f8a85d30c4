"""RigidLayer: Gaussians outside the co-simulator (captured scenes, objects on actors) splatted
in one pass with the hand's, depth-sorted together."""
import numpy as np
import pytest
import torch

from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.render import RigidLayer
from gausstac_maniskill.splat import (GaussianSet, PosedGaussians, intrinsics_from_fov, look_at, pose_gaussians,
                                      rgb_to_sh_dc)
from gausstac_maniskill.transforms import make_pose

W = H = 32
CAM = look_at([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], up=(0.0, -1.0, 0.0))[None]  # looking along +z
K = intrinsics_from_fov(W, H, 0.9)[None]


def wall(z, half, rgb, spacing=0.01, sh_degree=0):
    """Flat opaque Gaussians filling the square |x|, |y| <= half at depth z."""
    xs = np.arange(-half, half + 1e-9, spacing)
    x, y = np.meshgrid(xs, xs)
    pts = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)
    n = len(pts)
    sh = torch.zeros(n, (sh_degree + 1) ** 2, 3)
    sh[:, 0] = rgb_to_sh_dc(torch.tensor(rgb)).expand(n, 3)
    return GaussianSet.create(pts, log_scales=np.log([[spacing, spacing, spacing / 20]]).repeat(n, 0),
                              opacity_logits=np.full(n, 6.0), sh=sh)


def hand_and_scene(scene_z):
    """A red "hand" (a link-bound square, 1 m in front of the camera) and a blue captured
    wall (world frame, SH degree 1) at ``scene_z``, wider than the hand."""
    hand = wall(0.0, 0.1, (1.0, 0.0, 0.0))  # link frame; the link sits at z = 1
    hand_posed = pose_gaussians(hand, torch.as_tensor(make_pose([0, 0, 1.0]), dtype=torch.float32)[None])
    scene = RigidLayer(wall(scene_z, 0.6 * scene_z, (0.0, 0.0, 1.0), spacing=0.02 * scene_z, sh_degree=1))
    return hand_posed, scene


@pytest.mark.parametrize("scene_z, centre_rgb, centre_depth", [(0.5, (0, 0, 1), 0.5), (1.5, (1, 0, 0), 1.0)])
def test_scene_occludes_the_hand_only_when_in_front(scene_z, centre_rgb, centre_depth):
    hand, scene = hand_and_scene(scene_z)
    out = PosedGaussians.cat([hand, scene.posed()]).render(CAM, K, W, H)
    c = out.rgb[0, H // 2, W // 2]
    assert torch.allclose(c, torch.tensor(centre_rgb, dtype=torch.float32), atol=0.02), c
    assert abs(float(out.normalized_depth()[0, H // 2, W // 2]) - centre_depth) < 0.01
    corner = out.rgb[0, 1, 1]  # outside the hand: the scene everywhere
    assert torch.allclose(corner, torch.tensor([0.0, 0.0, 1.0]), atol=0.02), corner
    # sorted together, not pasted: the order of the parts does not matter
    swapped = PosedGaussians.cat([scene.posed(), hand]).render(CAM, K, W, H)
    assert torch.allclose(swapped.rgb, out.rgb, atol=1e-5)


def test_layer_follows_its_poses_and_caches_a_static_scene():
    g = wall(0.0, 0.02, (0.0, 1.0, 0.0))
    T = [make_pose([0.1, 0.2, 0.3])]
    layer = RigidLayer(g, poses=lambda: np.array(T))
    assert torch.allclose(layer.posed().means.mean(0), torch.tensor([0.1, 0.2, 0.3]), atol=1e-6)
    T[0] = make_pose([-0.1, 0.0, 0.5])  # the actor moved: posed again on the next call
    assert torch.allclose(layer.posed().means.mean(0), torch.tensor([-0.1, 0.0, 0.5]), atol=1e-6)
    static = RigidLayer(g)
    assert static.posed() is static.posed()


def test_cat_pads_sh_degrees_and_checks_batches():
    a = pose_gaussians(wall(1.0, 0.02, (1.0, 0.0, 0.0)))
    b = pose_gaussians(wall(1.0, 0.02, (1.0, 0.0, 0.0), sh_degree=3))
    both = PosedGaussians.cat([a, b])
    assert both.sh.shape == (len(a.means) + len(b.means), 16, 3)
    assert torch.equal(both.sh[: len(a.means), 1:], torch.zeros(len(a.means), 15, 3))
    batched = PosedGaussians(a.means[None], a.covars[None], a.sh_rotations[None], a.opacities, a.sh)
    with pytest.raises(ConfigError, match="batch shapes differ"):
        PosedGaussians.cat([a, batched])
