"""Scripted experts for the GaussTac tasks (for imitation-learning data and tests).

``make_expert(env)`` returns the expert of ``env``'s task; ``expert.act(obs)`` gives a
batched action ``[B, A]`` for the env's control mode (``pd_joint_pos`` or
``pd_joint_delta_pos``/``pd_joint_target_delta_pos``). Experts read the env's
privileged state (targets, tactile force sums), not only the observation.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from .errors import ConfigError

__all__ = ["Expert", "register_expert", "make_expert", "joint_targets_to_action", "EXPERTS"]

EXPERTS: dict[str, Callable] = {}


def register_expert(env_id: str):
    """Class decorator: the expert of task ``env_id``."""
    def deco(cls):
        EXPERTS[env_id] = cls
        return cls
    return deco


def make_expert(env) -> "Expert":
    """The scripted expert of ``env`` (a ``gym.make`` env, wrapped or not)."""
    base = env.unwrapped
    env_id = base.spec.id if base.spec is not None else None
    if env_id not in EXPERTS:
        raise ConfigError(f"no scripted expert for env {env_id!r}; experts exist for {sorted(EXPERTS)}")
    return EXPERTS[env_id](base)


def joint_targets_to_action(base, q_target: torch.Tensor) -> torch.Tensor:
    """Absolute joint targets ``[B, J]`` (action joint order, rad) -> action of ``base``'s
    control mode (delta modes: the step is clipped to the controller's limit)."""
    ctrl = base.agent.controller
    cfg = ctrl.config
    q_target = torch.as_tensor(q_target, dtype=torch.float32, device=base.device)
    if not getattr(cfg, "use_delta", False):
        return q_target
    ref = ctrl._target_qpos if getattr(cfg, "use_target", False) else base.qpos_in_action_order()
    # np.broadcast_to gives a read-only view, which torch would share and warn about: copy it
    low = torch.from_numpy(np.array(np.broadcast_to(cfg.lower, q_target.shape[-1:]), np.float32)).to(base.device)
    high = torch.from_numpy(np.array(np.broadcast_to(cfg.upper, q_target.shape[-1:]), np.float32)).to(base.device)
    delta = torch.minimum(torch.maximum(q_target - ref, low), high)
    if getattr(cfg, "normalize_action", True):
        delta = (delta - low) / (high - low) * 2 - 1
    return delta


class Expert:
    """Base of the scripted experts: ``reset()`` at episode start, ``act(obs)`` each step."""

    def __init__(self, env):
        self.env = env

    def reset(self) -> None:
        """Called after ``env.reset``."""

    def act(self, obs=None) -> torch.Tensor:  # pragma: no cover
        raise NotImplementedError


@register_expert("GaussTac-Gesture-v1")
class GestureExpert(Expert):
    """Drive the joints straight to the gesture."""

    def act(self, obs=None):
        return joint_targets_to_action(self.env, self.env.target_qpos)


class TipIK:
    """Position inverse kinematics of a pad's apex over some of the hand's joints.

    Damped least squares on a finite-difference Jacobian; forward kinematics from MuJoCo
    on the same URDF (:class:`~gausstac_maniskill.pose.MujocoPoseSource`), so the env's
    SAPIEN state is never touched. Positions are in the hand root frame [m].

    Args:
        env: a GaussTac env (unwrapped); its agent's pad URDF is loaded into MuJoCo.
        pad: pad id whose apex is placed.
        joints: names of the joints IK may move (others keep their value).
    """

    def __init__(self, env, pad: str, joints):
        geo = env.pad_geometry(pad)
        self.S = geo.sensor_frame
        self.src = _mujoco_source(type(env.agent).pad_urdf())
        self.link = self.src.link_names.index(geo.spec.link)
        self.action_names = list(env.agent.controller.config.joint_names)
        self.to_mj = [self.action_names.index(n) for n in self.src.joint_names]
        self.dofs = [self.action_names.index(j) for j in joints]
        self.limits = env.agent.robot.get_qlimits()[0, env.action_joint_index].detach().cpu().double().numpy()

    def frame(self, q: np.ndarray) -> np.ndarray:
        """4x4 pad sensor frame in the root frame for joint angles ``q`` (action order)."""
        self.src.set_joint_positions(np.asarray(q, np.float64)[self.to_mj])
        T = self.src.all_link_poses()[0, self.link].numpy()
        return T @ self.S

    def solve(self, q: np.ndarray, target: np.ndarray, normal: np.ndarray | None = None,
              normal_weight: float = 0.02, stay: float = 1.0e-3) -> np.ndarray:
        """Joint angles (action order) close to ``q``, within the joint limits, putting the
        apex at ``target`` and, given ``normal`` (unit, root frame), the pad's outward normal
        along it.

        Bounded least squares (``scipy.optimize.least_squares``) on
        ``[apex - target; normal_weight (n - normal); stay (q - q_start)]``: a pad normal off
        by 1 rad weighs as much as ``normal_weight`` [m] of position, so a finger whose
        joints cannot satisfy both (4 joints, 5 conditions) gives up a little of each; the
        ``stay`` term [m/rad] picks, among equal fits, the posture nearest ``q``."""
        from scipy.optimize import least_squares

        q = np.asarray(q, np.float64).copy()
        lo, hi = self.limits[self.dofs, 0], self.limits[self.dofs, 1]
        start = np.clip(q[self.dofs], lo + 1e-9, hi - 1e-9)
        target = np.asarray(target, np.float64)

        def residual(x):
            q[self.dofs] = x
            F = self.frame(q)
            r = [F[:3, 3] - target]
            if normal is not None:
                r.append(normal_weight * (F[:3, 2] - np.asarray(normal, np.float64)))
            r.append(stay * (x - start))
            return np.concatenate(r)

        fit = least_squares(residual, start, bounds=(lo, hi), xtol=1e-10, ftol=1e-12, max_nfev=60)
        q[self.dofs] = fit.x
        return q


_MJ_CACHE: dict = {}


def _mujoco_source(urdf: str):
    from .pose import MujocoPoseSource

    if urdf not in _MJ_CACHE:
        _MJ_CACHE[urdf] = MujocoPoseSource(urdf)
    return _MJ_CACHE[urdf]


def _world_to_root(env) -> np.ndarray:
    from .transforms import vec7_to_matrix

    T = vec7_to_matrix(env.agent.robot.pose.raw_pose).detach().cpu().double().numpy()
    return np.linalg.inv(T)


class _IndexFaceExpert(Expert):
    """Moves the index apex in the cube face frame: ``s`` along the face normal (0: touching
    the face, > 0: pressed in), ``t`` along the face's y axis (across the finger)."""

    joints = ("joint_0.0", "joint_1.0", "joint_2.0", "joint_3.0")
    approach_step = 1.0e-3   # m per control step before contact
    gain = 1.2e-4            # m of commanded depth per N of force error: about half the pad's contact
    #                          compliance against the face (0.43 mm at 1.66 N at dx = 2, 1.5 and 1 mm,
    #                          `bench resolution`), so the servo neither overshoots nor depends on dx
    max_depth_step = 3.0e-4  # m per step

    def reset(self):
        self.ik = TipIK(self.env, "index", self.joints)
        self.q_cmd = self.env.qpos_in_action_order().detach().cpu().double().numpy()
        a = self.env.apex_in_face().numpy()
        self.s = a[:, 2].copy()
        self.t = a[:, 1].copy()
        self.touched = np.zeros(len(self.s), bool)

    def track_force(self, target_force: np.ndarray) -> None:
        force = self.env.pad_force("index").cpu().numpy()
        self.touched |= force > 0.03
        for b in range(len(self.s)):
            if not self.touched[b]:
                self.s[b] = min(self.s[b] + self.approach_step, 0.25e-3 if self.s[b] < 0 else self.s[b] + 0.25e-3)
            else:
                self.s[b] += np.clip(self.gain * (target_force[b] - force[b]), -self.max_depth_step,
                                     self.max_depth_step)

    def command(self) -> torch.Tensor:
        env = self.env
        W2R = _world_to_root(env)
        for b in range(len(self.s)):
            face = env.face_frame[b].numpy()
            target_w = face[:3, 3] + face[:3, 2] * self.s[b] + face[:3, 1] * self.t[b]
            target = W2R[b, :3, :3] @ target_w + W2R[b, :3, 3]
            self.q_cmd[b] = self.ik.solve(self.q_cmd[b], target)
        return joint_targets_to_action(env, torch.as_tensor(self.q_cmd, dtype=torch.float32))


@register_expert("GaussTac-PressCube-v1")
class PressExpert(_IndexFaceExpert):
    """Approach the face, then servo the commanded depth on the pad's force."""

    def act(self, obs=None):
        self.track_force(self.env.target_force.cpu().numpy())
        return self.command()


@register_expert("GaussTac-SlideCube-v1")
class SlideExpert(_IndexFaceExpert):
    """Press to ``hold_force``, then move across the face 0.75 mm per step while servoing
    the force, until the slide distance (plus a margin) is covered."""

    hold_force = 1.0
    speed = 0.75e-3

    def reset(self):
        super().reset()
        self.sliding = np.zeros(len(self.s), bool)
        self.t0 = self.t.copy()

    def act(self, obs=None):
        env = self.env
        self.track_force(np.full(len(self.s), self.hold_force))
        force = env.pad_force("index").cpu().numpy()
        goal = env.slide_distance.numpy() + 1.0e-3
        for b in range(len(self.s)):
            if not self.sliding[b] and force[b] > 0.6 * self.hold_force:
                self.sliding[b] = True
            if self.sliding[b] and self.t[b] - self.t0[b] < goal[b]:
                self.t[b] += self.speed
        return self.command()


@register_expert("GaussTac-SqueezeSponge-v1")
class SqueezeExpert(_IndexFaceExpert):
    """Advance the apex into the sponge, servoing the measured compression."""

    def act(self, obs=None):
        env = self.env
        c = env.compression().numpy()
        target = env.target_compression.numpy()
        for b in range(len(self.s)):
            if self.s[b] < 0:
                self.s[b] = min(self.s[b] + self.approach_step, 0.0)
            else:
                self.s[b] += np.clip(0.8 * (target[b] - c[b]) * env.sponge_thickness, -0.5e-3, 0.75e-3)
        return self.command()


@register_expert("GaussTac-GraspLiftCube-v1")
class GraspLiftExpert(Expert):
    """Pinch the object between the thumb and index pads, lift it, hold it.

    Phases per env: ``descend`` (root straight down until the pinch point is at the object's
    centre), ``close`` (each pad's apex aimed, by IK on position and pad normal, at the
    middle of its face of the object and moved in ``approach_step`` per step until it
    touches; once both touch, their common depth is servoed: :meth:`_squeeze`), ``lift``
    (root up ``lift_step`` per step, still servoing) and ``hold``. The cube's grip force
    is physical, not tuned per resolution: ``safety`` times what Coulomb friction on two
    pads needs to carry the object, ``m g / (2 μ)``, and at least ``min_grip`` [N].
    Works on any :class:`~gausstac_maniskill.tasks.pinch_grasp.PinchGraspEnv`.
    """

    descend_step = 5.0e-3   # m per control step
    approach_step = 1.5e-3  # m per control step, before a pad touches
    lift_step = 3.0e-3      # m per control step
    gain = 2.0e-4           # m of commanded depth per N of force error (pad + finger compliance ~ 0.4 mm/N)
    max_depth_step = 3.0e-4  # m per control step
    safety = 2.0
    min_grip = 1.0          # N
    gap = 4.0e-3            # m: the pads start this far outside the faces
    max_joint_step = 0.1    # rad per control step of a finger joint's target (no swinging fingers)
    min_pinch_height = 0.02  # m above the ground: lower, the fingertips drag on the ground

    def reset(self):
        env = self.env
        self.thumb = TipIK(env, "thumb", ("joint_12.0", "joint_13.0", "joint_14.0", "joint_15.0"))
        self.index = TipIK(env, "index", ("joint_0.0", "joint_1.0", "joint_2.0", "joint_3.0"))
        self.q_cmd = env.qpos_in_action_order().detach().cpu().double().numpy()
        B = len(self.q_cmd)
        self.phase = np.array(["descend"] * B, dtype=object)
        self.depth = np.full((B, 2), -self.gap)  # commanded depth of (thumb, index) into their faces [m]
        self.touched = np.zeros((B, 2), bool)
        self.centre = [None] * B  # where the pads close, in the hand's base frame, fixed when closing began [m]
        g = float(np.linalg.norm(env.sim_config.scene_config.gravity))
        self.grip = max(self.min_grip, self.safety * env.object_mass * g / (2 * max(env.object_friction, 1e-3)))

    def act(self, obs=None):
        from .agents.allegro import ALLEGRO_PINCH_AXIS, ALLEGRO_PINCH_CENTRE

        env = self.env
        agent = type(env.agent)
        obj = env.object_centre().detach().cpu().double().numpy()
        # where the pads close: the object's centre, at least min_pinch_height above the ground
        grip_at = obj.copy()
        grip_at[:, 2] = np.maximum(grip_at[:, 2], self.min_pinch_height)
        forces = np.stack([env.touch_force("thumb").cpu().numpy(), env.touch_force("index").cpu().numpy()], axis=1)
        self._observe()
        h = env.pinch_half_width
        for b in range(len(self.q_cmd)):
            base = agent.base_pose(self.q_cmd[b, :6])  # commanded: the root drives are stiff
            pinch = base[:3, :3] @ np.asarray(ALLEGRO_PINCH_CENTRE) + base[:3, 3]
            if self.phase[b] == "descend":
                drop = pinch[2] - grip_at[b, 2]
                self.q_cmd[b, 2] -= min(self.descend_step, max(drop, 0.0))
                if drop <= 1e-4:
                    self.phase[b] = "close"
            else:
                self.touched[b] |= forces[b] > env.grasp_force
                if not np.all(self.touched[b]):  # move each pad in until it touches
                    self.depth[b, ~self.touched[b]] += self.approach_step
                else:  # then one common depth (the object between them centres itself, where
                    # the pads' forces balance: `bench hold`)
                    self.depth[b] += np.clip(self._squeeze(b, forces[b]), -self.max_depth_step, self.max_depth_step)
                if self.phase[b] == "close" and np.all(self.touched[b]) and self._ready_to_lift(b, forces[b]):
                    self.phase[b] = "lift"
                if self.phase[b] == "lift":
                    if obj[b, 2] - env.object_rest_height < env.lift_height + 5.0e-3:
                        self.q_cmd[b, 2] += self.lift_step
                    else:
                        self.phase[b] = "hold"
                base = agent.base_pose(self.q_cmd[b, :6])
            # the pads' targets on the object's faces, base frame: around the pinch point while
            # descending, then around where the object was when closing began (fixed in the
            # hand: targets that followed the object would chase it between the pads)
            u = np.asarray(ALLEGRO_PINCH_AXIS, np.float64)
            if self.phase[b] == "descend":
                centre = np.asarray(ALLEGRO_PINCH_CENTRE, np.float64)
            else:
                if self.centre[b] is None:
                    to_base = np.linalg.inv(base)
                    self.centre[b] = to_base[:3, :3] @ grip_at[b] + to_base[:3, 3]
                centre = self.centre[b]
            q = self.q_cmd[b].copy()
            for k, (ik, sign) in enumerate(((self.thumb, -1.0), (self.index, 1.0))):
                q = ik.solve(q, centre + sign * (h - self.depth[b, k]) * u, normal=-sign * u)
            step = np.clip(q[6:] - self.q_cmd[b, 6:], -self.max_joint_step, self.max_joint_step)
            self.q_cmd[b, 6:] += step
        return joint_targets_to_action(env, torch.as_tensor(self.q_cmd, dtype=torch.float32))

    def _observe(self) -> None:
        """Read what :meth:`_squeeze` needs for this step (all envs at once)."""

    def _squeeze(self, b: int, force: np.ndarray) -> float:
        """Change [m] of the pads' common depth once both touch: servo the mean normal force
        on the grip (servoing each pad on its own force would push the object back and forth)."""
        return self.gain * (self.grip - force.mean())

    def _ready_to_lift(self, b: int, force: np.ndarray) -> bool:
        return force.mean() > 0.8 * self.grip


@register_expert("GaussTac-GraspSqueezeSponge-v1")
class GraspSqueezeExpert(GraspLiftExpert):
    """The pinch-and-lift of :class:`GraspLiftExpert` with the pads' common depth servoed
    on the sponge's measured compression instead of a force: each pad moves in
    ``squeeze_gain`` of the compression error times the sponge's half width per step.
    Lifts once the compression is within half the task's tolerance."""

    squeeze_gain = 0.8
    max_depth_step = 6.0e-4  # m per control step

    def _observe(self) -> None:
        self.error = (self.env.target_compression - self.env.compression()).numpy()

    def _squeeze(self, b: int, force: np.ndarray) -> float:
        return self.squeeze_gain * self.error[b] * self.env.pinch_half_width

    def _ready_to_lift(self, b: int, force: np.ndarray) -> bool:
        return abs(self.error[b]) < 0.5 * self.env.tolerance
