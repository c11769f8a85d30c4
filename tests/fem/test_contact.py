"""A body at equilibrium under rigid colliders: the thin-layer theory, finite strain (its
stall detector and fallback), friction on a layer, and the product pad."""
import itertools
import math

import numpy as np
import pytest

from gausstac_maniskill.bench.quasistatic import layer_point
from gausstac_maniskill.bench.scenes import sphere
from gausstac_maniskill.errors import ConfigError
from gausstac_maniskill.fem import layer_body


@pytest.mark.parametrize("nu", [0.48, 0.499])
@pytest.mark.parametrize("a_over_h", [0.5, 1.0, 2.0])
def test_thin_layer_within_5_percent_at_four_elements(nu, a_over_h):
    """The 4 mm bonded layer with 1 mm elements (four through it), the layer solution's own
    indenter: within 5 % for a/h = 0.5 … 2, and at ν = 0.499 as at 0.48 (no locking)."""
    row = layer_point(a_over_h, 1e-3, nu)
    assert abs(row["err"]) < 5.0


def test_thin_layer_converges_under_refinement():
    coarse, fine = (layer_point(0.5, s, 0.48) for s in (1e-3, 5e-4))
    assert abs(fine["err"]) < abs(coarse["err"]) / 2
    assert abs(fine["err"]) < 2.0


def test_contact_conditions_hold_and_compliance_is_reciprocal():
    h, d, R = 3e-3, 3e-4, 6e-3
    body = layer_body(h, 6e-3, 1e-3, 0.3e6, 0.45)
    ball = sphere(R, [0.0, 0.0, h + R - d])
    for geometry in ("rest", "deformed"):
        res = body.solve(ball, geometry=geometry)
        lam = -res.force[:, 2]
        assert (lam >= 0).all() and lam.sum() > 0
        assert res.gap.min() > -1e-7                          # no point inside the sphere
        assert np.abs(res.gap[lam > 1e-9 * lam.max()]).max() < 1e-7  # force only where it touches
    # Maxwell–Betti: W_sd = W_dsᵀ (guards the kept columns' bookkeeping, not the physics)
    p = np.flatnonzero(np.abs(res.force).sum(1) > 0)[:4]
    W = body._columns
    for s, q in itertools.product(p, p):
        assert np.allclose(W[int(q)][s], W[int(s)][q].T, rtol=1e-8, atol=1e-16)
    with pytest.raises(ConfigError, match="geometry"):
        body.solve(ball, geometry="bent")


def _plate(top):
    return lambda x: (top - x[:, 2], np.tile([0.0, 0.0, -1.0], (len(x), 1)))


def _rollers(layer):
    """The layer's outer faces on rollers too: a homogeneous uniaxial strain under a plate."""
    from gausstac_maniskill.fem import QuasiStaticBody

    nodes = layer.body.nodes
    fixed = layer.fixed.copy()
    fixed[nodes[:, 0] == nodes[:, 0].max(), 0] = True
    fixed[nodes[:, 1] == nodes[:, 1].max(), 1] = True
    return QuasiStaticBody(layer.body, layer.E, layer.nu, fixed, layer.points, layer.point_elements,
                           model=layer.model)


def test_finite_strain_uniaxial_compression_is_exact():
    """20 % uniaxial compression: P_zz = μ λ^(−2/3) (λ − (2 + λ²)/(3λ)) + K ln λ / λ of the
    decoupled Neo-Hookean law (F = diag(1, 1, λ)), which the elements reproduce exactly."""
    E, nu, h, s = 0.26e6, 0.48, 4e-3, 1e-3
    body = _rollers(layer_body(h, 3e-3, s, E, nu, model="neo_hookean"))
    lam = 0.8
    res = body.solve(_plate(lam * h), tol=1e-12, rtol=0.0, max_iterations=200)
    mu, K = E / (2 * (1 + nu)), E / (3 * (1 - 2 * nu))
    P = mu * lam ** (-2 / 3) * (lam - (2 + lam ** 2) / (3 * lam)) + K * np.log(lam) / lam
    area = (3 * s) ** 2
    assert -res.total_force[2] == pytest.approx(-P * area, rel=1e-6)
    assert res.residual < 1e-6


