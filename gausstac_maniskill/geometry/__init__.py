"""Geometry both pad solvers share: rigid colliders and their signed distances
(:mod:`.colliders`), rigid motion inside Taichi kernels (:mod:`.kinematics`), point-to-mesh
queries (:mod:`.mesh_query`) and lattice points inside a box or a mesh (:mod:`.sampling`).
Units: SI (m)."""
from .colliders import Box, Capsule, Collider, HalfSpace, MeshCollider, Sphere, signed_distance
from .mesh_query import query_mesh, signed_distance_to_mesh
from .sampling import box_particles, mesh_particles

__all__ = ["Collider", "Sphere", "Box", "Capsule", "HalfSpace", "MeshCollider", "signed_distance",
           "query_mesh", "signed_distance_to_mesh", "box_particles", "mesh_particles"]
