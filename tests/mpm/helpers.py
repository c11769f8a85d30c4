"""Small scenes shared by the MPM tests (SI units)."""
import numpy as np

from gausstac_maniskill.config import Material, SolverSettings
from gausstac_maniskill.mpm import MPMWorld, box_particles


def pad_world(dx=1e-3, size=(0.01, 0.01, 0.006), material=None, contact="particle", **settings):
    """A block pad on a fixed kinematic base (bottom two cells), top face at z = 0."""
    s = SolverSettings(**{"dx": dx, "gravity": (0.0, 0.0, 0.0), "mass_scaling": 1.0, "max_substeps": 2000, **settings})
    world = MPMWorld(s, contact=contact)
    world.add_link("base", np.eye(4))
    hx, hy, hz = size
    pts = box_particles([-hx / 2, -hy / 2, -hz], [hx / 2, hy / 2, 0.0], s.particle_spacing)
    world.add_group("pad", pts, material or Material(E=3e5, nu=0.45, density=1100.0), link="base",
                    kinematic=pts[:, 2] < -hz + 2 * dx)
    return world
