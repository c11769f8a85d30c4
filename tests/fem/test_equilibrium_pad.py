"""The pad solved at equilibrium inside the co-simulator (fem/sensor.py, GaussTacSim(pad_solver="fem"))."""
import contextlib

import numpy as np
import pytest

from gausstac_maniskill.errors import ConfigError

DX = 2e-3  # 1 mm elements: the coarsest lattice, for speed


def _scene(friction=0.5, nu=None, dx=DX, indenter="sphere"):
    import dataclasses

    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim

    spec = bp.index_spec()
    if nu is not None:
        spec = dataclasses.replace(spec, material=dataclasses.replace(spec.material, nu=nu))
    with pytest.warns(Warning) if dx > 1e-3 else contextlib.nullcontext():
        sim = GaussTacSim([spec], {bp.INDEX: bp.LINK_POSE}, settings=SolverSettings(dx=dx), pad_solver="fem")
    W = bp.LINK_POSE @ sim.pads[bp.INDEX].sensor_frame
    sim.add_rigid_object("indenter", bp.indenter_collider(indenter, bp.indenter_pose(indenter, W, bp.GAP), friction))

    def press(z, x=0.0):
        maps = sim.step({bp.INDEX: bp.LINK_POSE}, 0.05, {"indenter": bp.indenter_pose(indenter, W, z, x)})[bp.INDEX]
        return W[:3, :3].T @ sim.object_wrench("indenter")[0], maps  # on the indenter, sensor axes

    return sim, W, press


def test_fem_pad_press_reads_consistent_forces_and_returns_to_rest():
    """Guards, not physics: the force map sums the same point forces as the indenter's
    reaction, the link receives what the indenter pushes (a massless pad), and the elements'
    internal forces balance the contact (the solve converged). Physics: the press stiffens
    as the patch grows, the surface yields less than the press, no taxel pulls, and the pad
    is exactly at rest once the indenter has left."""
    from gausstac_maniskill.bench import scenes as bp

    sim, W, press = _scene()
    F0, m0 = press(bp.GAP)
    assert not np.any(F0) and float(m0["force"].abs().sum()) == 0.0
    forces = []
    for z in (-0.5e-3, -1e-3):
        F, maps = press(z)
        forces.append(F[2])
        assert F[2] > 0
        assert float(maps["force"].sum()) == pytest.approx(F[2], rel=1e-5)
        assert float(maps["force"].min()) >= 0.0  # no pulling taxel
        f_link, _ = sim.link_wrench(bp.INDEX)
        np.testing.assert_allclose(f_link, -sim.object_wrench("indenter")[0], atol=1e-9)
        stress = -sim.pad_stress_force(bp.INDEX)[2]  # the elements' internal forces: equal at equilibrium
        assert stress == pytest.approx(F[2], rel=1e-3)  # (a guard on the solve's convergence)
        depth = float(maps["depth"].max())
        assert 0.3 * -z < depth < -z  # the surface yields less than the press
    assert forces[1] > 2.0 * forces[0]  # contact stiffens as the patch grows
    contacts = sim.link_contacts(bp.INDEX)
    assert list(contacts) == ["indenter"] and contacts["indenter"][6] > 0
    F, maps = press(3e-3)  # away: unloaded equilibrium is the rest shape, exactly
    assert not np.any(F)
    for k in ("depth", "shear", "force", "pressure"):
        assert float(maps[k].abs().max()) == 0.0
    x, _ = sim.pad_particles(bp.INDEX)
    pad = sim.pads[bp.INDEX]
    np.testing.assert_allclose(x, pad.rest @ bp.LINK_POSE[:3, :3].T + bp.LINK_POSE[:3, 3], atol=1e-7)


