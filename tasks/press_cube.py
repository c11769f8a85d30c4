"""``GaussTac-PressCube-v1``: press the index fingertip onto a fixed cube to a target force.

The Allegro hand (root fixed at the origin, fingers along +z, palm facing +x) starts
with its index finger bent; a fixed cube faces the index pad, its face 2–4 mm in front
of the pad's apex (drawn per episode). The normal force is the sum of the index pad's
tactile force map (the MPM contact force, not a SAPIEN contact). Success when it is
within ``tolerance`` (relative) of the target force, drawn in [0.8, 2.0] N. The target is
physical: the same press reads the same force within 5 % at dx = 2, 1.5 and 1 mm, and the
expert reaches it at each (``python -m gausstac_maniskill.bench resolution``).

Its captured-scene variant: ``gym.make("GaussTac-PressCube-v1", scene_ply="example")`` (the
packaged table top, placed by ``EXAMPLE_PLACEMENT``) or any INRIA ``.ply`` with
``scene_pose=`` (see :class:`~gausstac_maniskill.tasks.base.GaussTacEnv`): the splat camera
then draws the capture around the hand instead of SAPIEN's ground.
"""
from __future__ import annotations

import numpy as np
import sapien
import torch
from mani_skill.utils import common
from mani_skill.utils.registration import register_env

from ..geometry.colliders import Box
from ..physx import batched_pose
from ..task_checks import check_pair
from .base import GaussTacEnv

__all__ = ["PressCubeEnv", "IndexCubeTask", "INDEX_READY"]

#: Start posture (action order, rad): index bent towards the palm side, others relaxed.
INDEX_READY = np.array([0.0, 0.45, 0.55, 0.35, 0.0, 0.1, 0.1, 0.1, 0.0, 0.1, 0.1, 0.1, 0.35, 0.1, 0.1, 0.1],
                       np.float32)
CUBE_HALF = (0.02, 0.02, 0.012)  # m; the face the pad touches is the local -z face


class IndexCubeTask(GaussTacEnv):
    """Shared scene of the cube tasks: the hand in :data:`INDEX_READY` and a fixed cube
    whose -z face is parallel to the index pad, ``gap`` in front of its apex."""

    touch_pad = "index"
    gap_range = (0.002, 0.004)

    def _splat_camera_pose(self):
        from mani_skill.utils import sapien_utils

        return sapien_utils.look_at(eye=[0.2, -0.07, 0.17], target=[0.07, 0.05, 0.07])

    #: half extents [m] of the fixed block behind the face; the face is its local -z side
    block_half = CUBE_HALF

    def _load_scene(self, options: dict):
        super()._load_scene(options)
        self.face_frame = torch.zeros(self.num_envs, 4, 4, dtype=torch.float64)
        self.block = self._load_block()

    def _load_block(self):
        """The fixed cube the index pad touches (tasks may override)."""
        b = self.scene.create_actor_builder()
        b.add_box_collision(half_size=CUBE_HALF)
        b.add_box_visual(half_size=CUBE_HALF, material=sapien.render.RenderMaterial(base_color=[0.75, 0.3, 0.2, 1]))
        b.initial_pose = sapien.Pose(p=[0.09, 0.05, 0.06])
        cube = b.build_kinematic(name="cube")
        from ..render import box_gaussians

        self.add_mpm_rigid("cube", cube, Box(half_extents=CUBE_HALF, friction=0.5),
                           gaussians=box_gaussians(CUBE_HALF, 2.5e-3))
        return cube

    def _block_offset(self) -> float:
        """Distance [m] from the face to the block centre along the face normal."""
        return self.block_half[2]

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        n = len(env_idx)
        rng = self._batched_episode_rng[common.to_numpy(env_idx)]
        q = torch.as_tensor(INDEX_READY, device=self.device).expand(n, 16)
        self.agent.robot.set_pose(sapien.Pose())
        self.agent.reset(self.action_order_to_qpos(q))
        gap = torch.as_tensor(rng.uniform(*self.gap_range), dtype=torch.float64).reshape(n)
        S = self.pad_frame(self.touch_pad)[common.to_numpy(env_idx)]  # apex frame, z out of the pad
        face = S.clone()
        face[:, :3, 3] = S[:, :3, 3] + gap[:, None] * S[:, :3, 2]
        self.face_frame[env_idx.cpu()] = face
        centre = face[:, :3, 3] + self._block_offset() * face[:, :3, 2]
        from ..transforms import matrix_to_quat

        quat = np.stack([matrix_to_quat(R) for R in face[:, :3, :3].numpy()])
        self.block.set_pose(batched_pose(centre.numpy(), quat))
        self._init_task(env_idx, rng)

    def _init_task(self, env_idx, rng) -> None:
        """Task-specific randomisation (targets)."""

    def _get_task_state(self):
        return {"face_frame": self.face_frame.clone()}

    def _set_task_state(self, state, env_idx):
        self.face_frame[env_idx] = state["face_frame"].to(self.face_frame)

    def apex_in_face(self) -> torch.Tensor:
        """[B, 3] index pad apex in the cube face frame (z < 0: in front of the face) [m]."""
        S = self.pad_frame(self.touch_pad)
        F = self.face_frame
        return (torch.linalg.inv(F) @ S)[:, :3, 3]


@register_env("GaussTac-PressCube-v1", max_episode_steps=40)
class PressCubeEnv(IndexCubeTask):
    """Press the index pad onto the cube until the pad's normal force is on target.

    Args:
        tolerance: success when |F - F_target| < tolerance * F_target (in [0.001, 1]).
        force_range: target force range (lo, hi) [N], 0.01 <= lo <= hi <= 50.
    """

    def __init__(self, *args, tolerance: float = 0.15, force_range=(0.8, 2.0), **kwargs):
        self.check_range("tolerance", tolerance, 1e-3, 1.0)
        self.tolerance = float(tolerance)
        self.force_range = check_pair(self._env_id(), "force_range", force_range, 0.01, 50.0, "N")
        super().__init__(*args, **kwargs)

    def _load_scene(self, options: dict):
        super()._load_scene(options)
        self.target_force = torch.ones(self.num_envs, device=self.device)

    def _init_task(self, env_idx, rng):
        self.target_force[env_idx] = torch.as_tensor(rng.uniform(*self.force_range), dtype=torch.float32,
                                                     device=self.device).reshape(len(env_idx))

    def _get_task_state(self):
        return {**super()._get_task_state(), "target_force": self.target_force.clone()}

    def _set_task_state(self, state, env_idx):
        super()._set_task_state(state, env_idx)
        self.target_force[env_idx] = state["target_force"].to(self.target_force)

    def evaluate(self):
        force = self.pad_force(self.touch_pad)
        err = (force - self.target_force).abs()
        return dict(success=err < self.tolerance * self.target_force, force=force,
                    force_error=err)

    def _get_obs_extra(self, info: dict):
        return dict(target_force=self.target_force[:, None])

    def compute_dense_reward(self, obs, action, info):
        dist = self.apex_in_face()[:, 2].clamp(max=0).abs().to(self.device, torch.float32)  # approach
        r_reach = 1 - torch.tanh(200.0 * dist)
        r_force = 1 - torch.tanh(2.0 * info["force_error"] / self.target_force)
        return r_reach + 2 * r_force + 2 * info["success"].float()

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info) / 5.0
