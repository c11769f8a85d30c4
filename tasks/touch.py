"""``GaussTac-Touch-v1``: a sandbox for any GaussTac hand — one cube in front of one pad.

The hand starts open (its ``rest`` keyframe, else zero joint angles) with its root at the origin; a
cube is placed ``cube_gap`` [m] in front of the apex of pad ``touch_pad``, along the pad's outward
normal. ``free_cube=False`` (default): the cube is kinematic, one face parallel to the pad.
``free_cube=True``: the cube is dynamic and upright on a small fixed pedestal, ``cube_gap`` beyond
the pad's front-most point along the horizontal part of the pad normal (the pad must not face
straight up or down), registered with ``two_way=two_way`` so that a pad can push it.

With a two-way cube ``pad_reaction`` defaults to ``True``: the push reaches the cube through one
implicit spring (:mod:`.contact_spring`) and the hand through its joint drives (:mod:`.joint_contact`).
``pad_reaction=False`` couples explicitly (one pad step's wrench acts as a force in the next SAPIEN
step), stable only for a cube mass m > k·dt²/4 (k the pad's contact stiffness, dt the SAPIEN
timestep; a lighter cube gets a warning). ``success``: the touch pad's normal force exceeds
``force_threshold``; ``info`` also has every pad's force and the cube's displacement. Units: SI.
"""
from __future__ import annotations

import warnings

import numpy as np
import sapien
import torch
from mani_skill.utils import common
from mani_skill.utils.registration import register_env

from ..errors import ConfigError
from ..geometry.colliders import Box
from ..physx import batched_pose
from ..task_checks import check_flag
from ..transforms import matrix_to_quat
from .base import GaussTacEnv

__all__ = ["TouchEnv"]

#: Contact stiffness [N/m] of a default pad (2 mm, 0.3 MPa) pressed on a cube face, measured
#: (Ability index pad: 0.3 N at 0.3 mm, 1.5 N at 1.8 mm, 4 N at 2.7 mm); sets the two-way
#: stability bound.
_PAD_CONTACT_STIFFNESS = 2.0e3