def test_fem_pad_friction_resists_a_slide_and_state_round_trips():
    from gausstac_maniskill.bench import scenes as bp

    sim, W, press = _scene(friction=0.5)
    press(bp.GAP)
    press(-0.5e-3)
    press(-1e-3)
    saved = sim.state_dict()
    F_pressed, m_pressed = press(-1e-3)  # a held step from the saved state
    F_slid, maps = press(-1e-3, 1e-3)
    assert F_slid[0] < -0.1 * F_slid[2]  # the indenter is held back along -x
    assert abs(F_slid[0]) <= 0.55 * F_slid[2] + 1e-9  # and not beyond Coulomb's bound (μ = 0.5, curved surface)
    assert float(maps["shear"][..., 0].max()) > 1e-5  # the surface is dragged along +x
    sim.load_state_dict(saved)
    F_again, m_again = press(-1e-3)  # the same held step from the restored state: bit-exact
    np.testing.assert_array_equal(F_again, F_pressed)
    for k in m_pressed:
        np.testing.assert_array_equal(m_again[k].cpu().numpy(), m_pressed[k].cpu().numpy())
    sim.load_state_dict(saved)  # and the same slide from it (the restored state's pose is the saved one)
    np.testing.assert_array_equal(press(-1e-3, 1e-3)[0], F_slid)

    # the flat form (what ManiSkill's get_state_dict and RecordEpisode store), into a fresh scene
    sim.load_state_dict(saved)
    flat = sim.flat_state()
    assert flat["fem0_solved"][0] and flat["fem0_has_result_pose"][0] and flat["fem0_has_pose"][0]
    assert (flat["fem0_owner"] == 0).all()  # every point on the one object
    other, _, press_other = _scene(friction=0.5)
    other.load_flat_state(flat)
    np.testing.assert_array_equal(press_other(-1e-3, 1e-3)[0], F_slid)
    # kept in the process, not rebuilt
    assert other.solvers["fem"].pads[bp.INDEX].body is sim.solvers["fem"].pads[bp.INDEX].body
    from gausstac_maniskill.fem.sensor import forget_bodies

    forget_bodies()
    assert _scene(friction=0.5)[0].solvers["fem"].pads[bp.INDEX].body is not sim.solvers["fem"].pads[bp.INDEX].body
    flat_again = other.flat_state()  # (after a step: another state, the same shapes)
    assert {k: np.shape(v) for k, v in flat_again.items()} == {k: np.shape(v) for k, v in flat.items()}
    with pytest.raises(ConfigError, match="fem0_.*pad_solver='mpm'"):  # e.g. a state recorded with the MPM pads
        other.load_flat_state({k: v for k, v in flat.items() if not k.startswith("fem0_")})
    with pytest.raises(ConfigError, match="lacks.*owner"):  # a state without the points' owners
        other.load_flat_state({k: v for k, v in flat.items() if k != "fem0_owner"})
    # (the flag of a finite-strain step solved by the fallback)
    sim.solvers["fem"].pads[bp.INDEX].result.cut_cells_linear = True
    flagged = sim.flat_state()
    other.load_flat_state(flagged)
    assert other.solvers["fem"].pads[bp.INDEX].result.cut_cells_linear
    other.load_flat_state({k: v for k, v in flagged.items() if k != "fem0_cut_cells_linear"})  # a state without the flag
    assert not other.solvers["fem"].pads[bp.INDEX].result.cut_cells_linear


def _box_scene(halves: bool, friction: float):
    """The index pad pressed by a 24 × 24 mm box face, whole or as two boxes side by side
    split off the particle lattice (their union is the whole box's volume)."""
    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim
    from gausstac_maniskill.geometry.colliders import Box
    from gausstac_maniskill.transforms import make_pose

    with pytest.warns(Warning, match="spans only"):
        sim = GaussTacSim([bp.index_spec()], {bp.INDEX: bp.LINK_POSE}, settings=SolverSettings(dx=DX),
                          pad_solver="fem")
    W = bp.LINK_POSE @ sim.pads[bp.INDEX].sensor_frame
    a, h, split = 12e-3, 3e-3, 0.37e-3

    def poses(z, x=0.0):
        P = bp.indenter_pose("plate", W, z, x)  # local z toward the pad; the face at local z = 0
        if not halves:
            return {"whole": P @ make_pose([0.0, 0.0, -h], np.eye(3))}
        return {"left": P @ make_pose([split - a / 2, 0.0, -h], np.eye(3)),
                "right": P @ make_pose([split + a / 2, 0.0, -h], np.eye(3))}

    for key, pose in poses(bp.GAP).items():
        sim.add_rigid_object(key, Box(half_extents=(a / 2 if halves else a, a, h), pose=pose, friction=friction))

    def press(z, x=0.0):
        sim.step({bp.INDEX: bp.LINK_POSE}, 0.05, poses(z, x))
        return {k: W[:3, :3].T @ sim.object_wrench(k)[0] for k in poses(z)}

    return sim, press


