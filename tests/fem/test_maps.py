"""A linear pad's tactile maps as one matrix times its contact forces (fem/maps.py)."""
import os

import numpy as np
import pytest

DX = 2e-3  # 1 mm elements: the coarsest lattice, for speed


def _pad_and_body():
    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim
    from gausstac_maniskill.tactile.extract import TaxelBinning

    with pytest.warns(Warning, match="spans only"):
        sim = GaussTacSim([bp.index_spec()], {bp.INDEX: bp.LINK_POSE}, settings=SolverSettings(dx=DX),
                          pad_solver="fem")
    pad = sim.pads[bp.INDEX]
    return sim, pad, sim.solvers["fem"].pads[bp.INDEX].body, TaxelBinning.for_pad(pad)


def test_map_readout_reads_a_homogeneous_strain_exactly():
    """Physics of the readout: under a displacement field linear in position, u = G X, every
    element holds the strain ε = sym(G) exactly (trilinear elements reproduce linear fields),
    so every taxel with soft particles reads the pressure −zᵀσz of Hooke's law, σ = λ tr ε I +
    2μ ε; and depth and shear are the taxels' footprint-weighted means of −u·z and (u·x, u·y)
    over the surface particles (soft ones at G X, bonded ones at rest), computed here from the
    field at the particles, not from the elements."""
    from gausstac_maniskill.fem.maps import map_readout

    _, pad, body, binning = _pad_and_body()
    rng = np.random.default_rng(3)
    G = 0.01 * rng.standard_normal((3, 3))
    nodes = body.body.origin + body.body.nodes * body.body.size  # [V, 3] rest positions, link frame
    r = map_readout(pad, body, binning) @ (nodes @ G.T).ravel()
    T = binning.rows * binning.cols
    S = pad.sensor_frame[:3, :3]

    E, nu = body.E, body.nu
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    eps = 0.5 * (G + G.T)
    z = S[:, 2]
    expected_p = -(lam * np.trace(eps) + 2 * mu * z @ eps @ z)
    inside = (binning.taxel >= 0).any(axis=1)
    has_soft = binning.accumulate(~pad.kinematic & inside) > 1e-9
    assert has_soft.sum() > 0.5 * T
    np.testing.assert_allclose(r[3 * T:][has_soft], expected_p, rtol=1e-9)
    assert not np.any(r[3 * T:][~has_soft])

    u = np.where(pad.kinematic[:, None], 0.0, pad.rest @ G.T) @ S  # at the particles, sensor axes
    surf = pad.surface & inside
    count = np.maximum(binning.accumulate(surf), 1e-300)
    for row0, values in ((0, -u[:, 2]), (T, u[:, 0]), (2 * T, u[:, 1])):
        np.testing.assert_allclose(r[row0:row0 + T], binning.accumulate(surf, values) / count * (count > 1e-9),
                                   atol=1e-9 * np.abs(values).max())


def test_pad_maps_equal_the_particles_maps_and_need_no_factor():
    """Guards, not physics: the maps read as one matrix times the forces (what the co-simulator
    uses for a linear pad with its full compliance) equal those from the particles' state (one
    solve of the whole body), pressed and slid; once both matrices are on disk a fresh body
    reads its maps without factoring its stiffness."""
    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.config import SolverSettings
    from gausstac_maniskill.cosim import GaussTacSim
    from gausstac_maniskill.fem.sensor import forget_bodies
    from gausstac_maniskill.tactile.extract import tactile_maps

    forget_bodies()
    sim, pad, body, binning = _pad_and_body()
    W = bp.LINK_POSE @ pad.sensor_frame
    sim.add_rigid_object("ball", bp.indenter_collider("sphere", bp.indenter_pose("sphere", W, bp.GAP), 0.5))
    fp = sim.solvers["fem"].pads[bp.INDEX]
    for z, x in ((-0.5e-3, 0.0), (-1e-3, 0.0), (-1e-3, 1e-3)):
        maps = sim.step({bp.INDEX: bp.LINK_POSE}, 0.05, {"ball": bp.indenter_pose("sphere", W, z, x)})[bp.INDEX]
        assert fp.body.has_compliance and fp.result is not None
        pos, _, sigma, f = fp.particle_state(bp.LINK_POSE)
        ref = tactile_maps(pad, sim.solvers["fem"].binning[bp.INDEX], pos, bp.LINK_POSE, f, sigma)
        for k in ref:
            scale = float(ref[k].abs().max())
            assert scale > 0
            np.testing.assert_allclose(maps[k].cpu().numpy(), ref[k].numpy(), atol=1e-5 * scale)

    forget_bodies()
    with pytest.warns(Warning, match="spans only"):
        again = GaussTacSim([bp.index_spec()], {bp.INDEX: bp.LINK_POSE}, settings=SolverSettings(dx=DX),
                            pad_solver="fem")
    again.add_rigid_object("ball", bp.indenter_collider("sphere", bp.indenter_pose("sphere", W, -1e-3, 1e-3), 0.5))
    again.load_state_dict(sim.state_dict())
    m2 = again.step({bp.INDEX: bp.LINK_POSE}, 0.05, {"ball": bp.indenter_pose("sphere", W, -1e-3, 1e-3)})[bp.INDEX]
    fp = again.solvers["fem"].pads[bp.INDEX]
    assert fp.body is not body and not fp.body.factored
    for k in maps:
        np.testing.assert_allclose(m2[k].cpu().numpy(), maps[k].cpu().numpy(), atol=1e-6 * float(maps[k].abs().max()))
    forget_bodies()


def test_first_contact_sweeps_the_pad_once(tmp_path, monkeypatch):
    """Guard of the first-contact cost: a linear pad's compliance and its maps' response (the
    co-simulator's default binning) come from one sweep of its stiffness, and the maps then
    read need no second one; both are kept on disk."""
    from gausstac_maniskill.bench import scenes as bp
    from gausstac_maniskill.fem.contact import QuasiStaticBody
    from gausstac_maniskill.fem.sensor import forget_bodies

    monkeypatch.setenv("GAUSSTAC_CACHE", str(tmp_path))
    sweeps = []
    real = QuasiStaticBody.inverse_products

    def spy(self, loads, pairs, **k):
        sweeps.append(pairs)
        return real(self, loads, pairs, **k)

    monkeypatch.setattr(QuasiStaticBody, "inverse_products", spy)
    forget_bodies()
    sim, pad, body, _ = _pad_and_body()
    W = bp.LINK_POSE @ pad.sensor_frame
    sim.add_rigid_object("ball", bp.indenter_collider("sphere", bp.indenter_pose("sphere", W, bp.GAP), 0.5))
    maps = sim.step({bp.INDEX: bp.LINK_POSE}, 0.05, {"ball": bp.indenter_pose("sphere", W, -1e-3)})[bp.INDEX]
    assert float(maps["force"].sum()) > 0
    assert sweeps == [[(0, 0), (1, 0)]]
    assert sorted(f.split("-")[0] for f in os.listdir(tmp_path / "compliances")) == ["compliance", "readout"]
    forget_bodies()
