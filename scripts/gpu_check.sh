#!/usr/bin/env bash
# The GPU checks, on the lent machine (see scripts/gpu_pack.sh): the batched co-simulator and
# the kernel profile on Taichi cuda, then the CUDA tests of the MPM, tactile and splat paths.
# Each part has its own time limit (seconds: T_BATCH, T_KERN, T_PAD, T_TEST; 0 skips a part; T_PAD
# is off unless set; TESTS narrows the tests) so that a slow part leaves the others their time; logs go to $OUT.
cd "$(dirname "$0")/.."
export PYTHONUNBUFFERED=1
OUT=${OUT:-out/gpu}; mkdir -p "$OUT"
tar -xJf .whl/site312.tar.xz -C /tmp || exit 3
# the installed package maps agents/, tasks/ and assets/ into it (pyproject.toml); the source tree does not
for d in assets agents tasks; do ln -sfn ../$d gausstac_maniskill/$d; done
export PYTHONPATH=/tmp/site312:$PWD MUJOCO_GL=disable
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
if [ "${T_BATCH:-200}" -gt 0 ]; then
GAUSSTAC_ARCH=cuda timeout "${T_BATCH:-200}" python3 -m gausstac_maniskill.bench batch --envs ${ENVS:-1 16 64 256} \
    --steps 3 --loop-max 1 --camera 128 128 > "$OUT/batch.log" 2>&1; echo "bench batch: exit $?"
grep -o '| [0-9].*' "$OUT/batch.log"
fi
if [ "${T_KERN:-70}" -gt 0 ]; then
timeout "${T_KERN:-70}" python3 -m gausstac_maniskill.bench kernels --arch cuda > "$OUT/kernels.log" 2>&1
echo "bench kernels: exit $?"; grep -A2 "^index pad" "$OUT/kernels.log"
fi
if [ "${T_PAD:-0}" -gt 0 ]; then  # the pad at equilibrium: compliance on all the host's cores, then bench pad
GAUSSTAC_CACHE="$OUT/cache" timeout "$T_PAD" python3 -m gausstac_maniskill.bench pad --pad-solver fem \
    --indenters sphere plate --dx 1e-3 --arch cuda --out "$OUT/pad" > "$OUT/pad.log" 2>&1; echo "bench pad fem: exit $?"
rm -rf "$OUT/cache"; grep -E "^\| (sphere|plate)|build|ms" "$OUT/pad.log" | head -30
fi
[ "${T_TEST:-240}" -gt 0 ] || exit 0
GAUSSTAC_COMPILE=fast GAUSSTAC_TEST_ARCH=cuda timeout "${T_TEST:-240}" python3 -m pytest -m "not slow" \
    -p no:cacheprovider -n 14 --dist loadfile -v -rfE --tb=short --timeout 150 \
    ${TESTS:-tests/mpm tests/tactile tests/fem tests/test_batch.py tests/test_cosim.py tests/splat/test_rasterizer.py} \
    > "$OUT/tests.log" 2>&1; echo "CUDA tests: exit $?"
grep -E "^(FAILED|ERROR)|passed|failed" "$OUT/tests.log" | tail -40
