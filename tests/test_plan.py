"""CEM planning: action programs, the optimiser on a known scorer, and input checks."""

import numpy as np
import pytest

from pokeworld.errors import ConfigError
from pokeworld.plan import SimulatorScorer, control, episode_setup, make_config, programs


def test_programs_interpolate_between_knots():
    a = programs(np.array([[-1.0, 0.0, 1.0, 0.5]]))
    assert a.shape == (1, 16, 2)
    np.testing.assert_allclose(a[0, 0], [-1, 0])
    np.testing.assert_allclose(a[0, -1], [1, 0.5])
    assert np.all(np.diff(a[0, :, 0]) > 0)


class PushRight:
    """A scorer that prefers programs whose actions point to +x: CEM must find them."""

    def score(self, hist, cand, goal):
        return -cand[..., 0].mean(-1)


def test_cem_optimises_a_known_scorer():
    cfg = make_config("tiny", episodes=4, steps=12, population=32, elites=4, iterations=3)
    setup = episode_setup(cfg)
    x0 = setup["finger_pos"][:, 0]
    res_cem = control(cfg, setup, PushRight())
    res_rand = control(cfg, setup, None)
    assert res_cem["distance"].shape == (4, 13)
    moved = res_cem["finger_final"][:, 0] - x0
    assert np.all((moved > 0.3) | (res_cem["finger_final"][:, 0] > 0.9))  # driven to the right wall
    assert np.mean(res_rand["finger_final"][:, 0] - x0) < np.mean(moved) - 0.2


def test_bad_plan_configs_raise():
    with pytest.raises(ConfigError):
        make_config("tiny", elites=100, population=8)
    with pytest.raises(ConfigError):
        make_config("tiny", replan=0)


def _oracle(monkeypatch):
    """A planted scorer that knows the truth: the planning environment's own simulator (captured as it starts)."""
    import pokeworld.plan as plan

    live = {}
    start = plan.start_sim

    def captured(cfg, setup):
        live["sim"], obs = start(cfg, setup)
        return live["sim"], obs

    class Oracle:
        @staticmethod
        def live():
            return live["sim"]

        def score(self, hist, cand, goal):
            return SimulatorScorer(live["sim"]).score(hist, cand, goal)

    monkeypatch.setattr(plan, "start_sim", captured)
    return Oracle()


def test_cem_with_a_true_physics_scorer_pushes_objects_to_goals_random_does_not(monkeypatch):
    """Planted: score candidates by rolling the real simulator forward from the true state. Planning must then
    move objects and reach goals 0.55 away within the 48 steps, so the metrics can come out high; random must not."""
    # the reference environment's finger is capped at 3 units/s: its search needs 64 × 3 candidates to reach
    cfg = make_config("tiny", episodes=12, steps=48, population=64, elites=4, iterations=3)
    setup = episode_setup(cfg)
    oracle = control(cfg, setup, _oracle(monkeypatch))
    rand = control(cfg, setup, None)
    assert oracle["reach"] >= 0.5 and oracle["median_improvement"] > 0.2 and oracle["object_moved"] > 0.8
    assert rand["reach"] <= 0.25 and oracle["mean_improvement"] > rand["mean_improvement"] + 0.2


def test_planner_and_behaviour_policy_share_one_program_family():
    from pokeworld.sim import policy

    assert programs is policy.programs  # one definition: the two cannot drift apart
    knots = np.random.default_rng(0).normal(0, 2.0, (5, 4))
    a = programs(knots)
    assert np.abs(a).max() <= 1.0 and np.any(np.abs(a) == 1.0)  # clipped to the action box


