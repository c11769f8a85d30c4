"""Time integration per kind of group: free bodies move with their physical mass, quasi-static
pads (pseudo-mass, dynamic relaxation) settle to rest and ignore the hand's acceleration."""
import math

import numpy as np
import pytest
from helpers import pad_world

from gausstac_maniskill.config import Material, SolverSettings
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.mpm import MPMWorld, Sphere, box_particles
from gausstac_maniskill.transforms import make_pose, rotation_about

G = 9.81
FOAM = Material(E=2e4, nu=0.3, density=60.0)  # a light sponge: the worst case for mass scaling


def free_cube(mass_scaling=1000.0, velocity=None):
    s = SolverSettings(dx=2e-3, mass_scaling=mass_scaling, gravity=(0.0, 0.0, -G))
    world = MPMWorld(s)
    pts = box_particles([0, 0, 0], [0.01, 0.01, 0.01], s.particle_spacing)
    world.add_group("cube", pts, FOAM, velocity=velocity)
    return world


def test_free_body_falls_at_g_despite_pad_mass_scaling():
    """Mass scaling is a pseudo-mass of quasi-static groups only: a free cube in the hand's
    settings (×1000) falls g·t²/2 within 2 % (with the pseudo-mass it would fall 0.05 mm in
    0.1 s)."""
    world = free_cube()
    z0 = world.positions("cube")[:, 2].mean()
    for _ in range(10):
        world.step(0.01)
    drop = z0 - world.positions("cube")[:, 2].mean()
    assert drop == pytest.approx(0.5 * G * 0.1 ** 2, rel=0.02)
    assert not world.group("cube").quasi_static


def test_free_body_keeps_its_momentum():
    world = free_cube(velocity=[0.3, -0.2, 0.0])
    x0 = world.positions("cube").mean(0)
    for _ in range(5):
        world.step(0.01)
    v = world.velocities("cube").mean(0)
    assert v[:2] == pytest.approx([0.3, -0.2], abs=1e-4)
    assert v[2] == pytest.approx(-G * 0.05, rel=0.02)
    assert world.positions("cube").mean(0)[0] - x0[0] == pytest.approx(0.015, rel=0.01)


def test_free_body_keeps_its_spin():
    """APIC (Jiang et al. 2015) carries a rigid rotation without loss: a free cube spun at ω
    (no gravity) keeps its angular momentum about its centre, and each particle's velocity
    gradient C is the spin tensor [ω]×. An affine velocity passes through P2G and G2P exactly
    only with the right C: with C = 0 at the start the cube would lose 11 % of its spin in the
    first substep; a wrong gradient in G2P loses it at every one."""
    s = SolverSettings(dx=2e-3, gravity=(0.0, 0.0, 0.0), mass_scaling=1.0, max_substeps=2000)
    world = MPMWorld(s)
    pts = box_particles([0, 0, 0], [0.01, 0.01, 0.01], s.particle_spacing)
    omega = np.array([3.0, -2.0, 5.0])  # rad/s: the cube's edge moves 25 mm/s
    world.add_group("cube", pts, FOAM, velocity=np.cross(omega, pts - pts.mean(0)))

    def spin():
        x, v = world.positions("cube"), world.velocities("cube")
        r = x - x.mean(0)
        inertia = np.einsum("ni,ni->", r, r) * np.eye(3) - r.T @ r  # per unit particle mass
        return np.linalg.solve(inertia, np.cross(r, v).sum(0))

    for _ in range(5):
        world.step(0.01)
    assert spin() == pytest.approx(omega, rel=2e-3)
    C = world.state_dict()["particles"]["C"]
    skew = np.cross(np.eye(3), omega)  # [ω]×: row a is e_a × ω, so that [ω]× r = ω × r
    assert np.abs(C - skew).max() < 0.02 * np.linalg.norm(omega)


def test_a_free_group_cannot_be_quasi_static():
    world = MPMWorld(SolverSettings(dx=2e-3, mass_scaling=100.0))
    pts = box_particles([0, 0, 0], [0.004, 0.004, 0.004], 1e-3)
    with pytest.raises(ConfigError, match="physical inertia"):
        world.add_group("cube", pts, FOAM, quasi_static=True)
    world.add_link("base", np.eye(4))
    with pytest.raises(ConfigError, match="relaxation"):
        world.add_group("pad", pts, FOAM, link="base", kinematic=pts[:, 2] < 1e-3, relaxation=-1.0)


def pad_displacement(world, T):
    """Largest distance [m] of a pad particle from its rest place on a link at pose T
    (the pad's rest is its initial positions with the link at identity)."""
    x = world.positions("pad").astype(np.float64)
    return x @ T[:3, :3], (x - T[:3, 3]) @ T[:3, :3]


def press_and_release(friction=0.5, released_steps=3):
    """Press a sphere 1 mm into the block pad, slide it 1 mm, lift it off; return the largest
    particle distance [m] from rest after each released control step of 50 ms."""
    world = pad_world(mass_scaling=1000.0)
    rest = world.positions("pad").astype(np.float64)
    ball = world.add_collider(Sphere(radius=4e-3, pose=make_pose([0, 0, 4e-3]), friction=friction))
    for k in range(6):  # press 1 mm and slide 1 mm sideways
        world.set_collider_pose(ball, make_pose([1e-3 * max(0, k - 3) / 2, 0, 4e-3 - 1e-3 * min(1, (k + 1) / 3)]))
        world.step(0.05)
    assert np.abs(world.positions("pad") - rest).max() > 0.5e-3
    world.set_collider_pose(ball, make_pose([0, 0, 0.02]))
    out = []
    for _ in range(released_steps):
        world.step(0.05)
        out.append(float(np.abs(world.positions("pad") - rest).max()))
    return out


