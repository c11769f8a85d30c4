"""Seeding particles: :mod:`gausstac_maniskill.geometry.sampling`'s lattice points, importable here too."""
from ..geometry.sampling import box_particles, mesh_particles

__all__ = ["box_particles", "mesh_particles"]