def test_finite_strain_agrees_with_linear_at_small_strain_and_stiffens_at_large():
    h, E, nu = 4e-3, 0.3e6, 0.48
    forces = {}
    for strain in (0.01, 0.1):
        d = strain * h
        R = (0.5 * h) ** 2 / d
        ball = sphere(R, [0.0, 0.0, h + R - d])
        for model in ("linear", "neo_hookean"):
            body = layer_body(h, max(3 * math.sqrt(R * d), math.sqrt(R * d) + 4 * h), 1e-3, E, nu, model=model)
            forces[strain, model] = -body.solve(ball, geometry="deformed").total_force[2]
    assert forces[0.01, "neo_hookean"] == pytest.approx(forces[0.01, "linear"], rel=0.015)
    assert forces[0.1, "neo_hookean"] > 1.03 * forces[0.1, "linear"]


def test_finite_strain_relative_tolerance_leaves_little_in_the_force():
    """The finite-strain iterations stop at 5e-4 of the surface's largest displacement as well
    as at 1e-4 of an element (FINITE_RTOL): on the 4 mm layer pressed 25 % by a sphere, that
    moves the force by 2.4e-4 of a solve to 1e-4 of an element alone, in fewer iterations
    (16 against 18; on the product pad's plate press at dx = 1 mm, 54 against 93 over three
    steps)."""
    h, E, nu, strain = 4e-3, 0.3e6, 0.48, 0.25
    d = strain * h
    R = (0.5 * h) ** 2 / d
    ball = sphere(R, [0.0, 0.0, h + R - d])
    body = layer_body(h, math.sqrt(R * d) + 4 * h, 1e-3, E, nu, model="neo_hookean")
    tight = body.solve(ball, geometry="deformed", rtol=0.0, max_iterations=400)
    default = body.solve(ball, geometry="deformed", max_iterations=400)
    assert default.total_force[2] == pytest.approx(tight.total_force[2], rel=5e-4)
    assert default.iterations < tight.iterations


def test_finite_strain_warm_start_and_a_crushed_layer():
    from gausstac_maniskill.errors import SimulationError

    body = layer_body(2e-3, 3e-3, 1e-3, 0.3e6, 0.45, model="neo_hookean")
    first = body.solve(_plate(1.8e-3))
    again = body.solve(_plate(1.8e-3), warm=first)
    assert again.iterations <= 2
    assert again.total_force[2] == pytest.approx(first.total_force[2], rel=1e-4)
    with pytest.raises(SimulationError, match="layer"):
        body.solve(_plate(-0.5e-3), warm=first)  # the plate below the base: nothing can hold that


def test_a_stalled_finite_strain_solve_stops_early_and_says_so(monkeypatch):
    """Guards the stall detector's wiring, not physics: a fixed point that makes no progress (its
    mixing replaced by one that returns its input) fails after STALL_ITERATIONS iterations per
    mixing instead of max_iterations, with an error that names the stall at every mixing tried.
    A layer of whole cubes has no cut cubes to fall back on: its one law is the last resort, so
    it damps the mixing on a stall."""
    from gausstac_maniskill.errors import SimulationError
    from gausstac_maniskill.fem import contact

    calls = []
    monkeypatch.setattr(contact._Anderson, "next", lambda self, u, t: calls.append(1) or u)
    h = 4e-3
    body = _rollers(layer_body(h, 3e-3, 1e-3, 0.26e6, 0.48, model="neo_hookean"))
    with pytest.raises(SimulationError, match=r"mixing 1: finite-strain contact stalled.*mixing 0\.25: finite-strain "
                                              r"contact stalled.*fem_model='linear'") as err:
        body.solve(_plate(0.8 * h), max_iterations=10_000)
    assert "cut cubes linear" not in str(err.value)
    assert len(calls) == len(contact.DAMPED_MIXING) * contact.STALL_ITERATIONS