@register_env("GaussTac-Touch-v1", max_episode_steps=100)
class TouchEnv(GaussTacEnv):
    """A cube in front of one pad of any GaussTac hand (see the module docstring).

    Args:
        touch_pad: the pad the cube faces (default: ``"index"`` if the hand has one, else
            its first pad).
        cube_half_size: half edge of the cube [m].
        cube_gap: distance from the pad apex (free cube: the pad's front-most point) to the
            cube face at reset [m] (may be < 0 to start pressed in).
        free_cube: dynamic cube on a pedestal instead of a fixed one.
        two_way: with ``free_cube``, apply the pads' reaction wrench to the cube in SAPIEN.
        pad_reaction: as :class:`~gausstac_maniskill.tasks.base.GaussTacEnv`; default
            (None): ``True`` (implicit coupling) with a two-way cube, else ``False``.
        cube_density: [kg/m^3] (free cube; default steel).
        cube_friction: Coulomb friction of the cube, in SAPIEN (with the pedestal) and
            against the pads in the MPM.
        ground: a ground plane at ``ground_altitude`` [m] (in [-1, 0]: below the hand; looks only).
        force_threshold: touch pad normal force [N] above which ``success`` is true.
        init_qpos: initial joint positions (articulation qpos order) overriding the
            hand's ``rest`` keyframe.
    """

    SUPPORTED_ROBOTS = ["allegro_hand_right_gausstac", "floating_ability_hand_right_gausstac"]

    def __init__(self, *args, touch_pad: str | None = None, cube_half_size: float = 0.01,
                 cube_gap: float = 0.003, free_cube: bool = False, two_way: bool = True,
                 cube_density: float = 7800.0, cube_friction: float = 0.5, ground: bool = True,
                 ground_altitude: float = -0.15, force_threshold: float = 0.05, init_qpos=None,
                 pad_reaction=None, **kwargs):
        task = self._env_id()
        for name, v, lo, hi, unit in (("cube_half_size", cube_half_size, 1e-3, 0.2, "m"),
                                      ("cube_gap", cube_gap, -0.01, 0.2, "m"),
                                      ("cube_density", cube_density, 1.0, 1e5, "kg/m^3"),
                                      ("cube_friction", cube_friction, 0.0, 10.0, ""),
                                      ("force_threshold", force_threshold, 0.0, 1e4, "N"),
                                      ("ground_altitude", ground_altitude, -1.0, 0.0, "m")):
            self.check_range(name, v, lo, hi, unit)
        for name, v in (("free_cube", free_cube), ("two_way", two_way), ("ground", ground)):
            check_flag(task, name, v)
        if touch_pad is not None and not isinstance(touch_pad, str):
            raise ConfigError(f"{task}: touch_pad={touch_pad!r} must be a pad name (str) or None")
        if init_qpos is not None:
            try:
                q = np.asarray(init_qpos, np.float32)
            except (TypeError, ValueError):
                q = np.zeros((0, 0), np.float32)
            if q.ndim != 1 or not np.all(np.isfinite(q)):
                raise ConfigError(f"{task}: init_qpos={init_qpos!r} must be one finite joint angle [rad] per joint "
                                  "(articulation qpos order)")
        self.touch_pad_arg = touch_pad
        self.cube_half = float(cube_half_size)
        self.cube_gap = float(cube_gap)
        self.free_cube = bool(free_cube)
        self.two_way = bool(two_way) and self.free_cube
        self.cube_density = float(cube_density)
        self.cube_friction = float(cube_friction)
        self.ground_altitude = float(ground_altitude) if ground else None  # read by GaussTacEnv._load_scene
        self.force_threshold = float(force_threshold)
        self.init_qpos = None if init_qpos is None else np.asarray(init_qpos, np.float32)
        if pad_reaction is None:  # a two-way cube is pushed through the implicit springs
            pad_reaction = self.two_way
        super().__init__(*args, pad_reaction=pad_reaction, **kwargs)

    # ------------------------------------------------------------------ scene
    def _splat_camera_pose(self):
        from mani_skill.utils import sapien_utils

        return sapien_utils.look_at(eye=[0.28, -0.16, 0.26], target=[0.0, 0.02, 0.13])

    def _load_scene(self, options: dict):
        super()._load_scene(options)
        pads = self.pad_names
        if self.touch_pad_arg is None:
            self.touch_pad = "index" if "index" in pads else pads[0]
        elif self.touch_pad_arg not in pads:
            raise ConfigError(f"touch_pad={self.touch_pad_arg!r} is not a pad of {self.agent.uid!r}; pads: {pads}")
        else:
            self.touch_pad = self.touch_pad_arg
        if self.init_qpos is not None and self.init_qpos.shape[-1] != self.agent.robot.max_dof:
            raise ConfigError(f"init_qpos has {self.init_qpos.shape[-1]} values; {self.agent.uid!r} has "
                              f"{int(self.agent.robot.max_dof)} joints (qpos order)")
        h = self.cube_half
        mat = sapien.physx.PhysxMaterial(self.cube_friction, self.cube_friction, 0.0)
        b = self.scene.create_actor_builder()
        b.add_box_collision(half_size=[h] * 3, material=mat, density=self.cube_density)
        b.add_box_visual(half_size=[h] * 3, material=sapien.render.RenderMaterial(base_color=[0.8, 0.35, 0.2, 1]))
        self.cube = b.build(name="cube") if self.free_cube else b.build_kinematic(name="cube")
        if self.two_way and self.pad_coupling != "implicit":
            m_min = _PAD_CONTACT_STIFFNESS * self.sim_timestep ** 2 / 4  # the MPM steps with SAPIEN
            mass = self.cube_density * (2 * h) ** 3
            if mass < m_min:
                warnings.warn(f"GaussTac-Touch-v1: free cube of {mass * 1e3:.3g} g is lighter than "
                              f"~{m_min * 1e3:.3g} g, the least the explicit two-way coupling keeps stable at "
                              f"{1 / self.sim_timestep:g} Hz simulation; expect the pad to push it in jumps "
                              "(raise cube_density or sim_freq, or keep pad_reaction=True, the implicit coupling)")
        from ..render import box_gaussians

        self.add_mpm_rigid("cube", self.cube, Box(half_extents=(h, h, h), friction=self.cube_friction),
                           gaussians=box_gaussians((h, h, h), 2.5e-3), two_way=self.two_way)
        self.pedestal = None
        if self.free_cube:
            # top at the cube's bottom, from half a half-edge behind the cube's pad-side face (the
            # cube overhangs towards the pad, so the hand's lower links stay clear) to 3 half-edges
            # beyond its centre, along the push direction
            self._pedestal_half = np.array([1.75 * h, 1.5 * h, 0.005])
            pb = self.scene.create_actor_builder()
            pb.add_box_collision(half_size=self._pedestal_half, material=mat)
            pb.add_box_visual(half_size=self._pedestal_half,
                              material=sapien.render.RenderMaterial(base_color=[0.5, 0.5, 0.55, 1]))
            self.pedestal = pb.build_kinematic(name="pedestal")
        self.cube_start = torch.zeros(self.num_envs, 3, device=self.device)

    def _rest_qpos(self) -> torch.Tensor:
        if self.init_qpos is not None:
            q = self.init_qpos
        elif "rest" in getattr(self.agent, "keyframes", {}):
            q = np.asarray(self.agent.keyframes["rest"].qpos, np.float32)
        else:
            q = np.zeros(int(self.agent.robot.max_dof), np.float32)
        return torch.as_tensor(q, dtype=torch.float32, device=self.device)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        n = len(env_idx)
        self.agent.robot.set_pose(sapien.Pose())
        self.agent.reset(self._rest_qpos().expand(n, -1).clone())
        S = self.pad_frame(self.touch_pad)[common.to_numpy(env_idx)]  # [n, 4, 4] apex, z = outward normal
        apex, normal = S[:, :3, 3].numpy(), S[:, :3, 2].numpy()
        h, gap = self.cube_half, self.cube_gap
        if not self.free_cube:
            centre = apex + (gap + h) * normal
            quat = np.stack([matrix_to_quat(R) for R in S[:, :3, :3].numpy()])
        else:
            horiz = normal.copy()
            horiz[:, 2] = 0.0
            norm = np.linalg.norm(horiz, axis=1, keepdims=True)
            if np.any(norm < 0.3):
                raise ConfigError(f"free_cube: pad {self.touch_pad!r} faces up or down (normal {normal[0].round(3)}); "
                                  "a resting cube can only be placed beside a pad that faces sideways")
            horiz /= norm
            # the pad point furthest along ``horiz`` (the apex is on the sensor plane, not
            # necessarily on the pad's surface): the cube face goes ``gap`` beyond it
            geo = self.pad_geometry(self.touch_pad)
            link = S.numpy() @ np.linalg.inv(geo.sensor_frame)  # [n, 4, 4] pad link poses
            pts = np.einsum("nij,pj->npi", link[:, :3, :3], geo.rest) + link[:, None, :3, 3]  # [n, P, 3]
            front = np.argmax(np.einsum("npi,ni->np", pts, horiz), axis=1)
            tip = pts[np.arange(n), front] + 0.5 * geo.spacing * horiz
            centre = tip + (gap + h) * horiz
            yaw = np.arctan2(horiz[:, 1], horiz[:, 0])
            quat = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], 1)
            ped = centre + horiz * (self._pedestal_half[0] - 0.5 * h)
            ped[:, 2] = centre[:, 2] - h - self._pedestal_half[2]
            self.pedestal.set_pose(batched_pose(ped, quat))
        self.cube.set_pose(batched_pose(centre, quat))
        if self.free_cube:
            self.cube.set_linear_velocity(torch.zeros(n, 3))
            self.cube.set_angular_velocity(torch.zeros(n, 3))
        self.cube_start[env_idx] = torch.as_tensor(centre, dtype=torch.float32, device=self.device)

    def _get_task_state(self):
        return {"cube_start": self.cube_start.clone()}

    def _set_task_state(self, state, env_idx):
        self.cube_start[env_idx] = state["cube_start"].to(self.cube_start)

    # ------------------------------------------------------------------ task
    def cube_displacement(self) -> torch.Tensor:
        """[B, 3] cube centre displacement since the episode start [m]."""
        return self.cube.pose.p - self.cube_start

    def apex_distance(self) -> torch.Tensor:
        """[B] distance [m] from the touch pad's apex to the cube surface (0 inside)."""
        S = self.pad_frame(self.touch_pad).to(torch.float32)
        q = self.cube.pose.to_transformation_matrix().cpu().to(torch.float32)
        local = (torch.linalg.inv(q) @ S)[:, :3, 3]
        return (local.abs() - self.cube_half).clamp(min=0).norm(dim=1).to(self.device)

    def evaluate(self):
        forces = torch.stack([self.pad_force(p) for p in self.pad_names], dim=1).to(self.device)
        force = forces[:, self.pad_names.index(self.touch_pad)]
        return dict(success=force > self.force_threshold, pad_force=force, pad_forces=forces,
                    cube_displacement=self.cube_displacement().norm(dim=1))

    def _get_obs_extra(self, info: dict):
        return dict(cube_pose=self.cube.pose.raw_pose, pad_apex=self.pad_frame(self.touch_pad)[:, :3, 3]
                    .to(device=self.device, dtype=torch.float32))

    def compute_dense_reward(self, obs, action, info):
        reach = 1.0 - torch.tanh(100.0 * self.apex_distance())
        return reach + torch.tanh(info["pad_force"] / max(self.force_threshold, 1e-6)) + info["success"].float()

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info) / 3.0
