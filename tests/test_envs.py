"""Gymnasium registration, reset options, the checker and vector autoreset semantics."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import pokeworld.sim
from pokeworld.errors import ConfigError, InputError


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


def test_episode_truncates_after_max_episode_steps():
    env = gym.make("pokeworld/PokeWorld-v0", max_episode_steps=5)
    env.reset(seed=0)
    flags = [env.step(env.action_space.sample())[3] for _ in range(5)]
    assert flags == [False] * 4 + [True]
    env = gym.make("pokeworld/PokeWorld-v0", max_episode_steps=80)  # longer than the corpus: no earlier truncation
    env.reset(seed=0)
    assert [env.step(env.action_space.sample())[3] for _ in range(80)] == [False] * 79 + [True]


def test_the_registered_spec_says_where_episodes_truncate():
    """Gymnasium's convention: the registration names the episode length, so spec.max_episode_steps is 64."""
    env = gym.make("pokeworld/PokeWorld-v0")
    assert env.spec.max_episode_steps == pokeworld.sim.envs.EPISODE_STEPS == 64
    env.reset(seed=0)
    flags = [env.step(env.action_space.sample())[3] for _ in range(64)]
    assert flags == [False] * 63 + [True]
    venv = gym.make_vec("pokeworld/PokeWorld-v0", num_envs=2, vectorization_mode="vector_entry_point")
    assert venv.spec.max_episode_steps == 64 and venv.unwrapped.max_episode_steps == 64
    direct = pokeworld.sim.PokeWorldEnv()  # constructed directly, without Gymnasium's wrapper: truncates itself
    direct.reset(seed=0)
    assert [direct.step(direct.action_space.sample())[3] for _ in range(64)][-2:] == [False, True]
    with pytest.raises(ConfigError, match="max_episode_steps must be a positive integer"):
        pokeworld.sim.PokeWorldEnv(max_episode_steps=0)


def test_vector_env_next_step_autoreset():
    venv = gym.make_vec("pokeworld/PokeWorld-v0", num_envs=3, vectorization_mode="vector_entry_point",
                        max_episode_steps=4)
    obs, info = venv.reset(seed=0)
    assert obs["vision"].shape == (3, 64, 64, 1)
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


def test_import_pokeworld_alone_registers_without_loading_numba_or_torch():
    import subprocess
    import sys

    code = ("import sys, gymnasium, pokeworld\n"
            "assert not {'numba', 'torch', 'pokeworld.sim'} & set(sys.modules), sorted(sys.modules)\n"
            "env = gymnasium.make(pokeworld.ENV_ID)\n"
            "obs, info = env.reset(seed=0)\n"
            "assert obs['vision'].shape == (64, 64, 1)\n"
            "venv = gymnasium.make_vec(pokeworld.ENV_ID, num_envs=2, vectorization_mode='vector_entry_point')\n"
            "assert venv.reset(seed=0)[0]['vision'].shape == (2, 64, 64, 1)\n"
            "import pokeworld.sim\n"
            "pokeworld.register_envs(); pokeworld.sim.register()  # idempotent\n"
            "print('ok')\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"


def test_initial_velocities_are_bounded_by_the_observation_space():
    env = gym.make("pokeworld/PokeWorld-v0")
    vmax = float(env.observation_space["proprio"].high[2])
    assert vmax == float(-env.observation_space["proprio"].low[3]) == pokeworld.sim.PokeWorldSim.MAX_VEL
    for key in ("object_vel", "finger_vel"):
        for bad in ([1e9, 0.0], [0.0, -1.01 * vmax]):
            with pytest.raises(ConfigError, match=rf"{key} must lie in \[-50.000, 50.000\] per component"):
                env.reset(seed=0, options={key: bad})
        obs, info = env.reset(seed=0, options={key: [vmax, -vmax]})  # the bound itself is allowed
        np.testing.assert_allclose(info[key], [vmax, -vmax])
    obs, _ = env.reset(seed=0, options={"finger_vel": [vmax, -vmax]})
    assert env.observation_space.contains(obs)
    venv = pokeworld.sim.PokeWorldVectorEnv(num_envs=2)
    with pytest.raises(ConfigError, match="object_vel"):
        venv.reset(seed=0, options={"object_vel": [[0.0, 0.0], [60.0, 0.0]]})


def test_reset_accepts_the_papers_short_parameter_names():
    env = gym.make("pokeworld/PokeWorld-v0")
    _, info = env.reset(seed=0, options={"params": {"m": 2.0, "gamma": 1.5, "k": 1200.0}})
    assert (info["mass"], info["gamma"], info["stiffness"]) == (2.0, 1.5, 1200.0)
    with pytest.raises(ConfigError, match="given twice"):
        env.reset(options={"params": {"m": 2.0, "mass": 3.0}})
    with pytest.raises(ConfigError, match="'m' must be > 0|'mass' must be > 0"):
        env.reset(options={"params": {"m": -1.0}})
    with pytest.raises(ConfigError, match="unknown parameter 'q'"):
        env.reset(options={"params": {"q": 1.0}})


def test_actions_outside_the_box_are_clipped_to_it():
    """The action space is Box(-1, 1): [5, 0] acts exactly as [1, 0] (the force saturates), in the single and the
    vector env; a non-finite action is refused with one clear error."""
    def next_state(action):
        env = gym.make("pokeworld/PokeWorld-v0")
        env.reset(seed=5, options={"finger_pos": [0.3, 0.5], "object_pos": [0.7, 0.5]})
        for _ in range(3):
            obs, _, _, _, info = env.step(np.asarray(action, np.float32))
        return obs, info

    (o5, i5), (o1, i1), (_, i0) = next_state([5.0, 0.0]), next_state([1.0, 0.0]), next_state([0.0, 0.0])
    np.testing.assert_array_equal(o5["proprio"], o1["proprio"])
    np.testing.assert_array_equal(i5["finger_pos"], i1["finger_pos"])
    assert i1["finger_pos"][0] > i0["finger_pos"][0]  # and the push does move the finger
    venv = gym.make_vec("pokeworld/PokeWorld-v0", num_envs=2, vectorization_mode="vector_entry_point")
    venv.reset(seed=0, options={"finger_pos": [0.3, 0.5], "object_pos": [0.7, 0.5]})
    _, _, _, _, info = venv.step(np.array([[-9.0, 0.0], [-1.0, 0.0]], np.float32))
    np.testing.assert_array_equal(info["finger_pos"][0], info["finger_pos"][1])
    env = gym.make("pokeworld/PokeWorld-v0")
    env.reset(seed=0)
    with pytest.raises(InputError, match="finite") as refused:  # an action is input, not configuration
        env.step(np.array([np.nan, 0.0], np.float32))
    assert isinstance(refused.value, ValueError) and not isinstance(refused.value, ConfigError)


def test_env_class_docstring_documents_touch_truncation_reward_and_clipping():
    doc = " ".join(pokeworld.sim.envs.PokeWorldEnv.__doc__.split())
    for words in ("contact flag", "peak force", "64", "Reward: always 0", "clipped", "[5, 0]"):
        assert words in doc, words