@pytest.mark.parametrize("distance", [0.55, 0.3, 0.65])
def test_starts_put_the_goal_exactly_goal_distance_from_the_object(distance):
    cfg = make_config("cpu", episodes=200, goal_distance=distance)
    s = episode_setup(cfg)
    np.testing.assert_allclose(np.linalg.norm(s["goal"] - s["object_pos"], axis=1), distance, atol=1e-12)
    assert s["goal"].min() >= 0.15 and s["goal"].max() <= 0.85  # not clipped back toward the object
    assert s["object_pos"].min() >= 0.25 and s["object_pos"].max() <= 0.75
    assert np.linalg.norm(s["finger_pos"] - s["object_pos"], axis=1).min() >= 0.25
    ang = np.arctan2(*(s["goal"] - s["object_pos"]).T[::-1])
    assert np.histogram(ang, 4, (-np.pi, np.pi))[0].min() > 20  # every direction occurs
    assert make_config("cpu").goal_distance == 0.55  # the paper's example episode


def test_bad_goal_distance_and_rank_k_raise():
    with pytest.raises(ConfigError, match="goal_distance"):
        make_config("tiny", goal_distance=0.0)
    with pytest.raises(ConfigError, match="goal_distance"):
        make_config("tiny", goal_distance=0.7)
    with pytest.raises(ConfigError, match="rank_topk"):
        make_config("tiny", rank_topk=9, population=8)


class Planted:
    """A model scorer derived from the truth: the simulator's own costs, transformed per start."""

    def __init__(self, transform):
        self.transform = transform

    def score(self, hist, cand, goal):
        return self.transform(self.truth.score(hist, cand, goal))


def _rank(monkeypatch, transform, **overrides):
    from pokeworld.plan import rank_test

    cfg = make_config("cpu", **overrides)
    oracle = _oracle(monkeypatch)  # rank_test starts the environment through start_sim too
    scorer = Planted(transform)
    scorer.truth = oracle
    return rank_test(cfg, episode_setup(cfg), scorer)


def test_rank_test_reads_one_for_the_simulators_own_scores(monkeypatch):
    r = _rank(monkeypatch, lambda s: s)
    assert r["spearman"] == pytest.approx(1.0) and r["topk_overlap"] == 1.0
    assert r["candidates"] == 64 and r["k"] == 8 and r["topk_chance"] == 8 / 64
    assert r["starts"] >= 45 and r["topk_starts"] >= 15  # of 50: misses tie, so fewer starts decide a top 8
    assert 0.02 < r["moved"] < 0.9


def test_rank_test_reads_zero_for_shuffled_and_minus_one_for_negated_scores(monkeypatch):
    rng = np.random.default_rng(0)
    shuffled = _rank(monkeypatch, lambda s: rng.permuted(s, axis=1))
    assert abs(shuffled["spearman"]) < 0.1
    assert abs(shuffled["topk_overlap"] - 8 / 64) < 0.06
    negated = _rank(monkeypatch, lambda s: -s)
    assert negated["spearman"] == pytest.approx(-1.0) and negated["topk_overlap"] == 0.0


def test_rank_test_reads_the_counterfactual_fit_of_a_scorer_that_predicts_positions(monkeypatch):
    """The simulator's own end positions fit perfectly; positions that ignore the program (the object left where
    it starts) have no spread: the two readings a model's low rank ρ is told apart by."""
    import pokeworld.plan as plan

    oracle = _oracle(monkeypatch)

    class Positions:
        def __init__(self, blind):
            self.blind = blind

        def positions(self, hist, cand):
            path = oracle.rollout(cand)
            return {d: (path[:, :, 0] if self.blind else path[:, :, d])
                    for d, _ in plan.COST_TERMS}

        def score(self, hist, cand, goal):
            pos = self.positions(hist, cand)
            return sum(w * np.linalg.norm(pos[d] - goal[:, None], axis=-1) for d, w in plan.COST_TERMS)

    oracle.rollout = lambda cand: SimulatorScorer(oracle.live()).rollout(cand)
    cfg = make_config("cpu", episodes=20)
    truth = plan.rank_test(cfg, episode_setup(cfg), Positions(blind=False))
    assert truth["spread_ratio"] == pytest.approx(1.0) and truth["within_r2"] == pytest.approx(1.0)
    assert truth["spearman"] == pytest.approx(1.0)
    blind = plan.rank_test(cfg, episode_setup(cfg), Positions(blind=True))
    assert blind["spread_ratio"] == pytest.approx(0.0, abs=1e-9) and blind["within_r2"] == pytest.approx(0.0)
    assert truth["miss_displacement"] == 0.0 and blind["hit_displacement"] == 0.0

    class FingerDecoder(Positions):  # a decoder that reads the finger where the object should be
        def decode(self, obs):
            return obs["proprio"][:, :2]

    leaky = plan.rank_test(cfg, episode_setup(cfg), FingerDecoder(blind=False))
    assert leaky["within_r2"] == pytest.approx(1.0)  # the heads are perfect ...
    assert leaky["decoded_truth_miss_displacement"] > 0.1  # ... the decoder moves objects that stayed put
    assert leaky["decoded_truth_within_r2"] < 0.5


