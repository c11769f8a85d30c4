"""CachedKernel (kernel_launch.py): a kernel launched without Taichi's per-call key look-up.

These compare the cached launch with Taichi's own call of the same kernel: they guard the
caching (same results, the look-up skipped only while the same argpacks come back, Taichi's
type check kept for every new pack), not any physics."""
import numpy as np
import pytest
import taichi as ti

from gausstac_maniskill import kernel_launch
from gausstac_maniskill.kernel_launch import CachedKernel

Pack = ti.types.argpack(x=ti.types.ndarray(dtype=ti.f32, ndim=1), n=ti.types.ndarray(dtype=ti.i32, ndim=1))


@ti.kernel
def scale_add(p: Pack, a: ti.f32, twice: ti.template()) -> ti.f32:
    total = 0.0
    for i in range(p.n[0]):
        v = p.x[i] * a
        if ti.static(twice):
            v *= 2.0
        p.x[i] = v
        total += v
    return total


@ti.kernel
def add_one(x: ti.types.ndarray(dtype=ti.f32, ndim=1)):
    for i in x:
        x[i] += 1.0


@ti.kernel
def takes_any_ndarray(x: ti.types.ndarray()):
    for i in x:
        x[i] += 1.0


def _pack(values):
    x = ti.ndarray(ti.f32, len(values))
    x.from_numpy(np.asarray(values, np.float32))
    n = ti.ndarray(ti.i32, 1)
    n.from_numpy(np.array([len(values)], np.int32))
    return Pack(x=x, n=n)


class _Counting:
    """Counts the calls that take Taichi's ordinary path (look-up included)."""

    def __init__(self, kernel):
        self.kernel, self.calls = kernel, 0
        self.__name__ = kernel.__name__

    def __call__(self, *args):
        self.calls += 1
        return self.kernel(*args)


def test_cached_launch_matches_taichis_call_and_skips_the_look_up():
    cached = CachedKernel(scale_add)
    ordinary = _Counting(scale_add)
    cached.kernel = ordinary
    mine, ref = _pack([1.0, 2.0, 3.0]), _pack([1.0, 2.0, 3.0])
    for a, twice in [(0.5, False), (3.0, False), (2.0, True), (0.25, True), (1.5, False)]:
        got = cached(mine, a, twice)
        want = scale_add(ref, a, twice)
        assert got == want
        assert np.array_equal(mine.x.to_numpy(), ref.x.to_numpy())
    # the ordinary path once per template value (False, True); the other three calls launched directly
    assert ordinary.calls == 2
    other = _pack([4.0])  # a new pack: checked by the ordinary path again
    assert cached(other, 1.0, False) == pytest.approx(4.0)
    assert ordinary.calls == 3


def test_a_new_pack_or_array_of_the_wrong_type_is_still_refused():
    """Taichi checks an ndarray's type only where it looks the key up: launched directly, the
    wrong pack below runs without a complaint (measured: it returns 0.0)."""
    cached = CachedKernel(scale_add)
    cached(_pack([1.0]), 1.0, False)
    bad = Pack(x=ti.ndarray(ti.i32, 1), n=ti.ndarray(ti.i32, 1))  # building it checks nothing
    with pytest.raises(Exception, match="element type f32"):
        cached(bad, 1.0, False)
    plus = CachedKernel(add_one)
    x = ti.ndarray(ti.f32, 3)
    plus(x)
    plus(x)
    assert np.array_equal(x.to_numpy(), [2.0, 2.0, 2.0])
    with pytest.raises(Exception, match="element type f32"):
        plus(ti.ndarray(ti.i32, 3))


def test_the_switch_and_kernels_whose_key_depends_on_an_argument_of_no_fixed_type():
    with pytest.raises(TypeError, match="'x'"):
        CachedKernel(takes_any_ndarray)
    cached = CachedKernel(scale_add)
    ordinary = _Counting(scale_add)
    cached.kernel = ordinary
    p = _pack([1.0])
    cached(p, 1.0, False)
    kernel_launch.ENABLED = False
    try:
        cached(p, 1.0, False)  # GAUSSTAC_KERNEL_CACHE=0: Taichi's ordinary call every time
    finally:
        kernel_launch.ENABLED = True
    assert ordinary.calls == 2


