"""GaussTac tasks with a captured 3DGS scene (``scene_ply``/``scene_pose``) and a captured
object riding on a SAPIEN actor (``GaussTacEnv.add_captured_object``)."""
import gymnasium as gym
import numpy as np
import pytest
import sapien
import torch

import gausstac_maniskill  # noqa: F401  (registers the tasks)
from gausstac_maniskill.errors import AssetError, AssetWarning, ConfigError
from gausstac_maniskill.splat import GaussianSet, rgb_to_sh_dc, save_ply
from gausstac_maniskill.splat.example_scene import EXAMPLE_PLACEMENT, EXAMPLE_SCENE, TABLE_Z

KW = dict(obs_mode="rgb+depth", sim_backend="physx_cpu", mpm_dx=2e-3, splat_size=(96, 96))
BOX = 0.025  # half size [m] of the captured box
GREEN = (0.1, 0.8, 0.2)


def box_capture(path):
    """A green box of half size BOX / 2 in its capture frame (placed with scale 2)."""
    from gausstac_maniskill.render import box_gaussians

    g = box_gaussians([BOX / 2] * 3, 2e-3)
    save_ply(path, g.replace(sh=rgb_to_sh_dc(torch.tensor(GREEN)).expand(len(g), 1, 3).clone()))
    return path


def make_captured_env(ply):
    from gausstac_maniskill.tasks import PressCubeEnv

    class PressCubeWithCapturedBox(PressCubeEnv):
        """The captured table gets a SAPIEN collision proxy; a captured box falls onto it."""

        def _load_scene(self, options):
            super()._load_scene(options)
            b = self.scene.create_actor_builder()
            b.add_box_collision(half_size=[0.38, 0.35, 0.01])
            b.initial_pose = sapien.Pose(p=[-0.07, 0.10, TABLE_Z - 0.01])
            b.build_static(name="table_proxy")
            b = self.scene.create_actor_builder()
            b.add_box_collision(half_size=[BOX] * 3)
            b.add_box_visual(half_size=[BOX] * 3)  # SAPIEN's own look, hidden from the splat camera
            b.initial_pose = sapien.Pose(p=[0.0, 0.35, -0.06])  # in view, right, before the backdrop
            self.box = b.build(name="box")
            self.add_captured_object("box", self.box, ply, placement=dict(scale=2.0))

    return PressCubeWithCapturedBox(scene_ply=EXAMPLE_SCENE, scene_pose=EXAMPLE_PLACEMENT.as_dict(), **KW)


@pytest.fixture(autouse=True)
def _torch_single_thread():
    """One torch thread: the render path's many small torch ops are 10-50x slower with two
    OpenMP threads when another process holds a core (as in tests/splat/conftest.py)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def captured_env(tmp_path_factory):
    env = make_captured_env(box_capture(tmp_path_factory.mktemp("box") / "box.ply"))
    yield env
    env.close()


def pixel_of(camera, p):
    """(row, column) of world point p [3] in a camera's image."""
    params = camera.get_params()
    E = params["extrinsic_cv"][0].double().numpy()
    K = params["intrinsic_cv"][0].double().numpy()
    x = K @ (E[:, :3] @ np.asarray(p, float) + E[:, 3])
    return int(x[1] / x[2]), int(x[0] / x[2])


@pytest.mark.sapien
def test_press_cube_with_the_example_scene_resets_steps_and_looks_different():
    default = gym.make("GaussTac-PressCube-v1", **KW)
    scene = gym.make("GaussTac-PressCube-v1", scene_ply="example", **KW)
    try:
        rgb, depth = [], []
        for env in (default, scene):
            obs, info = env.reset(seed=0)
            for _ in range(2):
                obs, reward, *_ = env.step(env.action_space.sample() * 0)
            assert torch.isfinite(reward).all()
            rgb.append(obs["sensor_data"]["splat_camera"]["rgb"][0].float())
            depth.append(obs["sensor_data"]["splat_camera"]["depth"][0, ..., 0])
        assert rgb[1].shape == (96, 96, 3)
        assert (rgb[0] - rgb[1]).abs().mean() > 20  # the capture replaced SAPIEN's grey floor
        cam = scene.unwrapped._sensors["splat_camera"]
        assert cam.config.background == (0.0, 0.0, 0.0)  # SAPIEN's background render is skipped
        assert (depth[1] > 0).all()  # and the capture fills the whole frame (0 mm: nothing seen)
    finally:
        default.close()
        scene.close()


