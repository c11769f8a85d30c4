"""The compliance among all surface points, computed once and kept on disk (fem/compliance.py).

These tests guard bookkeeping, not physics: the full compliance (the plane-by-plane factor's)
must be the same matrix the contact solve builds column by column from SuperLU's (so the forces
do not depend on which path served them), and the disk cache must return what was stored (and
nothing stale or damaged). The physics of the solve is tested in
test_contact.py and test_equilibrium_pad.py."""
import os

import numpy as np
import pytest

from gausstac_maniskill.bench.scenes import sphere
from gausstac_maniskill.fem import compliance, layer_body


def _layer(nu=0.45, E=0.3e6):
    return layer_body(2e-3, 3e-3, 1e-3, E, nu)


def _lazy_matrix(body):
    """W [3S, 3S] from the body's own column solves, rows (d, j), columns (s, i)."""
    S = body.num_points
    return body.solve_columns(np.arange(S)).transpose(0, 3, 1, 2).reshape(3 * S, 3 * S)


def test_full_compliance_is_the_column_by_column_one(tmp_path, monkeypatch):
    monkeypatch.setenv("GAUSSTAC_CACHE", str(tmp_path))
    lazy, full = _layer(), _layer()
    full.precompute_compliance(progress=False)
    W = full._compliance
    ref = _lazy_matrix(lazy)
    assert W.dtype == np.float32 and W.shape == ref.shape
    assert np.abs(W - ref).max() < 1e-6 * np.abs(ref).max()
    assert np.array_equal(W, W.T)  # stored symmetric (Maxwell-Betti)
    assert full.columns_solved == full.num_points
    # a press reads the same forces either way
    ball = sphere(4e-3, [0.0, 0.0, 2e-3 + 4e-3 - 2e-4])
    fa, fb = lazy.solve(ball).force, full.solve(ball).force
    assert np.abs(fa).sum() > 0 and np.abs(fa - fb).max() < 1e-5 * np.abs(fa).max()


def test_cache_round_trip_scales_with_E_and_keys_on_nu(tmp_path, monkeypatch):
    monkeypatch.setenv("GAUSSTAC_CACHE", str(tmp_path))
    first = _layer()
    first.precompute_compliance(progress=False)
    files = os.listdir(tmp_path / "compliances")
    assert len(files) == 1 and files[0].startswith("compliance-")

    stiffer = _layer(E=0.6e6)  # same shape and nu: loaded, not solved, and W ∝ 1/E
    monkeypatch.setattr(type(stiffer), "inverse_products",
                        lambda self, *a, **k: pytest.fail("solved instead of loaded"))
    stiffer.precompute_compliance(progress=False)
    assert not stiffer.factored  # nothing needed K's factor
    np.testing.assert_allclose(stiffer._compliance, 0.5 * first._compliance, rtol=1e-6)
    monkeypatch.undo()

    monkeypatch.setenv("GAUSSTAC_CACHE", str(tmp_path))
    other = _layer(nu=0.49)  # another nu: another file
    other.precompute_compliance(progress=False)
    assert len(os.listdir(tmp_path / "compliances")) == 2
    assert compliance.compliance_key(other) != compliance.compliance_key(first)


def test_damaged_cache_is_recomputed_with_a_warning(tmp_path, monkeypatch):
    monkeypatch.setenv("GAUSSTAC_CACHE", str(tmp_path))
    body = _layer()
    path = tmp_path / "compliances" / f"compliance-{compliance.compliance_key(body)}.npy"
    path.parent.mkdir()
    path.write_bytes(b"not a numpy file")
    with pytest.warns(UserWarning, match=str(path.name)):
        body.precompute_compliance(progress=False)
    np.testing.assert_allclose(body._compliance, _lazy_matrix(_layer()), rtol=1e-5, atol=1e-6 * np.abs(
        body._compliance).max())
    assert np.load(path).shape == body._compliance.shape  # replaced by a good file


def test_cache_off_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("GAUSSTAC_CACHE", "off")
    assert compliance.cache_dir() is None
    monkeypatch.chdir(tmp_path)
    _layer().precompute_compliance(progress=False)
    assert not os.listdir(tmp_path)