@pytest.mark.parametrize("friction", [0.0, 0.5])
def test_fem_pad_pressed_by_two_objects_reads_as_their_union(friction):
    """A pad within reach of two objects meets both (each surface point the nearer): two boxes
    side by side press and drag it as the one box they make up (the same contact problem on
    the union), and each object receives its own points' forces. Then the flat state of a
    two-object contact restores bit-exactly (each point's hold kept on its own object)."""
    from gausstac_maniskill.bench import scenes as bp

    steps = [(bp.GAP, 0.0), (-0.25e-3, 0.0), (-0.5e-3, 0.0), (-0.5e-3, 0.25e-3)]
    whole, parts = _box_scene(False, friction), _box_scene(True, friction)
    for z, x in steps:
        F_whole, F_parts = whole[1](z, x)["whole"], parts[1](z, x)
        np.testing.assert_allclose(F_parts["left"] + F_parts["right"], F_whole, rtol=0,
                                   atol=1e-5 * np.abs(F_whole).max() + 1e-12)
    sim = parts[0]
    assert F_parts["left"][2] > 0.1 * F_whole[2] and F_parts["right"][2] > 0.1 * F_whole[2]  # both press
    f_link, _ = sim.link_wrench(bp.INDEX)  # the link gets what the two objects push
    np.testing.assert_allclose(f_link, -(sim.object_wrench("left")[0] + sim.object_wrench("right")[0]), atol=1e-9)
    assert sorted(sim.link_contacts(bp.INDEX)) == ["left", "right"]
    saved = sim.flat_state()
    assert saved["fem0_has_pose"].tolist() == [True, True] and set(saved["fem0_owner"].tolist()) == {0, 1}
    slid = parts[1](-0.5e-3, 0.5e-3)
    other = _box_scene(True, friction)
    other[0].load_flat_state(saved)
    again = other[1](-0.5e-3, 0.5e-3)
    for k in slid:
        np.testing.assert_array_equal(again[k], slid[k])


def test_fem_pad_linear_model_says_when_pressed_beyond_its_range():
    """A press of 75 % of the layer is outside the linear model's small-strain range: a
    SimulationWarning says so, once while it lasts, and not again after the pad came back."""
    import warnings as w

    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.errors import SimulationWarning

    sim, W, press = _scene(indenter="plate")
    with w.catch_warnings(record=True) as caught:
        w.simplefilter("always")
        for z in (bp.GAP, -1e-3, -3e-3, -3.2e-3, -1e-3):
            press(z)
        said = [c for c in caught if issubclass(c.category, SimulationWarning)]
        assert len(said) == 1 and "not physical" in str(said[0].message) and "of its 4 mm layer" in str(said[0].message)
        press(-3e-3)  # beyond it again: said again
        assert len([c for c in caught if issubclass(c.category, SimulationWarning)]) == 2


def test_fem_precompute_reaches_the_pads(monkeypatch):
    """Guard: GaussTacSim(fem_precompute=...) decides whether a pad's compliance is computed
    in full when its body is built (the default does at this coarse grid) or point by point;
    a pad whose compliance exceeds the default's limit is solved point by point and says so,
    naming the option (a CostWarning), while one asked for point by point says nothing."""
    import warnings

    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim
    from gausstac_maniskill.errors import CostWarning
    from gausstac_maniskill.fem import sensor
    from gausstac_maniskill.fem.sensor import forget_bodies

    for choice, limit, full in ((False, None, False), (None, None, True), (None, 1, False)):
        forget_bodies()  # (bodies are kept per process: build each one anew)
        if limit is not None:
            monkeypatch.setattr(sensor, "PRECOMPUTE_BYTES", limit)
        with pytest.warns(Warning, match="spans only"):
            sim = GaussTacSim([bp.index_spec()], {bp.INDEX: bp.LINK_POSE}, settings=SolverSettings(dx=DX),
                              pad_solver="fem", fem_precompute=choice)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            sim.prepare_pads()
        costly = [str(c.message) for c in caught if issubclass(c.category, CostWarning)]
        assert len(costly) == (limit is not None), costly
        if costly:
            assert "point by point" in costly[0] and "fem_precompute=True" in costly[0]
        body = sim.solvers["fem"].pads[bp.INDEX].body
        assert (body.columns_solved == body.num_points) is full
    forget_bodies()


