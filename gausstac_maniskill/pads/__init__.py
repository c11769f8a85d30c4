"""Pad solvers: what the co-simulator needs of a pad solver (:mod:`.interface`) and its two
implementations, the pads at equilibrium (:mod:`.fem`, linear or finite-strain FEM) and the
MLS-MPM pads (:mod:`.mpm`, particles of the scene's world)."""
from .fem import EquilibriumPads
from .interface import PadScene, PadSolver
from .mpm import MPMPads

__all__ = ["PadSolver", "PadScene", "EquilibriumPads", "MPMPads"]
