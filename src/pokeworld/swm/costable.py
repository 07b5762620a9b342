"""Our planning cost as a stable-worldmodel ``Costable``, and swm's CEM / iCEM / MPPI solvers against our planner.

:class:`PlanningCost` wraps any pokeworld planning scorer (``score(hist, cand, goal) -> (E, P)``: the X-JEPA
direct heads' decoded goal distance, :class:`pokeworld.plan.LatentScorer`, or the true simulator's,
:class:`pokeworld.plan.SimulatorScorer`) in swm's ``Costable`` protocol (``get_cost(info_dict, candidates)``), so
swm's solvers search for actions with exactly the cost our planner uses. :func:`run` plans on the same starts
(:func:`pokeworld.plan.episode_setup`) with every solver, with our own CEM (:func:`pokeworld.plan.control`) and with
the random controller, executing in the true PokeWorld simulator.

Search space: by default (``search="knots"``) the solvers optimise our planner's own action family, the two 2-d knots
of a 16-step program (swm horizon 2 x action dim 2; :func:`pokeworld.sim.policy.programs` turns them into actions),
so the comparison is between optimisers over one space. ``search="actions"`` lets them optimise all 16 raw
actions (horizon 16), the way swm plans for its own models.
"""

from __future__ import annotations

import contextlib
import io
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..config import from_preset, to_dict
from ..errors import ConfigError
from ..io import check_outputs, save_text, write_json
from ..plan import (
    METRICS,
    PRESETS as PLAN_PRESETS,
    LatentScorer,
    PlanConfig,
    SimulatorScorer,
    approach_of,
    check_models,
    control,
    episode_metrics,
    episode_setup,
    rank_test,
    settled_history,
    start_sim,
)
from ..preflight import require_finished_runs
from ..sim import PokeWorldSim
from ..sim.envs import vision_frames
from ..sim.policy import KNOT_SD, PROGRAM, programs
from . import solvers
from .require import stable_worldmodel

SOLVERS = ("cem", "icem", "mppi")
"""stable-worldmodel solvers compared (its CEMSolver, ICEMSolver, MPPISolver, found by :mod:`.solvers`)."""
SEARCH = {"knots": 2, "actions": PROGRAM}
"""Search space -> swm planning horizon (steps of 2-d actions the solver optimises)."""
INFO_KEYS = ("frames", "proprio", "touch", "actions")
"""The history a scorer reads (:meth:`pokeworld.plan.LatentScorer.score`), passed through swm's ``info_dict``."""


class PlanningCost:
    """A stable-worldmodel ``Costable`` whose cost is a pokeworld scorer's planning cost of the candidates' programs.

    The solvers hand :meth:`get_cost` an ``info_dict`` whose tensors they have expanded to (E, N, ...) (one copy
    per candidate, a view, not a copy) and candidates (E, N, horizon, 2); the cost is (E, N) float32. The
    ``info_dict`` carries the observation history and the goal (``info_for``).
    """

    def __init__(self, scorer, search: str = "knots"):
        if search not in SEARCH:
            raise ConfigError(f"search must be one of {sorted(SEARCH)}, got {search!r}")
        self.scorer, self.search = scorer, search
        self._info: tuple[dict, dict, np.ndarray] | None = None  # (info_dict, hist, goal) of the current solve

    @property
    def horizon(self) -> int:
        return SEARCH[self.search]

    def programs(self, action_candidates: torch.Tensor) -> np.ndarray:
        """Candidates (E, N, horizon, 2) -> the 16-step action programs they stand for, (E, N, 16, 2) in [-1, 1]."""
        a = np.asarray(action_candidates.detach().cpu(), dtype=np.float64)
        if a.ndim != 4 or a.shape[2:] != (self.horizon, 2):
            raise ConfigError(f"{self.search} candidates must be (envs, samples, {self.horizon}, 2), got {a.shape}")
        if self.search == "knots":
            return programs(a.reshape(*a.shape[:2], 4))
        return np.clip(a, -1.0, 1.0)

    def _history(self, info_dict: dict) -> tuple[dict, np.ndarray]:
        # a solve passes the same expanded info_dict to every iteration; handing the scorer the same history object
        # keeps LatentScorer's one-encode-per-replan cache, so swm's solvers encode no more frames than our CEM
        if self._info is None or self._info[0] is not info_dict:
            missing = [k for k in (*INFO_KEYS, "goal") if k not in info_dict]
            if missing:
                raise ConfigError(f"info_dict lacks {missing}; build it with pokeworld.swm.costable.info_for")
            hist = {k: np.asarray(info_dict[k][:, 0].cpu()) for k in INFO_KEYS}
            self._info = (info_dict, hist, np.asarray(info_dict["goal"][:, 0].cpu(), dtype=np.float64))
        return self._info[1], self._info[2]

    def criterion(self, info_dict: dict, action_candidates: torch.Tensor) -> torch.Tensor:
        """(E, N) planning cost (:data:`pokeworld.plan.COST_TERMS`) of the candidates' programs."""
        hist, goal = self._history(info_dict)
        scores = np.asarray(self.scorer.score(hist, self.programs(action_candidates), goal), dtype=np.float32)
        return torch.from_numpy(scores)

    def get_cost(self, info_dict: dict, action_candidates: torch.Tensor) -> torch.Tensor:
        return self.criterion(info_dict, action_candidates)


