"""Pads as MLS-MPM particles of the scene's world, relaxed quasi-statically with a pseudo-mass.

Each pad is a group of the world (:meth:`~gausstac_maniskill.mpm.MPMWorld.add_group`) bound to
its link: its soft layer touches rigid objects (SDF colliders) and soft objects (another
velocity field) in the world's step, and its maps are read from the world's device arrays
(:class:`~gausstac_maniskill.tactile.readout.TactileReadout`).

A pad with no object within the sleep margin that has relaxed (no particle more than
:data:`REST_TOLERANCE` from its rest place on the link, or no longer moving) is put exactly on
its rest shape and sleeps: the world does not step it, it is carried rigidly by its link and
reads zero maps. A pad never falls asleep deformed. Units: SI.
"""
from __future__ import annotations

import numpy as np

from ..tactile.readout import TactileReadout
from .interface import PadSolver

__all__ = ["MPMPads", "REST_TOLERANCE", "add_pad_group"]

#: A pad sleeps only once every particle is within this distance [m] of its rest place.
REST_TOLERANCE = 5.0e-6


def add_pad_group(scene, name: str, surface: str, pose: np.ndarray | None = None) -> None:
    """Scene pad ``name``'s particles as a group of the world, bound to its link, at rest on
    the link's world ``pose`` [4, 4] (default: the scene's link pose); ``surface``: ``"mesh"``
    (each surface particle's contact radius its depth below the link mesh) or ``"particles"``
    (half a spacing)."""
    pad = scene.pads[name]
    spec = pad.spec
    T = scene.link_pose(spec.link) if pose is None else pose
    world_pts = pad.rest @ T[:3, :3].T + T[:3, 3]
    # the bond surface lies ``thickness`` below the link surface, parallel to it
    scene.world.add_group(scene.world_name(name), world_pts, spec.material, link=scene.world_name(spec.link),
                          kinematic=pad.kinematic, spacing=scene.settings.particle_spacing,
                          contact_radius=pad.contact_radius if surface == "mesh" else None,
                          bond_distance=spec.thickness - pad.depth, bond_normal=pad.normal @ T[:3, :3].T)


