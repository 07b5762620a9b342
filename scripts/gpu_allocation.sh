#!/usr/bin/env bash
# One GPU allocation of the paper-budget map, in one command that ends inside the allocation (docs/model.md
# "GPU allocations"). A device machine comes bare, for 15 minutes, at most 10 a command, and returns at most 8 files
# of at most 16 MiB (64 MiB together) from OUT, so this script spends the allocation on training and returns each
# run as soon as it is measured:
#   1. device.json: the GPU (nvidia-smi name, driver), torch, CUDA, the UTC date, the commit (ALLOC_COMMIT);
#   2. a smoke check of at most a minute: the two tests of tests/test_cuda.py on the map's path (the CUDA-graph
#      default trains and resumes in the paper preset's objective and model; a GPU-trained run is measured),
#      skipped on a CPU;
#   3. the runs of VARIANTS one at a time (pokeworld.remote.run), each started only when its
#      predicted time fits what is left, measured with ridge probes and packed into OUT before the next starts;
#      the checkpoint of the run training is packed too, every ALLOC_SNAPSHOT_S seconds, so a kill at any moment
#      loses at most the run in progress, and a later allocation given this OUT in ALLOC_RESUME resumes it.
# OUT then holds allocation.log, device.json, .pokeworld-owned (pokeworld's record of what it wrote), records.tar.gz
# (the map's records: configs, metrics, measurements, progress, the corpus manifest, returned.json) and
# pack.tar.part00.. (the finished runs' final weights and the unfinished run's checkpoint, large tensors in
# bfloat16; pokeworld.remote.pack). No certificates are computed here (the CPU side certifies the
# same seeded corpus). ALLOC_MODE=bench instead runs the full CUDA tests and the benchmark, and trains nothing.
# Then, on the CPU side:  python scripts/merge_allocations.py OUT1 OUT2 ... --out ...   (merge; see there)
#                         python scripts/merge_allocations.py --plan OUT1 OUT2 ...     (the next allocation's command)
#
# Usage (repository root; pokeworld importable, e.g. PYTHONPATH=/tmp/site:$PWD/src as in ../shared/device/README.md):
#   bash scripts/gpu_allocation.sh OUT [RUNS...]     RUNS: VARIANT or VARIANT@SEED in priority order
#                                                    (default VFX VF V VX_t VX_p VX at seed 0, then the same at @1)
# Environment (all optional):
#   ALLOC_MODE           train (default) or bench (full CUDA tests and the benchmark, no training)
#   ALLOC_COMMIT         the commit this copy of the repository is (the device copy has no .git); into device.json
#   ALLOC_RESUME         folders earlier allocations returned (space-separated, a folder with spaces quoted as in a
#                        shell): their checkpoints are resumed and the runs they finished skipped
#                        (merge_allocations.py --plan prints which to give, quoted)
#   ALLOC_BUDGET_MIN     minutes for the whole script, its start to its last pack (default 8.5)
#   ALLOC_RESERVE_MIN    minutes kept at the end for the last pack; training stops there (default 0.5)
#   ALLOC_PRESET         map preset (default paper; tiny checks the script on a CPU in seconds)
#   ALLOC_STEPS          training steps per run (default 0: the preset's, 20,000 at paper)
#   ALLOC_TESTS          smoke (default in train mode), full (default in bench mode) or 0 (none)
#   ALLOC_TESTS_MAX_S    seconds the tests may take before they are killed (default 60 for smoke, 180 for full)
#   ALLOC_TESTS_BUDGET_S the tests' budget: a test that would start past it is skipped, by name (default 50 for
#                        smoke, 120 for full; tests/test_cuda.py runs the map's path first)
#   ALLOC_SNAPSHOT_S     seconds between checkpoint snapshots into OUT while a run trains (default 30)
#   ALLOC_S_PER_STEP     s/step predicted before this allocation has timed a run (default: the preset's prior,
#                        0.0081 at paper, the aligned VFX on an H200 with CUDA graphs)
#   ALLOC_OVERHEAD_S     seconds a run takes beside its steps, predicted likewise (default: paper 60)
#   ALLOC_BENCH_PRESETS  bench mode: benchmark presets (default "cpu paper"; empty skips the benchmark)
#   ALLOC_BENCH_CONFIGS  bench mode: configurations (default "fast fast+reduce-overhead": eager and CUDA graphs)
#   ALLOC_BENCH_STEPS    bench mode: timed steps per configuration (default 30)
#   ALLOC_BENCH_MAX_S    bench mode: seconds the benchmark may take (default 150)
#   ALLOC_MEASURE_DEVICE where each finished run is measured (ridge probes, prediction, glide test) before the next
#                        starts: auto (default: the GPU it trained on) or cpu (the machine's CPU cores); the MLP
#                        probes, the untrained bound, certificates and planning are left to the CPU side
#                        (scripts/complete_allocations.py; docs/model.md "Measurement on or off the training path")
#   ALLOC_CONCURRENCY    most runs training at once on the GPU (default 1: one after another). More: each run in a
#                        process of its own, a ramp from one run that doubles while the total steps/s grows by 8 %
#                        (pokeworld.remote.share; no accelerator setting is changed)
#   ALLOC_RETURN_PARTS   parts of at most 15 MiB the weights may take in all (default 0: what one return folder
#                        holds, 3); a lease sets more, since each of its commands returns the parts no earlier one did
#   ALLOC_WORK           the map's working folder (corpus, checkpoints; default a new folder under /tmp, never in OUT)
#   PYTHON               the interpreter (default python3)
set -uo pipefail
OUT=${1:?usage: bash scripts/gpu_allocation.sh OUT [RUNS...]}
shift
RUNS=("$@")
PY=${PYTHON:-python3}
MODE=${ALLOC_MODE:-train}
BUDGET_MIN=${ALLOC_BUDGET_MIN:-8.5}
PRESET=${ALLOC_PRESET:-paper}
BENCH_PRESETS=${ALLOC_BENCH_PRESETS-cpu paper}  # '-', not ':-': an empty value skips the benchmark
BENCH_CONFIGS=${ALLOC_BENCH_CONFIGS:-fast fast+reduce-overhead}
START=$(date +%s.%N)
export PYTHONUNBUFFERED=1

