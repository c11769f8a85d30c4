"""What a GaussTac task registers besides the hand: rigid objects the pads feel, captured objects
the splat camera draws on SAPIEN actors, MPM-only soft objects, and the captured 3DGS scene
around the task.

:class:`~gausstac_maniskill.tasks.base.GaussTacEnv` keeps one dict of each kind
(``add_mpm_rigid``, ``add_captured_object``, ``add_mpm_soft``); the co-simulator is built from
them every episode. Units: SI; poses are world frame unless a field says otherwise.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .config import Material
from .errors import AssetWarning, ConfigError
from .geometry.colliders import Collider

__all__ = ["RigidObject", "CapturedObject", "SoftObject", "captured_object", "load_scene_capture"]


@dataclass
class RigidObject:
    """A SAPIEN actor the pads feel through an SDF collider (collider in the actor frame)."""

    name: str
    actor: object
    collider: Collider
    gaussians: object = None
    two_way: bool = False
    offset: np.ndarray | None = None  #: [4, 4] the collider's pose in the actor frame (None: identity)


@dataclass
class CapturedObject:
    """A SAPIEN actor drawn by captured Gaussians (in the actor frame) that follow its pose."""

    name: str
    actor: object
    gaussians: object


@dataclass
class SoftObject:
    """An MPM-only deformable object: ``particles(env_idx)`` -> (world positions [N, 3] m,
    kinematic mask [N] or None, anchor 4x4 world pose or None); kinematic particles are
    glued to the fixed anchor frame."""

    name: str
    particles: Callable[[int], tuple]
    material: Material


def captured_object(name: str, actor, capture, placement=None, stacklevel: int = 2) -> CapturedObject:
    """The :class:`CapturedObject` of ``GaussTacEnv.add_captured_object(name, actor, capture,
    placement)``: ``capture`` (an INRIA ``.ply`` path or a ``GaussianSet``, capture frame)
    placed by ``placement`` (capture frame -> actor frame; ``Similarity``, dict, 4x4 or None).

    Raises:
        ConfigError: an actor without a collision shape.

    Warns:
        AssetWarning: the placed Gaussians are more than twice as large or small as the
            actor's collision mesh (the message gives the scale that would match), attributed
            as ``warnings.warn(..., stacklevel=stacklevel)`` in this function's caller would be.
    """
    from .splat import GaussianSet
    from .splat.capture import Similarity, capture_extent, load_capture, transform_gaussians

    placement = Similarity.coerce(placement, f"add_captured_object({name!r}).placement")
    if isinstance(capture, GaussianSet):
        g, label = transform_gaussians(capture, placement), f"captured object {name!r}"
    else:
        g, label = load_capture(capture, placement), f"{Path(capture).name} (captured object {name!r})"
    mesh = actor.get_first_collision_mesh(to_world_frame=False)
    if mesh is None:
        raise ConfigError(f"add_captured_object({name!r}): actor {actor.name!r} has no collision shape; "
                          "a captured object rides on an actor that SAPIEN simulates (add_*_collision)")
    size, mesh_size = capture_extent(g.means), float(np.max(mesh.extents))
    if size > 0 and not 0.5 <= size / mesh_size <= 2.0:
        hint = placement.scale * mesh_size / size
        warnings.warn(f"{label}: the placed Gaussians span {size:.3g} m but actor {actor.name!r}'s "
                      f"collision mesh spans {mesh_size:.3g} m; placement scale={hint:.4g} would match them",
                      AssetWarning, stacklevel=stacklevel + 1)
    return CapturedObject(name, actor, g)


def load_scene_capture(scene_ply, scene_pose, camera: str):
    """The placed captured scene of ``GaussTacEnv(scene_ply=..., scene_pose=...)``, or None."""
    if scene_ply is None:
        if scene_pose is not None:
            raise ConfigError("scene_pose was given without scene_ply (the captured scene it places)")
        return None
    if camera != "splat":
        raise ConfigError(f"scene_ply needs camera='splat' (SAPIEN's camera cannot draw Gaussians), got "
                          f"camera={camera!r}")
    from .splat.capture import Similarity, load_capture

    if isinstance(scene_ply, str) and scene_ply == "example":
        from .splat.example_scene import EXAMPLE_PLACEMENT, EXAMPLE_SCENE

        scene_ply, scene_pose = EXAMPLE_SCENE, EXAMPLE_PLACEMENT if scene_pose is None else scene_pose
    return load_capture(scene_ply, Similarity.coerce(scene_pose, "scene_pose"))
