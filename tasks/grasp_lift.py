"""``GaussTac-GraspLiftCube-v1``: pinch a free cube between the thumb and index pads, lift it
5 cm and hold it there for 2 s.

The floating Allegro hand (``floating_allegro_hand_right_gausstac``) starts open, its pinch
point (:data:`~gausstac_maniskill.agents.allegro.ALLEGRO_PINCH_CENTRE`) ``approach_height``
above a free cube that rests on the ground; the pinch axis (thumb -> index) is world +y.
The cube is drawn per episode within ``xy_range`` of the origin. It is a dynamic SAPIEN
body of mass ``cube_mass`` that the pads feel through an SDF collider with
``cube_friction``, two-way coupled: what the pads push on it, it takes in SAPIEN, and the
fingers take back through their joint drives (``pad_reaction=True``, the default here).
Nothing else holds it: the rigid cores of the pad links collide with it only when a pad is
crushed through.

Success: the cube is ``lift_height`` above its resting height, with the thumb and the
index or middle pad touching it (normal force above ``grasp_force``), for ``hold_time``
without a break. Dense reward: reach, grasp, lift and hold terms (see
:meth:`GraspLiftCubeEnv.compute_dense_reward`).
"""
from __future__ import annotations

import numpy as np
import sapien
import torch
from mani_skill.utils import common
from mani_skill.utils.registration import register_env

from ..errors import ConfigError
from ..mpm.colliders import Box
from ..transforms import matrix_to_quat
from .base import GaussTacEnv, batched_pose

__all__ = ["GraspLiftCubeEnv", "OPEN_HAND"]

#: Open hand (action order of the 16 finger joints, rad): index and thumb a few mm outside
#: a 20 mm cube at the pinch point, the other fingers relaxed.
OPEN_HAND = np.array([0.47, 1.45, 0.1, -0.1, 0.0, 0.1, 0.1, 0.1, 0.0, 0.1, 0.1, 0.1, 0.97, 0.07, 0.2, -0.1], np.float32)


