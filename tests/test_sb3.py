"""stable-baselines3 as a client of the Gymnasium env (the RL library most users try first): its environment
checker passes without a warning, and PPO with a CNN feature extractor on the Dict observation trains.

These need the ``test`` extra (stable-baselines3 is a test-only dependency)."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

sb3 = pytest.importorskip("stable_baselines3")
from stable_baselines3.common.env_checker import check_env  # noqa: E402
from stable_baselines3.common.preprocessing import is_image_space  # noqa: E402

from pokeworld.sim import PhysicsConfig  # noqa: E402
from pokeworld.sim.envs import PokeWorldEnv, vision_frames  # noqa: E402


def test_check_env_passes_without_a_warning():
    env = PokeWorldEnv()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning check_env raises fails the test
        check_env(env, warn=True)
    assert is_image_space(env.observation_space["vision"])  # what CnnPolicy / NatureCNN needs


def test_a_flat_frame_would_not_be_an_image_to_sb3():
    """The control: the old channel-less (H, W) layout is not an image space for sb3 (it would be flattened)."""
    assert not is_image_space(gym.spaces.Box(0, 255, (64, 64), np.uint8))


def test_ppo_with_a_cnn_extractor_trains_on_the_dict_observation(tmp_path):
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.torch_layers import NatureCNN

    env = PokeWorldEnv(physics=PhysicsConfig(image_size=36), max_episode_steps=16)  # NatureCNN's smallest input
    model = PPO("MultiInputPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu", verbose=0)
    extractor = model.policy.features_extractor.extractors["vision"]
    assert isinstance(extractor, NatureCNN)  # the frame goes through convolutions, not a flatten
    before = [p.detach().clone() for p in extractor.parameters()]
    model.set_logger(configure(str(tmp_path), []))  # sb3's default logger makes an SB3-<time> folder in /tmp
    model.learn(total_timesteps=256)
    assert model.num_timesteps >= 256
    assert any(not np.allclose(a.numpy(), b.detach().numpy()) for a, b in zip(before, extractor.parameters()))
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(action.astype(np.float32))


def test_vision_frames_drops_the_channel_and_refuses_other_layouts():
    obs, _ = PokeWorldEnv().reset(seed=0)
    assert obs["vision"].shape == (64, 64, 1) and vision_frames(obs["vision"]).shape == (64, 64)
    from pokeworld.errors import InputError

    with pytest.raises(InputError, match="one channel last"):
        vision_frames(np.zeros((64, 64), np.uint8))