def info_for(hist: dict, goal: np.ndarray, context: int) -> dict:
    """swm ``info_dict`` (tensors, leading dim E) from the running history lists, as pokeworld.plan.control feeds
    its scorer: the last ``context`` observations and the actions between them."""
    frames = np.stack(hist["frames"][-context:], 1)
    past = hist["actions"][-(frames.shape[1] - 1):] if frames.shape[1] > 1 else []
    actions = np.stack(past, 1) if len(past) else np.zeros((frames.shape[0], 0, 2), np.float32)
    return {"frames": torch.from_numpy(frames), "proprio": torch.from_numpy(np.stack(hist["proprio"][-context:], 1)),
            "touch": torch.from_numpy(np.stack(hist["touch"][-context:], 1)),
            "actions": torch.from_numpy(np.asarray(actions, np.float32)),
            "goal": torch.as_tensor(goal, dtype=torch.float32)}


@dataclass
class SwmPlanConfig:
    """Push-to-goal with stable-worldmodel's solvers on our planning cost, beside our own planner."""

    plan: PlanConfig = field(default_factory=lambda: PlanConfig(out="out/swm_plan"))
    """What every controller shares with ``pokeworld plan``: the runs (``--plan.runs``) and their decoder corpus
    (``--plan.data``), the starts and goals, the budget (population = swm num_samples, elites = topk, iterations =
    n_steps, replanning), and the output directory (``--plan.out``: swm_plan.json, swm_plan.md)."""
    solvers: tuple[str, ...] = SOLVERS
    """stable-worldmodel solvers to plan with (subset of cem, icem, mppi)."""
    search: str = "knots"
    """What the solvers optimise: "knots" (our two-knot program family, horizon 2) or "actions" (16 raw actions)."""
    icem_noise_beta: float = 2.0
    """iCEM colored-noise exponent (swm default)."""
    icem_alpha: float = 0.1
    """iCEM momentum of the mean/std update (swm default)."""
    icem_elite_keep: int = 5
    """iCEM elites carried to the next iteration (swm default; at most ``plan.elites``)."""
    mppi_temperature: float = 0.1
    """MPPI softmax temperature over the elites' costs (swm default 0.5 is flat at our cost scale, ~0.1 apart)."""
    ours: bool = True
    """Also plan with our own CEM (pokeworld.plan.control) on each run."""
    simulator_ceiling: bool = True
    """Also plan with swm CEM on the true simulator's cost (SimulatorScorer): the ceiling on these starts."""
    random_floor: bool = True
    """Also run the random controller (pokeworld.plan.control without a scorer): the floor."""

    def __post_init__(self) -> None:
        bad = sorted(set(self.solvers) - set(SOLVERS))
        if bad:
            raise ConfigError(f"unknown solvers {bad}; choose from {list(SOLVERS)}")
        if self.search not in SEARCH:
            raise ConfigError(f"search must be one of {sorted(SEARCH)}, got {self.search!r}")


