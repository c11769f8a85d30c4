"""Taichi MLS-MPM co-simulator: soft bodies, kinematic link-driven particles, SDF colliders.

The colliders and particle seeding are :mod:`gausstac_maniskill.geometry`'s (shared with the
equilibrium pads), importable here too."""
from ..geometry import (Box, Capsule, Collider, HalfSpace, MeshCollider, Sphere, box_particles, mesh_particles,
                        signed_distance)
from .model import Model
from .solver import MPMWorld
from .state import Group
from .stepper import StepInfo

__all__ = ["MPMWorld", "Model", "StepInfo", "Group", "Collider", "Sphere", "Box", "Capsule", "HalfSpace",
           "MeshCollider", "signed_distance", "box_particles", "mesh_particles"]