@register_env("GaussTac-GraspLiftCube-v1", max_episode_steps=100)
class GraspLiftCubeEnv(GaussTacEnv):
    """Grasp the cube with the thumb and a finger, lift it and hold it.

    Args:
        cube_mass: mass [kg] of the cube (10 g to 1 kg).
        cube_half_size: half edge [m] (10 to 40 mm: what the pinch spans).
        cube_friction: Coulomb friction between the pads and the cube.
        lift_height: height [m] above rest that counts as lifted.
        hold_time: time [s] the cube must stay lifted and grasped.
        grasp_force: normal force [N] above which a pad counts as touching.
        approach_height: start height [m] of the pinch point above the cube centre.
        xy_range: the cube's centre is drawn in [-xy_range, xy_range]² [m].
        pad_reaction: as :class:`~gausstac_maniskill.tasks.base.GaussTacEnv`; ``True`` here
            (without it the fingers feel nothing and crush the pads).
    """

    SUPPORTED_ROBOTS = ["floating_allegro_hand_right_gausstac"]
    ground_altitude = 0.0

    def __init__(self, *args, robot_uids="floating_allegro_hand_right_gausstac", cube_mass: float = 0.05,
                 cube_half_size: float = 0.02, cube_friction: float = 1.0, lift_height: float = 0.05,
                 hold_time: float = 2.0, grasp_force: float = 0.05, approach_height: float = 0.04,
                 xy_range: float = 0.01, pad_reaction=True, **kwargs):
        _check_range("cube_mass", cube_mass, 0.005, 1.0, "kg")
        _check_range("cube_half_size", cube_half_size, 0.01, 0.04, "m")
        _check_range("cube_friction", cube_friction, 0.0, 3.0, "")
        _check_range("lift_height", lift_height, 0.0, 0.2, "m")
        _check_range("hold_time", hold_time, 0.0, 20.0, "s")
        _check_range("approach_height", approach_height, 0.0, 0.1, "m")
        _check_range("xy_range", xy_range, 0.0, 0.05, "m")
        self.cube_mass, self.cube_half_size = float(cube_mass), float(cube_half_size)
        self.cube_friction, self.lift_height, self.hold_time = float(cube_friction), float(lift_height), float(hold_time)
        self.grasp_force, self.approach_height, self.xy_range = float(grasp_force), float(approach_height), float(xy_range)
        super().__init__(*args, robot_uids=robot_uids, pad_reaction=pad_reaction, **kwargs)

    def _splat_camera_pose(self):
        from mani_skill.utils import sapien_utils

        return sapien_utils.look_at(eye=[0.3, -0.25, 0.25], target=[0.0, 0.0, 0.06])

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict):
        super()._load_scene(options)
        h = self.cube_half_size
        b = self.scene.create_actor_builder()
        material = sapien.physx.PhysxMaterial(static_friction=self.cube_friction, dynamic_friction=self.cube_friction,
                                              restitution=0.0)
        b.add_box_collision(half_size=[h] * 3, density=self.cube_mass / (2 * h) ** 3, material=material)
        b.add_box_visual(half_size=[h] * 3, material=sapien.render.RenderMaterial(base_color=[0.2, 0.55, 0.85, 1]))
        b.initial_pose = sapien.Pose(p=[0.0, 0.0, h])
        self.cube = b.build(name="cube")
        from ..render import box_gaussians

        self.add_mpm_rigid("cube", self.cube, Box(half_extents=(h, h, h), friction=self.cube_friction),
                           gaussians=box_gaussians((h, h, h), 2.5e-3), two_way=True)
        B = self.num_envs
        self.hold_steps = torch.zeros(B, dtype=torch.int32)

    @property
    def hold_steps_needed(self) -> int:
        """Control steps the cube must stay lifted and grasped."""
        return int(np.ceil(self.hold_time * self.control_freq - 1e-9))

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        from ..agents.allegro import ALLEGRO_PINCH_CENTRE, pinch_down_rotation

        n = len(env_idx)
        rng = self._batched_episode_rng[common.to_numpy(env_idx)]
        h = self.cube_half_size
        xy = np.asarray(rng.uniform(-self.xy_range, self.xy_range, size=2)).reshape(n, 2)
        centre = np.concatenate([xy, np.full((n, 1), h)], axis=1)
        self.cube.set_pose(batched_pose(centre, np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))))
        self.cube.set_linear_velocity(torch.zeros(n, 3))
        self.cube.set_angular_velocity(torch.zeros(n, 3))
        R = pinch_down_rotation()
        qpos = np.zeros((n, 22))
        for i in range(n):
            base = np.eye(4)
            base[:3, :3] = R
            base[:3, 3] = centre[i] + [0.0, 0.0, self.approach_height] - R @ np.asarray(ALLEGRO_PINCH_CENTRE)
            qpos[i, :6] = type(self.agent).root_qpos(base)
        qpos[:, 6:] = OPEN_HAND
        self.agent.robot.set_pose(sapien.Pose())
        self.agent.reset(self.action_order_to_qpos(torch.as_tensor(qpos, dtype=torch.float32, device=self.device)))
        self.hold_steps[env_idx.cpu()] = 0

    # ------------------------------------------------------------------ task
    def cube_height(self) -> torch.Tensor:
        """[B] height [m] of the cube's centre above its resting height."""
        return (self.cube.pose.p[:, 2] - self.cube_half_size).float()

    def pinch_point(self) -> torch.Tensor:
        """[B, 3] world position [m] of the hand's pinch point (between thumb and index pads)."""
        from ..agents.allegro import ALLEGRO_PINCH_CENTRE

        names = self._pose_source.link_names
        P = self._pose_source.all_link_poses()[:, names.index("base_link")].detach().cpu().double()
        c = torch.as_tensor([*ALLEGRO_PINCH_CENTRE, 1.0], dtype=torch.float64)
        return (P @ c)[:, :3].float().to(self.device)

    def grasped(self) -> torch.Tensor:
        """[B] the thumb and the index or middle pad touch the cube (normal force above ``grasp_force``)."""
        thumb = self.pad_force("thumb") > self.grasp_force
        finger = torch.maximum(self.pad_force("index"), self.pad_force("middle")) > self.grasp_force
        return thumb & finger

    def _after_control_step(self):
        super()._after_control_step()
        held = (self.grasped().cpu() & (self.cube_height().cpu() >= self.lift_height))
        self.hold_steps = torch.where(held, self.hold_steps + 1, torch.zeros_like(self.hold_steps))

    def evaluate(self):
        height = self.cube_height()
        return dict(success=(self.hold_steps >= self.hold_steps_needed).to(self.device),
                    grasped=self.grasped(), lifted=height >= self.lift_height, height=height,
                    hold_time=(self.hold_steps.float() / self.control_freq).to(self.device),
                    cube_speed=self.cube.linear_velocity.norm(dim=1).float())

    def _get_task_state(self):
        return {"hold_steps": self.hold_steps.clone()}

    def _set_task_state(self, state, env_idx):
        self.hold_steps[env_idx] = state["hold_steps"].to(self.hold_steps)

    def _get_obs_extra(self, info: dict):
        return dict(cube_pose=self.cube.pose.raw_pose.float(), pinch_point=self.pinch_point(),
                    hold_time=info["hold_time"][:, None])

    def compute_dense_reward(self, obs, action, info):
        """reach (pinch point to cube centre, 0..1) + grasp (0..1) + 2 lift (height
        fraction while grasped) + 2 hold (held time fraction) + 3 on success."""
        reach = 1 - torch.tanh(10.0 * (self.pinch_point() - self.cube.pose.p.float()).norm(dim=1))
        grasp = info["grasped"].float()
        lift = (info["height"] / self.lift_height).clamp(0.0, 1.0) * grasp
        hold = (info["hold_time"] / self.hold_time).clamp(max=1.0) if self.hold_time > 0 else info["lifted"].float()
        return reach + grasp + 2 * lift + 2 * hold + 3 * info["success"].float()

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info) / 9.0


def _check_range(name: str, value, low: float, high: float, unit: str) -> None:
    if not isinstance(value, (int, float)) or not low <= value <= high:
        raise ConfigError(f"GaussTac-GraspLiftCube-v1: {name}={value!r} must be a number in [{low}, {high}] {unit}".rstrip())