class MPMPads(PadSolver):
    """The scene's MPM pads (module docstring): groups of its world, stepped by the world."""

    kind = "mpm"

    def __init__(self, scene, settings):
        super().__init__(scene, settings)
        self._readout: TactileReadout | None = None

    def _w(self, name: str) -> str:
        return self.scene.world_name(name)

    def add(self, name: str, asleep: bool = False) -> None:
        """Pad ``name`` as a group of the world, awake at the scene's link pose; ``asleep``: at
        rest where the world holds its link (its pose at the end of the last step) and asleep
        (a pad that joins a scene already stepped; it wakes when an object nears)."""
        if not asleep:
            add_pad_group(self.scene, name, self.settings.surface)
        else:
            world, group = self.scene.world, self._w(name)
            add_pad_group(self.scene, name, self.settings.surface, world.link_pose(self._w(self._pad(name).spec.link)))
            world.set_awake(group, False)
        self.names.append(name)
        self.awake[name] = not asleep
        self._readout = None

    # ------------------------------------------------------------------ sleeping
    def set_near(self, name: str, near: bool) -> None:
        world = self.scene.world
        if not near and self.awake[name]:
            x = world.positions(self._w(name)).astype(np.float64)
            settled = self._relative_speed(name, x) * world.last_dt_ctrl < 0.2 * REST_TOLERANCE
            if np.abs(self._displacement(name, x)).max() >= REST_TOLERANCE and not settled:
                near = True  # still moving back: stay awake until the pad has relaxed
            else:
                # away from every object, the unloaded elastic solution is the rest shape:
                # sleep exactly there (what remains is MPM's numerical plasticity)
                world.rest_group(self._w(name))
        if near != self.awake[name]:
            world.set_awake(self._w(name), near)
            self.awake[name] = near

    def _relative_speed(self, name: str, x: np.ndarray) -> float:
        """Largest speed [m/s] of pad ``name``'s soft particles (at world positions x [N, 3])
        relative to its link's rigid motion (bound particles move with the link by definition;
        their finite-difference velocity carries float32 rounding of ~3e-5 m/s)."""
        pad = self._pad(name)
        world = self.scene.world
        link = self._w(pad.spec.link)
        T, (v_o, w) = world.link_pose(link), world.link_twist(link)
        soft = ~pad.kinematic
        rigid = v_o + np.cross(w, x[soft] - T[:3, 3])
        return float(np.linalg.norm(world.velocities(self._w(name))[soft] - rigid, axis=1).max())

    def _displacement(self, name: str, x: np.ndarray) -> np.ndarray:
        """[N, 3] displacement [m] of pad ``name``'s particles (at world positions x [N, 3])
        from rest, in the link frame."""
        pad = self._pad(name)
        T = self.scene.world.link_pose(self._w(pad.spec.link))  # where the particles were last stepped to
        return (x - T[:3, 3]) @ T[:3, :3] - pad.rest

    # ------------------------------------------------------------------ readout
    def readout(self) -> TactileReadout:
        """The :class:`~gausstac_maniskill.tactile.readout.TactileReadout` of these pads."""
        if self._readout is None:
            self._readout = TactileReadout(self.scene.world, [self._pad(n) for n in self.names], [self.slots()])
        return self._readout

    def slots(self) -> list[tuple[str, str]]:
        """Per pad, the world's names of its particle group and its link."""
        return [(self._w(n), self._w(self._pad(n).spec.link)) for n in self.names]

    def tactile(self) -> dict:
        if not self.names:
            return {}
        return {name: {k: v[0] for k, v in m.items()} for name, m in self.readout().maps().items()}

    def contact_forces(self, name: str) -> np.ndarray:
        return self.scene.world.contact_forces(self._w(name))

    def stress_force(self, name: str) -> np.ndarray:
        """By virtual work over the soft particles (:meth:`MPMWorld.virtual_work_force`): with a
        test field φ = 1 − d/h over the layer (d the rest depth below the pad surface, h the
        layer thickness), f = Σ_p V0_p J_p σ_p F_p⁻ᵀ N_p / h, N_p the rest outward normal."""
        p = self._pad(name)
        world = self.scene.world
        grad_phi = (p.normal @ world.binding_rotation(self._w(p.name)).T) / p.spec.thickness  # world at binding
        grad_phi[p.kinematic] = 0.0
        f = world.virtual_work_force(self._w(p.name), grad_phi)
        R = self.scene.link_pose(p.spec.link)[:3, :3] @ p.sensor_frame[:3, :3]
        return R.T @ f

    def particles(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        g = self._w(name)
        return self._carried(name, self.scene.world.positions(g), self.scene.world.deformation_gradients(g))

    # ------------------------------------------------------------------ rendering
    def _carried(self, name: str, x: np.ndarray, F: np.ndarray):
        D = self.carry(name)
        if D is None:
            return x, F
        return (x @ D[:3, :3].T + D[:3, 3]).astype(np.float32), (D[:3, :3] @ F).astype(np.float32)

    def carry(self, name: str) -> np.ndarray | None:
        g = self.scene.world.group(self._w(name))
        if g.awake or g.sleep_pose is None:
            return None
        return self.scene.link_pose(self._pad(name).spec.link) @ np.linalg.inv(g.sleep_pose)

    def fill_particles(self, rows: np.ndarray, x: np.ndarray, F: np.ndarray) -> None:
        """``rows``: world particle indices (ascending)."""
        for name in self.names:
            g = self.scene.world.group(self._w(name))
            lo, hi = np.searchsorted(rows, (g.start, g.stop))  # the group's rows among ``rows`` (ascending)
            if hi > lo:
                x[lo:hi], F[lo:hi] = self._carried(name, x[lo:hi], F[lo:hi])
