"""GaussianSplatCamera and TactileSensor inside a ManiSkill env, checked against SAPIEN's camera."""
import gymnasium as gym
import numpy as np
import pytest
import sapien
import torch
from mani_skill.sensors.camera import CameraConfig

import gausstac_maniskill  # noqa: F401
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.sensors import GaussianSplatCamera, GaussianSplatCameraConfig
from gausstac_maniskill.tasks.press_cube import PressCubeEnv

pytestmark = pytest.mark.sapien


class _TwoCameras(PressCubeEnv):
    """PressCube with a plain SAPIEN camera next to the splat camera (same pose and size), and a
    yellow marker box in view that has no Gaussians (SAPIEN draws it in the background)."""

    def _load_scene(self, options: dict):
        super()._load_scene(options)
        b = self.scene.create_actor_builder()
        b.add_box_visual(half_size=[0.01, 0.01, 0.01],
                         material=sapien.render.RenderMaterial(base_color=[0.9, 0.8, 0.1, 1]))
        b.initial_pose = sapien.Pose(p=[0.13, 0.1, 0.03])
        self.marker = b.build_kinematic(name="marker")

    @property
    def _default_sensor_configs(self):
        splat = super()._default_sensor_configs[0]
        plain = CameraConfig(uid="sapien_camera", pose=splat.pose, width=splat.width, height=splat.height,
                             fov=splat.fov, near=splat.near, far=splat.far)
        return [splat, plain]


@pytest.fixture(scope="module")
def env():
    e = _TwoCameras(obs_mode="rgb+depth+segmentation", render_mode="rgb_array", sim_backend="physx_cpu",
                    splat_size=(160, 120))
    e.reset(seed=0)
    yield e
    e.close()


def test_splat_camera_obs_match_sapien_camera_layout(env):
    obs = env.get_obs()
    splat, plain = obs["sensor_data"]["splat_camera"], obs["sensor_data"]["sapien_camera"]
    assert isinstance(env._sensors["splat_camera"], GaussianSplatCamera)
    for key in ("rgb", "depth"):
        assert splat[key].shape == plain[key].shape, key
        assert splat[key].dtype == plain[key].dtype, key
    assert splat["rgb"].shape == (1, 120, 160, 3) and splat["depth"].shape == (1, 120, 160, 1)
    ps, pp = obs["sensor_param"]["splat_camera"], obs["sensor_param"]["sapien_camera"]
    assert set(ps) == set(pp) == {"extrinsic_cv", "cam2world_gl", "intrinsic_cv"}
    for k in ps:
        assert torch.allclose(ps[k], pp[k], atol=1e-6), k


def test_splat_depth_agrees_with_sapien_on_the_hand(env):
    """Where SAPIEN sees the hand, the splatted hand lies at the same depth (rendering vs SAPIEN)."""
    obs = env.get_obs()
    cam = env._sensors["sapien_camera"]
    depth_with_hand = obs["sensor_data"]["sapien_camera"]["depth"][0, ..., 0].float()
    with env._splat_source.hidden():
        cam.capture()
        depth_without = cam.get_obs(rgb=False, depth=True, position=False, segmentation=False)["depth"][0, ..., 0]
    hand = (depth_with_hand > 0) & ((depth_without.float() - depth_with_hand).abs() > 5)  # mm
    assert hand.sum() > 500, "the hand should cover part of the image"
    splat = obs["sensor_data"]["splat_camera"]["depth"][0, ..., 0].float()
    covered = (splat[hand] > 0).float().mean().item()
    err = (splat[hand] - depth_with_hand[hand]).abs()
    assert covered > 0.9, covered
    assert err.median().item() < 3.0, err.median()  # millimetres
    # the SAPIEN background taken for compositing had the hand hidden
    bg_depth = env._sensors["splat_camera"]._background[1][0]  # metres, inf where empty
    d = depth_without.float() / 1000.0
    assert torch.equal(bg_depth[hand], torch.where(d > 0, d, torch.full_like(d, float("inf")))[hand])


def test_background_is_reused_until_something_in_it_moves(env):
    """SAPIEN's background picture is taken again only when the camera or a visible SAPIEN
    entity moved (or after a reset); a reused picture gives the same image as a fresh one. An
    object drawn by its Gaussians (the cube) is hidden from that picture: it may move without
    a new one."""
    from gausstac_maniskill.tasks.base import batched_pose

    cam = env._sensors["splat_camera"]
    rgb = lambda: env.get_obs()["sensor_data"]["splat_camera"]["rgb"].clone()  # noqa: E731
    rgb()
    n = cam.background_renders
    first = rgb()
    assert cam.background_renders == n, "nothing moved: the background picture is reused"
    cam.invalidate_background()
    fresh = rgb()
    assert cam.background_renders == n + 1
    assert torch.equal(fresh, first)  # the reused picture is the one SAPIEN takes now
    # the cube (drawn by its Gaussians, which follow it at the next step) moves 2 cm: the
    # background stays
    p, q = env.block.pose.p.clone(), env.block.pose.q.clone()
    try:
        env.block.set_pose(batched_pose(p + torch.tensor([0.0, 0.0, 0.02]), q))
        rgb()
        assert cam.background_renders == n + 1
    finally:
        env.block.set_pose(batched_pose(p, q))
    # the marker (drawn by SAPIEN) moves 2 cm: the background is taken again, the image changes
    p, q = env.marker.pose.p.clone(), env.marker.pose.q.clone()
    try:
        env.marker.set_pose(batched_pose(p + torch.tensor([0.0, 0.0, 0.02]), q))
        moved = rgb()
        assert cam.background_renders == n + 2
        assert (moved.int() - first.int()).abs().max() > 50
        rgb()
        assert cam.background_renders == n + 2  # still again: reused at the new place
    finally:
        env.marker.set_pose(batched_pose(p, q))
    assert torch.equal(rgb(), first) and cam.background_renders == n + 3
    # the camera moves: taken again
    local = cam.camera.get_local_pose()
    try:
        cam.camera.set_local_pose(sapien.Pose(local.p[0].tolist(), local.q[0].tolist())
                                  * sapien.Pose([0.0, 0.01, 0.0]))
        assert not torch.equal(rgb(), first) and cam.background_renders == n + 4
    finally:
        cam.camera.set_local_pose(sapien.Pose(local.p[0].tolist(), local.q[0].tolist()))
    # a new episode may look different in ways no pose shows: taken again
    env.reset(seed=0)
    assert cam.background_renders > n + 4


