"""GaussianSet validation and the INRIA .ply format."""
import math

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from gausstac_maniskill.errors import AssetError, ConfigError
from gausstac_maniskill.splat import (GaussianSet, covariance_from_scale_rotation, load_ply,
                                      quat_multiply, quat_to_rotmat, rgb_to_sh_dc, rotmat_to_quat,
                                      save_ply, sh_dc_to_rgb)

FIELDS = ("means", "quats", "log_scales", "opacity_logits", "sh", "link_id", "group")


def make_set(n=7, degree=2, seed=0, labels=True):
    gen = torch.Generator().manual_seed(seed)
    return GaussianSet.create(
        torch.randn(n, 3, generator=gen),
        torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=1),
        torch.randn(n, 3, generator=gen) - 4,
        torch.randn(n, generator=gen),
        torch.randn(n, (degree + 1) ** 2, 3, generator=gen),
        link_id=torch.arange(n) % 3 if labels else None,
        group=torch.arange(n) - 2 if labels else None,
    )


def assert_same(a: GaussianSet, b: GaussianSet):
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and torch.equal(x, y), f


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("labels", [True, False])
def test_ply_round_trip_is_lossless(tmp_path, degree, labels):
    g = make_set(degree=degree, seed=degree, labels=labels)
    path = tmp_path / "scene.ply"
    save_ply(path, g)
    h = load_ply(path)
    assert h.sh_degree == degree
    assert_same(g, h)
    names = [p.name for p in PlyData.read(str(path))["vertex"].properties]
    assert ("link_id" in names) == labels  # plain sets stay plain INRIA files


def test_ply_layout_is_inria(tmp_path):
    """Property order, f_rest channel-major, raw (logit/log) values, little endian."""
    g = make_set(n=3, degree=1)
    path = tmp_path / "scene.ply"
    save_ply(path, g, labels=False)
    raw = path.read_bytes()
    assert b"format binary_little_endian 1.0" in raw[:200]
    v = PlyData.read(str(path))["vertex"]
    names = [p.name for p in v.properties]
    assert names == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
                     *[f"f_rest_{i}" for i in range(9)], "opacity", "scale_0", "scale_1",
                     "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    # f_rest_{c*(K-1)+k} is coefficient k+1 of channel c
    for c in range(3):
        for k in range(3):
            assert np.array_equal(v[f"f_rest_{c * 3 + k}"], g.sh[:, k + 1, c].numpy())
    assert np.array_equal(v["opacity"], g.opacity_logits.numpy())
    assert np.array_equal(v["scale_2"], g.log_scales[:, 2].numpy())
    assert np.array_equal(v["rot_0"], g.quats[:, 0].numpy())  # w first


def write_ply(path, columns: dict, text=False):
    """Write a vertex element from {name: array} with plyfile (for malformed files)."""
    n = len(next(iter(columns.values())))
    rec = np.empty(n, dtype=[(k, np.asarray(v).dtype.str) for k, v in columns.items()])
    for k, v in columns.items():
        rec[k] = v
    PlyData([PlyElement.describe(rec, "vertex")], text=text).write(str(path))


def inria_columns(n=4, degree=1):
    rng = np.random.default_rng(0)
    cols = {k: rng.normal(size=n).astype(np.float32) for k in
            ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2")}
    for i in range(3 * ((degree + 1) ** 2 - 1)):
        cols[f"f_rest_{i}"] = rng.normal(size=n).astype(np.float32)
    for k in ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"):
        cols[k] = rng.normal(size=n).astype(np.float32)
    return cols


def test_plain_inria_file_gets_default_labels_and_unit_quats(tmp_path):
    cols = inria_columns()
    write_ply(tmp_path / "plain.ply", cols)
    g = load_ply(tmp_path / "plain.ply")
    assert torch.equal(g.link_id, torch.zeros(4, dtype=torch.int64))
    assert torch.equal(g.group, torch.full((4,), -1, dtype=torch.int64))
    assert torch.allclose(g.quats.norm(dim=1), torch.ones(4))
    q = np.stack([cols[f"rot_{i}"] for i in range(4)], 1)
    assert np.allclose(g.quats.numpy(), q / np.linalg.norm(q, axis=1, keepdims=True))
    write_ply(tmp_path / "ascii.ply", cols, text=True)  # ASCII files load too
    assert torch.allclose(load_ply(tmp_path / "ascii.ply").means, g.means)


def test_missing_file(tmp_path):
    with pytest.raises(AssetError, match="nothere.ply"):
        load_ply(tmp_path / "nothere.ply")


@pytest.mark.parametrize("cut", [37, 1000])
def test_truncated_file_names_file_and_field(tmp_path, cut):
    g = make_set(n=40, degree=1, labels=False)
    path = tmp_path / "scene.ply"
    save_ply(path, g)
    raw = path.read_bytes()
    # data rows are 26 float32 = 104 bytes; cut inside a row at a known property
    (tmp_path / "cut.ply").write_bytes(raw[:-cut])
    row_bytes = 104
    data_start = raw.index(b"end_header\n") + len(b"end_header\n")
    keep = len(raw) - cut - data_start
    row, off = divmod(keep, row_bytes)
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
             *[f"f_rest_{i}" for i in range(9)], "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3"]
    with pytest.raises(AssetError) as err:
        load_ply(tmp_path / "cut.ply")
    msg = str(err.value)
    assert "cut.ply" in msg and f"vertex {row}" in msg and f"'{names[off // 4]}'" in msg, msg


