"""Link poses from MuJoCo: a URDF hand (default: ManiSkill's Allegro right hand)
with one position actuator per joint.

The URDF is loaded as ManiSkill ships it: a ``<mujoco><compiler .../></mujoco>``
block inserted after ``<robot>`` sets the mesh folder, balances the inertias and
keeps every link a body (``fusestatic="false"``, so the fixed ``*_tip`` links
stay bodies with their own poses). The hand's root is welded to the world at
``base_pose``; move it with :meth:`MujocoPoseSource.set_base_pose`.
"""
from __future__ import annotations

import re
from pathlib import Path

import mujoco
import numpy as np
import torch

from ..errors import AssetError, ConfigError, SimulationError
from ..transforms import as_pose_matrix, matrix_to_quat
from ..urdf import default_hand_urdf
from .base import PoseSource, resolve_names

#: Palm <-> finger-base pairs whose collision boxes overlap at rest.
ALLEGRO_CONTACT_EXCLUDES = tuple(("base_link", f"link_{i}.0") for i in (0, 4, 8, 12))


def load_urdf_spec(urdf_path) -> mujoco.MjSpec:
    """Parse a URDF into an editable ``MjSpec`` (meshes resolved next to the URDF).

    Raises AssetError naming the file when it is missing or MuJoCo rejects it.
    """
    path = Path(urdf_path)
    if not path.is_file():
        raise AssetError(f"URDF file not found: {path}")
    text = path.read_text()
    compiler = ('<mujoco><compiler meshdir="{}" balanceinertia="true" '
                'discardvisual="false" fusestatic="false"/></mujoco>')
    meshdir = str(path.resolve().parent).replace('"', "&quot;")
    text, n = re.subn(r"(<robot\b[^>]*>)", lambda m: m.group(1) + compiler.format(meshdir),
                      text, count=1)
    if n == 0:
        raise AssetError(f"{path} is not a URDF: no <robot> element")
    try:
        return mujoco.MjSpec.from_string(text)
    except ValueError as err:
        raise AssetError(f"MuJoCo could not load URDF {path}: {err}") from err


