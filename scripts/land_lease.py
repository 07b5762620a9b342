"""Land a GPU lease's returned folders in the repository (pokeworld.remote.land).

    python scripts/land_lease.py RETURN1 RETURN2 ... --record docs/results/leases/ID [--models models]
"""

from pokeworld.remote.land import main

if __name__ == "__main__":
    raise SystemExit(main())