def test_pad_relaxes_after_contact():
    """After a 1 mm press-and-slide the pad relaxes within one step to a plateau and stays
    there. Measured with friction 0.5: 15 µm after 1 step, 12–19 µm over 40 steps (F-bar;
    13–14 µm without). The plateau is MPM's numerical plasticity; GaussTacSim puts a
    settled pad away from objects exactly at rest before it sleeps."""
    u = press_and_release(released_steps=10)
    assert u[0] < 4e-5
    assert max(u) < 4e-5, [round(x * 1e6, 1) for x in u]


@pytest.mark.xfail(strict=True, reason="known gap: the pad plateaus at 12-19 µm instead of "
                   "coming within 0.01 mm of rest in 3 steps. Not F drift alone: resetting F to the "
                   "particles' own displacement gradient (least squares over rest-lattice neighbours) "
                   "after contact still leaves 11 µm; the rest sits in sub-cell particle displacements "
                   "the grid does not see. The tactile maps meet the bound (taxels average them): "
                   "tests/test_cosim.py::test_maps_return_to_rest_while_the_object_stays_near")
def test_pad_returns_to_rest_within_three_control_steps():
    """The settle bound taken per particle, stricter than per taxel: |u| < 0.01 mm within 3
    control steps of 50 ms after contact ends."""
    assert press_and_release()[-1] < 1e-5


def test_pseudo_mass_ignores_the_hand_acceleration():
    """A pad carried by a link that starts, stops and turns quickly (no contact) stays on its
    rest shape: its pseudo-mass (×1000) resists deformation only, not the link's acceleration."""
    world = pad_world(mass_scaling=1000.0)
    rest = world.positions("pad").astype(np.float64)
    worst = 0.0
    for k in range(12):  # 0.2 m/s for 3 steps, stop, rotate 0.3 rad/step, stop
        t = 0.01 * min(k + 1, 3)
        ang = 0.3 * min(max(k - 4, 0), 4)
        T = make_pose([t, 0.0, 0.0], rotation_about([0, 1, 0], ang))
        world.set_link_pose("base", T)
        world.step(0.05)
        local = (world.positions("pad").astype(np.float64) - T[:3, 3]) @ T[:3, :3]
        worst = max(worst, float(np.abs(local - rest).max()))
    assert worst < 1e-5, f"pad deformed {worst * 1e3:.4f} mm by the link's acceleration"
    assert math.isfinite(worst)


def press_hold_move(hold_scaling, held=8, state_at=None):
    """A 4 mm sphere pressed 1 mm into the block pad over three control steps of 50 ms, held
    ``held`` steps, then moved 0.2 mm sideways; per step (Fn [N], substeps). With ``state_at``
    also the world and its state after that many steps."""
    world = pad_world(mass_scaling=1000.0, hold_scaling=hold_scaling)
    ball = world.add_collider(Sphere(radius=4e-3, pose=make_pose([0, 0, 4e-3]), friction=0.5))
    out, saved = [], None
    for k in range(3 + held + 1):
        x = 2e-4 if k == 3 + held else 0.0
        world.set_collider_pose(ball, make_pose([x, 0, 4e-3 - 1e-3 * min(1, (k + 1) / 3)]))
        world.step(0.05)
        out.append((float(world.collider_wrench(ball)[0][2]), world.last_step.substeps))
        if state_at == k + 1:
            saved = world.state_dict()
    return out, (world, ball, saved)


def test_a_settled_held_pad_takes_fewer_substeps_and_keeps_its_force():
    """Dynamic relaxation's equilibrium does not depend on the pseudo-mass: once the pressed pad
    has settled and nothing moves, it takes 16x the pseudo-mass (4x fewer substeps) and reads
    the force the default pseudo-mass reads, within 0.5 % (measured: 0.06-0.2 %); the sphere's
    first move brings the default back for that step. Guards the switch both ways and that it
    leaves the held force alone; the held force itself is checked against theory elsewhere."""
    held, _ = press_hold_move(16.0)
    ref, _ = press_hold_move(1.0)
    assert all(h[1] == r[1] for h, r in zip(held[:4], ref[:4]))  # pressing: the default pseudo-mass
    holding = [k for k in range(4, 11) if held[k][1] * 3 <= ref[k][1]]
    assert holding and holding[0] <= 6 and holding == list(range(holding[0], 11)), (held, ref)
    for k in holding:
        assert held[k][0] == pytest.approx(ref[k][0], rel=5e-3), (k, held[k], ref[k])
    assert held[11][1] == ref[11][1]  # moved: the default again
    assert held[11][0] == pytest.approx(ref[11][0], rel=0.01)


def test_a_held_pad_state_reloads_bit_exact():
    """A state saved while a pad holds (its larger pseudo-mass) loads into a fresh world, which
    then steps exactly like the original: one more held step, then the move."""
    _, (world, _, saved) = press_hold_move(16.0, held=7, state_at=9)  # steps 4-10 held, 11 moves
    assert saved["hold"][0]
    twin = pad_world(mass_scaling=1000.0, hold_scaling=16.0)
    ball = twin.add_collider(Sphere(radius=4e-3, pose=make_pose([0, 0, 4e-3]), friction=0.5))
    twin.load_state_dict(saved)
    assert twin.group("pad").hold
    for x in (0.0, 2e-4):
        twin.set_collider_pose(ball, make_pose([x, 0, 3e-3]))
        twin.step(0.05)
    assert not twin.group("pad").hold
    assert np.array_equal(twin.positions("pad"), world.positions("pad"))
    assert np.array_equal(twin.velocities("pad"), world.velocities("pad"))
