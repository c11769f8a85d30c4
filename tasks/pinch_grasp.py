"""Shared scene of the pinch-grasp tasks: the floating Allegro hand above one free object on
the ground, pinch axis (thumb -> index) along world +y.

A task subclass builds its object in ``_load_scene``, places it in :meth:`_place_object`
and says where it is (:meth:`object_centre`), how wide it is across the pinch
(:attr:`pinch_half_width`), its mass and friction (what the grip must carry), and which
pad force counts as touching (:meth:`touch_force`). This class places the hand, counts
the hold and gives the reach/grasp/lift/hold reward terms.
"""
from __future__ import annotations

import numpy as np
import sapien
import torch
from mani_skill.utils import common

from ..task_checks import check_range
from .base import GaussTacEnv

__all__ = ["PinchGraspEnv", "OPEN_HAND", "check_range"]

#: Open hand (action order of the 16 finger joints, rad): index and thumb a few mm outside
#: a 20 mm cube at the pinch point, the other fingers relaxed.
OPEN_HAND = np.array([0.47, 1.45, 0.1, -0.1, 0.0, 0.1, 0.1, 0.1, 0.0, 0.1, 0.1, 0.1, 0.97, 0.07, 0.2, -0.1], np.float32)


class PinchGraspEnv(GaussTacEnv):
    """The floating hand and one free object on the ground (see the module docstring).

    Args:
        lift_height: height [m] above rest that counts as lifted.
        hold_time: time [s] the object must stay lifted and grasped.
        grasp_force: normal force [N] above which a pad counts as touching.
        approach_height: start height [m] of the pinch point above the object's centre.
        xy_range: the object's centre is drawn in [-xy_range, xy_range]² [m].
        pad_reaction: as :class:`~gausstac_maniskill.tasks.base.GaussTacEnv`; ``True`` here
            (without it the fingers feel nothing and crush the pads).
    """

    SUPPORTED_ROBOTS = ["floating_allegro_hand_right_gausstac"]
    ground_altitude = 0.0

    def __init__(self, *args, robot_uids="floating_allegro_hand_right_gausstac", lift_height: float = 0.05,
                 hold_time: float = 2.0, grasp_force: float = 0.05, approach_height: float = 0.04,
                 xy_range: float = 0.01, pad_reaction=True, **kwargs):
        self.check_range("lift_height", lift_height, 0.0, 0.2, "m")
        self.check_range("hold_time", hold_time, 0.0, 20.0, "s")
        self.check_range("grasp_force", grasp_force, 0.0, 100.0, "N")
        self.check_range("approach_height", approach_height, 0.0, 0.1, "m")
        self.check_range("xy_range", xy_range, 0.0, 0.05, "m")
        self.lift_height, self.hold_time = float(lift_height), float(hold_time)
        self.grasp_force, self.approach_height, self.xy_range = float(grasp_force), float(approach_height), float(xy_range)
        super().__init__(*args, robot_uids=robot_uids, pad_reaction=pad_reaction, **kwargs)

    def _splat_camera_pose(self):
        from mani_skill.utils import sapien_utils

        return sapien_utils.look_at(eye=[0.3, -0.25, 0.25], target=[0.0, 0.0, 0.06])

    # ------------------------------------------------------------------ object (subclass)
    @property
    def object_mass(self) -> float:
        """The object's mass [kg]."""
        raise NotImplementedError

    @property
    def object_friction(self) -> float:
        """Coulomb friction between the pads and the object."""
        raise NotImplementedError

    @property
    def pinch_half_width(self) -> float:
        """Half the object's rest extent [m] along the pinch axis."""
        raise NotImplementedError

    @property
    def object_rest_height(self) -> float:
        """Height [m] of the object's centre when it rests on the ground."""
        raise NotImplementedError

    def object_centre(self) -> torch.Tensor:
        """[B, 3] world position [m] of the object's centre (float32, env device)."""
        raise NotImplementedError

    def _place_object(self, env_idx: torch.Tensor, centre: np.ndarray) -> None:
        """Put the object of envs ``env_idx`` at rest with its centre at ``centre`` [n, 3] m."""
        raise NotImplementedError

    def touch_force(self, pad: str) -> torch.Tensor:
        """[B] normal force [N] of ``pad`` on the object (what ``grasp_force`` is compared with)."""
        return self.pad_force(pad)

    def _hold_condition(self) -> torch.Tensor:
        """[B] bool (CPU): extra condition of a hold step (default: none)."""
        return torch.ones(self.num_envs, dtype=torch.bool)

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict):
        super()._load_scene(options)
        self.hold_steps = torch.zeros(self.num_envs, dtype=torch.int32)

    @property
    def hold_steps_needed(self) -> int:
        """Control steps the object must stay lifted and grasped."""
        return int(np.ceil(self.hold_time * self.control_freq - 1e-9))

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        from ..agents.allegro import ALLEGRO_PINCH_CENTRE, pinch_down_rotation

        n = len(env_idx)
        rng = self._batched_episode_rng[common.to_numpy(env_idx)]
        xy = np.asarray(rng.uniform(-self.xy_range, self.xy_range, size=2)).reshape(n, 2)
        centre = np.concatenate([xy, np.full((n, 1), self.object_rest_height)], axis=1)
        self._place_object(env_idx, centre)
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
    def object_height(self) -> torch.Tensor:
        """[B] height [m] of the object's centre above its resting height."""
        return self.object_centre()[:, 2] - self.object_rest_height

    def pinch_point(self) -> torch.Tensor:
        """[B, 3] world position [m] of the hand's pinch point (between thumb and index pads)."""
        from ..agents.allegro import ALLEGRO_PINCH_CENTRE

        names = self._pose_source.link_names
        P = self._pose_source.all_link_poses()[:, names.index("base_link")].detach().cpu().double()
        c = torch.as_tensor([*ALLEGRO_PINCH_CENTRE, 1.0], dtype=torch.float64)
        return (P @ c)[:, :3].float().to(self.device)

    def grasped(self) -> torch.Tensor:
        """[B] the thumb and the index or middle pad touch the object (normal force above ``grasp_force``)."""
        thumb = self.touch_force("thumb") > self.grasp_force
        finger = torch.maximum(self.touch_force("index"), self.touch_force("middle")) > self.grasp_force
        return thumb & finger

    def _after_control_step(self):
        super()._after_control_step()
        held = self.grasped().cpu() & (self.object_height().cpu() >= self.lift_height) & self._hold_condition()
        self.hold_steps = torch.where(held, self.hold_steps + 1, torch.zeros_like(self.hold_steps))

    def _pinch_info(self) -> dict:
        height = self.object_height()
        return dict(success=(self.hold_steps >= self.hold_steps_needed).to(self.device),
                    grasped=self.grasped(), lifted=height >= self.lift_height, height=height,
                    hold_time=(self.hold_steps.float() / self.control_freq).to(self.device))

    def _get_task_state(self):
        return {"hold_steps": self.hold_steps.clone()}

    def _set_task_state(self, state, env_idx):
        self.hold_steps[env_idx] = state["hold_steps"].to(self.hold_steps)

    def _pinch_reward(self, info: dict) -> torch.Tensor:
        """reach (pinch point to object centre, 0..1) + grasp (0..1) + 2 lift (height
        fraction while grasped) + 2 hold (held time fraction)."""
        reach = 1 - torch.tanh(10.0 * (self.pinch_point() - self.object_centre()).norm(dim=1))
        grasp = info["grasped"].float()
        lift = (info["height"] / self.lift_height).clamp(0.0, 1.0) * grasp if self.lift_height > 0 else grasp
        hold = (info["hold_time"] / self.hold_time).clamp(max=1.0) if self.hold_time > 0 else info["lifted"].float()
        return reach + grasp + 2 * lift + 2 * hold