def test_readout_response_is_the_compliance_row_and_keyed_on_E(tmp_path, monkeypatch):
    """A readout's response to point forces, solved by its adjoint (one solve per readout),
    equals the compliance's row it reads when the readout is a surface point's displacement
    (Maxwell-Betti: two routes to one matrix); it is kept on disk per Young's modulus (M ∝ 1/E
    here, where the readout does not depend on E)."""
    import scipy.sparse as sp

    from gausstac_maniskill.fem.hex import trilinear

    monkeypatch.setenv("GAUSSTAC_CACHE", str(tmp_path))
    body = _layer()
    d = 7  # the readout: surface point d's displacement along z
    nodes, w = trilinear(body.body, body.points[d:d + 1], body.point_elements[d:d + 1])
    A = sp.csr_matrix((w[0], (np.zeros(8, int), 3 * nodes[0] + 2)), shape=(1, body.body.num_dofs))
    M = compliance.readout_responses(body, A, progress=False)
    W = _lazy_matrix(_layer())  # rows (d, j), columns (s, i); symmetric
    np.testing.assert_allclose(M[0], W[3 * d + 2], rtol=1e-5, atol=1e-6 * np.abs(W).max())

    stiffer = _layer(E=0.6e6)
    np.testing.assert_allclose(compliance.readout_responses(stiffer, A, progress=False), 0.5 * M, rtol=1e-6)
    assert len([f for f in os.listdir(tmp_path / "compliances") if f.startswith("readout-")]) == 2


def _point_readout(body, d, axis=2):
    """[1, 3V]: surface point d's displacement along ``axis``, as a readout."""
    import scipy.sparse as sp

    from gausstac_maniskill.fem.hex import trilinear

    nodes, w = trilinear(body.body, body.points[d:d + 1], body.point_elements[d:d + 1])
    return sp.csr_matrix((w[0], (np.zeros(8, int), 3 * nodes[0] + axis)), shape=(1, body.body.num_dofs))


def test_compliance_and_readout_responses_come_from_one_sweep(tmp_path, monkeypatch):
    """Guards the bookkeeping of the shared sweep: readouts named with the compliance get their
    responses from the compliance's own sweep (one sweep in all, counted), the same as each
    computed alone (to float32 rounding), kept on disk under the keys a lone computation uses;
    where the compliance is on disk already, the readouts are not even built."""
    monkeypatch.setenv("GAUSSTAC_CACHE", str(tmp_path))
    body = _layer()
    A, B = _point_readout(body, 7), _point_readout(body, 3, axis=0)
    sweeps = []
    real = type(body).inverse_products

    def spy(self, loads, pairs, **k):
        sweeps.append(pairs)
        return real(self, loads, pairs, **k)

    monkeypatch.setattr(type(body), "inverse_products", spy)
    body.precompute_compliance(progress=False, readouts=lambda: [A, B, A])  # A twice: computed once
    assert sweeps == [[(0, 0), (1, 0), (2, 0)]]
    MA, MB = (compliance.readout_responses(body, R, progress=False) for R in (A, B))
    assert len(sweeps) == 1  # taken from the compliance's sweep
    assert len([f for f in os.listdir(tmp_path / "compliances") if f.startswith("readout-")]) == 2

    monkeypatch.setenv("GAUSSTAC_CACHE", "off")
    alone = _layer()
    W = alone.inverse_between(alone.point_loads(np.arange(alone.num_points)))
    for M, R in ((MA, A), (MB, B)):
        ref = compliance.readout_responses(alone, R, progress=False)
        assert M.shape == ref.shape and M.dtype == np.float32
        np.testing.assert_allclose(M, ref, rtol=0, atol=1e-6 * np.abs(ref).max())
    np.testing.assert_allclose(body._compliance, W, rtol=0, atol=1e-6 * np.abs(W).max())
    np.testing.assert_allclose(MA[0], W[3 * 7 + 2], rtol=0, atol=1e-6 * np.abs(W).max())  # Maxwell-Betti

    monkeypatch.setenv("GAUSSTAC_CACHE", str(tmp_path))
    sweeps.clear()
    again = _layer()
    again.precompute_compliance(progress=False, readouts=lambda: pytest.fail("built although W is on disk"))
    assert not sweeps and np.array_equal(again._compliance, body._compliance)
    np.testing.assert_array_equal(compliance.readout_responses(again, A, progress=False), MA)
    assert not sweeps  # from disk

    for f in os.listdir(tmp_path / "compliances"):  # W gone, the responses still on disk: W alone is swept
        if f.startswith("compliance-"):
            os.remove(tmp_path / "compliances" / f)
    third = _layer()
    third.precompute_compliance(progress=False, readouts=[A, B])
    assert sweeps == [[(0, 0)]]
    np.testing.assert_array_equal(compliance.readout_responses(third, B, progress=False), MB)
    assert len(sweeps) == 1


