"""swm/PokeWorld-v0: registration, swm's variation space driving the hidden physics, World collection, swm policies."""

import gymnasium as gym
import numpy as np
import pytest
import stable_worldmodel as swm

from pokeworld.errors import ConfigError
from pokeworld.io import OWNED_RECORD
from pokeworld.sim.core import PARAM_NAMES, ParamRanges
from pokeworld.swm.env import (
    DEFAULT_VARIATIONS,
    ENV_ID,
    GOAL_RADIUS,
    CollectConfig,
    make_world,
    register,
    run as collect,
)

register()


def fixed(**values):
    """Reset options resampling nothing and setting ``values`` (swm's variation_values)."""
    return {"variation": [], "variation_values": values}


PUSH_START = {"finger.start_position": np.array([0.25, 0.5]), "object.start_position": np.array([0.65, 0.5]),
              "goal.position": np.array([0.5, 0.8]), "physics.gamma": np.array(1.0),
              "physics.stiffness": np.array(2000.0)}


def test_register_is_idempotent_and_env_has_swm_shapes():
    assert register() == ENV_ID and register() == ENV_ID
    assert ENV_ID in gym.registry and ENV_ID in swm.envs.WORLDS
    env = gym.make(ENV_ID)
    obs, info = env.reset(seed=0)
    assert set(obs) == {"proprio", "touch"} and obs["proprio"].shape == (4,) and obs["touch"].shape == (7,)
    assert env.observation_space.contains(obs)
    assert set(PARAM_NAMES) <= set(info) and info["goal"].shape == (64, 64, 3) and info["goal"].dtype == np.uint8
    assert info["goal_pos"].shape == (2,) and info["goal_radius"] == GOAL_RADIUS
    pixels = env.render()
    assert pixels.shape == (64, 64, 3) and pixels.dtype == np.uint8
    assert (pixels[..., 0] == pixels[..., 1]).all() and pixels.max() > 0  # gray PokeWorld frame in RGB
    assert not np.array_equal(pixels, info["goal"])  # the goal image moves the object to the goal
    obs, reward, _terminated, _truncated, info = env.step(np.array([0.5, -0.5], np.float32))
    assert reward == pytest.approx(-info["distance"])
    assert info["distance"] == pytest.approx(np.linalg.norm(info["object_pos"] - info["goal_pos"]), abs=1e-6)
    names = env.unwrapped.variation_space.names()
    assert {"physics.mass", "physics.stiffness", "physics.gamma", "physics.bias", "physics.gain"} <= set(names)
    assert set(DEFAULT_VARIATIONS) <= set(names)


def test_default_reset_samples_hidden_physics_within_pokeworld_ranges():
    env = gym.make(ENV_ID).unwrapped
    r = ParamRanges()
    draws = np.array([[env.reset(seed=s)[1][k] for k in ("mass", "gamma", "stiffness")] for s in range(24)])
    for col, (lo, hi) in zip(draws.T, (r.mass, r.gamma, r.stiffness)):
        assert (col >= lo).all() and (col <= hi).all() and np.unique(col).size == 24
    # stiffness is log-uniform like ParamRanges: its median sits near the geometric, not the arithmetic, mean
    assert abs(np.log(np.median(draws[:, 2])) - np.log(np.sqrt(r.stiffness[0] * r.stiffness[1]))) < 0.5
    assert env.reset(seed=3)[1]["mass"] == env.reset(seed=3)[1]["mass"]


def push(env, mass, launch=5, steps=11):
    """Launch the finger at the object for ``launch`` steps, then let it coast: (object displacement, peak speed)."""
    _, info = env.reset(seed=0, options=fixed(**PUSH_START, **{"physics.mass": np.array(mass)}))
    assert info["mass"] == pytest.approx(mass)
    start, peak = info["object_pos"].copy(), 0.0
    for t in range(steps):
        _, _, _, _, info = env.step(np.array([1.0 if t < launch else 0.0, 0.0], np.float32))
        peak = max(peak, float(np.linalg.norm(info["object_vel"])))
    return info["object_pos"] - start, peak, info


def test_variation_values_set_the_hidden_mass_and_the_object_responds_as_physics_says():
    env = gym.make(ENV_ID).unwrapped
    light, light_peak, info_light = push(env, 0.5)
    heavy, heavy_peak, info_heavy = push(env, 3.0)
    assert info_light["stiffness"] == info_heavy["stiffness"] == pytest.approx(2000.0)
    # the same finger strike sends the light object faster and further along the strike, neither sideways
    assert heavy[0] > 0.02 and light[0] > 2 * heavy[0] and light_peak > 2 * heavy_peak
    assert abs(light[1]) < 0.01 and abs(heavy[1]) < 0.01


def test_out_of_range_variation_and_unknown_options_are_config_errors():
    env = gym.make(ENV_ID).unwrapped
    with pytest.raises(ConfigError, match="variation"):
        env.reset(options=fixed(**{"physics.mass": np.array(50.0)}))
    with pytest.raises(ConfigError, match="unknown reset options"):
        env.reset(options={"params": {"mass": 1.0}})


