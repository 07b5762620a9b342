"""Restitution and post-contact displacement against stiffness under both contact-damping laws (run by hand).

Measures, in the simulator, head-on impacts over the corpus's stiffness range at the impact speeds the default
corpus holds (its contact-onset speeds, quartiles), for the "constant" and "tangent" readings of "normal damping at
zeta of critical" (docs/design.md, "Contact damping") in the calibrated environment (whose two laws these are; the
reference environment's hertz law is measured by scripts/reference_fidelity.py), and writes JSON + a Markdown table:

    python scripts/contact_law.py --out docs/results/contact_law
"""

import argparse
from pathlib import Path

import numpy as np

from pokeworld.io import write_json
from dataclasses import replace

from pokeworld.sim import contact, environments
from pokeworld.sim.generate import make_config, simulate

STIFFNESS = (500.0, 1000.0, 2000.0, 4000.0, 6000.0)
CALIBRATED = environments.physics("calibrated")


def corpus_speeds(law: str, episodes: int) -> np.ndarray:
    cfg = make_config("cpu", num_episodes=episodes, environment="calibrated",
                      physics=replace(CALIBRATED, contact_damping=law))
    return contact.impact_speeds(simulate(cfg, progress=False, render=False).labels)


def markdown(rec: dict) -> str:
    lines = ["# Contact damping: what stiffness leaves after contact\n",
             f"`{rec['command']}`. Head-on impacts, m = {rec['table']['mass']}, γ = {rec['table']['gamma']}, "
             "default physics (finger damping on, no commanded force). Impact speeds: the quartiles of the default "
             f"corpus's contact-onset speeds ({rec['corpus_episodes']} episodes, {rec['default_law']} law): "
             + ", ".join(f"{s:.2f}" for s in rec['table']['speeds']) + ".\n"]
    for law, r in rec["table"]["laws"].items():
        lines += [f"\n## {law}\n", "| k | " + " | ".join(f"e @ {s:.2f}" for s in rec["table"]["speeds"])
                  + " | " + " | ".join(f"Δx₁₆ @ {s:.2f}" for s in rec["table"]["speeds"]) + " |",
                  "|---" * (1 + 2 * len(rec["table"]["speeds"])) + "|"]
        for i, k in enumerate(rec["table"]["stiffness"]):
            lines.append(f"| {k:.0f} | " + " | ".join(f"{x:.3f}" for x in r["restitution"][i]) + " | "
                         + " | ".join(f"{x:.4f}" for x in r["displacement"][i]) + " |")
        lines.append("| soft / stiff | " + " | ".join(f"{x:.2f}" for x in r["restitution_ratio_soft_to_stiff"])
                     + " | " + " | ".join(f"{x:.2f}" for x in r["displacement_ratio_soft_to_stiff"]) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/results/contact_law", help="output stem (.json and .md)")
    ap.add_argument("--episodes", type=int, default=1200, help="episodes of the corpus whose impact speeds are used")
    args = ap.parse_args()
    speeds = {law: corpus_speeds(law, args.episodes) for law in ("constant", "tangent")}
    default_law = CALIBRATED.contact_damping
    quartiles = np.quantile(speeds[default_law], [0.25, 0.5, 0.75])
    table = contact.law_table(CALIBRATED, STIFFNESS, quartiles)
    rec = {"command": f"python scripts/contact_law.py --out {args.out} --episodes {args.episodes}",
           "corpus_episodes": args.episodes, "table": table, "default_law": default_law,
           "corpus_impact_speed_quantiles": {law: dict(zip(("q10", "q25", "q50", "q75", "q90"),
                                                           np.quantile(s, [0.1, 0.25, 0.5, 0.75, 0.9]).tolist()))
                                             for law, s in speeds.items()},
           "corpus_impacts": {law: int(s.size) for law, s in speeds.items()}}
    write_json(f"{args.out}.json", rec)
    Path(f"{args.out}.md").write_text(markdown(rec))
    print(f"[contact_law] wrote {args.out}.json and {args.out}.md")


if __name__ == "__main__":
    main()