def test_a_stalled_finite_strain_step_falls_back_to_linear_cut_cubes(monkeypatch):
    """Guards the fallback's wiring, not physics (the plate's slide that needs it is too slow
    for a unit test). On the product pad's cut cells at dx = 2 mm, the fixed point is made to stall
    while the cut cubes are finite: the step is solved again with them linear, says so (the
    result's flag, a SimulationWarning), and reads what a body whose cut cubes are always linear
    reads, to its residual. The next step tries the cut cubes finite again."""
    from gausstac_maniskill.bench.scenes import index_pad, indenter_collider, indenter_pose
    from gausstac_maniskill.errors import SimulationWarning
    from gausstac_maniskill.fem import contact, pad_body
    from gausstac_maniskill.fem import hex as fem_hex
    from gausstac_maniskill.fem.pad import collider_indenter

    pad = index_pad(2e-3)
    ball = collider_indenter(indenter_collider("sphere", indenter_pose("sphere", pad.sensor_frame, -0.5e-3), 0.0))
    reference = pad_body(pad, model="neo_hookean")
    monkeypatch.setattr(fem_hex, "CUT_FINITE_SHARE", math.inf)
    always_linear = reference.solve(ball, max_iterations=400)
    monkeypatch.undo()
    laws = []
    real_remainder, real_next = contact.QuasiStaticBody._remainder, contact._Anderson.next

    def remainder(self, u, cut_cells=True):
        laws.append(cut_cells)
        return real_remainder(self, u, cut_cells)

    monkeypatch.setattr(contact.QuasiStaticBody, "_remainder", remainder)
    monkeypatch.setattr(contact._Anderson, "next", lambda self, u, t: u if laws[-1] else real_next(self, u, t))
    body = pad_body(pad, model="neo_hookean")
    with pytest.warns(SimulationWarning, match=r"stalled.*solved with them linear"):
        res = body.solve(ball, max_iterations=400)
    assert res.cut_cells_linear and not always_linear.cut_cells_linear
    assert laws.count(True) == contact.STALL_ITERATIONS + 1 and laws[-1] is False  # (the last one stops)
    assert np.allclose(res.force, always_linear.force, rtol=0, atol=1e-6 * np.abs(res.force).max())
    assert res.residual == pytest.approx(always_linear.residual, rel=1e-6)
    laws.clear()
    monkeypatch.setattr(contact._Anderson, "next", real_next)
    again = body.solve(ball, warm=res, max_iterations=400)
    assert laws[0] is True and not again.cut_cells_linear


def _plate_indenter(z, mu, x=0.0):
    from gausstac_maniskill.fem import Indenter

    pose = np.eye(4)
    pose[:3, 3] = [x, 0.0, z]
    return Indenter(lambda q: (-q[:, 2], np.tile([0.0, 0.0, -1.0], (len(q), 1))), pose, mu)


def test_friction_stiffens_a_confined_layer_and_a_slide_drags_at_mu():
    """A plate pressed into a bonded, nearly incompressible layer: friction holds the layer
    from flowing out, so the force grows with μ up to full stick; slid far, every point
    slips and the drag is μ times the normal force (Amontons–Coulomb)."""
    h = 4e-3
    forces = []
    for mu in (0.0, 0.3, 5.0):
        body = layer_body(h, 6e-3, 1e-3, 0.3e6, 0.48)
        warm = None
        for z in (h - 0.1e-3, h - 0.2e-3, h - 0.3e-3):
            warm = body.solve(_plate_indenter(z, mu), warm=warm)
        forces.append(-warm.total_force[2])
    assert forces[0] < 0.98 * forces[1] < 0.98 * forces[2]
    body = layer_body(h, 6e-3, 1e-3, 0.3e6, 0.48)
    warm = body.solve(_plate_indenter(h - 0.3e-3, 0.3))
    slid = body.solve(_plate_indenter(h - 0.3e-3, 0.3, x=1e-3), warm=warm)
    fn, ft = -slid.total_force[2], np.hypot(*slid.total_force[:2])
    assert (slid.state[np.abs(slid.force).sum(1) > 0] == 2).all()
    assert ft == pytest.approx(0.3 * fn, rel=1e-3)
    assert slid.total_force[0] > 0  # the plate drags the layer along +x


def _sphere_slide(size, half_width=8e-3):
    """The product pad's layer (4 mm Dragon Skin 10, ν = 0.48), flat and bonded, in elements
    of ``size``: a 5 mm sphere (μ = 0.5) pressed 1 mm in three steps and held three, then slid
    2 mm along +x in four and held three (``bench pad``'s protocol). Returns the held
    (Fn, Ft) [N] after the press and after the slide, as (press Fn, slide Fn, slide Ft)."""
    from gausstac_maniskill.fem import Indenter

    h, R, d = 4e-3, 5e-3, 1e-3
    body = layer_body(h, half_width, size, 0.26e6, 0.48, quarter=False)

    def ball(x, z):
        pose = np.eye(4)
        pose[:3, 3] = [x, 0.0, h + R - z]
        return Indenter(sphere(R, [0.0, 0.0, 0.0]), pose, 0.5)

    warm = None
    for z in (d / 3, 2 * d / 3, d, d, d, d):
        warm = body.solve(ball(0.0, z), geometry="deformed", warm=warm)
    press = -warm.total_force[2]
    for x in (0.5e-3, 1e-3, 1.5e-3, 2e-3, 2e-3, 2e-3, 2e-3):
        warm = body.solve(ball(x, d), geometry="deformed", warm=warm)
    return press, -warm.total_force[2], warm.total_force[0]