def test_rank_test_scores_every_controller_on_the_same_candidates_from_the_same_starts(monkeypatch):
    seen = []

    class Recorder:
        def score(self, hist, cand, goal):
            seen.append((hist["proprio"].copy(), cand.copy(), goal.copy()))
            assert hist["frames"].shape[1] == 1 and hist["actions"].shape[1] == 0  # the planner's first replan
            return cand[..., 0].mean(-1)

    from pokeworld.plan import rank_test

    cfg = make_config("tiny", episodes=6, population=16, rank_topk=4)
    setup = episode_setup(cfg)
    rank_test(cfg, setup, Recorder())
    rank_test(cfg, setup, Recorder())
    for a, b in zip(*seen):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(seen[0][0][:, 0, :2], setup["finger_pos"], atol=1e-6)
    assert seen[0][1].shape == (6, 16, 16, 2)


def test_plan_runs_reports_the_rank_test_per_model_and_in_the_table(monkeypatch, tmp_path):
    import pokeworld.plan as plan

    oracle = _oracle(monkeypatch)

    class FakeLatent:  # stands in for a trained run: "good" scores like the simulator, "bad" the reverse
        def __init__(self, run_dir, data, *args):
            self.sign = 1.0 if "good" in run_dir else -1.0

        def score(self, hist, cand, goal):
            return self.sign * oracle.score(hist, cand, goal)

    monkeypatch.setattr(plan, "LatentScorer", FakeLatent)
    monkeypatch.setattr(plan, "planning_physics", lambda runs, data: plan.PhysicsConfig())  # no store behind them
    cfg = make_config("tiny", episodes=8, steps=4, population=16, rank_topk=4)
    out = plan.plan_runs(cfg, {"good": [str(tmp_path / "good")], "bad": [str(tmp_path / "bad")]})
    s = out["summary"]
    assert s["random"]["spearman"] is None
    assert s["good"]["spearman"] == pytest.approx(1.0) and s["good"]["topk_overlap"] == 1.0
    assert s["bad"]["spearman"] == pytest.approx(-1.0)
    assert s["good"]["per_run"]["good"]["spearman"] == pytest.approx(1.0)
    table = "\n".join(plan.table_lines(s))
    assert "| +1.00 | 1.00 (0.25) |" in table and "| -1.00 | 0.00 (0.25) |" in table and "| — | — |" in table


def test_the_simulator_controller_is_the_planners_ceiling(tmp_path):
    """--simulator-controller plans with the true simulator's scores (perfect ranking): on the same starts it must
    reach goals that random does not, and `pokeworld plan` runs with it alone."""
    from pokeworld import plan

    cfg = make_config("tiny", episodes=12, steps=48, population=64, elites=4, iterations=3, simulator_controller=True,
                      runs=(), out=str(tmp_path / "p"))
    summary = plan.plan_runs(cfg, {})["summary"]
    assert set(summary) == {"random", "simulator"}
    assert summary["simulator"]["reach"] >= 0.5 and summary["random"]["reach"] <= 0.2
    assert summary["simulator"]["spearman"] is None  # no rank test of the simulator against itself
    plan.run(cfg)
    assert "| simulator |" in (tmp_path / "p" / "plan.md").read_text()
    with pytest.raises(ConfigError, match="--runs"):
        plan.run(make_config("tiny", out=str(tmp_path / "q"), runs=()))


