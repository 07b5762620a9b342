"""Calibrate PokeWorld's free constants to the paper's observable corpus statistics (run by hand).

The spec fixes dt, sub-steps, radii, masses and the parameter ranges; F_max, finger damping and
the behaviour policy's knobs are free. This script searches them (random search, then a local
refinement around the best point) to minimise the summed squared log-ratio between our corpus
statistics (:mod:`pokeworld.sim.stats`) and the paper's, on render-free corpora, and writes every
evaluated point to JSON. docs/design.md ("Calibration") records the outcome; the search is
:func:`pokeworld.sim.calibration.calibrate`.

    python scripts/calibrate_env.py --out docs/results/calibration.json --samples 160 --refine 80
"""

import argparse
import json

from pokeworld.io import write_json
from pokeworld.sim.calibration import calibrate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/results/calibration.json")
    ap.add_argument("--samples", type=int, default=160, help="random-search points")
    ap.add_argument("--refine", type=int, default=80, help="local refinement points")
    ap.add_argument("--episodes", type=int, default=1200, help="episodes per evaluated corpus")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--start", default="", help="a previous output JSON: refine from its best point too")
    ap.add_argument("--mode-weights", type=float, nargs=3, default=None,
                    help="fix pursuit / strike-retreat / drift weights instead of searching them")
    ap.add_argument("--strike-gain-min", type=float, default=0.0, help="floor on the strike gain")
    args = ap.parse_args()
    res = calibrate(args.samples, args.refine, args.episodes, args.seed, args.start, args.mode_weights,
                    args.strike_gain_min)
    write_json(args.out, res)
    print(json.dumps({"best": res["best"], "confirm": res["confirm_2400_episodes_seed1"]}, indent=1, default=str))


if __name__ == "__main__":
    main()
