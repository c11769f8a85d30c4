"""Quasi-static linear elasticity on a voxel lattice: a pad at equilibrium per control step.

The explicit MPM (:mod:`gausstac_maniskill.mpm`) relaxes a pad towards equilibrium with a
pseudo-mass; this package solves the equilibrium itself. A pad is quasi-static at control
rates (its elastic wave crosses it in under a millisecond), and in its link frame its rest
shape never changes, so its stiffness matrix is assembled and factored once:

* :mod:`.hex` — trilinear hexahedra on the pad's particle lattice (whole cubes, or cut
  cells that follow a curved layer's surface and bond),
  selective reduced integration against volumetric locking, assembly and interpolation.
* :mod:`.indenters` — rigid colliders as the body sees them (signed distance, frame, friction).
* :mod:`.signorini` — the contact problem on the surface points near a collider, given the
  body's compliance among them (frictionless: a linear complementarity problem; with Coulomb
  friction: semismooth Newton on Alart and Curnier's equations).
* :mod:`.contact` — the body at equilibrium under rigid colliders (:class:`QuasiStaticBody`):
  that problem at each outer iteration, with the body's compliance at the points near the
  colliders computed once and kept.
* :mod:`.compliance` — that compliance among all surface points, and any linear readout's
  response to point forces, computed once and kept on disk.
* :mod:`.plane_cholesky` — Pᵀ K⁻¹ Q for those: the stiffness factored lattice plane by lattice
  plane, all the solves at once in dense BLAS 3.
* :mod:`.maps` — a linear pad's tactile maps as one matrix times its contact forces.
* :mod:`.pad`, :mod:`.sensor` — the product's pads as such bodies, read as the MPM's pads are.
"""
from .contact import ContactResult, QuasiStaticBody
from .hex import VoxelBody, element_stiffness, stiffness, voxel_body
from .indenters import Indenter, Indenters
from .pad import collider_indenter, layer_body, pad_body
from .signorini import solve_frictional, solve_lcp

__all__ = ["VoxelBody", "element_stiffness", "stiffness", "voxel_body", "QuasiStaticBody", "ContactResult",
           "solve_lcp", "solve_frictional", "Indenter", "Indenters", "pad_body", "layer_body", "collider_indenter"]