def test_human_render_camera_is_a_splat_camera(env):
    img = env.render()
    assert isinstance(env._human_render_cameras["render_camera"], GaussianSplatCamera)
    assert img.shape == (1, 256, 256, 3) and img.dtype == torch.uint8
    assert img.float().std() > 10


def test_tactile_sensor_images(env):
    img = env.tactile_sensor.get_images()
    assert img.shape == (1, 16, 64, 3) and img.dtype == torch.uint8


def test_plain_background_and_bad_background():
    e = gym.make("GaussTac-Gesture-v1", obs_mode="rgb", splat_background=(1.0, 1.0, 1.0), sim_backend="physx_cpu")
    try:
        obs, _ = e.reset(seed=0)
        rgb = obs["sensor_data"]["splat_camera"]["rgb"][0]
        assert (rgb == 255).all(dim=-1).float().mean() > 0.5  # mostly the white background
        assert (rgb < 100).all(dim=-1).any()  # and the dark hand
    finally:
        e.close()
    with pytest.raises(ConfigError, match="background"):
        GaussianSplatCameraConfig(uid="c", pose=sapien.Pose(), width=8, height=8, fov=1.0, background="blue")


def test_splat_camera_is_lit_by_the_scene_lights_by_default(env):
    """``lighting="scene"``: each env's SAPIEN lights (here ManiSkill's default set-up), read
    again after a reset; ``"baked"`` gives no lighting; anything else is a clear error."""
    from gausstac_maniskill.splat import MANISKILL_DEFAULT

    cam = env._sensors["splat_camera"]
    assert cam.config.lighting == "scene"
    (lighting,) = cam.lighting()
    for field in ("ambient", "directions", "colors"):
        assert np.allclose(getattr(lighting, field), getattr(MANISKILL_DEFAULT, field), atol=1e-6), field
    cam.invalidate_background()
    assert cam._lighting is None
    cfg = GaussianSplatCameraConfig(uid="c", pose=sapien.Pose(), width=8, height=8, fov=1.0, lighting="baked")
    assert cfg.lighting == "baked"
    with pytest.raises(ConfigError, match="lighting"):
        GaussianSplatCameraConfig(uid="c", pose=sapien.Pose(), width=8, height=8, fov=1.0, lighting="sun")


def test_capture_without_scene_is_a_clear_error(env):
    cam = GaussianSplatCamera.adopt(env._sensors["sapien_camera"])
    with pytest.raises(ConfigError, match="no scene attached"):
        cam.capture()


class _MountedCamera(PressCubeEnv):
    """A splat camera riding on the index fingertip (``mount``), like a wrist/finger camera."""

    @property
    def _default_sensor_configs(self):
        link = self.agent.robot.links_map["link_3.0"]
        return [GaussianSplatCameraConfig(uid="finger_camera", pose=sapien.Pose([0.0, 0.0, -0.06]), width=64,
                                          height=48, fov=1.2, near=0.005, far=2.0, mount=link)]


def test_splat_camera_mounted_on_a_link_follows_it():
    e = _MountedCamera(obs_mode="rgb", sim_backend="physx_cpu")
    try:
        obs, _ = e.reset(seed=0)
        ext0 = obs["sensor_param"]["finger_camera"]["extrinsic_cv"].clone()
        assert obs["sensor_data"]["finger_camera"]["rgb"].shape == (1, 48, 64, 3)
        a = torch.zeros(e.action_space.shape)
        a[..., 2] = 1.0  # flex the index finger's middle joint
        for _ in range(3):
            obs, *_ = e.step(a)
        assert not torch.allclose(obs["sensor_param"]["finger_camera"]["extrinsic_cv"], ext0, atol=1e-4)
        assert obs["sensor_data"]["finger_camera"]["rgb"].float().std() > 5
    finally:
        e.close()


def test_segmentation_comes_from_sapien_with_the_hand(env):
    obs = env.get_obs()
    seg_splat = obs["sensor_data"]["splat_camera"]["segmentation"]
    seg_plain = obs["sensor_data"]["sapien_camera"]["segmentation"]
    assert seg_splat.shape == seg_plain.shape and seg_splat.dtype == seg_plain.dtype
    assert torch.equal(seg_splat, seg_plain)  # same pose and size: the hand is in it
