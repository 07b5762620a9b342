#!/usr/bin/env bash
# The paper-preset identifiability map (the factorial, one seed) on one GPU, as measured for
# docs/results/map_paper.md: the six variants train as one stacked group, the certificates (the gate's
# instruments: GRU oracle, linear floor, drag; contact windows) are computed on the CPU cores while they train,
# probes are ridge (no MLP), three runs are measured at a time.
# Usage: bash scripts/paper_map_gpu.sh MAPDIR STEPS [more `pokeworld map` options]
#   STEPS: training steps per run (20000 is the paper's; fewer when the GPU time on hand is short).
set -euo pipefail
MAP=${1:?map directory}
STEPS=${2:?training steps per run}
shift 2
exec python3 -m pokeworld.cli map --preset paper --out "$MAP" --experiments factorial --seeds 0 \
  --stack --certify-alongside --certify-estimators gru linear drag --certify-kinds contact \
  --no-mlp-probes --workers 3 --train-steps "$STEPS" --pack "$MAP/map_paper.tar.gz" "$@"
