"""Closed-loop planning (paper App. C Table "planning"): CEM push-to-goal with the factorial's runs beside a
random controller; the planner itself is :mod:`pokeworld.plan`."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from .. import plan
from ..config import to_dict
from ..io import read_json_if_present, write_json
from ..plan import table_lines
from .runs import RunSpec, corpus_dir, run_dir, spec, with_map_training

if TYPE_CHECKING:
    from .config import MapConfig

NAME = "planning"


def specs(c: MapConfig) -> list[RunSpec]:
    """Closed-loop planning (App. C): the factorial's own multi-horizon runs (same names, so a map that runs the
    factorial trains each once); the planner itself runs after training (:func:`ensure_planning`)."""
    return [spec("factorial", v, s, c.sigreg_weight, corpus=c.planning_corpus) for v in c.planning_variants
            for s in c.seeds]


def planning_dir(c: MapConfig) -> Path:
    """Where the map writes the planning outputs."""
    return Path(c.out) / "planning"

def ensure_planning(c: MapConfig) -> dict:
    """Plan with the planning variants' finished runs and a random controller (same planner, budget, starts
    and goals for all); writes ``planning/planning.json``, ``distances.npz`` and the episode figure.

    Skipped when ``planning.json`` was computed with the same planner config from the same finished runs.
    Returns ``{"config", "summary", "runs", "figure"}`` (summary: controller -> reach, median improvement).
    """
    # runs=(): the map hands its runs over below; the CLI default run is not one of them (and not in the cache key)
    pcfg = plan.make_config(c.preset, out=str(planning_dir(c)), seed=c.data_seed, runs=())
    runs: dict[str, list[str]] = {}
    for s in (with_map_training(c, s) for s in specs(c)):
        runs.setdefault(s.train["variant"], []).append(str(run_dir(c, s.name)))
    # where the models ran is not part of what was planned (the device path equals the CPU's to float rounding)
    planned_config = {k: v for k, v in to_dict(pcfg).items() if k != "device"}
    key = {"config": planned_config, "runs": {v: [[Path(d).name, (Path(d) / "DONE").stat().st_mtime_ns]
                                                  for d in dirs] for v, dirs in runs.items()}}
    out = planning_dir(c)
    path = out / "planning.json"
    prev = read_json_if_present(path, "the map's planning record")
    if prev is not None:
        if prev.get("key") == key:
            print(f"[map] {path} is up to date; skipping planning")
            return prev["result"]
    out.mkdir(parents=True, exist_ok=True)
    # the position decoder is fit on the corpus the planned runs were trained on
    planned = plan.plan_runs(pcfg, runs, data=str(corpus_dir(c, c.planning_corpus)))
    figs = plan.write_outputs(planned, out, pcfg.goal_radius)
    result = {"config": to_dict(pcfg), "summary": planned["summary"], "runs": runs,
              "figure": [str(p.relative_to(Path(c.out))) for p in figs]}
    write_json(path, {"key": key, "result": result})
    return result


def planning_table(results: dict) -> list[str]:
    """App. C Table "planning": goal-region reach and median distance improvement per controller."""
    pl = results.get("planning")
    if not pl:
        return []
    cfg = pl["config"]
    corpus = results.get("map_config", {}).get("planning_corpus", "standard")
    trained = ("the factorial's runs" if corpus == "standard" else
               f"runs trained on the `{corpus}` corpus (docs/design.md, \"Planning: open-loop behaviour data\")")
    # records from before the released planner's fields hold none of them: the object-only cost, fixed goals
    approach = cfg.get("approach_weight", 0.0)
    cost = (f"the decoded object's distance to the goal plus {approach:g} × the decoded finger's distance to a push "
            f"point {cfg.get('approach_offset', 0.18):g} behind the object (the released planner's cost)" if approach
            else "the decoded object's distance to the goal")
    goals = (f"goals uniform, at least {cfg['goal_distance']:g} from the object" if cfg.get("goals") == "uniform"
             else f"goals {cfg['goal_distance']:g} from the object")
    settle = f" after {cfg['settle']} zero-action steps" if cfg.get("settle") else ""
    figure = ", ".join(f"`{f}`" for f in pl.get("figure", [])[:1])
    return ["## Closed-loop planning (push-to-goal; same planner, budget, starts and goals for every controller)", "",
            f"CEM over two-knot action programs scored by the direct Δ=4/16 heads ({cost}), {cfg['episodes']} "
            f"held-out episodes of {cfg['steps']} steps{settle}, {goals}, replanning every {cfg['replan']} steps, "
            f"population {cfg['population']} × {cfg['iterations']} iterations; reach = the object's centre enters the "
            f"goal radius {cfg['goal_radius']:g}; improvement = the start object-goal distance minus the closest one "
            "(the paper's) and minus the final one (medians over episodes). "
            f"Representations are {trained} (mean over seeds; per seed in results.json); rank ρ and top-k overlap: "
            "how each model orders the CEM's candidate programs against the true simulator; Δ=16 spread ratio and "
            "within-start R²: how much its predicted end positions vary across those programs against the true "
            "spread, and how much of the programs' true counterfactual outcomes they explain "
            "(`pokeworld.evaluate.counterfactual`)." + (f" Figure: {figure}." if figure else ""), "",
            *table_lines(pl["summary"]), ""]


section = planning_table


__all__ = ['NAME', 'specs', 'section', 'planning_dir', 'ensure_planning', 'planning_table']
