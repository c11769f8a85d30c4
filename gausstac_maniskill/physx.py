"""SAPIEN PhysX helpers of the GaussTac tasks: loading the PhysX GPU library with an error that
names the file, adding a wrench to ManiSkill actors and links for the coming SAPIEN step, and
ManiSkill poses of a batch of envs from NumPy arrays. Units: SI."""
from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils.structs.pose import Pose

from .errors import ConfigError

__all__ = ["enable_physx_gpu", "apply_wrench", "batched_pose"]


def enable_physx_gpu(sim_backend) -> None:
    """Load SAPIEN's PhysX GPU library now, so that a failure names the file. SAPIEN fetches
    it from GitHub into ``~/.sapien/physx/<version>/`` on first use (on a machine without
    internet, a ConnectionError inside ``gym.make``)."""
    from pathlib import Path

    import sapien.physx

    if sapien.physx.is_gpu_enabled():
        return
    version = sapien.physx.version()
    folder = Path.home() / ".sapien" / "physx" / version
    try:
        sapien.physx.enable_gpu()
    except Exception as err:  # noqa: BLE001 - any failure here: the library is missing or broken
        raise ConfigError(
            f"sim_backend={sim_backend!r}: SAPIEN could not load its PhysX GPU library "
            f"{folder / 'libPhysXGpu_64.so'} ({type(err).__name__}: {str(err).splitlines()[0][:200]}). SAPIEN "
            f"downloads it on first use from https://github.com/sapien-sim/physx-precompiled/releases/download/"
            f"{version}/linux-so.zip; on a machine without internet, download that file elsewhere and unzip it "
            f"into {folder}") from err


def apply_wrench(entity, w: np.ndarray) -> None:
    """Add w [B, 6] (force [N], torque [N·m] about the entity's origin, world frame) to the
    rigid body of each env of a ManiSkill actor or link for the coming SAPIEN step (CPU
    sim), as a force at its centre of mass and the torque that keeps the moment."""
    if not np.any(w):
        return
    origin = entity.pose.raw_pose[:, :3].detach().cpu().double().numpy()
    for b, body in enumerate(entity._bodies):
        if not np.any(w[b]):
            continue
        com = np.asarray((body.entity_pose * body.cmass_local_pose).p, np.float64)
        force, torque = w[b, :3], w[b, 3:]
        torque_com = torque + np.cross(origin[b] - com, force)  # the moment about the centre of mass
        body.add_force_torque(force.astype(np.float32), torque_com.astype(np.float32))


def batched_pose(p, q) -> Pose:
    """ManiSkill pose of n envs from positions [n, 3] m and quaternions (w, x, y, z) [n, 4]."""
    return Pose.create_from_pq(torch.as_tensor(np.asarray(p), dtype=torch.float32),
                               torch.as_tensor(np.asarray(q), dtype=torch.float32))
