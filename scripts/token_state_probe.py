"""Where does a spatial-token model keep stiffness? Probe its predictor state three ways.

The probe and its documentation live in :mod:`pokeworld.diagnostics.token_state`; this is its command line.

    python scripts/token_state_probe.py out/map/data/standard out/map/runs/VF-…-tokensTrue-s0 \
        out/map/runs/VFX-…-tokensTrue-s0 --reference out/map/runs/VFX-…-standard-s0 \
        --out docs/results/token_state_probe_cpu.json
"""

import sys

from pokeworld.diagnostics.token_state import main

if __name__ == "__main__":
    sys.exit(main())
