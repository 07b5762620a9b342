"""Why a decoded direct-Δ error can sit above the static baseline while the head's latent error is small.

The diagnostic and its documentation live in :mod:`pokeworld.diagnostics.decoded_error`; this is its command line.

    python scripts/decoded_error_spectrum.py out/map/runs/VF-…-tokensTrue-s0 out/map/runs/VFX-…-standard-s0 \
        --out docs/results/decoded_error_spectrum_cpu.json
"""

import sys

from pokeworld.diagnostics.decoded_error import main

if __name__ == "__main__":
    sys.exit(main())
