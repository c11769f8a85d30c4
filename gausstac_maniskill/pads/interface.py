"""What the co-simulator needs of a pad solver, and what a pad solver reads of its scene.

A scene (:class:`~gausstac_maniskill.cosim.GaussTacSim`) holds one :class:`PadSolver` per pad
kind (equilibrium pads, :mod:`.fem`; MLS-MPM pads, :mod:`.mpm`) and only orchestrates: it
moves the links and objects, decides which pads are near an object, and asks each solver to
sleep or wake its pads, to solve them at the step's end and to read them out. A solver holds
its pads' state (the scene's world holds the MPM pads' particles) and reads the scene through
:class:`PadScene`. Units: SI; poses are 4x4 rigid transforms, world frame unless named.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Mapping, Protocol, Sequence

import numpy as np
import torch

from ..config import PadSolverSettings
from ..owner import Owner

__all__ = ["PadScene", "PadSolver", "Maps"]

#: A pad's tactile maps: ``{"depth": [H, W] m, "shear": [H, W, 2] m, "force": [H, W] N,
#: "pressure": [H, W] Pa}`` float32 on the Taichi arch's device.
Maps = Mapping[str, torch.Tensor]


class PadScene(Protocol):
    """What a pad solver reads of the scene it belongs to."""

    world: object  #: the scene's :class:`~gausstac_maniskill.mpm.MPMWorld` (maybe shared by a batch)
    settings: object  #: the world's :class:`~gausstac_maniskill.config.SolverSettings`
    urdf: str  #: the URDF the pad links' meshes come from
    env: int  #: the scene's env index in its world
    pads: Mapping[str, object]  #: pad name -> :class:`~gausstac_maniskill.tactile.Pad`, in pad order

    def world_name(self, name: str) -> str:
        """The world's name of the scene's link or group ``name``."""

    def link_pose(self, link: str) -> np.ndarray:
        """The link's world pose [4, 4] at the end of the current step."""

    @property
    def rigid_objects(self) -> Mapping[str, int]:
        """Rigid object name -> its collider's index in the world."""

    @property
    def soft_objects(self) -> Sequence[str]:
        """The soft objects' names (each its world group's, see :meth:`world_name`)."""


class PadSolver(ABC):
    """The pads of one kind in one scene: built, stepped, put to sleep and read out.

    A step is: the scene sets the link poses (:meth:`after_link_poses`), says for every pad
    whether an object is near (:meth:`set_near`), the world steps, then :meth:`end_step`
    solves what the world does not. Readouts (:meth:`tactile`, :meth:`contact_forces`,
    :meth:`stress_force`, :meth:`particles`, the wrenches) describe the last step.

    Args:
        scene: the scene the pads belong to (:class:`PadScene`).
        settings: the pads' settings, shared by every solver of the scene.
    """

    #: the solver's kind, ``"fem"`` or ``"mpm"``
    kind: str = ""
    scene = Owner()  # the scene the pads belong to

    def __init__(self, scene: PadScene, settings: PadSolverSettings):
        self.scene = scene  # held weakly (owner.Owner): the scene owns its solvers
        self.settings = settings
        self.names: list[str] = []  # the pads this solver solves, in the scene's pad order
        self.awake: dict[str, bool] = {}  # pad name -> simulated this step

    def __contains__(self, name: str) -> bool:
        return name in self.awake

    def __len__(self) -> int:
        return len(self.names)

    def _pad(self, name: str):
        return self.scene.pads[name]

    # ------------------------------------------------------------------ building
    @abstractmethod
    def add(self, name: str) -> None:
        """Take scene pad ``name`` (its geometry :attr:`PadScene.pads`), at rest on its link."""

    def prepare(self) -> None:
        """Build now what the first contact would build (a no-op where nothing is deferred)."""

    # ------------------------------------------------------------------ stepping
    def after_link_poses(self) -> None:
        """The scene holds the step's end link poses (before the objects move)."""

    @abstractmethod
    def set_near(self, name: str, near: bool) -> None:
        """An object is (``near``) or is not within the sleep margin of pad ``name`` over the
        coming step: wake it, or let it sleep once it is at rest (:attr:`awake`)."""

    def end_step(self) -> None:
        """The world has stepped: solve what it does not (the equilibrium pads)."""

    # ------------------------------------------------------------------ readout
    @abstractmethod
    def tactile(self) -> dict[str, Maps]:
        """``{pad: maps}`` (:data:`Maps`) of this solver's pads in the last step; zeros asleep."""

    @abstractmethod
    def contact_forces(self, name: str) -> np.ndarray:
        """[N, 3] world contact force [N] on each of pad ``name``'s particles in the last step."""

    @abstractmethod
    def stress_force(self, name: str) -> np.ndarray:
        """[3] total contact force [N] on awake pad ``name`` read from its stress, sensor frame."""

    @abstractmethod
    def particles(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """World positions [N, 3] and deformation gradients [N, 3, 3] (float32) of pad
        ``name``'s particles, a sleeping pad carried rigidly by its link."""

    def object_wrench(self, obj: str, origin: np.ndarray, f: np.ndarray, tau: np.ndarray):
        """The force [N] and torque [N·m] (about ``origin``) on rigid object ``obj``: ``f``,
        ``tau`` (what the world's particles exerted) with this solver's pads' reaction
        added (none where the world holds the pads)."""
        return f, tau

    def link_wrench(self, link: str, f: np.ndarray, tau: np.ndarray):
        """The force [N] and torque [N·m] (about the link origin) on hand link ``link``: ``f``,
        ``tau`` (the world's) with what this solver's pads on it passed to it added."""
        return f, tau

    def link_contacts(self, link: str) -> dict:
        """This solver's pads' rows of :meth:`GaussTacSim.link_contacts` on ``link`` that the
        world does not hold, by object (None: soft objects): [7] force, torque, indentation."""
        return {}

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        """What of the pads' state the world does not hold (a deep copy; :meth:`load_state`)."""
        return {}

    def load_state(self, state: Mapping) -> None:
        """Restore a :meth:`state` of the same pads."""

    def flat_state(self) -> dict[str, np.ndarray]:
        """:meth:`state` as fixed-shape arrays, named uniquely in the scene."""
        return {}

    def load_flat_state(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore a :meth:`flat_state` (``state`` may hold the whole scene's entries)."""

    # ------------------------------------------------------------------ rendering
    def carry(self, name: str) -> np.ndarray | None:
        """[4, 4] the rigid motion since pad ``name`` fell asleep that moves its world particles to
        where it is drawn, or None while they are where it is."""
        return None

    def fill_particles(self, rows: np.ndarray, x: np.ndarray, F: np.ndarray) -> None:
        """Write where this solver's pads are drawn into ``x`` [P', 3] and ``F`` [P', 3, 3], the
        particles ``rows`` ([P'] ascending) of the solver's own numbering (the world's particle
        indices for pads in the world) that lie on its pads."""