@pytest.mark.sapien
def test_captured_object_follows_its_actor_and_occludes_the_scene(captured_env):
    env = captured_env
    env.reset(seed=0)
    zs = []
    for _ in range(4):  # 1.5 cm above the table: it lands in the second step
        obs, *_ = env.step(torch.zeros(env.action_space.shape))
        layer = env.cosims[0]._scene.layers[-1]  # the captured objects' layer
        T = env.box.pose.to_transformation_matrix()[0].double()
        local = layer.gaussians.means.double()  # actor frame
        assert torch.allclose(layer.posed().means.double(), local @ T[:3, :3].T + T[:3, 3], atol=1e-5)
        zs.append(float(T[2, 3]))
    assert zs[0] > zs[-1] and abs(zs[-1] - (TABLE_Z + BOX)) < 2e-3  # it fell and rests on the table
    r, c = pixel_of(env._sensors["splat_camera"], env.box.pose.p[0].numpy())
    seen = obs["sensor_data"]["splat_camera"]["rgb"][0, r, c].float() / 255
    assert torch.allclose(seen, torch.tensor(GREEN), atol=0.15), seen  # in front of the captured wall
    depth = float(obs["sensor_data"]["splat_camera"]["depth"][0, r, c, 0]) / 1000
    E = env._sensors["splat_camera"].get_params()["extrinsic_cv"][0].double().numpy()
    box_z = float((E[:, :3] @ env.box.pose.p[0].double().numpy() + E[:, 3])[2])
    assert box_z - 3 ** 0.5 * BOX - 1e-3 < depth < box_z  # its near side, not the wall behind it


@pytest.mark.sapien
def test_captured_object_checks_its_actor(captured_env):
    import trimesh

    class Stub:
        name = "stub"

        def __init__(self, mesh):
            self.mesh = mesh

        def get_first_collision_mesh(self, to_world_frame=False):
            return self.mesh

    env = captured_env
    g = GaussianSet.create(np.random.default_rng(0).uniform(-0.01, 0.01, (50, 3)))
    with pytest.raises(ConfigError, match="'box' already registered"):
        env.add_captured_object("box", Stub(None), g)
    with pytest.raises(ConfigError, match="actor 'stub' has no collision shape"):
        env.add_captured_object("ghost", Stub(None), g)
    with pytest.warns(AssetWarning, match=r"captured object 'big'.*collision mesh spans 0.2 m; placement scale=1"):
        env.add_captured_object("big", Stub(trimesh.creation.box([0.2] * 3)), g, placement=dict(scale=0.5))
    del env._captured["big"]  # a stub cannot be posed: keep the env usable


def test_scene_options_are_checked_before_sapien_starts(tmp_path):
    with pytest.raises(ConfigError, match="scene_pose was given without scene_ply"):
        gym.make("GaussTac-PressCube-v1", scene_pose=EXAMPLE_PLACEMENT.as_dict(), **KW)
    with pytest.raises(ConfigError, match="scene_ply needs camera='splat'"):
        gym.make("GaussTac-PressCube-v1", scene_ply=EXAMPLE_SCENE, camera="sapien", **KW)
    with pytest.raises(ConfigError, match="scene_pose: Similarity.scale=-1"):
        gym.make("GaussTac-PressCube-v1", scene_ply=EXAMPLE_SCENE, scene_pose=dict(scale=-1), **KW)
    with pytest.raises(AssetError, match="nothere.ply"):
        gym.make("GaussTac-PressCube-v1", scene_ply=tmp_path / "nothere.ply", **KW)
