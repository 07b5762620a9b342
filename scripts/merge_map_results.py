"""Fold runs measured by a later `pokeworld map` invocation into an earlier map's results.json and re-render it.

The logic and its documentation live in :mod:`pokeworld.experiments.merge`; this is its command line.

    python scripts/merge_map_results.py docs/results/frontier_cpu.json out/map/results.json \
        --experiments tokens controls attributes --out merged.json --markdown merged.md
"""

import sys

from pokeworld.experiments.merge import main

if __name__ == "__main__":
    sys.exit(main())