def test_truncated_header(tmp_path):
    save_ply(tmp_path / "scene.ply", make_set())
    (tmp_path / "h.ply").write_bytes((tmp_path / "scene.ply").read_bytes()[:150])
    with pytest.raises(AssetError, match="h.ply"):
        load_ply(tmp_path / "h.ply")


@pytest.mark.parametrize("field", ["x", "f_dc_1", "opacity", "scale_1", "rot_3", "f_rest_4"])
def test_missing_property(tmp_path, field):
    cols = inria_columns(degree=1)
    if field == "f_rest_4":  # renaming keeps the count right but leaves a gap
        cols["f_rest_99"] = cols.pop(field)
    else:
        del cols[field]
    write_ply(tmp_path / "scene.ply", cols)
    with pytest.raises(AssetError, match=rf"scene\.ply: vertex property '{field}' missing"):
        load_ply(tmp_path / "scene.ply")


def test_odd_properties(tmp_path):
    cols = inria_columns(degree=1)
    del cols["f_rest_8"]  # 8 rest coefficients: not 3((d+1)^2 - 1)
    write_ply(tmp_path / "a.ply", cols)
    with pytest.raises(AssetError, match=r"a\.ply: vertex property 'f_rest_\*' count is 8"):
        load_ply(tmp_path / "a.ply")

    cols = inria_columns(degree=0)
    cols["scale_0"][2] = np.nan
    write_ply(tmp_path / "b.ply", cols)
    with pytest.raises(AssetError, match=r"b\.ply: vertex property 'scale_0' has non-finite"):
        load_ply(tmp_path / "b.ply")

    cols = inria_columns(degree=0)
    cols["link_id"] = np.zeros(4, np.float32)  # labels must be integers
    write_ply(tmp_path / "c.ply", cols)
    with pytest.raises(AssetError, match=r"c\.ply: vertex property 'link_id'"):
        load_ply(tmp_path / "c.ply")

    cols = inria_columns(degree=0)
    for i in range(4):
        cols[f"rot_{i}"][1] = 0.0
    write_ply(tmp_path / "d.ply", cols)
    with pytest.raises(AssetError, match=r"d\.ply: vertex property 'rot_0\.\.3'"):
        load_ply(tmp_path / "d.ply")

    # a list property where a scalar is expected
    n = 4
    cols = inria_columns(degree=0)
    dtype = [(k, "f4") for k in cols if k != "opacity"] + [("opacity", "O")]
    rec = np.empty(n, dtype=dtype)
    for k in cols:
        if k != "opacity":
            rec[k] = cols[k]
    for i in range(n):
        rec["opacity"][i] = np.zeros(2, np.float32)
    PlyData([PlyElement.describe(rec, "vertex")]).write(str(tmp_path / "e.ply"))
    with pytest.raises(AssetError, match=r"e\.ply: vertex property 'opacity' is a list"):
        load_ply(tmp_path / "e.ply")


def test_no_vertex_element(tmp_path):
    rec = np.zeros(2, dtype=[("a", "f4")])
    PlyData([PlyElement.describe(rec, "face")]).write(str(tmp_path / "f.ply"))
    with pytest.raises(AssetError, match=r"f\.ply: element 'vertex' missing"):
        load_ply(tmp_path / "f.ply")


def test_gaussian_set_validation():
    g = make_set(n=5)
    with pytest.raises(ConfigError, match=r"quats.*\[N, 4\]"):
        g.replace(quats=torch.zeros(5, 3))
    with pytest.raises(ConfigError, match=r"sh"):
        g.replace(sh=torch.zeros(5, 5, 3))
    with pytest.raises(ConfigError, match=r"link_id.*integer"):
        g.replace(link_id=torch.zeros(5))
    with pytest.raises(ConfigError, match=r"means"):
        GaussianSet.create(torch.zeros(5, 3)).replace(means=torch.zeros(5, 2))


def test_gaussian_set_helpers():
    a, b = make_set(n=3, degree=0), make_set(n=4, degree=2)
    c = GaussianSet.cat([a, b])
    assert len(c) == 7 and c.sh_degree == 2
    assert torch.equal(c.sh[:3, 1:], torch.zeros(3, 8, 3))
    assert_same(c[3:], b)
    rgb = torch.tensor([0.2, 0.5, 0.9])
    assert torch.allclose(sh_dc_to_rgb(rgb_to_sh_dc(rgb)), rgb)


def test_rotation_helpers_closed_form():
    # 90° about z
    q = torch.tensor([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
    R = quat_to_rotmat(q)
    assert torch.allclose(R, torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), atol=1e-6)
    qs = torch.nn.functional.normalize(torch.randn(100, 4, generator=torch.Generator()
                                                   .manual_seed(0)), dim=1)
    Rs = quat_to_rotmat(qs)
    back = rotmat_to_quat(Rs)
    assert torch.allclose(back, qs * torch.sign(qs[:, :1]), atol=1e-5)
    assert torch.allclose(quat_to_rotmat(quat_multiply(qs, qs.flip(0))), Rs @ Rs.flip(0),
                          atol=1e-5)
    cov = covariance_from_scale_rotation(q, torch.tensor([1.0, 2.0, 3.0]))
    assert torch.allclose(cov, torch.diag(torch.tensor([4.0, 1.0, 9.0])), atol=1e-5)
