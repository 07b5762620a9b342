"""Our planning cost as a stable-worldmodel Costable, driven by swm's own CEM / iCEM / MPPI solvers."""

import json

import numpy as np
import pytest
import torch

from pokeworld.errors import ConfigError
from pokeworld.plan import SimulatorScorer, episode_setup, start_sim
from pokeworld.swm import costable
from pokeworld.swm.costable import PlanningCost, info_for, make_config, make_solver, solver_control


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A tiny simulated corpus and an X-JEPA trained on it for a few steps (Δ=1, 4, 16 heads)."""
    from pokeworld.data import save
    from pokeworld.sim.generate import make_config as corpus_config, simulate
    from pokeworld.train import make_config as train_config, run as train

    d = tmp_path_factory.mktemp("swmplan")
    save(simulate(corpus_config("tiny", num_episodes=24, batch_envs=24), progress=False), d / "data")
    train(train_config("tiny", data=str(d / "data"), out=str(d / "run"), steps=4))
    return str(d / "run"), str(d / "data")


class ShuffledScorer:
    """The simulator's costs, each episode's candidates permuted at random: same values, order destroyed."""

    def __init__(self, sim):
        self.truth, self.rng = SimulatorScorer(sim), np.random.default_rng(0)

    def score(self, hist, cand, goal):
        s = self.truth.score(hist, cand, goal)
        return self.rng.permuted(s, axis=1)


def _info(cfg):
    setup = episode_setup(cfg.plan)
    sim, obs = start_sim(cfg.plan, setup)
    hist = {"frames": [obs["vision"][..., 0]], "proprio": [obs["proprio"]], "touch": [obs["touch"]], "actions": []}
    return sim, info_for(hist, setup["goal"], cfg.plan.context), setup


@pytest.mark.parametrize("search", ["knots", "actions"])
@pytest.mark.parametrize("solver", ["cem", "icem", "mppi"])
def test_cost_has_the_shapes_swm_solvers_expect(tiny_run, search, solver):
    run_dir, data = tiny_run
    from pokeworld.plan import LatentScorer

    cfg = make_config("tiny", plan={"episodes": 3, "population": 6, "elites": 2, "rank_topk": 2}, search=search)
    _sim, info, _ = _info(cfg)
    cost = PlanningCost(LatentScorer(run_dir, data), search)
    cand = torch.randn(3, 6, cost.horizon, 2)
    expanded = {k: v[:, None].expand(3, 6, *v.shape[1:]) for k, v in info.items()}
    c = cost.get_cost(expanded, cand)
    assert c.shape == (3, 6) and c.dtype == torch.float32 and torch.isfinite(c).all()
    assert cost.programs(cand).shape == (3, 6, 16, 2) and np.abs(cost.programs(cand)).max() <= 1.0
    out = make_solver(solver, cost, cfg).solve(info)  # swm asserts the (envs, samples) cost shape itself
    assert out["actions"].shape == (3, cost.horizon, 2) and len(out["costs"]) == 3
    with pytest.raises(ConfigError, match="candidates must be"):
        cost.get_cost(expanded, torch.randn(3, 6, cost.horizon + 1, 2))


def test_simulator_cost_makes_swm_cem_push_objects_to_goals_a_shuffled_cost_does_not():
    """Planted: the same solver and budget, one cost ranks candidates truly and one in random order."""
    cfg = make_config("tiny", plan={"episodes": 10, "steps": 48, "population": 32, "elites": 4, "iterations": 2})
    setup = episode_setup(cfg.plan)
    true = solver_control(cfg, setup, "cem", SimulatorScorer)
    shuffled = solver_control(cfg, setup, "cem", ShuffledScorer)
    assert true["mean_improvement"] > shuffled["mean_improvement"] + 0.15
    assert true["reach"] >= 0.4 and shuffled["reach"] <= 0.2
    # all controllers start from identical states
    assert np.allclose(true["distance"][:, 0], shuffled["distance"][:, 0])


def test_comparison_runs_end_to_end_on_a_tiny_trained_run(tiny_run, tmp_path):
    run_dir, data = tiny_run
    cfg = make_config("tiny", plan={"runs": (run_dir,), "data": data, "out": str(tmp_path / "cmp")})
    path = costable.run(cfg)
    rep = json.loads(path.read_text())
    label = costable.run_label(run_dir)
    expected = {"random", "simulator/swm-cem", f"{label}/ours", *(f"{label}/swm-{s}" for s in ("cem", "icem", "mppi"))}
    assert set(rep["results"]) == expected
    for v in rep["results"].values():
        assert 0 <= v["reach"] <= 1 and v["s_per_decision"] > 0
    assert set(rep["rank_test"][label]) >= {"spearman", "topk_overlap"}
    table = (tmp_path / "cmp" / "swm_plan.md").read_text()
    assert all(f"| {k} |" in table for k in expected)


def test_bad_configs_raise():
    with pytest.raises(ConfigError, match="unknown solvers"):
        make_config("tiny", solvers=("cem", "adam"))
    with pytest.raises(ConfigError, match="search"):
        make_config("tiny", search="joints")
    with pytest.raises(ConfigError, match="elites"):
        make_config("tiny", plan={"elites": 99})
    with pytest.raises(ConfigError, match="--plan.runs"):  # the runs are the shared PlanConfig's
        costable.run(make_config("tiny", simulator_ceiling=False, plan={"runs": ()}))


def test_one_solve_hands_the_scorer_one_history_and_every_candidate_as_a_program():
    """Every iteration of a solve scores the same history object (LatentScorer encodes it once per replan, as in
    our CEM) and knots become our two-knot programs."""
    from pokeworld.sim.policy import programs

    class Recording:
        def __init__(self):
            self.hists, self.cands = [], []

        def score(self, hist, cand, goal):
            self.hists.append(hist)
            self.cands.append(cand)
            return np.linalg.norm(cand[:, :, -1] - goal[:, None], axis=-1)  # wants the last action at the goal

    cfg = make_config("tiny", plan={"episodes": 2, "population": 16, "elites": 4, "iterations": 3})
    _, info, setup = _info(cfg)
    rec = Recording()
    cost = PlanningCost(rec, "knots")
    out = make_solver("cem", cost, cfg).solve(info)
    assert len(rec.cands) == 3 and all(h is rec.hists[0] for h in rec.hists)
    assert rec.hists[0]["frames"].shape == (2, 1, *info["frames"].shape[2:]) and rec.hists[0]["actions"].shape == (2, 0, 2)
    assert rec.cands[0].shape == (2, 16, 16, 2)
    # a program runs linearly from its first knot to its second (exact where neither knot was clipped)
    c = rec.cands[0]
    inside = (np.abs(c[:, :, [0, -1]]) < 1).all((-1, -2))
    assert inside.sum() >= 8 and np.abs(c).max() <= 1
    assert np.allclose(c[inside], programs(np.concatenate([c[:, :, 0], c[:, :, -1]], -1))[inside])
    # the solver's mean moves toward the scorer's optimum: the last knot toward the goal (clipped to [-1, 1])
    last = out["actions"][:, -1].numpy()
    assert np.all(np.linalg.norm(last - setup["goal"], axis=1) < np.linalg.norm(setup["goal"], axis=1))