case "$MODE" in train) TESTS=${ALLOC_TESTS:-smoke} ;; bench) TESTS=${ALLOC_TESTS:-full} ;;
  *) echo "ALLOC_MODE must be train or bench, not $MODE" >&2; exit 2 ;; esac
case "$TESTS" in smoke) TESTS_MAX_S=${ALLOC_TESTS_MAX_S:-60} ;;
  full|1) TESTS=full; TESTS_MAX_S=${ALLOC_TESTS_MAX_S:-180} ;; 0) ;; *) echo "ALLOC_TESTS must be smoke, full or 0, not $TESTS" >&2; exit 2 ;; esac
OUT=$(realpath -m "$OUT")
WORK=$(realpath -m "${ALLOC_WORK:-$(mktemp -d /tmp/pokeworld-allocation.XXXXXX)}")
# the device machine returns everything under OUT: the corpus and checkpoints (gigabytes) must stay outside it
case "$WORK/" in "$OUT"/*) echo "ALLOC_WORK ($WORK) must not lie inside OUT ($OUT)" >&2; exit 2 ;; esac
mkdir -p "$OUT" "$WORK/map" || exit 2
exec > >(tee -a "$OUT/allocation.log") 2>&1

elapsed_s() { awk -v s="$START" -v n="$(date +%s.%N)" 'BEGIN { printf "%.0f", n - s }'; }
log() { echo "[gpu_allocation +$(elapsed_s)s] $*"; }

log "mode $MODE, device -> $OUT/device.json"
"$PY" -c 'import json, sys; from pokeworld.remote.allocations import write_device
print(json.dumps(write_device(sys.argv[1])))' "$OUT/device.json" || exit 3
cp "$OUT/device.json" "$WORK/map/device.json"  # the records take it along

if [ "$TESTS" = smoke ]; then
  # the map's path on the GPU: CUDA-graph training with its resume in the paper preset's objective and model (the
  # released reference's form), and the measurement of a GPU-trained run
  log "smoke check: tests/test_cuda.py, the map's path (at most $TESTS_MAX_S s)"
  POKEWORLD_CUDA_BUDGET_S=${ALLOC_TESTS_BUDGET_S:-50} timeout "$TESTS_MAX_S" "$PY" -m pytest -q -rs \
    -p no:cacheprovider tests/test_cuda.py \
    -k "(cuda_default_trains_as_eager_and_resumes and reference) or gpu_trained_run_is_measured" 2>&1 | tail -n 5
  log "smoke check exit status ${PIPESTATUS[0]}"
elif [ "$TESTS" = full ]; then
  log "CUDA tests (at most $TESTS_MAX_S s) -> cuda_tests.log"
  # ordered and budgeted (tests/test_cuda.py): the tests past the budget are skipped by name, and the measured
  # duration of each test that ran comes back in cuda_times.json, the next allocation's expectation
  POKEWORLD_CUDA_BUDGET_S=${ALLOC_TESTS_BUDGET_S:-120} POKEWORLD_CUDA_TIMES="$OUT/cuda_times.json" \
    timeout "$TESTS_MAX_S" "$PY" -m pytest -q -rs -p no:cacheprovider tests/test_cuda.py >"$OUT/cuda_tests.log" 2>&1
  echo "exit status $?" >>"$OUT/cuda_tests.log"
  tail -n 3 "$OUT/cuda_tests.log"
fi

RC=0
if [ "$MODE" = bench ]; then
  if [ -n "$BENCH_PRESETS" ]; then
    log "benchmark: presets $BENCH_PRESETS, configurations $BENCH_CONFIGS (at most ${ALLOC_BENCH_MAX_S:-150} s)"
    # shellcheck disable=SC2086  # word lists
    timeout "${ALLOC_BENCH_MAX_S:-150}" "$PY" benchmarks/train_fast_path.py --presets $BENCH_PRESETS \
      --configs $BENCH_CONFIGS --steps "${ALLOC_BENCH_STEPS:-30}" --out "$OUT/bench.json" \
      || log "the benchmark did not finish (exit status $?)"
  fi
else
  args=("$OUT" --work "$WORK" --preset "$PRESET" --steps "${ALLOC_STEPS:-0}" --budget-min "$BUDGET_MIN"
        --reserve-min "${ALLOC_RESERVE_MIN:-0.5}" --started "$START" --snapshot-s "${ALLOC_SNAPSHOT_S:-30}")
  [ ${#RUNS[@]} -gt 0 ] && args+=(--runs "${RUNS[@]}")
  [ -n "${ALLOC_S_PER_STEP:-}" ] && args+=(--prior-s-per-step "$ALLOC_S_PER_STEP")
  [ -n "${ALLOC_OVERHEAD_S:-}" ] && args+=(--prior-overhead-s "$ALLOC_OVERHEAD_S")
  [ -n "${ALLOC_MEASURE_DEVICE:-}" ] && args+=(--measure-device "$ALLOC_MEASURE_DEVICE")
  [ -n "${ALLOC_CONCURRENCY:-}" ] && args+=(--concurrency "$ALLOC_CONCURRENCY")
  [ -n "${ALLOC_RETURN_PARTS:-}" ] && args+=(--return-parts "$ALLOC_RETURN_PARTS")
  [ -n "${ALLOC_PART_BYTES:-}" ] && args+=(--part-bytes "$ALLOC_PART_BYTES")
  # ALLOC_RESUME is a shell-quoted list of folders (as merge_allocations.py --plan prints it): passed as one word
  # and split by Python's shlex, never by this shell's word splitting or expansion
  [ -n "${ALLOC_RESUME:-}" ] && args+=(--resume-list "$ALLOC_RESUME")
  log "training: preset $PRESET, runs ${RUNS[*]:-(the default queue)}, budget $BUDGET_MIN min, at most ${ALLOC_CONCURRENCY:-1} at once"
  # the GPU's utilisation and memory into the log every 15 s while the runs train (read only; nothing is set)
  GPU_WATCH=""
  if command -v nvidia-smi >/dev/null 2>&1; then
    ( nvidia-smi --query-gpu=utilization.gpu,utilization.memory,memory.used --format=csv,noheader -l 15 2>/dev/null \
      | sed -u 's/^/[gpu util, mem util, mem used] /' ) &
    GPU_WATCH=$!
  fi
  "$PY" -m pokeworld.remote.run "${args[@]}"
  RC=$?
  [ -n "$GPU_WATCH" ] && { pkill -P "$GPU_WATCH" 2>/dev/null; kill "$GPU_WATCH" 2>/dev/null; }
fi

# what the device machine returns: at most 8 files of at most 16 MiB each, 64 MiB together
problems=$("$PY" -c 'import sys; from pathlib import Path
from pokeworld.remote.pack import check_return_folder
print("; ".join(check_return_folder(Path(sys.argv[1]))))' "$OUT")
if [ -n "$problems" ] && [ "${ALLOC_RETURN_PARTS:-0}" -gt 0 ] 2>/dev/null; then
  problems="; more than one return holds: a lease's commands return it in pieces ($problems)"
elif [ -n "$problems" ]; then
  problems="; NOT ALL OF IT COMES BACK: $problems"
fi
log "OUT holds $(find "$OUT" -type f | wc -l) files ($(du -sh "$OUT" | cut -f1))$problems"
log "done (exit status $RC)"
exit $RC
