"""Friction between a collider and a soft layer, against contact mechanics (SI units).

A strip of silicone (E = 0.3 MPa, ν = 0.45), h = 4 mm thick and L = 8 h long, bonded to a rigid
base, two cells wide between slip walls (plane strain), is pressed 2 % by a rigid plate. The
plate is then moved 0.05 h along the strip and held.

* Where the plate sticks (μ = 1), the layer is in simple shear: the plate carries
  F_x = G A u / h (G the shear modulus, A the contact area, u the plate's move). The free ends
  of a strip 8 h long lower it by about h/L; the test allows 5 %.
* Where the plate slides (μ = 0.1), F_x = μ F_z (Coulomb), and once it stops the layer
  stays sheared at that limit.
* In both, the held force stays where it is: static friction holds a position (without the
  anchors of ``contact_scatter`` a stuck layer creeps back at a rate proportional to its
  load: F_x falls to 42 % of G A u / h 40 steps after the move, and on).
"""
import math

import numpy as np
import pytest

from gausstac_maniskill.config import Material, SolverSettings
from gausstac_maniskill.mpm import HalfSpace, MPMWorld, box_particles

E, NU, RHO = 3e5, 0.45, 1100.0
H, DX = 4e-3, 1e-3


def shear_strip(friction: float, length: float = 8 * H, press: float = 0.02, move: float = 0.05):
    """Press the strip, move the plate by ``move``·h along x, hold. Returns (F_x, F_z) on the
    plate [N] after every held step, and the simple-shear force G A u / h [N]."""
    s = SolverSettings(dx=DX, gravity=(0.0, 0.0, 0.0), max_substeps=1_000_000, mass_scaling=1.0)
    z_bond = (math.floor(-H / DX) + 0.5) * DX  # the bond half a cell above a node plane
    z_top, width = z_bond + H, 2 * DX
    world = MPMWorld(s)
    world.add_link("base", np.eye(4))
    pts = box_particles([0.0, 0.0, z_bond - 2 * DX], [length, width, z_top], s.particle_spacing)
    group = world.add_group("strip", pts, Material(E=E, nu=NU, density=RHO), link="base",
                            kinematic=pts[:, 2] < z_bond)
    world.add_slip_wall(1, 0.0, "+")
    world.add_slip_wall(1, width, "-")

    def pose(depth, u):
        T = np.diag([1.0, -1.0, -1.0, 1.0])  # the half-space's solid side up
        T[0, 3], T[2, 3] = u, z_top - depth
        return T

    plate = world.add_collider(HalfSpace(pose=pose(0.0, 0.0), friction=friction))
    dt = 1.0 / (4.0 * group.relaxation)  # 4 control steps per relaxation time of the layer
    d, u = press * H, move * H
    for k in range(30):
        world.set_collider_pose(plate, pose(d * min(1.0, (k + 1) / 20), 0.0))
        world.step(dt)
    held = []
    for k in range(60):
        world.set_collider_pose(plate, pose(d, u * min(1.0, (k + 1) / 20)))
        world.step(dt)
        if k >= 35:
            F = world.collider_wrench(plate)[0]
            held.append((-F[0], F[2]))
    G = E / (2 * (1 + NU))
    return np.array(held), G * length * width * u / H


def test_a_stuck_plate_shears_the_layer_as_simple_shear_and_holds():
    held, simple_shear = shear_strip(friction=1.0)
    Fx, Fz = held[:, 0], held[:, 1]
    assert np.all(Fz > 0)
    assert Fx[-1] == pytest.approx(simple_shear, rel=0.05)
    assert Fx[-1] < Fz[-1]  # it did stick (below μ F_z)
    # static friction: no creep over the last 15 held steps (3.75 relaxation times)
    assert abs(Fx[-1] - Fx[-16]) < 0.005 * Fx[-1]


def test_a_sliding_plate_drags_with_coulomb_friction_and_holds_at_the_limit():
    mu = 0.1
    held, simple_shear = shear_strip(friction=mu)
    Fx, Fz = held[:, 0], held[:, 1]
    assert mu * Fz[-1] < 0.5 * simple_shear  # the move asks for more than friction can give
    assert Fx[-1] / Fz[-1] == pytest.approx(mu, rel=0.03)
    assert abs(Fx[-1] - Fx[-16]) < 0.005 * Fx[-1]