def test_planning_table_rows_follow_the_papers_order_whatever_the_summary_order():
    """A summary read back from a record written with sorted keys is alphabetical; the table still lists random,
    V, VX_t, VX_p, VFX (the paper's order), then any other controller."""
    from pokeworld import plan

    row = {"reach": 0.0, "median_improvement": 0.0, "mean_improvement": 0.0, "object_moved": 0.0}
    summary = {k: dict(row) for k in sorted(["VFX", "VX_p", "VX_t", "V", "random", "simulator"])}
    labels = [line.split(" | ")[0].lstrip("| ") for line in plan.table_lines(summary)[2:]]
    assert labels == ["random", "V", "VX_t", "VX_p", "VFX", "simulator"]


@pytest.mark.parametrize("context", [1, 5])
def test_cached_direct_latents_equal_the_whole_trunk_per_candidate(context, monkeypatch):
    """The planner's direct-head predictions (context keys/values computed once per episode) equal running the
    trunk over every candidate's whole context, and do not depend on how candidates are batched."""
    import torch

    import pokeworld.plan as plan
    from pokeworld.models.xjepa import XJEPA

    torch.manual_seed(0)
    m = XJEPA("VFX", image_size=16, channels=(4, 8, 8, 8), latent_dim=8, width=16, depth=2, heads=2).eval()
    rng = np.random.default_rng(0)
    E, P = 3, 5
    z = torch.randn(E, context, 8)
    past = rng.uniform(-1, 1, (E, context - 1, 2)).astype(np.float32)
    cand = programs(rng.normal(0, 0.8, (E, P, 4)))
    with torch.no_grad():
        zc = z[:, None].expand(E, P, context, 8).reshape(E * P, context, 8)
        acts = np.concatenate([np.repeat(past[:, None], P, 1).reshape(E * P, context - 1, 2),
                               cand[:, :, 0].reshape(E * P, 1, 2)], 1).astype(np.float32)
        h = m.trunk(zc, acts)[:, -1:]
        whole = {d: m.predict(h, cand.reshape(E * P, 16, 2).astype(np.float32), d)[:, 0] for d in (4, 16)}
    cached = plan.direct_latents(m, z, past, cand)
    monkeypatch.setattr(plan, "CANDIDATE_BATCH", 2 * P)  # two episodes per batch
    batched = plan.direct_latents(m, z, past, cand)
    for d in (4, 16):
        torch.testing.assert_close(cached[d], whole[d], rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(batched[d], whole[d], rtol=1e-5, atol=1e-5)
    assert not torch.allclose(cached[16][:P], cached[16][P:2 * P])  # episodes differ: a real comparison


def test_approach_term_ranks_the_push_side_when_nothing_moves():
    """With the object still (every candidate ties on the object term), the approach term prefers the finger on
    the far side of the object from the goal; without it the costs tie. A finger at the push point costs nothing
    beyond the object's distance."""
    from pokeworld.plan import decoded_cost

    goal = np.array([[0.8, 0.5]])
    obj = np.full((1, 3, 2), [0.5, 0.5])
    fingers = np.array([[[0.32, 0.5], [0.68, 0.5], [0.5, 0.8]]])  # behind, in front, beside
    objects = {4: obj, 16: obj}
    plain = decoded_cost(objects, goal)
    np.testing.assert_allclose(plain, 1.5 * 0.3)
    shaped = decoded_cost(objects, goal, {4: fingers, 16: fingers}, weight=0.4, offset=0.18)
    assert np.argmin(shaped[0]) == 0 and shaped[0, 1] > shaped[0, 2] > shaped[0, 0]
    np.testing.assert_allclose(shaped[0, 0], 1.5 * 0.3, atol=1e-6)
    import torch

    as_t = lambda d: {k: torch.as_tensor(v) for k, v in d.items()}  # noqa: E731
    np.testing.assert_allclose(decoded_cost(as_t(objects), torch.as_tensor(goal), as_t({4: fingers, 16: fingers}),
                                            0.4, 0.18).numpy(), shaped)


def test_uniform_goals_keep_their_distance_and_box():
    cfg = make_config("tiny", episodes=200, goals="uniform", goal_distance=0.25)
    s = episode_setup(cfg)
    d = np.linalg.norm(s["goal"] - s["object_pos"], axis=1)
    assert d.min() >= 0.25 and np.all((s["goal"] >= 0.2) & (s["goal"] <= 0.8))
    assert np.linalg.norm(s["object_pos"] - s["finger_pos"], axis=1).min() >= 0.25
    assert 0.3 < np.median(d) < 0.45  # the released planner's draws: a median start distance near 0.36
    with pytest.raises(ConfigError, match="goals must be one of"):
        make_config("tiny", goals="ring")
    with pytest.raises(ConfigError, match="approach_weight applies to the decoder cost"):
        make_config("tiny", cost="goal_l2", approach_weight=0.4)


def test_settle_steps_fill_the_context_before_control():
    cfg = make_config("tiny", episodes=2, steps=4, settle=3, population=4, elites=2)
    seen = []

    class Recorder:
        def score(self, hist, cand, goal):
            seen.append(hist["frames"].shape[1])
            return -cand[..., 0].mean(-1)

    res = control(cfg, episode_setup(cfg), Recorder())
    assert seen[0] == 4  # the start and three settle frames
    assert res["distance"].shape == (2, 5)  # the metrics count control steps only


def test_runs_are_labelled_by_variant_unless_two_share_one(tmp_path):
    """A lone run of each variant stands under its variant (the paper's row beside it); two runs of one variant
    keep their folder names, so neither hides the other."""
    import json

    from pokeworld.plan import controller_labels

    def run(name, variant):
        d = tmp_path / name
        d.mkdir()
        (d / "config.json").write_text(json.dumps({"variant": variant, "data": "store"}))
        (d / "DONE").write_text("finished\n")
        return str(d)

    v, vfx, vfx2 = run("a", "V"), run("b", "VFX"), run("c", "VFX")
    assert controller_labels([v, vfx]) == {"V": [v], "VFX": [vfx]}
    assert controller_labels([v, vfx, vfx2]) == {"a": [v], "b": [vfx], "c": [vfx2]}


def test_episode_metrics_on_planted_distances():
    """Reach counts an episode whose object ever enters the radius; the closest-approach improvement (the paper's)
    and the final one differ exactly when the object overshoots."""
    from pokeworld.plan import episode_metrics

    dist = np.array([[0.5, 0.3, 0.05, 0.4],    # passes through the goal, ends away: reach, closest 0.45, final 0.1
                     [0.4, 0.4, 0.4, 0.4],     # never moves
                     [0.3, 0.2, 0.15, 0.15]])  # approaches, never enters 0.1
    path = np.zeros((3, 4, 2))
    path[0, 1:, 0] = 0.2
    path[2, 1:, 0] = 0.1
    m = episode_metrics(dist, path, goal_radius=0.1)
    assert m["reach"] == pytest.approx(1 / 3)
    assert m["median_closest_improvement"] == pytest.approx(0.15)  # of 0.45, 0.0, 0.15
    assert m["median_improvement"] == pytest.approx(0.1)  # of 0.1, 0.0, 0.15
    assert m["object_moved"] == pytest.approx(2 / 3)
