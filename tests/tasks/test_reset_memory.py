"""A reset frees the last episode's co-simulators at once: every reset builds them anew
(``GaussTacEnv._build_cosims``), so whatever keeps the old ones alive grows a long data
collection's memory. A reference cycle through them (a pad solver or splat scene holding its
simulator strongly) keeps each episode's pads, Gaussians and MPM world, some 3-10 MB, until
Python's cyclic collector runs its rare full pass, and the heap they spread over stays mapped:
resident memory then grows by 2.4-7 MB per reset."""
import gc
import os
import weakref

import gymnasium as gym
import pytest

import gausstac_maniskill  # noqa: F401  (registers agents and tasks)

pytestmark = pytest.mark.sapien

#: resets whose resident memory growth is measured (after the fixture's warm-up)
RESETS = 25
#: bound on that growth [MB]: with a cycle through the co-simulators it is 85-110 MB (3.4-4.4 MB
#: per reset: each episode's arrays wait for the cyclic collector's rare full passes, and the heap
#: they spread over stays mapped); freed by reference counting, 0.0 MB. 0.5 MB per reset is
#: far from both: room for the allocator and a noisy host, well under the leak.
MAX_GROWTH_MB = 0.5 * RESETS


@pytest.fixture(scope="module")
def env():
    env = gym.make("GaussTac-PressCube-v1", sim_backend="physx_cpu")  # the default 1 mm grid, as reported
    env.reset(seed=0)
    for _ in range(2):  # warm-up: caches, kernels, the allocator's first arenas
        env.reset()
    yield env
    env.close()


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _episode_objects(u) -> list:
    """The current episode's co-simulation: the batch, its MPM world, every env's simulator,
    pad solvers and splat scene."""
    objs = [u._batch, u._batch.world]
    for sim in u.cosims:
        objs += [sim, *sim.solvers.values()]
        if sim.splat_scene is not None:
            objs.append(sim.splat_scene)
    return objs


class _NoCycleCollector:
    """``with _NoCycleCollector():`` Python's cyclic collector off (what it frees does not count)."""

    def __enter__(self):
        self.enabled = gc.isenabled()
        gc.disable()

    def __exit__(self, *exc):
        if self.enabled:
            gc.enable()


def test_reset_frees_the_last_episode_by_reference_counting(env):
    """Without the cyclic collector, a reset leaves nothing of the last episode alive."""
    u = env.unwrapped
    refs = [weakref.ref(o) for o in _episode_objects(u)]
    with _NoCycleCollector():
        env.reset()
        alive = sorted({type(r()).__name__ for r in refs if r() is not None})
    assert not alive, f"a reset left the last episode's {alive} alive (a reference cycle through them?)"


def test_resets_leave_no_cyclic_garbage_of_the_package(env):
    """What resets discard, reference counting frees: the cyclic collector finds none of this
    package's objects (another cycle through a co-simulator's parts would hold their arrays)."""
    gc.collect()
    with _NoCycleCollector():
        for _ in range(3):
            env.reset()
        gc.set_debug(gc.DEBUG_SAVEALL)  # keep what the collector finds, to name it
        try:
            gc.collect()
            found = sorted({type(o).__qualname__ for o in gc.garbage
                            if type(o).__module__.startswith("gausstac_maniskill")})
        finally:
            gc.set_debug(0)
            gc.garbage.clear()
    assert not found, f"3 resets left reference cycles through {found}"


def test_resident_memory_stays_flat_over_resets(env):
    gc.collect()
    start = _rss_mb()
    for _ in range(RESETS):
        env.reset()
    growth = _rss_mb() - start
    assert growth < MAX_GROWTH_MB, f"resident memory grew {growth:.1f} MB over {RESETS} resets " \
                                   f"({growth / RESETS:.2f} MB per reset)"


#: the long run of ``make bench``: resets and random steps of each task family
LONG_RESETS = int(os.environ.get("GAUSSTAC_LONG_RESETS", "200"))
LONG_FAMILIES = [("GaussTac-Gesture-v1", {}), ("GaussTac-PressCube-v1", {}), ("GaussTac-SlideCube-v1", {}),
                 ("GaussTac-GraspLiftCube-v1", {}), ("RotateValveLevel0-v1", {"stock": True}),
                 ("TriFingerRotateCubeLevel0-v1", {"stock": True})]


@pytest.mark.slow
@pytest.mark.xfail(strict=True, raises=AssertionError,
                   reason="known gap: with 3 random steps per episode every family still grows, 0.39 MB per episode "
                   "(TriFinger 2 MB; stock RotateValve: flat); tracemalloc sees under 0.6 MB of Python "
                   "allocations over 100 episodes, so it is native memory (Taichi or SAPIEN objects made by an "
                   "episode's first steps); resets alone are flat (the tests above)")
@pytest.mark.parametrize("env_id,how", LONG_FAMILIES, ids=[f[0] for f in LONG_FAMILIES])
def test_memory_stays_flat_over_hundreds_of_resets_and_random_steps(env_id, how):
    """``LONG_RESETS`` episodes of 3 random steps each (2 mm grid): resident memory after the
    first tenth (warm-up) grows by less than 0.25 MB per reset over the rest."""
    kw = dict(sim_backend="physx_cpu", obs_mode="state_dict", mpm_dx=2e-3)
    env = gausstac_maniskill.make_tactile(env_id, **kw) if how.get("stock") else gym.make(env_id, **kw)
    try:
        env.action_space.seed(0)
        warm = max(LONG_RESETS // 10, 2)
        for i in range(LONG_RESETS):
            if i == warm:
                start = _rss_mb()
            env.reset(seed=i)
            for _ in range(3):
                env.step(env.action_space.sample())
        grown = _rss_mb() - start
        assert grown < 0.25 * (LONG_RESETS - warm), f"{env_id}: grew {grown:.1f} MB over {LONG_RESETS - warm} resets"
    finally:
        env.close()
