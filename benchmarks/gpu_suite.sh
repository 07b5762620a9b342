#!/usr/bin/env bash
# Everything a GPU session measures first, in one command (docs/model.md "GPU"): the CUDA tests, the fast-path and
# stacked-ensemble benchmarks, and the cost of the paper preset's CPU stages (corpus generation, measurement) on
# that machine's cores. Usage: bash benchmarks/gpu_suite.sh OUTDIR [--stacked-only]
# (pokeworld importable: installed or on PYTHONPATH)
set -uo pipefail
OUT=${1:?output directory}
mkdir -p "$OUT"
log() { echo "[gpu_suite $(date +%T)] $*"; }
nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.sm,clocks.max.sm --format=csv | tee "$OUT/gpu.txt"
python3 -c "import torch; print('torch', torch.__version__, torch.cuda.get_device_name(), 'cores', __import__('os').cpu_count())" | tee -a "$OUT/gpu.txt"
log "CUDA tests"
python3 -m pytest -q -p no:cacheprovider tests/test_cuda.py 2>&1 | tail -25 | tee "$OUT/cuda_tests.log"
if [ "${2:-}" != "--stacked-only" ]; then  # (re-measure the stacked path only)
  log "fast path"
  python3 benchmarks/train_fast_path.py --presets cpu paper --steps 40 --out "$OUT/train_fast_path_gpu.json"
fi
log "stacked, seeds"
python3 benchmarks/train_stacked.py --presets paper --members 1 2 4 6 12 --steps 30 --out "$OUT/train_stacked_gpu.json"
log "stacked, factorial"
python3 benchmarks/train_stacked.py --presets paper --mix factorial --members 6 --steps 30 --out "$OUT/train_stacked_factorial_gpu.json"
if [ "${2:-}" != "--stacked-only" ]; then
  log "paper-preset stage costs"
  python3 benchmarks/paper_stage_costs.py --out "$OUT/paper_stage_costs_gpu.json"
fi
log done
