"""The pose-source interface: a rigid hand's link names -> world transforms.

A pose source is what drives the co-simulator's kinematic particles. It hides
whether the link poses come from SAPIEN (ManiSkill) or from MuJoCo: both give
``[B, L, 4, 4]`` homogeneous transforms, batch first, in metres.
"""
from __future__ import annotations

import abc
import difflib
from typing import Mapping, Sequence

import numpy as np
import torch

from ..errors import ConfigError


def resolve_names(requested: Sequence[str], available: Sequence[str], kind: str) -> list[int]:
    """Indices of ``requested`` names in ``available``.

    Raises ConfigError naming the first unknown name and the closest matches,
    e.g. ``unknown link 'link_3_tip'; did you mean 'link_3.0_tip'?``.
    """
    if isinstance(requested, str):
        raise ConfigError(f"{kind} names must be a list of strings, got the string {requested!r}")
    index = {name: i for i, name in enumerate(available)}
    out = []
    for name in requested:
        if name not in index:
            close = difflib.get_close_matches(str(name), list(available), n=3, cutoff=0.5)
            hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
            raise ConfigError(
                f"unknown {kind} {name!r}{hint} (available: {', '.join(available)})")
        out.append(index[name])
    return out


class PoseSource(abc.ABC):
    """Link poses of one articulated hand, possibly over ``num_envs`` parallel envs.

    Attributes (set by subclasses):
        link_names:   names of every link, in the order of :meth:`all_link_poses`.
        joint_names:  names of the actuated (revolute/prismatic) joints.
        joint_limits: ``[J, 2]`` float64 (lower, upper), radians for revolute joints,
                      in ``joint_names`` order.
        num_envs:     batch size ``B`` of the returned poses.
    """

    link_names: list[str]
    joint_names: list[str]
    joint_limits: np.ndarray
    num_envs: int

    @abc.abstractmethod
    def all_link_poses(self) -> torch.Tensor:
        """World transforms of all links, ``[B, len(link_names), 4, 4]``, metres."""

    def link_poses(self, names: Sequence[str] | None = None) -> torch.Tensor:
        """World transforms of the named links (all links when ``names`` is None).

        Returns ``[B, L, 4, 4]``: rotation in ``[..., :3, :3]``, position (metres)
        in ``[..., :3, 3]``, link order as in ``names``. Unknown names raise ConfigError.
        """
        poses = self.all_link_poses()
        if names is None:
            return poses
        idx = resolve_names(names, self.link_names, "link")
        return poses[:, idx]

    def joint_vector(self, q, what: str = "joint value") -> np.ndarray:
        """A ``[J]`` float64 vector in ``joint_names`` order from an array or a name->value dict.

        A dict may name a subset of the joints; the others are NaN in the result
        (callers fill them in). Unknown names and non-finite values raise ConfigError.
        """
        J = len(self.joint_names)
        if isinstance(q, Mapping):
            out = np.full(J, np.nan)
            idx = resolve_names(list(q.keys()), self.joint_names, "joint")
            for i, (name, value) in zip(idx, q.items()):
                v = float(value)
                if not np.isfinite(v):
                    raise ConfigError(f"{what} of joint {name!r} is {v}; it must be finite")
                out[i] = v
            return out
        arr = np.asarray(q.detach().cpu() if isinstance(q, torch.Tensor) else q, dtype=np.float64)
        arr = arr.reshape(-1) if arr.ndim == 2 and arr.shape[0] == 1 else arr
        if arr.shape != (J,):
            raise ConfigError(
                f"{what}s must have shape ({J},) in joint_names order, got {arr.shape}")
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            i = int(bad[0])
            raise ConfigError(
                f"{what} of joint {self.joint_names[i]!r} is {arr[i]}; it must be finite")
        return arr
