"""``GaussTac-Gesture-v1``: bring the Allegro hand to a named gesture.

No object: every pad sleeps, so the step costs what SAPIEN costs plus a few
milliseconds; the tactile maps read zero. Success when every joint is within
``tolerance`` (rad) of the gesture. The gesture is drawn per episode from the seed
unless ``gesture=`` fixes it.
"""
from __future__ import annotations

import numpy as np
import sapien
import torch
from mani_skill.utils import common
from mani_skill.utils.registration import register_env

from ..errors import ConfigError
from .base import GaussTacEnv

__all__ = ["GestureEnv", "GESTURES"]

def _pose(**q) -> np.ndarray:
    v = np.zeros(16, np.float32)
    for name, val in q.items():
        v[int(name[1:])] = val
    return v


_CURL = dict(j1=1.3, j2=1.4, j3=1.1, j5=1.3, j6=1.4, j7=1.1, j9=1.3, j10=1.4, j11=1.1)
#: Joint targets [rad] in action order (joint_0.0 ... joint_15.0).
GESTURES = {
    "open": _pose(j12=0.3),
    # the thumb lies beside the curled fingers: opposed further, it blocks the middle finger
    "fist": _pose(**_CURL, j12=0.6, j13=0.1, j14=0.4, j15=0.4),
    "point": _pose(**{k: v for k, v in _CURL.items() if k not in ("j1", "j2", "j3")}, j12=1.1, j13=0.5, j14=0.8, j15=0.7),
    "peace": _pose(j0=-0.25, j4=0.25, j9=1.3, j10=1.4, j11=1.1, j12=1.1, j13=0.5, j14=0.8, j15=0.7),
    "thumbs_up": _pose(**_CURL, j12=0.3, j13=-0.1, j14=0.0, j15=0.0),
    "spread": _pose(j0=-0.4, j4=0.0, j8=0.4, j12=0.5, j13=0.0),
}


@register_env("GaussTac-Gesture-v1", max_episode_steps=50)
class GestureEnv(GaussTacEnv):
    """Reach a target hand gesture (one of :data:`GESTURES`).

    Args:
        gesture: fix the gesture (default: drawn per episode from the seed).
        tolerance: success when max |q - q_target| < tolerance [rad].
    """

    def __init__(self, *args, gesture: str | None = None, tolerance: float = 0.05, **kwargs):
        if gesture is not None and not (isinstance(gesture, str) and gesture in GESTURES):
            raise ConfigError(f"gesture={gesture!r} is not a known gesture; choose from {sorted(GESTURES)}")
        self.check_range("tolerance", tolerance, 1e-4, 1.0, "rad")
        self.gesture_names = sorted(GESTURES)
        self.fixed_gesture = gesture
        self.tolerance = float(tolerance)
        super().__init__(*args, **kwargs)

    def _splat_camera_pose(self):
        from mani_skill.utils import sapien_utils

        return sapien_utils.look_at(eye=[0.3, -0.1, 0.28], target=[0.0, 0.03, 0.05])

    def _load_scene(self, options: dict):
        super()._load_scene(options)
        self._targets = torch.as_tensor(np.stack([GESTURES[n] for n in self.gesture_names]), device=self.device)
        self.gesture_index = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        b = len(env_idx)
        if self.fixed_gesture is not None:
            idx = torch.full((b,), self.gesture_names.index(self.fixed_gesture), dtype=torch.long)
        else:
            idx = torch.as_tensor(self._batched_episode_rng[common.to_numpy(env_idx)].randint(0, len(GESTURES)),
                                  dtype=torch.long).reshape(b)
        self.gesture_index[env_idx] = idx.to(self.device)
        q0 = torch.as_tensor(GESTURES["open"], device=self.device)
        self.agent.reset(self.action_order_to_qpos(q0.expand(b, 16)))
        self.agent.robot.set_pose(sapien.Pose())

    @property
    def target_qpos(self) -> torch.Tensor:
        """[B, 16] gesture joint targets in action order."""
        return self._targets[self.gesture_index]

    def joint_error(self) -> torch.Tensor:
        """[B, 16] |q - q_target| in action order."""
        return (self.qpos_in_action_order() - self.target_qpos).abs()

    def evaluate(self):
        err = self.joint_error()
        return dict(success=err.max(dim=1).values < self.tolerance, max_joint_error=err.max(dim=1).values)

    def _get_obs_extra(self, info: dict):
        onehot = torch.nn.functional.one_hot(self.gesture_index, len(GESTURES)).float()
        return dict(target_qpos=self.target_qpos, gesture=onehot)

    def compute_dense_reward(self, obs, action, info):
        r = 1.0 - torch.tanh(3.0 * self.joint_error().mean(dim=1))
        return r + info["success"].float()

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info) / 2.0