Inner = ti.types.argpack(v=ti.types.ndarray(dtype=ti.f32, ndim=1), s=ti.f32)
Ints = ti.types.argpack(a=ti.types.ndarray(dtype=ti.i32, ndim=1))
Outer = ti.types.argpack(inner=Inner, ints=Ints)  # packs of packs, as the solver's World


@ti.kernel
def mixed(o: Outer, y: ti.types.ndarray(dtype=ti.f32, ndim=1), c: ti.f32, n: ti.i32, flip: ti.template()) -> ti.f32:
    total = 0.0
    for i in range(n):
        w = o.inner.v[i] * c + o.inner.s + o.ints.a[i]
        if ti.static(flip):
            w = -w
        y[i] = w
        total += w
    return total


def test_lean_arguments_fill_the_launch_context_as_taichi_does():
    """The fast path puts the arguments into the launch context itself (a nested pack, ndarrays
    inside and outside packs, float and int scalars, a return value) and must fill the same
    slots as Taichi's own launch: each call is compared with Taichi's path on the same inputs.
    (A pack holding an ndarray beside a nested pack reads the nested pack's array in place of
    its own, on both paths: Taichi 1.7's layout; the solver's World holds packs only.)"""
    cached = CachedKernel(mixed)

    def inputs():
        a = ti.ndarray(ti.i32, 4)
        a.from_numpy(np.array([1, 2, 3, 4], np.int32))
        v = ti.ndarray(ti.f32, 4)
        v.from_numpy(np.array([0.5, 1.5, 2.5, 3.5], np.float32))
        return Outer(inner=Inner(v=v, s=0.25), ints=Ints(a=a)), ti.ndarray(ti.f32, 4)

    mine, ref = inputs(), inputs()
    for c, n, flip in [(1.0, 4, False), (2.0, 3, False), (-1.0, 4, True), (0.5, 2, True), (3.0, 4, False)]:
        got = cached(*mine, c, n, flip)
        kernel_launch.LEAN_ARGS = False
        try:
            want = cached(*ref, c, n, flip)  # the same cached variant, its arguments set by Taichi
        finally:
            kernel_launch.LEAN_ARGS = True
        assert got == want
        assert np.array_equal(mine[1].to_numpy(), ref[1].to_numpy())
    assert mine[1].to_numpy()[0] == pytest.approx(3.0 * 0.5 + 0.25 + 1)


def test_an_array_with_a_gradient_is_launched_by_taichi():
    """The planned context sets no gradient pointers: an array with one goes through Taichi's
    own argument setting on every launch, with the same result."""
    plus = CachedKernel(add_one)
    x = ti.ndarray(ti.f32, 3, needs_grad=True)
    for _ in range(3):
        plus(x)
    assert plus._keys[()][2] is False
    assert np.array_equal(x.to_numpy(), [3.0, 3.0, 3.0])


_AFTER_RESET = """
import taichi as ti
from gausstac_maniskill.kernel_launch import CachedKernel
P = ti.types.argpack(x=ti.types.ndarray(dtype=ti.f32, ndim=1))
@ti.kernel
def inc(p: P, a: ti.f32):
    for i in p.x:
        p.x[i] += a
k = CachedKernel(inc)
for _ in range(2):
    ti.init(arch=ti.cpu, log_level=ti.ERROR)
    x = ti.ndarray(ti.f32, 3)
    pack = P(x=x)
    k(pack, 1.0)
    k(pack, 2.0)
    print(x.to_numpy().tolist())
    del pack, x
    ti.reset()
"""


def test_a_cached_kernel_survives_a_taichi_reset(tmp_path):
    """After ti.reset the compiled variant is gone: the next call compiles again (in a child
    process: the test session's Taichi must not be reset)."""
    import subprocess
    import sys

    script = tmp_path / "after_reset.py"  # Taichi reads a kernel's source from its file
    script.write_text(_AFTER_RESET)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert [line for line in out.stdout.splitlines() if line.startswith("[3")] == ["[3.0, 3.0, 3.0]"] * 2
