"""Link poses read from a ManiSkill (SAPIEN) articulation, batched over its envs."""
from __future__ import annotations

import numpy as np
import torch

from ..errors import ConfigError
from ..transforms import vec7_to_matrix
from .base import PoseSource


def _find_articulation(obj):
    """The ManiSkill ``Articulation`` behind an env, a wrapped env, an agent or itself."""
    if hasattr(obj, "unwrapped") and hasattr(obj.unwrapped, "agent"):
        obj = obj.unwrapped.agent
    if hasattr(obj, "robot"):
        obj = obj.robot
    if not (hasattr(obj, "links") and hasattr(obj, "get_active_joints")):
        raise ConfigError(
            f"SapienPoseSource needs a ManiSkill env, agent or Articulation, got {type(obj).__name__}")
    return obj


class SapienPoseSource(PoseSource):
    """Link poses of a ManiSkill robot, ``[B, L, 4, 4]`` on the simulator's device.

    Args:
        source: a ManiSkill env (``env.unwrapped.agent`` is used), an agent
            (its ``.robot``) or an ``Articulation``.

    ``link_names`` are the URDF link names in ManiSkill's link order;
    ``joint_names`` / ``joint_limits`` (``[J, 2]``, radians) follow the
    articulation's active-joint (qpos) order, which for the Allegro is
    0, 4, 8, 12, 1, 5, ... — map joints by name, not by position.
    Poses are read live: call :meth:`link_poses` after each sim step.
    """

    def __init__(self, source):
        self.robot = _find_articulation(source)
        self._links = list(self.robot.links)
        self.link_names = [link.name for link in self._links]
        self.joint_names = [j.name for j in self.robot.get_active_joints()]
        limits = self.robot.get_qlimits()
        limits = limits.detach().cpu().numpy() if isinstance(limits, torch.Tensor) else np.asarray(limits)
        self.joint_limits = np.asarray(limits, dtype=np.float64).reshape(-1, len(self.joint_names), 2)[0]
        self.num_envs = int(self.robot.pose.raw_pose.shape[0])

    def joint_positions(self) -> torch.Tensor:
        """Current joint positions ``[B, J]``, radians, in ``joint_names`` order."""
        return self.robot.get_qpos()

    def all_link_poses(self) -> torch.Tensor:
        """World transforms of every link, ``[B, L, 4, 4]`` (simulator dtype, float32)."""
        raw = torch.stack([link.pose.raw_pose for link in self._links], dim=1)  # [B, L, 7]
        return vec7_to_matrix(raw)
