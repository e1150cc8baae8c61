#!/usr/bin/env bash
# The render device's GPU checks, in one call on a GPU machine of this project (README.md beside
# this file): install the carried wheels, the CUDA tests, then the path tier's per-frame cost on
# the exported default demo. Writes under $OUT (or out/gpu_checks): pytest.log, render_device_cuda.json,
# images_cuda.npz. Each step has its own time limit, so a slow one leaves the others' results.
set -u
OUT=${OUT:-out/gpu_checks}
mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$OUT/gpu.txt"
timeout 240 python3 -m pytest --noconftest -p no:cacheprovider -q -rs tests/test_render_cuda.py 2>&1 | tee "$OUT/pytest.log"
[ "${SKIP_BENCH:-0}" = 1 ] || timeout 180 python3 benchmarks/bench_render_device.py time "${1:-.devdata/default_frames.npz}" --device cuda --spp 16 --repeats 5 \
    --out "$OUT" 2>&1 | tee "$OUT/bench.log"
