"""Gymnasium registration, reset options, the checker and vector autoreset semantics."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import pokeworld.sim  # noqa: F401  (registers the ids)
from pokeworld.errors import ConfigError


def test_check_env_passes():
    env = gym.make("pokeworld/PokeWorld-v0")
    check_env(env.unwrapped, skip_render_check=True)


def test_reset_options_set_exact_initial_conditions():
    env = gym.make("pokeworld/PokeWorld-v0")
    obs, info = env.reset(seed=3, options={"params": {"mass": 2.0, "gamma": 1.0, "stiffness": 1000.0},
                                            "finger_pos": [0.2, 0.3], "object_pos": [0.6, 0.7],
                                            "object_vel": [0.5, 0.0]})
    assert info["mass"] == 2.0 and info["gamma"] == 1.0 and info["stiffness"] == 1000.0
    np.testing.assert_allclose(info["object_pos"], [0.6, 0.7])
    np.testing.assert_allclose(obs["proprio"][:2], [0.2, 0.3])
    obs2, r, term, trunc, info2 = env.step(np.zeros(2, np.float32))
    assert info2["object_pos"][0] > 0.6 and r == 0.0 and not term
    with pytest.raises(ConfigError, match="unknown reset options"):
        env.reset(options={"wind": 1.0})


def test_episode_truncates_after_max_steps():
    env = gym.make("pokeworld/PokeWorld-v0", max_steps=5)
    env.reset(seed=0)
    flags = [env.step(env.action_space.sample())[3] for _ in range(5)]
    assert flags == [False] * 4 + [True]


def test_vector_env_next_step_autoreset():
    venv = gym.make_vec("pokeworld/PokeWorld-v0", num_envs=3, vectorization_mode="vector_entry_point",
                        max_steps=4)
    obs, info = venv.reset(seed=0)
    assert obs["vision"].shape == (3, 64, 64)
    masses = info["mass"].copy()
    for _ in range(3):
        _, _, _, trunc, _ = venv.step(np.zeros((3, 2), np.float32))
        assert not trunc.any()
    _, _, _, trunc, _ = venv.step(np.zeros((3, 2), np.float32))
    assert trunc.all()
    obs, rew, _, trunc, info = venv.step(np.zeros((3, 2), np.float32))  # the autoreset step
    assert not trunc.any() and np.all(rew == 0)
    assert not np.allclose(info["mass"], masses)  # new episodes, new hidden parameters
    assert np.all(obs["touch"] == 0)


def test_same_seed_same_episode():
    a = gym.make("pokeworld/PokeWorld-v0")
    b = gym.make("pokeworld/PokeWorld-v0")
    oa, ia = a.reset(seed=11)
    ob, ib = b.reset(seed=11)
    np.testing.assert_array_equal(oa["vision"], ob["vision"])
    assert ia["stiffness"] == ib["stiffness"]
