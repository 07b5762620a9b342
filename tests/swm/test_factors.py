"""Labelled swm datasets into the protocol: factors read from ``variation.*`` columns, and the factor gate certifies a
factor planted in the dynamics while refusing a pure-noise one."""

import h5py
import numpy as np
import pytest

from pokeworld.errors import DataError
from pokeworld.swm.factor_gate import FactorCertifyConfig, certify_factors
from pokeworld.swm.factors import FactorDataConfig, read_factors

DT = 0.1


def planted_rollouts(episodes: int, steps: int, seed: int = 0) -> dict[str, np.ndarray]:
    """A damped point pushed by random forces: ``damping`` shapes the velocity trace, ``noise`` shapes nothing."""
    rng = np.random.default_rng(seed)
    damping = rng.uniform(0.5, 4.0, episodes)
    noise = rng.uniform(0.0, 1.0, episodes)
    actions = rng.uniform(-1, 1, (episodes, steps + 1, 1))
    x, v = np.zeros((episodes, steps + 1)), np.zeros((episodes, steps + 1))
    x[:, 0], v[:, 0] = rng.uniform(-1, 1, episodes), rng.uniform(-1, 1, episodes)
    for t in range(steps):
        v[:, t + 1] = v[:, t] * (1 - damping * DT) + actions[:, t, 0] * DT * 4
        x[:, t + 1] = x[:, t] + v[:, t + 1] * DT
    actions[:, -1] = np.nan  # World.collect's last row holds no transition of the episode
    pixels = np.zeros((episodes, steps + 1, 8, 8, 3), np.uint8)
    col = np.clip(((x + 2) / 4 * 8).astype(int), 0, 7)
    pixels[np.arange(episodes)[:, None], np.arange(steps + 1)[None], 4, col] = 255
    return {"pixels": pixels, "observation": np.stack([x, v], -1).astype(np.float32), "action": actions,
            "variation.drag.damping": np.repeat(damping[:, None, None], steps + 1, 1).astype(np.float32),
            "variation.noise.level": np.repeat(noise[:, None, None], steps + 1, 1).astype(np.float32),
            "variation.floor.color": np.full((episodes, steps + 1, 3), 0.5, np.float32),
            "step_idx": np.tile(np.arange(steps + 1), (episodes, 1))}


def write_swm_h5(path, episodes: dict[str, np.ndarray]) -> str:
    """swm's HDF5 layout: one column per key with episodes back to back, plus ep_len / ep_offset."""
    E, T1 = episodes["pixels"].shape[:2]
    with h5py.File(path, "w") as f:
        for k, v in episodes.items():
            f.create_dataset(k, data=v.reshape(E * T1, *v.shape[2:]))
        f.create_dataset("ep_len", data=np.full(E, T1, np.int32))
        f.create_dataset("ep_offset", data=np.arange(E, dtype=np.int64) * T1)
    return str(path)


@pytest.fixture(scope="module")
def planted(tmp_path_factory):
    return write_swm_h5(tmp_path_factory.mktemp("factors") / "planted.h5", planted_rollouts(160, 24))


def test_factors_become_per_episode_targets_and_the_rest_is_listed(planted):
    ds = read_factors(planted, FactorDataConfig())
    assert sorted(ds.params) == ["drag.damping", "noise.level"] == ds.manifest["probe_params"]
    assert "not varied" in ds.manifest["dropped_factors"]["floor.color[0]"]
    assert ds.manifest["observations"] == ["observation"]
    assert ds.frames.shape == (160, 25, 8, 8) and ds.proprio.shape == (160, 25, 2)
    assert ds.actions.shape == (160, 24, 1) and ds.touch.shape == (160, 25, 0)
    raw = h5py.File(planted, "r")["variation.drag.damping"][()].reshape(160, 25)
    np.testing.assert_array_equal(ds.params["drag.damping"], raw[:, 0])


def test_a_factor_changing_within_episodes_is_dropped_with_its_reason(tmp_path):
    eps = planted_rollouts(12, 8)
    eps["variation.noise.level"][:, 3:] += 0.5
    ds = read_factors(write_swm_h5(tmp_path / "drift.h5", eps), FactorDataConfig())
    assert "noise.level" not in ds.params
    assert "within episodes" in ds.manifest["dropped_factors"]["noise.level"]


def test_unknown_factor_and_missing_observations_are_refused(planted):
    with pytest.raises(DataError, match=r"no factor 'spinner.density'.*drag.damping"):
        read_factors(planted, FactorDataConfig(factors=("spinner.density",)))
    with pytest.raises(DataError, match="observation columns \\['qpos'\\]"):
        read_factors(planted, FactorDataConfig(observations=("qpos",)))


def test_links_are_refused_as_by_swm_import(tmp_path, planted):
    path = tmp_path / "linked.h5"
    with h5py.File(path, "w") as f:
        f["pixels"] = h5py.ExternalLink(planted, "pixels")
        f["ep_len"], f["ep_offset"] = np.array([1]), np.array([0])
    with pytest.raises(DataError, match="link"):
        read_factors(path, FactorDataConfig())


def test_planted_factor_is_certified_and_noise_is_not(planted):
    # the certificate split is what matters here: 64 probe-fit / 64 probe-test episodes, every window (the GRU
    # oracle needs some hundred optimiser steps; the linear floor cannot read a damping, which multiplies velocity)
    ds = read_factors(planted, FactorDataConfig(split_fractions=(0.2, 0.4, 0.4)))
    cfg = FactorCertifyConfig(window=8, stride=1, gru_hidden=32, gru_layers=1, epochs=150, patience=20)
    certs = certify_factors(ds, ("drag.damping", "noise.level"), cfg)
    gate = certs["gate"]
    assert gate["drag.damping"]["passed"] and gate["drag.damping"]["paper_rule_passed"], gate["drag.damping"]
    assert not gate["noise.level"]["passed"] and not gate["noise.level"]["paper_rule_passed"], gate["noise.level"]
    assert certs["estimators"]["gru"]["all"]["noise.level"] < 0.2
    assert certs["estimators"]["linear"]["all"]["drag.damping"] < 0.4  # the floor alone would not certify it
    assert set(certs["estimators"]) == {"gru", "linear", "sysid"}
    # the local-dynamics fit reads the damping off each window's velocity decay, and nothing of the noise level
    assert certs["estimators"]["sysid"]["all"]["drag.damping"] > 0.95
    assert certs["estimators"]["sysid"]["all"]["noise.level"] < 0.2
    assert gate["drag.damping"]["rule"] == "best estimator R^2 on all windows >= 0.4"
