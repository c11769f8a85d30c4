"""Pads from the Allegro URDF and bad pad descriptions."""
import numpy as np
import pytest
import trimesh

from gausstac_maniskill.config import PadSpec, SensorLayout
from gausstac_maniskill.errors import AssetError, ConfigError
from gausstac_maniskill.tactile import ALLEGRO_TIPS, allegro_pad_specs, build_pad
from gausstac_maniskill.urdf import default_hand_urdf, link_mesh

DX = 1.5e-3
H = DX / 2


@pytest.mark.parametrize("spec", allegro_pad_specs(), ids=lambda s: s.link)
def test_pads_build_for_all_four_allegro_tips(spec):
    mesh = link_mesh(default_hand_urdf(), spec.link)
    pad = build_pad(spec, mesh, H, DX)
    assert pad.num_particles > 500
    soft = ~pad.kinematic
    # soft layer within `thickness` of the surface, kinematic layer one cell below it
    assert pad.depth[soft].max() <= spec.thickness + 1e-9
    assert pad.depth[pad.kinematic].min() > spec.thickness
    assert pad.depth[pad.kinematic].max() <= spec.thickness + 2 * DX + 1e-9
    # all on the palmar side (+x), inside the cone
    assert np.all(pad.rest[:, 0] > 0)
    # the sensor frame is a rotation whose z is the pad axis
    S = pad.sensor_frame
    np.testing.assert_allclose(S[:3, :3] @ S[:3, :3].T, np.eye(3), atol=1e-9)
    np.testing.assert_allclose(S[:3, 2], spec.axis, atol=1e-9)
    assert spec.link in ALLEGRO_TIPS


def test_mesh_contact_radius_reaches_the_mesh():
    """pad_surface="mesh": an outer particle's contact radius is its depth below the mesh
    (so centre + radius along the normal is on the mesh); inner particles keep h/2."""
    spec = allegro_pad_specs()[1]
    pad = build_pad(spec, link_mesh(default_hand_urdf(), spec.link), H, DX)
    r, outer = pad.contact_radius, pad.depth < H
    np.testing.assert_allclose(r[outer], np.clip(pad.depth[outer], 0.05 * H, H))
    assert np.all(r[~outer] == 0.5 * H)
    assert 0.0 < r.min() and r.max() <= H


def test_wrong_link_name_suggests_the_right_one():
    with pytest.raises(ConfigError, match=r"'link_3.0_tipp' is not in allegro_hand_right.urdf.*link_3.0_tip"):
        link_mesh(default_hand_urdf(), "link_3.0_tipp")


def test_mesh_with_no_volume(tmp_path):
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0]], faces=[[0, 1, 2]])
    with pytest.raises(AssetError, match="watertight"):
        build_pad(PadSpec(link="x"), flat, H, DX, mesh_name="flat.obj")


def test_region_selecting_no_particles():
    mesh = link_mesh(default_hand_urdf(), "link_3.0_tip")
    with pytest.raises(ConfigError, match=r"pad 'link_3.0_tip'.*selects 0 soft and 0 kinematic"):
        build_pad(PadSpec(link="link_3.0_tip", thickness=2 * DX, cone_deg=0.01), mesh, H, DX)


def test_bad_pad_fields():
    with pytest.raises(ConfigError, match=r"PadSpec\.axis"):
        PadSpec(link="a", axis=(0, 0, 0))
    with pytest.raises(ConfigError, match=r"PadSpec\.thickness"):
        PadSpec(link="a", thickness=-1)
    with pytest.raises(ConfigError, match=r"SensorLayout\.rows"):
        SensorLayout(rows=0)


def test_layer_thinner_than_a_cell_is_refused_and_under_resolved_warns():
    import pytest

    from gausstac_maniskill.errors import ConfigError, ResolutionWarning
    from gausstac_maniskill.tactile.pad import check_layer_resolution

    spec = PadSpec(link="link_3.0_tip", thickness=2e-3)
    with pytest.raises(ConfigError, match=r"PadSpec.thickness=0.002 m is thinner than one grid cell"):
        check_layer_resolution(spec, 3e-3)
    with pytest.warns(ResolutionWarning, match=r"spans only 2.0 grid cells"):
        check_layer_resolution(spec, 1e-3)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_layer_resolution(spec, 0.5e-3)  # 4 cells: resolved, silent


def test_rigid_core_is_the_link_without_the_soft_layer():
    """pad_core_meshes: in the pad's cone the core lies CORE_DEPTH·thickness below the surface
    (the finger's hard stop), outside it the core is the link's own collision mesh, no soft
    particle shallower than the stop lies inside it (but near the cone's rim) and every
    bound particle does."""
    from gausstac_maniskill.tactile import pad_core_meshes
    from gausstac_maniskill.tactile.pad import CORE_DEPTH

    spec = allegro_pad_specs()[1]
    mesh = link_mesh(default_hand_urdf(), spec.link)
    pieces = pad_core_meshes(spec, mesh)
    assert len(pieces) == 2 and all(p.is_convex and p.is_watertight for p in pieces)
    stop = CORE_DEPTH * spec.thickness
    lo, hi = np.min([p.bounds[0] for p in pieces], 0), np.max([p.bounds[1] for p in pieces], 0)
    # along the pad axis (+x) the core stops `stop` short of the surface; at the back (-x)
    # and along the finger (z) the rigid link is unchanged
    assert hi[0] == pytest.approx(mesh.bounds[1, 0] - stop, abs=2e-5)
    assert lo[0] == pytest.approx(mesh.bounds[0, 0], abs=1e-9)
    np.testing.assert_allclose([lo[2], hi[2]], mesh.bounds[:, 2], atol=1e-9)
    pad = build_pad(spec, mesh, H, DX)
    inside = np.any([p.contains(pad.rest) for p in pieces], 0)
    d = pad.rest - mesh.center_mass
    angle = np.degrees(np.arccos(d @ np.asarray(spec.axis) / np.linalg.norm(d, axis=1)))
    shallow = pad.depth < stop - 1e-4
    assert not np.any(inside & shallow & (angle < spec.cone_deg - 15))  # the layer is in front of the core
    assert np.mean(inside[shallow]) < 0.2  # near the rim the back of the link covers some of it (15 %)
    assert np.all(inside[pad.depth > spec.thickness + H])  # the link behind the layer is core
    with pytest.raises(ConfigError, match="no rigid core"):
        pad_core_meshes(PadSpec(link=spec.link, thickness=0.02), mesh)
