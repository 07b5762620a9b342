"""Compare a converted store of a synthetic RH20T-layout corpus with its ground truth
(:mod:`pokeworld.real.conversion_check`).

    python scripts/check_synth_conversion.py STORE ROOT [--out FILE.json]
"""

import sys

from pokeworld.real.conversion_check import main

if __name__ == "__main__":
    sys.exit(main())
