"""Where a Gaussian-NLL run puts its learned precision (docs/results/frontier_cpu.md, "Controls").

The measurement and its documentation live in :mod:`pokeworld.diagnostics.nll_precision`; this is its command line.

    python scripts/nll_precision.py DATA RUN [RUN ...] [--windows 256] [--out FILE.json]
"""

from pokeworld.diagnostics.nll_precision import main

if __name__ == "__main__":
    main()
