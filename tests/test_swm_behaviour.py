"""The held random behaviour policy's actions (pokeworld.swm.behaviour.HeldActions, no swm needed): each environment
holds a uniform action inside the bounds for a number of steps inside the hold range, seeded."""

import numpy as np
import pytest

from pokeworld.errors import ConfigError
from pokeworld.swm.behaviour import HeldActions


def run_lengths(column: np.ndarray) -> list[int]:
    change = np.flatnonzero(np.any(column[1:] != column[:-1], axis=-1)) + 1
    edges = np.concatenate([[0], change, [len(column)]])
    return np.diff(edges).tolist()[1:-1]  # the first and last runs may be cut by the sample's ends


def test_actions_are_held_for_the_hold_range_inside_the_bounds():
    low, high = np.array([[-1.0, 0.0]] * 3), np.array([[1.0, 2.0]] * 3)
    pol = HeldActions(low, high, (3, 6), seed=0)
    acts = np.stack([pol.next() for _ in range(400)])  # (steps, envs, dim)
    assert acts.shape == (400, 3, 2)
    assert (acts >= low).all() and (acts <= high).all()
    for env in range(3):
        runs = run_lengths(acts[:, env])
        assert runs and min(runs) >= 3 and max(runs) <= 6, runs
        assert len(set(runs)) > 1  # the hold length itself is random
    assert not np.array_equal(acts[:, 0], acts[:, 1])  # environments hold independent actions


def test_a_hold_of_one_step_is_a_fresh_action_every_step_and_the_seed_reproduces():
    low, high = -np.ones((2, 1)), np.ones((2, 1))
    acts = np.stack([HeldActions(low, high, (1, 1), seed=4).next() for _ in range(1)])
    pol = HeldActions(low, high, (1, 1), seed=4)
    seq = np.stack([pol.next() for _ in range(50)])
    assert (np.abs(np.diff(seq[:, 0, 0])) > 0).all()
    assert np.array_equal(acts[0], seq[0])
    again = HeldActions(low, high, (1, 1), seed=4)
    assert np.array_equal(np.stack([again.next() for _ in range(50)]), seq)


@pytest.mark.parametrize("hold", [(0, 3), (5, 2), (1,), (1, 5000)])
def test_a_bad_hold_is_refused(hold):
    with pytest.raises(ConfigError, match="hold must be two step counts"):
        HeldActions(-np.ones((1, 1)), np.ones((1, 1)), hold, seed=0)


def test_counted_policy_counts_calls_and_returns_the_actions():
    from pokeworld.swm.certify_env import counted

    class Policy:
        def get_action(self, obs, **kwargs):
            return obs * 2

    policy = Policy()
    with counted(policy) as calls:
        assert [policy.get_action(i, extra=1) for i in range(3)] == [0, 2, 4] and calls == [3]
    assert "get_action" not in vars(policy)  # the counting closure (which holds the policy) is gone afterwards
