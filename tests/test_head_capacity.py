"""The head-capacity diagnostic: its samples obey the contact gate, its score separates a perfect from a
phantom predictor, and the fit can come out either way — a head learns the gate from the true state and not
from features that carry no state."""

import numpy as np

from pokeworld.diagnostics.head_capacity import HeadCapacityConfig, fit_and_score, sample, score


def test_samples_move_the_object_only_when_the_program_touches_it():
    x, a, y = sample(400, 0)
    assert x.shape == (400, 8) and a.shape == (400, 16, 2) and y.shape == (400, 2)
    assert np.all(x[:, 2:4] == 0) and np.all(x[:, 6:8] == 0)  # finger and object start at rest
    moved = np.linalg.norm(y, axis=1) > 0
    assert 0.15 < moved.mean() < 0.85  # both outcomes are common, so the gate is what must be learned
    # the gate is geometric: a finger that starts far from the object reaches it less often
    gap = np.linalg.norm(x[:, 0:2] - x[:, 4:6], axis=1)
    assert moved[gap > 0.4].mean() < moved[gap < 0.2].mean()


def test_score_tells_a_perfect_from_a_phantom_predictor():
    _, _, y = sample(400, 1)
    perfect = score(y.copy(), y)
    assert perfect["miss_displacement"] == 0 and perfect["r2"] == 1
    assert perfect["hit_displacement"] == perfect["hit_true_displacement"]
    phantom = y.copy()
    phantom[np.linalg.norm(y, axis=1) == 0] = [0.1, 0.0]  # pushes that never happened
    bad = score(phantom, y)
    assert abs(bad["miss_displacement"] - 0.1) < 1e-9 and bad["r2"] < perfect["r2"]


def test_the_fit_reads_the_gate_from_the_true_state_and_not_from_stateless_features():
    cfg = HeadCapacityConfig(steps=600, hidden=64)
    fit, test = sample(3000, 0), sample(1000, 1)
    true_state = fit_and_score(2, fit, test, cfg)
    assert true_state["r2"] > 0.2 and true_state["miss_displacement"] < true_state["hit_displacement"]
    # planted null: features drawn independently of the start (a state that holds nothing); only the program
    # remains, which cannot tell a hit from a miss
    rng = np.random.default_rng(0)
    noise = [(rng.normal(size=d[0].shape), *d[1:]) for d in (fit, test)]
    blind = fit_and_score(2, noise[0], noise[1], cfg)
    assert blind["r2"] < true_state["r2"] - 0.15
    # the gate: from the state, misses are predicted to move far less than hits; without it, almost as much
    assert true_state["miss_displacement"] < 0.5 * true_state["hit_displacement"]
    assert blind["miss_displacement"] > 0.7 * blind["hit_displacement"]


def test_frozen_states_read_a_trained_run_at_the_start_observation(tmp_path):
    """--run swaps the true state for a trained model's trunk state at the rendered start observation, one row per
    (start, program), conditioned on the program's first action."""
    from pokeworld.data import save
    from pokeworld.diagnostics.head_capacity import frozen_states
    from pokeworld.train import make_config, run, synthetic_dataset

    save(synthetic_dataset(num_episodes=6, steps=24, size=16, seed=0), tmp_path / "syn")
    out = run(make_config("tiny", data=str(tmp_path / "syn"), out=str(tmp_path / "r"), steps=2))
    x, acts, _, obs = sample(6, 0, observe=True)
    h = frozen_states(out, obs, acts)
    assert h.shape == (6, make_config("tiny").width) and np.isfinite(h).all()
    flipped = acts.copy()
    flipped[:, 0] *= -1  # the trunk state depends on the first action (AdaLN conditioning), as in planning
    assert not np.allclose(frozen_states(out, obs, flipped), h)
