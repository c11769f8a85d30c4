"""Quasi-static linear elasticity on a voxel lattice: a pad at equilibrium per control step.

The explicit MPM (:mod:`gausstac_maniskill.mpm`) relaxes a pad towards equilibrium with a
pseudo-mass; this package solves the equilibrium itself. A pad is quasi-static at control
rates (its elastic wave crosses it in under a millisecond), and in its link frame its rest
shape never changes, so its stiffness matrix is assembled and factored once:

* :mod:`.hex` — trilinear hexahedra on the pad's particle lattice (whole cubes, or cut
  cells that follow a curved layer's surface and bond),
  selective reduced integration against volumetric locking, assembly and interpolation.
* :mod:`.contact` — contact of the body's surface points with rigid colliders (frictionless:
  a linear complementarity problem; with Coulomb friction: semismooth Newton on Alart and
  Curnier's equations) on the points near them, with the body's compliance at those points
  computed once and kept.
* :mod:`.compliance` — that compliance among all surface points, and any linear readout's
  response to point forces, computed once and kept on disk.
* :mod:`.plane_cholesky` — Pᵀ K⁻¹ Q for those: the stiffness factored lattice plane by lattice
  plane, all the solves at once in dense BLAS 3.
* :mod:`.maps` — a linear pad's tactile maps as one matrix times its contact forces.
* :mod:`.pad`, :mod:`.sensor` — the product's pads as such bodies, read as the MPM's pads are.
"""
from .contact import ContactResult, Indenter, Indenters, QuasiStaticBody, solve_frictional, solve_lcp
from .hex import VoxelBody, element_stiffness, stiffness, voxel_body
from .pad import collider_indenter, layer_body, pad_body

__all__ = ["VoxelBody", "element_stiffness", "stiffness", "voxel_body", "QuasiStaticBody", "ContactResult",
           "solve_lcp", "solve_frictional", "Indenter", "Indenters", "pad_body", "layer_body", "collider_indenter"]
