"""Collect several `pokeworld plan` outputs into one record and one table (run by hand).

Each NAME=DIR names a folder `pokeworld plan --out DIR` wrote; the record keeps, per invocation, the command that
reproduces it (rebuilt from its plan.json config, run folders as given there), the config and, per controller, the
planning metrics, the rank test and the time per decision. NaN (a metric a controller does not have) becomes null.

    python scripts/collect_plans.py --out docs/results/planning_costs_cpu.json \
        --markdown docs/results/planning_costs_cpu.md decoder=out/plan_decoder goal_l2=out/plan_goal_l2
"""

import argparse
import json
import math
from pathlib import Path

from pokeworld.io import atomic_path, write_json
from pokeworld.published.paper import PLANNING

KEEP = ("reach", "median_closest_improvement", "median_improvement", "mean_improvement", "object_moved", "spearman",
        "topk_overlap", "topk_chance",
        "goal_truth_spearman", "goal_truth_topk_overlap", "miss_displacement", "hit_displacement",
        "hit_true_displacement", "within_r2", "decoded_truth_within_r2", "seconds_per_decision")
FLAGS = ("episodes", "steps", "replan", "population", "elites", "iterations", "context", "goal_radius",
         "goal_distance", "goals", "settle", "approach_weight", "approach_offset", "rank_topk", "cost", "goal_finger",
         "heads", "seed", "simulator_controller")


def clean(v):
    return None if isinstance(v, float) and not math.isfinite(v) else v


def flag(key: str, value) -> str:
    name = key.replace("_", "-")
    if isinstance(value, bool):  # tyro's boolean flags: --name / --no-name
        return f"--{name}" if value else f"--no-{name}"
    return f"--{name} {value}"


def command(cfg: dict) -> str:
    flags = " ".join(flag(k, cfg[k]) for k in FLAGS if k in cfg)
    data = f" --data {cfg['data']}" if cfg.get("data") else ""
    return f"pokeworld plan {flags} --runs {' '.join(cfg['runs'])}{data} --out {cfg['out']}"


def collect(folder: Path) -> dict:
    plan = json.loads((folder / "plan.json").read_text())
    results = {name: {k: clean(r.get(k)) for k in KEEP if k in r} for name, r in plan["results"].items()}
    return {"command": command(plan["config"]), "config": plan["config"], "results": results}


def cell(v, pct: bool = False) -> str:
    if v is None:
        return "—"
    return f"{100 * v:.0f} %" if pct else f"{v:+.2f}"


def table(record: dict) -> list[str]:
    lines = ["| invocation | controller | reach (paper) | median improvement, start − closest (paper) | "
             "median improvement, start − final | object moved | rank ρ | top-k overlap (chance) | "
             "goal control: top-k | s / decision |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name, inv in record["invocations"].items():
        for ctl, r in inv["results"].items():
            paper = PLANNING.get(ctl)
            reach = cell(r.get("reach"), True) + (f" ({100 * paper[0]:.0f} %)" if paper else "")
            closest = cell(r.get("median_closest_improvement")) + (f" ({paper[1]:+.2f})" if paper else "")
            chance = r.get("topk_chance")
            overlap = "—" if r.get("topk_overlap") is None else f"{r['topk_overlap']:.2f} ({chance:.2f})"
            goal = "—" if r.get("goal_truth_topk_overlap") is None else f"{r['goal_truth_topk_overlap']:.2f}"
            spd = "—" if r.get("seconds_per_decision") is None else f"{r['seconds_per_decision']:.1f}"
            lines.append(f"| {name} | {ctl} | {reach} | {closest} | {cell(r.get('median_improvement'))} | "
                         f"{cell(r.get('object_moved'), True)} | {cell(r.get('spearman'))} | {overlap} | {goal} | "
                         f"{spd} |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("entries", nargs="+", help="NAME=DIR: a folder `pokeworld plan --out DIR` wrote")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--markdown", type=Path)
    ap.add_argument("--note", default="", help="one line on what was planned with (models, corpus, machine)")
    args = ap.parse_args()
    record = {"note": args.note, "invocations": {}}
    for entry in args.entries:
        name, sep, folder = entry.partition("=")
        if not sep or not (Path(folder) / "plan.json").is_file():
            raise SystemExit(f"error: {entry!r} is not NAME=DIR with DIR/plan.json; "
                             "run `pokeworld plan --out DIR` first")
        record["invocations"][name] = collect(Path(folder))
    write_json(args.out, record)
    wrote = [str(args.out)]
    if args.markdown:
        text = "\n".join([f"# Planning: {args.note}" if args.note else "# Planning", "",
                          *(f"- {n}: `{inv['command']}`" for n, inv in record["invocations"].items()), "",
                          *table(record), ""])
        with atomic_path(args.markdown) as tmp:
            Path(tmp).write_text(text)
        wrote.append(str(args.markdown))
    print(f"[collect_plans] wrote {', '.join(wrote)}")


if __name__ == "__main__":
    main()
