"""Can a direct Δ = 16 head of a given depth represent where an action program sends the object?

The measurement and its documentation live in :mod:`pokeworld.diagnostics.head_capacity`; this is its command line.

    python scripts/head_capacity.py --out docs/results/head_capacity.json
"""

import sys

from pokeworld.diagnostics.head_capacity import main

if __name__ == "__main__":
    sys.exit(main())