PRESETS = {"tiny": {"plan": PLAN_PRESETS["tiny"], "icem_elite_keep": 1}, "cpu": {}}


def make_config(preset: str = "cpu", **overrides) -> SwmPlanConfig:
    return from_preset(SwmPlanConfig, PRESETS, preset, **overrides)


def make_solver(name: str, cost: PlanningCost, cfg: SwmPlanConfig):
    """A configured swm solver with our planner's budget: ``population`` samples, ``elites`` top-k, ``iterations``
    steps, initial std KNOT_SD around a zero mean (our CEM's first proposal), all episodes in one batch."""
    swm = stable_worldmodel()
    from gymnasium.spaces import Box

    common = {"batch_size": cfg.plan.episodes, "num_samples": cfg.plan.population, "var_scale": KNOT_SD,
              "n_steps": cfg.plan.iterations, "topk": cfg.plan.elites, "device": "cpu", "seed": cfg.plan.seed}
    extra = {"icem": {"noise_beta": cfg.icem_noise_beta, "alpha": cfg.icem_alpha,
                      "n_elite_keep": min(cfg.icem_elite_keep, cfg.plan.elites)},
             "mppi": {"temperature": cfg.mppi_temperature}}.get(name, {})
    solver = solvers.make_solver(swm, name, cost, **extra, **common)  # 0.1.1's or the next release's layout
    receding = cfg.plan.replan if cfg.search == "actions" else 1
    solver.configure(action_space=Box(-1.0, 1.0, (cfg.plan.episodes, 2), np.float32), n_envs=cfg.plan.episodes,
                     config=solvers.plan_config(swm, horizon=cost.horizon, receding_horizon=receding,
                                                warm_start=False))
    return solver


def solver_control(cfg: SwmPlanConfig, setup: dict, solver_name: str,
                   scorer_for: Callable[[PokeWorldSim], object]) -> dict:
    """Run every episode in the true simulator, replanning every ``replan`` steps with an swm solver on
    PlanningCost(scorer_for(sim)) and executing the first actions of the program its mean stands for."""
    sim, obs = start_sim(cfg.plan, setup)
    cost = PlanningCost(scorer_for(sim), cfg.search)
    solver = make_solver(solver_name, cost, cfg)
    goal = setup["goal"]
    hist = settled_history(cfg.plan, sim, obs)
    dist, obj_path = [np.linalg.norm(sim.state[:, 4:6] - goal, axis=1)], [sim.state[:, 4:6].copy()]
    plan = np.zeros((cfg.plan.episodes, PROGRAM, 2))
    for t in range(cfg.plan.steps):
        k = t % cfg.plan.replan
        if k == 0:
            with contextlib.redirect_stdout(io.StringIO()):  # every swm solve prints its time
                solved = solver.solve(info_for(hist, goal, cfg.plan.context))
            plan = cost.programs(solved["actions"][:, None])[:, 0]
        a = plan[:, k]
        obs = sim.step(a)
        for key, v in (("frames", vision_frames(obs["vision"])), ("proprio", obs["proprio"]), ("touch", obs["touch"]),
                       ("actions", a.astype(np.float32))):
            hist[key].append(v)
        dist.append(np.linalg.norm(sim.state[:, 4:6] - goal, axis=1))
        obj_path.append(sim.state[:, 4:6].copy())
    d = np.stack(dist, 1)
    return episode_metrics(d, np.stack(obj_path, 1), cfg.plan.goal_radius) | {"distance": d}


