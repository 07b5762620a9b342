"""Merge GPU allocations of the paper-budget map (``scripts/gpu_allocation.sh``) into one record and its report, or
print the next allocation's command from what earlier ones returned.

The logic and its documentation live in :mod:`pokeworld.remote.allocations`; this is its command line.

    python scripts/merge_allocations.py ALLOC_A ALLOC_B ... --certificates certificates_paper.json \
        --out docs/results/map_paper.json --markdown docs/results/map_paper.md [--runs-out runs/paper]
    python scripts/merge_allocations.py --plan ALLOC_A ALLOC_B ... [--commit SHA]
"""

import sys

from pokeworld.remote.allocations import main

if __name__ == "__main__":
    sys.exit(main())
