"""How the behaviour mix sets stiffness recoverability: corpus statistics and a cheap GRU certificate per point.

Reproduces ``impact_scan`` in docs/results/calibration.json (docs/design.md, "Calibration"): each point is
a set of generator overrides; for each, a render-free corpus (default 1,200 episodes, seed 0), its
observable statistics and calibration loss, and the GRU and linear certificates on contact windows with a
smaller budget than the ``cpu`` certificate (3,000 fit windows, 60 epochs), so the values read lower than
``pokeworld certify`` and are comparable only with each other. The points and the per-point measurement are
in :mod:`pokeworld.sim.calibration`. Run by hand (≈ 2–3 min per point, 1 core):

    python scripts/scan_impacts.py --out scan.json
    python scripts/scan_impacts.py --points '{"mine": {"policy": {"strike_gain": 0.9}}}'
"""

import argparse
import json

import torch

from pokeworld.io import write_json
from pokeworld.sim.calibration import SCAN, scan_point


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="scan.json")
    ap.add_argument("--points", default="", help="JSON {name: overrides} instead of the built-in scan")
    ap.add_argument("--episodes", type=int, default=1200)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    points = json.loads(args.points) if args.points else SCAN
    rows = {}
    for name, point in points.items():
        rows[name] = scan_point(point, args.episodes, args.seed)
        r = rows[name]
        print(f"{name}: loss {r['stats_loss']:.3f} GRU " + " ".join(f"{k} {v:+.2f}" for k, v in r["gru_contact"].items()))
    write_json(args.out, rows)


if __name__ == "__main__":
    main()
