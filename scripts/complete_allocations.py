"""The CPU side of GPU allocations: the same seeded corpus, the MLP probes and the untrained bound of every returned
run, the certificates and planning, each stage recorded with this machine, its date and its time.

The logic and its documentation live in :mod:`pokeworld.remote.complete`; this is its command line.

    python scripts/complete_allocations.py ALLOC_A ALLOC_B ... --work WORK [--plan-episodes N] [--certify-...]
    python scripts/merge_allocations.py ALLOC_A ALLOC_B ... --cpu-side WORK --out docs/results/map_paper.json \
        --markdown docs/results/map_paper.md
"""

import sys

from pokeworld.remote.complete import main

if __name__ == "__main__":
    sys.exit(main())