class MujocoPoseSource(PoseSource):
    """A URDF hand simulated by MuJoCo, position-controlled joint by joint.

    Args:
        urdf_path: URDF file; default ManiSkill's Allegro right hand.
        base_pose: ``[4, 4]`` world transform of the root link (metres); default identity.
        kp: actuator stiffness, N·m/rad. The Allegro's distal links have ~2e-5 kg·m²
            joint inertia, so kp = 3 gives ~60 Hz joint bandwidth while staying
            stable at the 2 ms time step (measured: kp = 10 stable, 30 diverges).
        dampratio: actuator damping as a fraction of critical (1 = critically damped).
        timestep: MuJoCo time step, seconds.
        gravity: world gravity, m/s² (the hand is welded to the world).
        gravity_compensation: cancel gravity on the hand's links (as the Allegro's
            own controller does), so targets are tracked without a steady sag.
        contact_excludes: body-name pairs never in contact; default the Allegro palm
            <-> finger-base pairs (pairs naming absent bodies are skipped only for the default).

    The model/data split mirrors MuJoCo's: ``self.model`` (``MjModel``) is the
    description, ``self.data`` (``MjData``) the state. ``num_envs`` is 1.
    """

    def __init__(self, urdf_path=None, base_pose=None, kp: float = 3.0,
                 dampratio: float = 1.0, timestep: float = 0.002,
                 gravity=(0.0, 0.0, -9.81), gravity_compensation: bool = True,
                 contact_excludes=None):
        for name, value in (("kp", kp), ("dampratio", dampratio), ("timestep", timestep)):
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"MujocoPoseSource.{name} must be a positive number, got {value}")
        self.urdf_path = Path(urdf_path) if urdf_path is not None else Path(default_hand_urdf())
        spec = load_urdf_spec(self.urdf_path)
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        spec.option.timestep = float(timestep)
        spec.option.gravity = np.asarray(gravity, dtype=np.float64)

        body_names = {b.name for b in spec.bodies}
        if gravity_compensation:
            for body in spec.bodies:
                body.gravcomp = 1.0
        pairs = ALLEGRO_CONTACT_EXCLUDES if contact_excludes is None else contact_excludes
        for a, b in pairs:
            if a in body_names and b in body_names:
                spec.add_exclude(bodyname1=a, bodyname2=b)
            elif contact_excludes is not None:
                bad = a if a not in body_names else b
                resolve_names([bad], sorted(body_names), "contact-exclude body")

        joints = [j for j in spec.joints
                  if j.type in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)]
        for j in joints:
            act = spec.add_actuator()
            act.name = f"{j.name}_position"
            act.trntype = mujoco.mjtTrn.mjTRN_JOINT
            act.target = j.name
            act.set_to_position(kp=float(kp), dampratio=float(dampratio))
            if j.range[0] < j.range[1]:  # URDF "continuous" joints have no range
                act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
                act.ctrlrange = np.asarray(j.range, dtype=np.float64)
        try:
            self.model = spec.compile()
        except ValueError as err:
            raise AssetError(f"MuJoCo could not compile URDF {self.urdf_path}: {err}") from err
        self.data = mujoco.MjData(self.model)
        m = self.model

        self.num_envs = 1
        self.joint_names = [j.name for j in joints]
        jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in self.joint_names]
        self._qadr = m.jnt_qposadr[jid].copy()
        self._vadr = m.jnt_dofadr[jid].copy()
        self.joint_limits = np.where(m.jnt_limited[jid, None].astype(bool), m.jnt_range[jid],
                                     np.array([-np.inf, np.inf]))
        self.link_names = [m.body(i).name for i in range(1, m.nbody)]  # body 0 is the world
        self._root = int(m.body_rootid[1])
        self.set_base_pose(np.eye(4) if base_pose is None else base_pose)
        self.set_joint_positions(np.clip(np.zeros(len(jid)), *self.joint_limits.T))  # in-limit rest

    # --- state ------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Simulated time, seconds."""
        return float(self.data.time)

    def set_base_pose(self, pose) -> None:
        """Weld the root link at ``pose`` (``[4, 4]`` world transform, metres)."""
        T = as_pose_matrix(pose.detach().cpu().numpy() if isinstance(pose, torch.Tensor)
                           else pose, "base_pose")
        self.model.body_pos[self._root] = T[:3, 3]
        self.model.body_quat[self._root] = matrix_to_quat(T[:3, :3])
        mujoco.mj_forward(self.model, self.data)

    def joint_positions(self) -> np.ndarray:
        """Current joint positions ``[J]``, radians, in ``joint_names`` order."""
        return self.data.qpos[self._qadr].copy()

    def joint_targets(self) -> np.ndarray:
        """Current position targets ``[J]``, radians, in ``joint_names`` order."""
        return self.data.ctrl.copy()

    def set_joint_targets(self, q) -> None:
        """Set the actuators' position targets (radians).

        ``q``: ``[J]`` array in ``joint_names`` order, or a dict name -> angle
        (joints not named keep their target). Targets are clipped to the joint
        limits; NaN/inf raise ConfigError naming the joint.
        """
        q = self.joint_vector(q, "target")
        q = np.where(np.isnan(q), self.data.ctrl, q)
        self.data.ctrl[:] = np.clip(q, self.joint_limits[:, 0], self.joint_limits[:, 1])

    def set_joint_positions(self, q) -> None:
        """Teleport the joints to ``q`` (radians; array or dict as for targets), zero
        their velocities, make the targets equal and recompute the kinematics.

        Values are not clipped, so exact configurations can be compared across simulators.
        """
        q = self.joint_vector(q, "position")
        q = np.where(np.isnan(q), self.data.qpos[self._qadr], q)
        self.data.qpos[self._qadr] = q
        self.data.qvel[self._vadr] = 0.0
        self.data.ctrl[:] = np.clip(q, self.joint_limits[:, 0], self.joint_limits[:, 1])
        mujoco.mj_forward(self.model, self.data)

    def step(self, n: int = 1) -> None:
        """Advance the dynamics by ``n`` time steps (``n * model.opt.timestep`` seconds).

        Raises SimulationError if the state diverges. (MuJoCo itself would only
        print a warning and silently reset the state to the rest pose.)
        """
        bad = self.data.warning[mujoco.mjtWarning.mjWARN_BADQACC]
        before = int(bad.number)
        for k in range(int(n)):
            mujoco.mj_step(self.model, self.data)
            if bad.number != before:
                raise SimulationError(
                    f"MuJoCo diverged (NaN/huge acceleration) at step {k + 1} of {n}; "
                    "the state was reset to the rest pose. Lower kp or the time step")

    # --- PoseSource -------------------------------------------------------------
    def all_link_poses(self) -> torch.Tensor:
        """World transforms of every body but the world, ``[1, L, 4, 4]`` float64."""
        T = np.zeros((1, len(self.link_names), 4, 4))
        T[0, :, :3, :3] = self.data.xmat[1:].reshape(-1, 3, 3)
        T[0, :, :3, 3] = self.data.xpos[1:]
        T[0, :, 3, 3] = 1.0
        return torch.from_numpy(T)
