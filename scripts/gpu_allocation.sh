#!/usr/bin/env bash
# One GPU allocation of the paper-budget map, in one command that ends inside the allocation (docs/model.md
# "GPU allocations"): the CUDA tests, a short benchmark (s/step of the cpu and paper presets, eager against CUDA
# graphs), then as many complete paper-preset factorial runs (seed 0, 20,000 steps) as the time left allows, in
# the priority order of VARIANTS, each measured with ridge probes. No certificates are computed here (the CPU side
# certifies the same seeded corpus). Everything that comes back is small and lands in OUT, at most 8 files:
#   device.json       the GPU (nvidia-smi name, driver), torch, CUDA, the UTC date, the git commit
#   cuda_tests.log    tests/test_cuda.py
#   bench.json        benchmarks/train_fast_path.py
#   map_<preset>.tar.gz  the map's pack: map_config/progress/device JSON, the corpus manifest (its content hash),
#                     each run's config, metrics and measurement; never checkpoints or data
#   allocation.log    this script's output
# A run the budget cuts short is listed as partial in progress.json and left out of the merged record.
# Merge any number of allocations: python scripts/merge_allocations.py OUT1 OUT2 ... --out ... (see there).
#
# Usage (repository root; pokeworld importable, e.g. PYTHONPATH=/tmp/site:$PWD/src as in ../shared/device/README.md):
#   bash scripts/gpu_allocation.sh OUT [VARIANTS...]        VARIANTS default: VFX VF V VX_t VX_p VX
# Environment (all optional):
#   ALLOC_BUDGET_MIN     minutes for the whole script, compilation included (default 8.5)
#   ALLOC_RESERVE_MIN    minutes the map keeps for measuring a run that just finished and packing (default 1.5)
#   ALLOC_PRESET         map preset (default paper; tiny checks the script on a CPU in seconds)
#   ALLOC_STEPS          training steps per run (default 0: the preset's, 20,000 at paper)
#   ALLOC_TESTS          1 runs tests/test_cuda.py first, 0 skips it (default 1)
#   ALLOC_TESTS_MAX_S    seconds the tests may take (default 180)
#   ALLOC_BENCH_PRESETS  benchmark presets (default "cpu paper"; set empty to skip the benchmark)
#   ALLOC_BENCH_CONFIGS  benchmark configurations (default "fast fast+reduce-overhead": eager and CUDA graphs)
#   ALLOC_BENCH_STEPS    timed steps per configuration (default 30)
#   ALLOC_BENCH_MAX_S    seconds the benchmark may take (default 150)
#   ALLOC_MAP_ARGS       more `pokeworld map` options (e.g. "--experiments factorial planning")
#   ALLOC_WORK           the map's working folder (corpus, checkpoints; default a new folder under /tmp, never in OUT)
#   PYTHON               the interpreter (default python3)
set -uo pipefail
OUT=${1:?usage: bash scripts/gpu_allocation.sh OUT [VARIANTS...]}
shift
VARIANTS=("$@")
[ ${#VARIANTS[@]} -eq 0 ] && VARIANTS=(VFX VF V VX_t VX_p VX)
PY=${PYTHON:-python3}
BUDGET_MIN=${ALLOC_BUDGET_MIN:-8.5}
RESERVE_MIN=${ALLOC_RESERVE_MIN:-1.5}
PRESET=${ALLOC_PRESET:-paper}
STEPS=${ALLOC_STEPS:-0}
BENCH_PRESETS=${ALLOC_BENCH_PRESETS-cpu paper}  # '-', not ':-': an empty value skips the benchmark
BENCH_CONFIGS=${ALLOC_BENCH_CONFIGS:-fast fast+reduce-overhead}
START=$(date +%s.%N)

OUT=$(realpath -m "$OUT")
WORK=$(realpath -m "${ALLOC_WORK:-$(mktemp -d /tmp/pokeworld-allocation.XXXXXX)}")
# the device machine returns everything under OUT: the corpus and checkpoints (gigabytes) must stay outside it
case "$WORK/" in "$OUT"/*) echo "ALLOC_WORK ($WORK) must not lie inside OUT ($OUT)" >&2; exit 2 ;; esac
mkdir -p "$OUT" "$WORK/map" || exit 2
exec > >(tee -a "$OUT/allocation.log") 2>&1

elapsed_s() { awk -v s="$START" -v n="$(date +%s.%N)" 'BEGIN { printf "%.0f", n - s }'; }
log() { echo "[gpu_allocation +$(elapsed_s)s] $*"; }

log "device -> $OUT/device.json"
"$PY" -c 'import json, sys; from pokeworld.experiments.allocations import write_device
print(json.dumps(write_device(sys.argv[1])))' "$OUT/device.json" || exit 3
cp "$OUT/device.json" "$WORK/map/device.json"  # the map's pack takes it along

if [ "${ALLOC_TESTS:-1}" = 1 ]; then
  log "CUDA tests (at most ${ALLOC_TESTS_MAX_S:-180} s)"
  timeout "${ALLOC_TESTS_MAX_S:-180}" "$PY" -m pytest -q -p no:cacheprovider tests/test_cuda.py >"$OUT/cuda_tests.log" 2>&1
  echo "exit status $?" >>"$OUT/cuda_tests.log"
  tail -n 3 "$OUT/cuda_tests.log"
fi

if [ -n "$BENCH_PRESETS" ]; then
  log "benchmark: presets $BENCH_PRESETS, configurations $BENCH_CONFIGS (at most ${ALLOC_BENCH_MAX_S:-150} s)"
  # shellcheck disable=SC2086  # word lists
  timeout "${ALLOC_BENCH_MAX_S:-150}" "$PY" benchmarks/train_fast_path.py --presets $BENCH_PRESETS \
    --configs $BENCH_CONFIGS --steps "${ALLOC_BENCH_STEPS:-30}" --out "$OUT/bench.json" \
    || log "the benchmark did not finish (exit status $?)"
fi

LEFT_MIN=$(awk -v b="$BUDGET_MIN" -v e="$(elapsed_s)" 'BEGIN { printf "%.2f", b - e / 60 }')
RC=0
if awk -v l="$LEFT_MIN" -v r="$RESERVE_MIN" 'BEGIN { exit !(l > r + 0.25) }'; then
  log "map: preset $PRESET, variants ${VARIANTS[*]}, $LEFT_MIN min left (reserve $RESERVE_MIN)"
  args=(map --preset "$PRESET" --out "$WORK/map" --experiments factorial --seeds 0 --variants "${VARIANTS[@]}"
        --no-certify --no-mlp-probes --no-untrained --time-budget-min "$LEFT_MIN" --time-reserve-min "$RESERVE_MIN"
        --pack "$OUT/map_$PRESET.tar.gz")
  [ "$STEPS" != 0 ] && args+=(--train-steps "$STEPS")
  # shellcheck disable=SC2086  # ALLOC_MAP_ARGS is a word list
  "$PY" -m pokeworld.cli "${args[@]}" ${ALLOC_MAP_ARGS:-}
  RC=$?
  [ -f "$WORK/map/progress.json" ] && log "progress: $(cat "$WORK/map/progress.json" | tr -d ' \n')"
else
  log "only $LEFT_MIN min left of $BUDGET_MIN: no map started"
  RC=4
fi

# what the device machine returns: at most 8 files of at most 16 MiB each
n=$(find "$OUT" -type f | wc -l)
big=$(find "$OUT" -type f -size +16M)
log "OUT holds $n files ($(du -sh "$OUT" | cut -f1))${big:+; over 16 MiB: $big}"
[ "$n" -le 8 ] || log "more than 8 files in OUT: not all of them come back"
log "done (exit status $RC)"
exit $RC
