"""How the behaviour mix sets stiffness recoverability: corpus statistics and a cheap GRU certificate per point.

Reproduces ``impact_scan`` in docs/results/calibration.json (docs/design.md, "Calibration"): each point is
a set of generator overrides; for each, a render-free corpus (default 1,200 episodes, seed 0), its
observable statistics and calibration loss, and the GRU and linear certificates on contact windows with a
smaller budget than the ``cpu`` certificate (3,000 fit windows, 60 epochs), so the values read lower than
``pokeworld certify`` and are comparable only with each other. Run by hand (≈ 2–3 min per point, 1 core):

    python scripts/scan_impacts.py --out scan.json
    python scripts/scan_impacts.py --points '{"mine": {"policy": {"strike_gain": 0.9}}}'
"""

from __future__ import annotations

import argparse
import json

import torch

from calibrate_env import evaluate_corpus, loss
from pokeworld import certify
from pokeworld.io import write_json

#: the points of the scan in docs/results/calibration.json (overrides of the current defaults' generator
#: are written in full where the defaults have changed since: A is the kinematic-only calibration)
KINEMATIC_ONLY = {"physics": {"force_max": 5.3, "finger_damping": 1.25},
                  "policy": {"mode_weights": (0.68, 0.17, 0.15), "switch_prob": 0.026, "pursuit_gain": 0.5,
                             "strike_gain": 0.42, "retreat_steps": (2, 9), "launch_fraction": 0.67,
                             "launch_speed": (3.0, 3.3)}}


def _on_kinematic(**policy) -> dict:
    return {"physics": dict(KINEMATIC_ONLY["physics"]), "policy": {**KINEMATIC_ONLY["policy"], **policy}}


SCAN = {
    "A": _on_kinematic(),
    "B": _on_kinematic(mode_weights=(0.34, 0.5, 0.16)),
    "C": _on_kinematic(mode_weights=(0.34, 0.5, 0.16), strike_gain=0.8),
    "E": _on_kinematic(mode_weights=(0.2, 0.65, 0.15), strike_gain=1.0),
    "F": _on_kinematic(mode_weights=(0.15, 0.7, 0.15), strike_gain=1.0, retreat_steps=(2, 5)),
    "G": _on_kinematic(mode_weights=(0.15, 0.7, 0.15), strike_gain=1.0, pursuit_gain=0.8),
    "defaults": {"physics": {}, "policy": {}},
}


def scan_point(point: dict, episodes: int, seed: int) -> dict:
    ds, stats = evaluate_corpus(point, episodes, seed)
    cfg = certify.make_config("cpu", estimators=("gru", "linear"), kinds=("contact",), max_windows=3000, epochs=60,
                              separate_targets=False)  # the joint fit every point in calibration.json was scanned with
    est = certify.certify(ds, cfg)["estimators"]
    return {"point": point, "stats": stats, "stats_loss": loss(stats),
            "gru_contact": est["gru"]["contact"], "linear_contact": est["linear"]["contact"]}


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