def timed(cfg: SwmPlanConfig, fn: Callable[[], dict]) -> dict:
    """``fn()``'s metrics plus wall seconds per decision (one replan of all episodes, simulator steps included)
    and per episode-decision."""
    t0 = time.perf_counter()
    res = fn()
    wall = time.perf_counter() - t0
    decisions = -(-cfg.plan.steps // cfg.plan.replan)
    return ({k: res[k] for k in METRICS}
            | {"wall_s": wall, "s_per_decision": wall / decisions,
               "ms_per_episode_decision": 1e3 * wall / decisions / cfg.plan.episodes})


def run_label(run_dir: str) -> str:
    return Path(run_dir).name.split("-")[0] or Path(run_dir).name


def compare(cfg: SwmPlanConfig) -> dict:
    """Every controller on one start/goal set: {label: metrics}, plus each run's rank test."""
    pc, setup = cfg.plan, episode_setup(cfg.plan)
    results, ranks = {}, {}

    def record(label: str, fn: Callable[[], dict]) -> None:
        results[label] = timed(cfg, fn)
        r = results[label]
        print(f"[swm-plan] {label}: reach {r['reach']:.0%}, mean improvement {r['mean_improvement']:+.3f}, "
              f"{r['s_per_decision']:.2f} s/decision", flush=True)

    if cfg.random_floor:
        record("random", lambda: control(pc, setup, None))
    if cfg.simulator_ceiling:
        record("simulator/swm-cem", lambda: solver_control(cfg, setup, "cem",
                                                           lambda sim: SimulatorScorer(sim, approach_of(pc))))
    for r in cfg.plan.runs:
        label = run_label(r)
        scorer = LatentScorer(r, pc.data, pc.heads, pc.cost, pc.goal_finger, device=pc.device,
                              approach=approach_of(pc))
        ranks[label] = rank_test(pc, setup, scorer)
        if cfg.ours:
            record(f"{label}/ours", lambda s=scorer: control(pc, setup, s))
        for name in cfg.solvers:
            record(f"{label}/swm-{name}",
                   lambda n=name, s=scorer: solver_control(cfg, setup, n, lambda sim: s))
    return {"results": results, "rank_test": ranks}


def table_lines(results: dict) -> list[str]:
    lines = [("| controller | reach | mean improvement | median improvement | object moved | s / decision | "
             "ms / episode-decision |"), "|---|---|---|---|---|---|---|"]
    for k, v in results.items():
        lines.append(f"| {k} | {v['reach']:.0%} | {v['mean_improvement']:+.3f} | {v['median_improvement']:+.3f} | "
                     f"{v['object_moved']:.0%} | {v['s_per_decision']:.2f} | {v['ms_per_episode_decision']:.1f} |")
    return lines


def run(cfg: SwmPlanConfig) -> Path:
    """Plan with every controller, write swm_plan.json and swm_plan.md under ``cfg.plan.out``; returns the JSON
    path."""
    if not cfg.plan.runs and not cfg.simulator_ceiling:
        raise ConfigError("give at least one trained run directory with --plan.runs (or keep --simulator-ceiling)")
    # the runs as `pokeworld plan` checks them and the outputs, before the random controller or any solver runs
    require_finished_runs(cfg.plan.runs, "swm-plan", "every --plan.runs value must be a finished run folder",
                          cfg.plan.data)
    out = check_outputs(cfg.plan.out, "swm_plan.json", "swm_plan.md")
    check_models(cfg.plan, cfg.plan.runs)
    stable_worldmodel()
    torch.set_num_threads(1)
    compared = compare(cfg)
    lines = table_lines(compared["results"])
    write_json(out / "swm_plan.json", {"config": to_dict(cfg), **compared, "notes": solver_notes(cfg)})
    save_text(out / "swm_plan.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return out / "swm_plan.json"


def solver_notes(cfg: SwmPlanConfig) -> list[str]:
    """How the swm solvers' budget and update rules differ from our CEM's (pokeworld.plan.control)."""
    p = cfg.plan
    return [(f"all controllers: {p.population} candidates x {p.iterations} iterations, {p.elites} elites, "
            f"replanning every {p.replan} of {p.steps} steps, 16-step programs, initial std {KNOT_SD} around 0"),
            f"swm search space: {cfg.search} (horizon {SEARCH[cfg.search]} x 2)",
            ("ours: std floor +0.05 per iteration, fresh proposals every iteration; swm CEM: no std floor, candidate 0 "
            "is the current mean"),
            (f"swm iCEM: colored noise beta {cfg.icem_noise_beta}, momentum {cfg.icem_alpha}, keeps "
            f"{min(cfg.icem_elite_keep, cfg.plan.elites)} elites, clamps candidates to [-1, 1]"),
            f"swm MPPI: softmax(-cost / {cfg.mppi_temperature}) over the top {cfg.plan.elites}, std never updated",
            "no controller warm-starts from its previous plan (our planner does not)"]
