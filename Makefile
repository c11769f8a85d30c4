# Every target does its own set-up on a fresh machine (virtualenv, pip, Vulkan driver).
PY := .venv/bin/python
export PYTHONUNBUFFERED := 1

.PHONY: setup demo test bench clean

setup:
	@bash scripts/setup.sh

# make demo compiles with GAUSSTAC_COMPILE=fast unless told otherwise (GAUSSTAC_COMPILE= make demo: the
# product build, which compiles about 3x longer for steps about 1.2x shorter; `bench compile` measures it)
demo: setup
	GAUSSTAC_COMPILE=$${GAUSSTAC_COMPILE-fast} $(PY) -m gausstac_maniskill.cli demo

# Two workers, one test file each at a time: a test process keeps one core busy (Python,
# SAPIEN, Taichi compiling). GAUSSTAC_COMPILE=fast: Taichi skips its whole-kernel CSE,
# 14 s instead of 109 s to compile the pad's kernels on a fresh machine (bench compile).
# GAUSSTAC_CPU_PIN=0: the two test processes share the cores, so their Taichi workers stay unpinned.
test: setup
	GAUSSTAC_COMPILE=fast GAUSSTAC_CPU_PIN=0 $(PY) -m pytest -m "not slow" -q -n 2 --dist loadfile --durations=25

bench: setup
	$(PY) -m pytest -m slow -q || [ $$? -eq 5 ]   # exit 5: no test selected (none marked slow)
	$(PY) -m gausstac_maniskill.bench hertz --grid-contact
	$(PY) -m gausstac_maniskill.bench splat
	$(PY) -m gausstac_maniskill.bench hand
	$(PY) -m gausstac_maniskill.bench envs
	$(PY) -m gausstac_maniskill.bench thinlayer
	$(PY) -m gausstac_maniskill.bench pad --curve --indenters sphere --out out/bench_pad_sphere
	$(PY) -m gausstac_maniskill.bench pad --curve --indenters plate --out out/bench_pad_plate
	$(PY) -m gausstac_maniskill.bench motion
	$(PY) -m gausstac_maniskill.bench motion --mover link
	$(PY) -m gausstac_maniskill.bench quasistatic
	$(PY) -m gausstac_maniskill.bench pad --pad-solver fem --indenters sphere plate --dx 2e-3 1e-3 6.6667e-4 --out out/bench_pad_fem
	$(PY) -m gausstac_maniskill.bench pad --curve --pad-solver fem --indenters sphere --dx 2e-3 1.5e-3 1e-3 7.5e-4 6.6667e-4 --out out/bench_pad_fem_sphere
	$(PY) -m gausstac_maniskill.bench pad --curve --pad-solver fem --indenters plate --dx 2e-3 1.5e-3 1e-3 7.5e-4 --out out/bench_pad_fem_plate
	$(PY) -m gausstac_maniskill.bench envs --tasks GaussTac-PressCube-v1 --sweep-tasks GaussTac-PressCube-v1 GaussTac-SlideCube-v1 GaussTac-GraspLiftCube-v1 --dx 1e-3 --pad-solvers auto mpm --no-fsr --out out/bench_envs_fem
	$(PY) -m gausstac_maniskill.bench kernels
	$(PY) -m gausstac_maniskill.bench compile
	$(PY) -m gausstac_maniskill.bench soft
	$(PY) -m pip install -q 'jax>=0.4'  # bench optical's baseline: taxim's own height map (its JAX backend)
	$(PY) -m gausstac_maniskill.bench optical
	$(PY) -m gausstac_maniskill.bench patch
	$(PY) -m gausstac_maniskill.bench patch --pad-solver fem --out out/bench_patch_fem
	$(PY) -m gausstac_maniskill.bench look
	$(PY) -m gausstac_maniskill.bench close
	$(PY) -m gausstac_maniskill.bench drive_contact
	$(PY) -m gausstac_maniskill.bench close --dx 2e-3 --steps 20 --reaction --sim-freq 100
	$(PY) -m gausstac_maniskill.bench close --dx 2e-3 --steps 20 --reaction explicit --sim-freq 2000
	$(PY) -m gausstac_maniskill.bench grasp --dx 2e-3 1e-3
	$(PY) -m gausstac_maniskill.bench sponge --dx 2e-3 --nu 0.2 0.45
	$(PY) -m gausstac_maniskill.bench resolution --tasks GaussTac-PressCube-v1 --dx 2e-3 1.5e-3 1e-3
	$(PY) -m gausstac_maniskill.bench resolution --tasks GaussTac-GraspSqueezeSponge-v1 --dx 2e-3 1.5e-3 --settle 5 --out out/bench_resolution_sponge
	$(PY) -m gausstac_maniskill.bench hold
	$(PY) -m gausstac_maniskill.bench batch --camera 128 128
	$(PY) -m gausstac_maniskill.bench scale --backend physx_cpu --envs 1 --steps 5

clean:
	rm -rf .venv out build *.egg-info