def test_fem_pad_held_step_keeps_the_equilibrium():
    """Guards the held-step shortcut: an unchanged relative pose keeps the last solution (no
    solve); a motion beyond the solver's tolerance solves again."""
    from gausstac_maniskill.bench import scenes as bp

    sim, W, press = _scene(friction=0.5)
    press(bp.GAP)
    press(-1e-3)
    fp = sim.solvers["fem"].pads[bp.INDEX]
    res = fp.result
    press(-1e-3)
    assert fp.result is res
    press(-1e-3 - 10 * fp.hold_tolerance)
    assert fp.result is not res and fp.result.total_force[2] != res.total_force[2]


def test_fem_pad_released_within_reach_reads_zero():
    """A pressed, frictional pad whose indenter backs off to just clear of it (still within one
    element: solved, no point in contact) reads zero force and maps (guards against the last
    step's warm start being taken for this solve's contact points)."""
    from gausstac_maniskill.bench import scenes as bp

    sim, W, press = _scene(friction=0.5)
    press(bp.GAP)
    press(-0.5e-3)
    F, maps = press(0.3 * DX / 2)  # 0.3 mm clear: within the 1 mm element, touching nothing
    assert sim.solvers["fem"].pads[bp.INDEX].result is not None  # it was solved, not released
    assert not np.any(F) and float(maps["force"].abs().max()) == 0.0
    F, maps = press(-0.5e-3)  # and presses again from there
    assert F[2] > 0


def test_fem_pad_near_incompressible_is_stable_and_stiffer():
    """ν = 0.499: no locking in the elements (selective reduced integration), a finite press;
    a bonded thin layer stiffens as ν → 0.5, so it reads more than at ν = 0.48."""
    from gausstac_maniskill.bench import scenes as bp

    out = []
    for nu in (0.48, 0.499):
        sim, W, press = _scene(friction=0.0, nu=nu)
        press(bp.GAP)
        F, maps = press(-1e-3)
        assert np.isfinite(maps["pressure"].cpu().numpy()).all()
        out.append(F[2])
    assert 0 < out[0] < out[1] < 3.0 * out[0]


def test_fem_pad_bad_input():
    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim

    args = ([bp.index_spec()], {bp.INDEX: bp.LINK_POSE})
    with pytest.raises(ConfigError, match="pad_solver"):
        GaussTacSim(*args, pad_solver="implicit")
    with pytest.raises(ConfigError, match="pad_surface='mesh'"):
        GaussTacSim(*args, settings=SolverSettings(dx=DX), pad_solver="fem", pad_surface="particles")
    with pytest.warns(Warning):
        sim = GaussTacSim(*args, settings=SolverSettings(dx=DX), pad_solver="fem", fem_model="neo_hookean")
    with pytest.raises(ConfigError, match="fem_model='linear' only.*'neo_hookean'"):
        sim.add_soft_object("sponge", np.zeros((8, 3)) + [0, 0, 0.2], bp.index_spec().material)
    assert not sim.solvers["fem"].surface_colliders and not sim.world.colliders  # nothing added by the refusal
    rest = sim.flat_state()  # at rest, before any solve: no body assembled for it
    assert not rest["fem0_solved"][0] and sim.solvers["fem"].pads[bp.INDEX]._body is None
    from gausstac_maniskill.fem.sensor import EquilibriumPad

    with pytest.raises(ConfigError, match="model"):
        EquilibriumPad(sim.pads[bp.INDEX], model="hooke")


