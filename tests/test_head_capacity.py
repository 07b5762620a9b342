"""The head-capacity diagnostic: its samples obey the contact gate, its score separates a perfect from a
blind predictor, and a head fit on the true state learns the gate."""

import numpy as np

from pokeworld.diagnostics.head_capacity import HeadCapacityConfig, fit_head, sample, score


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


def test_a_head_fit_on_the_true_state_learns_the_gate():
    cfg = HeadCapacityConfig(steps=600, hidden=64)
    x, a, y = sample(3000, 0)
    xt, at, yt = sample(1000, 1)
    mu, sd = x.mean(0), x.std(0) + 1e-6
    amu, asd = a.reshape(3000, -1).mean(0), a.reshape(3000, -1).std(0) + 1e-6
    import torch

    head = fit_head(2, (x - mu) / sd, (a.reshape(3000, -1) - amu) / asd, y, cfg)
    with torch.no_grad():
        pred = head(torch.tensor((xt - mu) / sd, dtype=torch.float32),
                    torch.tensor((at.reshape(1000, -1) - amu) / asd, dtype=torch.float32)).numpy() / 10
    s = score(pred, yt)
    assert s["r2"] > 0.2 and s["miss_displacement"] < s["hit_displacement"]
