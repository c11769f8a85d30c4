"""Taichi MLS-MPM co-simulator: soft bodies, kinematic link-driven particles, SDF colliders."""
from .colliders import Box, Capsule, Collider, HalfSpace, MeshCollider, Sphere, signed_distance
from .sampling import box_particles, mesh_particles
from .solver import Group, MPMWorld, StepInfo

__all__ = ["MPMWorld", "StepInfo", "Group", "Collider", "Sphere", "Box", "Capsule", "HalfSpace",
           "MeshCollider", "signed_distance", "box_particles", "mesh_particles"]