def test_default_pads_stay_at_equilibrium_with_soft_objects():
    """GaussTacSim's default (pad_solver="auto"): the pads solved at equilibrium, also when a soft
    object comes (before or after they touched something: each pad's surface becomes a collider
    of the MPM world). Finite-strain pads (fem_model="neo_hookean") meet soft objects only as
    MPM pads: a soft object added before they touched anything turns them into those; one
    added after is refused with what to do. pad_surface="particles" (the equilibrium pads'
    contact is on the mesh) resolves to the MPM pads."""
    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim

    args = ([bp.index_spec()], {bp.INDEX: bp.LINK_POSE})
    settings = SolverSettings(dx=DX)
    mat = bp.index_spec().material
    # a 6 × 6 × 3 mm block of the pad's material touching the pad face (particles 0.5 mm apart)
    g = np.stack(np.meshgrid(np.arange(-3e-3, 3e-3, 5e-4), np.arange(-3e-3, 3e-3, 5e-4), np.arange(2.5e-4, 3e-3, 5e-4),
                             indexing="ij"), -1).reshape(-1, 3)
    far = g + [0, 0, 0.2]
    for touched in (False, True):
        with pytest.warns(Warning, match="spans only"):
            sim = GaussTacSim(*args, settings=settings)
        W = bp.LINK_POSE @ sim.pads[bp.INDEX].sensor_frame
        block = g @ W[:3, :3].T + W[:3, 3] + W[:3, 2] * 1e-4
        if touched:
            sim.add_rigid_object("ball", bp.indenter_collider("sphere", bp.indenter_pose("sphere", W, -0.5e-3), 0.5))
            sim.step({bp.INDEX: bp.LINK_POSE}, 0.05)
            assert sim.solvers["fem"].pads[bp.INDEX].touching
        sim.add_soft_object("block", far if touched else block, mat)
        fem = sim.solvers["fem"]
        assert sim.pad_solver == "fem" and bp.INDEX in fem.pads and bp.INDEX in fem.surface_colliders

    with pytest.warns(Warning):
        nh = GaussTacSim(*args, settings=settings, fem_model="neo_hookean")
    nh.add_soft_object("block", block, mat)
    assert nh.pad_solver == "mpm" and not nh.solvers["fem"].pads
    nh.step({bp.INDEX: bp.LINK_POSE}, 0.01)
    assert nh.is_awake(bp.INDEX)  # an MPM pad, woken by the block beside it
    with pytest.warns(Warning):
        nh = GaussTacSim(*args, settings=settings, fem_model="neo_hookean")
    nh.add_rigid_object("ball", bp.indenter_collider("sphere", bp.indenter_pose("sphere", W, -0.5e-3), 0.5))
    nh.step({bp.INDEX: bp.LINK_POSE}, 0.05)
    with pytest.raises(ConfigError, match="'neo_hookean' and have touched something already.*pad_solver='mpm'"):
        nh.add_soft_object("block", far, mat)
    with pytest.warns(Warning, match="spans only"):
        assert GaussTacSim(*args, settings=settings, pad_surface="particles").pad_solver == "mpm"


def _sponge_distance_to_pad(sim, pad_name: str, sponge: np.ndarray) -> float:
    """Smallest distance [m] of the ``sponge`` particles [N, 3] (world) outside the pad's deformed
    surface, along the nearest surface point's outward normal (negative: inside the pad)."""
    from scipy.spatial import cKDTree

    fp = sim.solvers["fem"].pads[pad_name]
    T = sim._link_pose[fp.pad.spec.link]
    body = fp.body
    surface = body.points + (0.0 if fp.result is None else fp.result.displacement)
    local = (sponge - T[:3, 3]) @ T[:3, :3]
    near = cKDTree(surface).query(local)[1]
    return float(np.einsum("si,si->s", local - surface[near], fp.pad.normal[fp.point_particles][near]).min())


