"""CEM planning: action programs, the optimiser on a known scorer, and input checks."""

import numpy as np
import pytest

from pokeworld.errors import ConfigError
from pokeworld.plan import control, episode_setup, make_config, programs


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


def test_cem_with_a_true_physics_scorer_pushes_objects_to_goals_random_does_not(monkeypatch):
    """Planted: score candidates by rolling the real simulator forward from the true state. Planning must then
    move objects and reach goals, so the metrics can come out high; the random controller must not."""
    import pokeworld.plan as plan
    from pokeworld.sim import PhysicsConfig, PokeWorldSim

    live = {}

    class Captured(PokeWorldSim):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            live["sim"] = self

    class PhysicsScorer:
        def score(self, hist, cand, goal):
            sim, (n, P) = live["sim"], cand.shape[:2]
            b = PokeWorldSim(n * P, PhysicsConfig(), seed=0)
            b.reset()
            b.state[:], b.params[:] = np.repeat(sim.state, P, 0), np.repeat(sim.params, P, 0)
            for t in range(cand.shape[2]):
                b.step(cand.reshape(n * P, -1, 2)[:, t], render=False)
            return np.linalg.norm(b.state[:, 4:6].reshape(n, P, 2) - goal[:, None], axis=-1)

    monkeypatch.setattr(plan, "PokeWorldSim", Captured)
    cfg = make_config("tiny", episodes=12, steps=32, population=32, elites=4, iterations=2)
    setup = episode_setup(cfg)
    oracle = control(cfg, setup, PhysicsScorer())
    rand = control(cfg, setup, None)
    assert oracle["reach"] >= 0.5 and oracle["median_improvement"] > 0.1 and oracle["object_moved"] > 0.8
    assert rand["reach"] <= 0.25 and oracle["mean_improvement"] > rand["mean_improvement"] + 0.1