def test_success_is_the_object_within_the_goal_radius():
    env = gym.make(ENV_ID).unwrapped
    values = dict(PUSH_START, **{"goal.radius": np.array(0.15), "goal.position": np.array([0.84, 0.5]),
                                 "physics.mass": np.array(0.5)})
    _, info = env.reset(seed=1, options=fixed(**values))
    assert info["distance"] > 0.15
    for t in range(30):
        _, reward, terminated, _, info = env.step(np.array([1.0, 0.0], np.float32))
        assert terminated == (info["distance"] < 0.15)
        if terminated:
            break
    assert terminated and t > 0 and reward == pytest.approx(-info["distance"])


def test_world_collects_episodes_into_its_default_lance_format(tmp_path):
    world = make_world(num_envs=2, steps=6, image_size=64)
    world.set_policy(swm.policy.RandomPolicy(seed=0))
    world.collect(tmp_path / "pw.lance", episodes=3, seed=0, progress=False)  # format='lance' is World's default
    world.close()
    ds = swm.data.load_dataset(tmp_path / "pw.lance")
    assert type(ds).__name__ == "LanceDataset" and len(ds.lengths) == 3
    assert {"pixels", "proprio", "touch", "action", "goal", "goal_pos", *PARAM_NAMES} <= set(ds.column_names)
    ends = np.asarray(ds.get_col_data("terminated"))[:, 0] + np.asarray(ds.get_col_data("truncated"))[:, 0]
    masses = np.asarray(ds.get_col_data("mass"))[:, 0]
    for length, offset in zip(ds.lengths, ds.offsets):
        rows = slice(offset, offset + length)
        assert length <= 6 and ends[rows][-1] > 0 and (ends[rows][:-1] == 0).all()  # ends only at its last row
        assert np.unique(masses[rows]).size == 1  # the hidden mass is fixed within an episode...
    assert np.unique(masses).size == 3  # ...and resampled on every reset
    ep = ds.load_episode(0)
    assert tuple(ep["pixels"].shape) == (int(ds.lengths[0]), 3, 64, 64) and tuple(ep["touch"].shape[1:]) == (7,)


def test_swm_random_policy_evaluates_on_pokeworld():
    world = make_world(num_envs=2, steps=5, image_size=32)
    world.set_policy(swm.policy.RandomPolicy(seed=0))
    results = world.evaluate(episodes=4, seed=0)
    world.close()
    assert 0.0 <= results["success_rate"] <= 100.0 and len(results["episode_successes"]) == 4
    assert world.infos["pixels"].shape == (2, 1, 32, 32, 3) and world.infos["touch"].shape == (2, 1, 7)


def test_collect_config_checks_and_writes_atomically(tmp_path):
    with pytest.raises(ConfigError, match="format"):
        CollectConfig(format="parquet")
    with pytest.raises(ConfigError, match=r"\.h5"):
        CollectConfig(out=str(tmp_path / "x.lance"), format="hdf5")
    out = collect(CollectConfig(out=str(tmp_path / "pw.h5"), episodes=2, steps=3, num_envs=1))
    # no staging file left behind; the output is recorded as pokeworld's, so a later --overwrite may replace it
    assert sorted(p.name for p in tmp_path.iterdir()) == [OWNED_RECORD, "pw.h5"]
    assert list(swm.data.load_dataset(out).lengths) == [3, 3]
    with pytest.raises(ConfigError, match="exists"):
        collect(CollectConfig(out=str(out), episodes=1, steps=3, num_envs=1))


def test_bias_and_gain_variations_reach_the_finger():
    env = gym.make(ENV_ID, ranges=ParamRanges(bias=1.0, gain=(0.5, 1.5))).unwrapped

    def finger_drift(bias, gain, action):
        values = dict(PUSH_START, **{"physics.bias": np.array(bias), "physics.gain": np.array(gain)})
        _, info = env.reset(seed=0, options=fixed(**values))
        assert (info["bias_x"], info["bias_y"], info["gain"]) == pytest.approx((*bias, gain))
        start = info["finger_pos"].copy()
        for _ in range(3):
            _, _, _, _, info = env.step(np.array(action, np.float32))
        return info["finger_pos"] - start

    assert np.allclose(finger_drift([0.0, 0.0], 1.0, [0.0, 0.0]), 0.0)
    drift = finger_drift([0.0, 0.8], 1.0, [0.0, 0.0])  # no command, yet the biased finger moves along +y
    assert drift[1] > 0.005 and abs(drift[0]) < 1e-6
    weak, strong = finger_drift([0.0, 0.0], 0.5, [1.0, 0.0]), finger_drift([0.0, 0.0], 1.5, [1.0, 0.0])
    assert strong[0] > 2 * weak[0] > 0  # the gain scales the commanded force
