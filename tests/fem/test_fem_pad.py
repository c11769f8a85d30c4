"""Quasi-static bodies built from the product's pads (fem/pad.py)."""
import numpy as np
import pytest


def test_product_pad_press_is_positive_monotone_and_repeatable():
    from gausstac_maniskill.bench.quasistatic import _pad
    from gausstac_maniskill.bench.pad import _collider, indenter_pose
    from gausstac_maniskill.fem import pad_body
    from gausstac_maniskill.mpm.colliders import signed_distance

    pad = _pad(1e-3)
    body = pad_body(pad)
    assert body.fixed.any(axis=1).sum() > 0
    S = pad.sensor_frame
    forces = []
    for d in (0.25e-3, 0.5e-3, 1e-3):
        col = _collider("sphere", indenter_pose("sphere", S, -d), 0.0)

        def sdf(x, col=col):
            phi, n = signed_distance(col, x)
            return phi.astype(float), n.astype(float)

        first = body.solve(sdf)
        again = body.solve(sdf)  # every column kept: a held step
        assert np.array_equal(first.force, again.force)
        forces.append(-(S[:3, :3].T @ first.total_force)[2])
    assert 0 < forces[0] < forces[1] < forces[2]


def test_collider_indenter_matches_the_collider_and_rejects_bad_friction():
    from gausstac_maniskill.errors import ConfigError
    from gausstac_maniskill.fem import Indenter, collider_indenter
    from gausstac_maniskill.mpm import Sphere, signed_distance
    from gausstac_maniskill.transforms import make_pose

    link = make_pose([0.01, -0.02, 0.03], np.eye(3))
    ball = Sphere(radius=5e-3, pose=make_pose([0.012, -0.02, 0.04], np.eye(3)), friction=0.4)
    ind = collider_indenter(ball, link)
    x = np.random.default_rng(0).normal(size=(20, 3)) * 5e-3  # link frame
    phi, n = ind(x)
    ref_phi, ref_n = signed_distance(ball, x + link[:3, 3])
    assert np.allclose(phi, ref_phi, atol=1e-7) and np.allclose(n, ref_n, atol=1e-5)
    assert ind.friction == pytest.approx(0.4)
    with pytest.raises(ConfigError, match="friction"):
        Indenter(lambda q: (q[:, 2], q), np.eye(4), friction=-1.0)
