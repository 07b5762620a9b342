"""Search the behaviour mix under a contact-damping law: corpus statistics and certificates per point (run by hand).

Each point overrides the default generator's behaviour mix (pursuit / strike-retreat / OU weights, strike gain,
launch fraction and speeds). Every point gets the paper's corpus statistics (render-free corpora,
:func:`pokeworld.sim.calibration.evaluate_corpus`) and their calibration loss; with ``--certify`` also the cheap
contact certificates of :func:`pokeworld.sim.calibration.scan_point` (GRU oracle and linear floor, 3,000 windows,
60 epochs — they read lower than the ``cpu`` certificates). docs/design.md, "Behaviour mix under the constant law".

    python scripts/mix_grid.py --out docs/results/mix_grid.json --law constant --certify
"""

import argparse
import itertools
import json
import time

from pokeworld.io import write_json
from pokeworld.sim.calibration import evaluate_corpus, loss, scan_point
from pokeworld.sim.stats import PAPER_STATS

MIXES = ((0.2, 0.65, 0.15), (0.35, 0.5, 0.15), (0.5, 0.35, 0.15), (0.68, 0.17, 0.15))
"""Pursuit / strike-retreat / OU weights: from the impact-rich default to the kinematic-only calibration's mix."""
LAUNCH = ((0.29, (2.55, 5.0)), (0.5, (1.0, 3.0)))
"""Launch fraction and speed range: the default's, and more but slower launches (longer free glides)."""
STRIKE_GAINS = (0.7, 1.0)


def points(law: str) -> list[dict]:
    out = []
    for mix, (launch, speed), gain in itertools.product(MIXES, LAUNCH, STRIKE_GAINS):
        out.append({"physics": {"contact_damping": law},
                    "policy": {"mode_weights": mix, "launch_fraction": launch, "launch_speed": speed,
                               "strike_gain": gain}})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/results/mix_grid.json")
    ap.add_argument("--law", default="constant", choices=("constant", "tangent"))
    ap.add_argument("--episodes", type=int, default=1200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--certify", action="store_true", help="add the cheap contact certificates (≈1 min a point)")
    args = ap.parse_args()
    rows, t0 = [], time.time()
    for i, point in enumerate(points(args.law)):
        if args.certify:
            row = scan_point(point, args.episodes, args.seed)
        else:
            _, stats = evaluate_corpus(point, args.episodes, args.seed)
            row = {"point": point, "stats": stats, "stats_loss": loss(stats)}
        rows.append(row)
        print(f"[mix_grid] {i + 1}: {json.dumps(point['policy'])} loss {row['stats_loss']:.3f}"
              + (f" gru log k {row['gru_contact']['log_k']:+.2f} log m {row['gru_contact']['log_m']:+.2f}"
                 if args.certify else ""), flush=True)
    cmd = (f"python scripts/mix_grid.py --out {args.out} --law {args.law} --episodes {args.episodes} "
           f"--seed {args.seed}" + (" --certify" if args.certify else ""))
    write_json(args.out, {"command": cmd, "paper": PAPER_STATS, "rows": rows, "seconds": time.time() - t0})
    print(f"[mix_grid] wrote {len(rows)} points to {args.out}")


if __name__ == "__main__":
    main()
