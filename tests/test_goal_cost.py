"""The planner's goal-latent cost: the goal observation it encodes, a planted latent that ranks like the simulator,
and the cost end to end on a trained tiny run."""

import numpy as np
import pytest
import torch

import pokeworld.plan as plan
from pokeworld.evaluate.ranking import agreement
from pokeworld.sim import PhysicsConfig

PHYS = PhysicsConfig()


def test_goal_observation_draws_the_object_at_the_goal_and_the_finger_behind_it():
    finger, goal = np.array([[0.2, 0.5], [0.5, 0.8]]), np.array([[0.6, 0.5], [0.5, 0.3]])
    obs = plan.goal_observation(PHYS, finger, goal, "behind")
    size = PHYS.image_size
    for i, g in enumerate(goal):
        row, col = int(g[1] * size), int(g[0] * size)
        assert obs["vision"][i, row, col, 0] == int(PHYS.object_intensity + 0.5)  # the object's centre pixel
    # touching the object on the far side from the finger: on the finger-goal line, at contact distance
    reach = PHYS.finger_radius + PHYS.object_radius
    np.testing.assert_allclose(obs["proprio"][:, :2], [[0.6 - reach, 0.5], [0.5, 0.3 + reach]], atol=1e-6)
    np.testing.assert_array_equal(obs["proprio"][:, 2:], 0.0)
    assert obs["touch"].shape == (2, 7) and not obs["touch"].any()
    current = plan.goal_observation(PHYS, finger, goal, "current")
    np.testing.assert_allclose(current["proprio"][:, :2], finger, atol=1e-6)


class PositionLatents(plan.LatentScorer):
    """A scorer whose latent *is* the object's position: its predictions are the simulator's true positions Δ
    steps into each program (or, ``blind``, the start position), its goal latent the goal itself."""

    def __init__(self, truth, cost: str, blind: bool = False):  # no run: the latent space is planted
        self.cost, self.truth, self.blind = cost, truth, blind

    def latents(self, hist, cand):
        path = self.truth(cand)
        E, P = cand.shape[:2]
        return {d: torch.from_numpy(path[:, :, 0 if self.blind else d].reshape(E * P, 2)) for d, _ in plan.COST_TERMS}

    def goal_latents(self, hist, goal):
        return torch.from_numpy(goal)


@pytest.mark.parametrize("cost", ["goal_l2", "goal_l1"])
def test_a_goal_cost_on_true_future_latents_ranks_like_the_simulator(monkeypatch, cost):
    live = {}
    start = plan.start_sim

    def captured(cfg, setup):
        live["sim"], obs = start(cfg, setup)
        return live["sim"], obs

    monkeypatch.setattr(plan, "start_sim", captured)
    cfg = plan.make_config("cpu", episodes=20)
    setup = plan.episode_setup(cfg)
    sim, obs = plan.start_sim(cfg, setup)
    truth = lambda cand: plan.SimulatorScorer(live["sim"]).rollout(cand)  # noqa: E731
    cand = plan.rank_candidates(cfg)
    simulator = plan.cost(truth(cand), setup["goal"])
    seeing = agreement(PositionLatents(truth, cost).score({}, cand, setup["goal"]), simulator, cfg.rank_topk)
    blind = agreement(PositionLatents(truth, cost, blind=True).score({}, cand, setup["goal"]), simulator,
                      cfg.rank_topk)
    # squared Euclidean is a monotone reading of each distance (the two horizons' weights aside); L1 in a planted
    # 2-d latent is the city-block distance, which orders off-axis programs differently
    assert seeing["spearman"] > (0.95 if cost == "goal_l2" else 0.8) and seeing["topk_overlap"] > 0.7
    assert abs(blind["spearman"]) < 0.1 or np.isnan(blind["spearman"])  # a latent that ignores the program cannot


@pytest.mark.slow
def test_plan_with_the_goal_cost_on_a_trained_tiny_run(tmp_path):
    from pokeworld.sim import generate
    from pokeworld.train import single
    from pokeworld.train.config import make_config as train_config

    store = generate.run(generate.make_config("tiny", out=str(tmp_path / "data")))
    run = single.run(train_config("tiny", variant="VFX", data=str(store), out=str(tmp_path / "VFX")))
    cfg = plan.make_config("tiny", cost="goal_l2")
    planned = plan.plan_runs(cfg, {"VFX": [str(run)]})
    s = planned["summary"]["VFX"]
    assert np.isfinite(s["goal_truth_spearman"]) and s["seconds_per_decision"] > 0
    assert np.isfinite(s["miss_displacement"])  # the decoder's diagnostics still read the predicted latents
    assert planned["setup"]["physics"].contact_damping == PHYS.contact_damping  # the run's own arena
    scorer = plan.LatentScorer(str(run), "", cost="goal_l1", physics=planned["setup"]["physics"])
    sim, obs = plan.start_sim(cfg, planned["setup"])
    hist = {"frames": obs["vision"][:, None, ..., 0], "proprio": obs["proprio"][:, None], "touch": obs["touch"][:, None],
            "actions": np.zeros((cfg.episodes, 0, 2), np.float32)}
    cand = plan.rank_candidates(cfg)
    scores = scorer.score(hist, cand, planned["setup"]["goal"])
    assert scores.shape == cand.shape[:2] and np.all(scores >= 0) and np.isfinite(scores).all()
