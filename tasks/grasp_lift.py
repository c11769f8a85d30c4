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
from mani_skill.utils.registration import register_env

from ..geometry.colliders import Box
from ..physx import batched_pose
from .pinch_grasp import OPEN_HAND, PinchGraspEnv

__all__ = ["GraspLiftCubeEnv", "OPEN_HAND"]


@register_env("GaussTac-GraspLiftCube-v1", max_episode_steps=100)
class GraspLiftCubeEnv(PinchGraspEnv):
    """Grasp the cube with the thumb and a finger, lift it and hold it.

    Args:
        cube_mass: mass [kg] of the cube (10 g to 1 kg).
        cube_half_size: half edge [m] (10 to 40 mm: what the pinch spans).
        cube_friction: Coulomb friction between the pads and the cube.
        **kwargs: ``lift_height``, ``hold_time``, ``grasp_force``, ``approach_height``,
            ``xy_range``, ``pad_reaction`` (see :class:`~gausstac_maniskill.tasks.pinch_grasp.PinchGraspEnv`)
            and :class:`~gausstac_maniskill.tasks.base.GaussTacEnv`'s arguments.
    """

    def __init__(self, *args, cube_mass: float = 0.05, cube_half_size: float = 0.02, cube_friction: float = 1.0,
                 **kwargs):
        self.check_range("cube_mass", cube_mass, 0.005, 1.0, "kg")
        self.check_range("cube_half_size", cube_half_size, 0.01, 0.04, "m")
        self.check_range("cube_friction", cube_friction, 0.0, 3.0, "")
        self.cube_mass, self.cube_half_size, self.cube_friction = float(cube_mass), float(cube_half_size), float(cube_friction)
        super().__init__(*args, **kwargs)

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

    @property
    def object_mass(self) -> float:
        return self.cube_mass

    @property
    def object_friction(self) -> float:
        return self.cube_friction

    @property
    def pinch_half_width(self) -> float:
        return self.cube_half_size

    @property
    def object_rest_height(self) -> float:
        return self.cube_half_size

    def object_centre(self) -> torch.Tensor:
        return self.cube.pose.p.float()

    def _place_object(self, env_idx: torch.Tensor, centre: np.ndarray) -> None:
        n = len(env_idx)
        self.cube.set_pose(batched_pose(centre, np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))))
        self.cube.set_linear_velocity(torch.zeros(n, 3))
        self.cube.set_angular_velocity(torch.zeros(n, 3))

    # ------------------------------------------------------------------ task
    def evaluate(self):
        return dict(**self._pinch_info(), cube_speed=self.cube.linear_velocity.norm(dim=1).float())

    def _get_obs_extra(self, info: dict):
        return dict(cube_pose=self.cube.pose.raw_pose.float(), pinch_point=self.pinch_point(),
                    hold_time=info["hold_time"][:, None])

    def compute_dense_reward(self, obs, action, info):
        """reach (pinch point to cube centre, 0..1) + grasp (0..1) + 2 lift (height
        fraction while grasped) + 2 hold (held time fraction) + 3 on success."""
        return self._pinch_reward(info) + 3 * info["success"].float()

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info) / 9.0