def test_fem_pad_meets_a_soft_sponge_and_reads_its_push():
    """Physics: an equilibrium pad pressed by an MPM sponge bound to a holder (``bench soft``'s
    scene, here at dx = 2 mm) reads in its force map the sponge's own stress force (virtual work
    over the sponge: a reading independent of the contact impulses) within 6 %, and no sponge
    particle passes into the pad's deformed surface. Guards: the pad's surface collider is
    lowered where the pad was pushed in (the shape coupling is wired), the link receives the push
    (the soft row, key None), a held step from a saved state is bit-exact (on CUDA to float32
    rounding), and the pad is exactly at rest, its collider at its rest shape, once the sponge
    has been pulled away."""
    from gausstac_maniskill.bench import soft

    with pytest.warns(Warning, match="spans only"):
        sim, press, reading = soft.sponge_scene(1, DX, "fem")
    for k in range(5):
        maps = press(soft.PRESS * min(1.0, (k + 1) / 3))[soft.INDEX]
    in_map, on_pad, on_sponge = reading()
    assert on_sponge > 0.3 and in_map == pytest.approx(on_sponge, rel=0.06)
    assert float(maps["force"].min()) >= 0.0 and float(maps["depth"].max()) > 0.0
    sponge = sim.world.positions("sponge").astype(np.float64)
    assert _sponge_distance_to_pad(sim, soft.INDEX, sponge) > 0.0  # nothing passes through the pad
    contacts = sim.link_contacts(soft.INDEX)
    assert list(contacts) == [None]
    R = sim._link_pose[soft.INDEX][:3, :3] @ sim.pads[soft.INDEX].sensor_frame[:3, :3]
    np.testing.assert_allclose(-(R.T @ sim.link_wrench(soft.INDEX)[0])[2], in_map, rtol=1e-5)  # pushed in: -z

    saved = sim.state_dict()
    c = sim.solvers["fem"].surface_colliders[soft.INDEX]
    rest = sim.solvers["fem"].surface_rest[soft.INDEX]
    pushed_in = -float(sim.solvers["fem"].pads[soft.INDEX].normal_displacement().min())
    held = press(soft.PRESS)[soft.INDEX]
    met = -float(sim.solvers["fem"].pads[soft.INDEX]._surface[0].min())  # the shape the sponge met then (relaxed)
    assert float((sim.world.colliders[c].sdf - rest).max()) == pytest.approx(met, rel=1e-4)
    assert met == pytest.approx(pushed_in, rel=0.02)  # held: the shape solved the step before
    sim.load_state_dict(saved)
    again = press(soft.PRESS)[soft.INDEX]
    for k in held:  # bit-exact on the CPU; CUDA's atomic scatter sums in a run-dependent order
        tol = 0.0 if sim.world.bit_reproducible else 1e-5 * float(held[k].abs().max())
        np.testing.assert_allclose(again[k].cpu().numpy(), held[k].cpu().numpy(), rtol=0, atol=tol, err_msg=k)

    for _ in range(3):  # the holder pulled 3 mm back: the sponge leaves the pad
        maps = press(-3e-3)[soft.INDEX]
    assert sim.solvers["fem"].pads[soft.INDEX].result is None
    for k in ("depth", "shear", "force", "pressure"):
        assert float(maps[k].abs().max()) == 0.0
    press(-3e-3)  # (the collider takes the rest shape before the step after the release)
    assert sim.world.colliders[c].sdf is rest


def test_fem_pad_held_against_an_object_as_stiff_as_itself_settles(monkeypatch):
    """The staggered pad–object coupling where the object is as stiff as the pad (the sponge of
    ``bench soft`` made of the pad's 260 kPa): fed the pad's solved shape as it is, the held
    force swings ±4.5 % from step to step without settling; relaxed
    (:meth:`~gausstac_maniskill.fem.sensor.EquilibriumPad.relax_surface`) it settles within
    0.5 % over the last held steps, and the map reads the sponge's own stress within 6 %."""
    from gausstac_maniskill.bench import soft

    monkeypatch.setattr(soft, "SPONGE", dict(soft.SPONGE, E=2.6e5))
    with pytest.warns(Warning, match="spans only"):
        sim, press, reading = soft.sponge_scene(1, DX, "fem")
    forces = []
    for k in range(9):
        press(soft.PRESS * min(1.0, (k + 1) / 3))
        forces.append(reading())
    last = [f[0] for f in forces[-3:]]
    assert max(last) - min(last) < 0.005 * last[-1], last
    assert forces[-1][0] == pytest.approx(forces[-1][2], rel=0.06)
    assert sim.solvers["fem"].pads[soft.INDEX]._surface[3] > 0.3  # κ read from the hold: the object is stiff


def test_centre_state_neo_hookean_linearises_to_the_linear_stress():
    """The two material laws of the pad agree at small strain (the stress read for the maps)."""
    from gausstac_maniskill.fem.hex import centre_state, voxel_body

    ijk = np.stack(np.meshgrid(*[np.arange(3)] * 3, indexing="ij"), -1).reshape(-1, 3)
    body = voxel_body(ijk, np.zeros(3), 1e-3)
    u = np.random.default_rng(1).normal(size=(len(body.nodes), 3)) * 1e-9
    F_lin, s_lin = centre_state(body, u, 2e5, 0.48, "linear")
    F_nh, s_nh = centre_state(body, u, 2e5, 0.48, "neo_hookean")
    np.testing.assert_allclose(F_lin, F_nh)
    np.testing.assert_allclose(s_nh, s_lin, atol=1e-4 * np.abs(s_lin).max())
    assert np.abs(s_lin).max() > 0