def test_a_compliance_beyond_the_memory_at_hand_is_refused_by_name(monkeypatch):
    """Asked for a compliance this machine cannot hold while computing it, the body says so
    (naming itself and the memory) before it starts, and nothing is computed."""
    monkeypatch.setenv("GAUSSTAC_CACHE", "off")
    body = _layer()
    monkeypatch.setattr(compliance, "available_memory", lambda: 1000)
    monkeypatch.setattr(type(body), "inverse_products", lambda self, *a, **k: pytest.fail("computed anyway"))
    from gausstac_maniskill.errors import ConfigError

    with pytest.raises(ConfigError, match=r"layer: compliance at \d+ surface points: needs about .* GiB .* "
                                          r"0\.0 GiB available \(the machine's free memory, or its container's "
                                          r"limit\).*fem_precompute=False"):
        body.precompute_compliance(progress=False)
    assert not body.has_compliance
    assert compliance.available_memory() is not None or not os.path.exists("/proc/meminfo")


def _fake_host(tmp_path, meminfo_kb, cgroup_lines, files):
    """A /proc and /sys under tmp_path: MemAvailable, /proc/self/cgroup and cgroup files {path: text}."""
    (tmp_path / "proc/self").mkdir(parents=True)
    (tmp_path / "proc/meminfo").write_text(f"MemTotal: 99999999 kB\nMemAvailable: {meminfo_kb} kB\n")
    (tmp_path / "proc/self/cgroup").write_text("\n".join(cgroup_lines) + "\n")
    for path, text in files.items():
        (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / path).write_text(text)
    return str(tmp_path)


def test_available_memory_follows_a_container_limit(tmp_path):
    """Guards the memory check against a container's limit (the kernel would kill the process
    instead of our error): the least of MemAvailable and each cgroup's limit − (usage − inactive
    file cache), over the group and its ancestors, for cgroup v2 and v1; 'no limit' is none."""
    GiB = 2 ** 30
    v2 = _fake_host(tmp_path / "v2", 8 * GiB // 1024, ["0::/job/task"], {
        "sys/fs/cgroup/job/task/memory.max": "max\n",
        "sys/fs/cgroup/job/task/memory.current": f"{GiB}\n",
        "sys/fs/cgroup/job/memory.max": f"{3 * GiB}\n",  # the parent's limit binds
        "sys/fs/cgroup/job/memory.current": f"{2 * GiB}\n",
        "sys/fs/cgroup/job/memory.stat": f"anon 1\ninactive_file {GiB // 2}\n",
    })
    assert compliance.available_memory(v2) == 3 * GiB - (2 * GiB - GiB // 2)
    v1 = _fake_host(tmp_path / "v1", 8 * GiB // 1024, ["4:memory:/box", "1:cpu:/box"], {
        "sys/fs/cgroup/memory/box/memory.limit_in_bytes": f"{4 * GiB}\n",
        "sys/fs/cgroup/memory/box/memory.usage_in_bytes": f"{GiB}\n",
        "sys/fs/cgroup/memory/memory.limit_in_bytes": "9223372036854771712\n",  # the root: no limit
        "sys/fs/cgroup/memory/memory.usage_in_bytes": f"{5 * GiB}\n",
    })
    assert compliance.available_memory(v1) == 3 * GiB
    roomy = _fake_host(tmp_path / "roomy", GiB // 1024, ["4:memory:/box"], {
        "sys/fs/cgroup/memory/box/memory.limit_in_bytes": f"{4 * GiB}\n",
        "sys/fs/cgroup/memory/box/memory.usage_in_bytes": f"{GiB}\n",
    })
    assert compliance.available_memory(roomy) == GiB  # the machine has less than the group allows
    bare = _fake_host(tmp_path / "bare", GiB // 1024, ["0::/"], {})
    assert compliance.available_memory(bare) == GiB
    assert compliance.available_memory(str(tmp_path / "nowhere")) is None