def test_a_sliding_sphere_on_a_flat_layer_converges():
    """Convergence of the frictional slide at coarse settings, on the flat layer (no voxel
    staircase): 1 mm and 0.5 mm elements (four and eight through the layer) agree within
    2 % pressed and 7 % slid. Measured at 10 mm half width: 0.5 mm elements are within 0.9 %
    of 0.333 mm ones in Fn and Ft after the slide, 1 mm ones +6.3 % and +4.9 %; on the curved
    product pad the same 0.5 mm elements read +3.9 % and +5.2 % (``bench pad``). The sphere ploughs the surface it drags ahead of it, so the drag
    exceeds μ·Fn."""
    coarse, fine = _sphere_slide(1e-3), _sphere_slide(5e-4)
    assert coarse[0] == pytest.approx(fine[0], rel=0.02)
    assert coarse[1] == pytest.approx(fine[1], rel=0.07)
    assert coarse[2] == pytest.approx(fine[2], rel=0.07)
    assert fine[2] > 0.5 * fine[1]          # dragged along +x, at more than μ·Fn
    assert fine[1] < fine[0]                # sliding unloads the layer (it sticks less)


def test_newton_agrees_with_tresca_iterations_on_a_pressed_layer(monkeypatch):
    """The plate pressed into a bonded layer with μ = 0.5 (stuck centre, slipping rim): the
    semismooth Newton solve converges without falling back, also from the last step's forces,
    and its forces and states are the Tresca iterations' (two independent algorithms for the
    same conditions) to their tolerances (1e-7 m in the points' motion)."""
    from gausstac_maniskill.fem import signorini

    h = 4e-3
    results = {}
    calls = []
    tresca = signorini._solve_tresca
    monkeypatch.setattr(signorini, "_solve_tresca", lambda *a, **k: calls.append(1) or tresca(*a, **k))
    for method, iterations in (("newton", signorini.NEWTON_ITERATIONS), ("tresca", 0)):
        monkeypatch.setattr(signorini, "NEWTON_ITERATIONS", iterations)
        results[method] = layer_body(h, 6e-3, 1e-3, 0.3e6, 0.48).solve(_plate_indenter(h - 0.2e-3, 0.5))
        assert len(calls) == (0 if method == "newton" else 1)
    new, ref = results["newton"], results["tresca"]
    assert {1, 2} <= set(new.state.tolist()) and (new.state == ref.state).all()
    np.testing.assert_allclose(new.total_force, ref.total_force, rtol=0, atol=1e-3 * np.abs(ref.total_force).max())
    np.testing.assert_allclose(new.force, ref.force, rtol=0, atol=1e-2 * np.abs(ref.force).max())
    monkeypatch.setattr(signorini, "NEWTON_ITERATIONS", 40)
    deeper = layer_body(h, 6e-3, 1e-3, 0.3e6, 0.48).solve(_plate_indenter(h - 0.4e-3, 0.5), warm=new)
    assert len(calls) == 1 and deeper.total_force[2] < 1.5 * new.total_force[2]


def test_a_solve_from_its_own_solution_takes_one_pass():
    """Guard of the warm start on the deformed geometry (contact read where the surface is):
    a sphere pressed into a bonded layer, then solved again from that result with nothing
    moved, reads the same forces in one outer pass (a solve started from the rest surface takes
    two or three), with friction or without; and without friction (a unique
    solution) a deeper press from it matches the same press from rest."""
    from gausstac_maniskill.fem import Indenter

    h, R = 4e-3, 5e-3

    def ball(depth, mu):
        pose = np.eye(4)
        pose[2, 3] = h + R - depth
        return Indenter(sphere(R, np.zeros(3)), pose, mu)

    for mu in (0.0, 0.5):
        body = layer_body(h, 6e-3, 0.5e-3, 0.3e6, 0.48)
        first = body.solve(ball(0.4e-3, mu), geometry="deformed", margin=0.0)
        assert first.iterations >= 2
        again = body.solve(ball(0.4e-3, mu), geometry="deformed", margin=0.0, warm=first)
        assert again.iterations == 1
        np.testing.assert_allclose(again.force, first.force, rtol=0, atol=1e-5 * np.abs(first.force).max())
    deeper = body.solve(ball(0.6e-3, 0.0), geometry="deformed", margin=0.0, warm=first)
    cold = body.solve(ball(0.6e-3, 0.0), geometry="deformed", margin=0.0)
    assert deeper.total_force[2] == pytest.approx(cold.total_force[2], rel=1e-5)
