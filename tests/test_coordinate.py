"""The coordinate test end to end on the tiny preset: derived flow corpus, log-speed certificate, VFX beside VFX."""

import json

import numpy as np
import pytest

from pokeworld.data import load
from pokeworld import experiments as experiment


@pytest.mark.slow
def test_tiny_coordinate_experiment(tmp_path):
    out = tmp_path / "map"
    c = experiment.make_config("tiny", out=str(out), workers=1, experiments=("coordinate",))
    experiment.run(c)
    std, flow = load(out / "data" / "standard"), load(out / "data" / "flow")
    assert flow.proprio.shape[-1] == 7 and flow.manifest["proprio_channels"][-1] == "log_speed"
    np.testing.assert_array_equal(flow.proprio[..., :4], std.proprio)  # only channels are added
    np.testing.assert_array_equal(flow.frames, std.frames)
    speed = np.linalg.norm(flow.proprio[..., 4:6], axis=-1)
    np.testing.assert_allclose(flow.proprio[..., 6], np.log(np.maximum(speed, 0.01)), rtol=1e-5, atol=1e-5)
    assert (out / "data" / "flow" / "flow_sensor.pt").exists()
    res = json.loads((out / "results.json").read_text())
    assert set(res["runs"]) == {"VFX-h1-4-16-lam0.02-standard-s0", "VFX-h1-4-16-lam0.02-flow-s0"}
    assert res["runs"]["VFX-h1-4-16-lam0.02-flow-s0"]["probes"]["ridge"]["contact"]
    cert = res["certificates"]["flow"]
    # the tiny corpus has too few pure-glide windows for the glide certificate; contact windows still run
    assert "contact" in cert["estimators"]["linear_logspeed"] and "linear" in cert["estimators"]
    assert cert["gate"] == res["certificates"]["standard"]["gate"]  # same episodes: the standard gate
    assert "velocity_r2" in cert["flow_sensor"]
    md = (out / "results.md").read_text()
    assert "## The coordinate test" in md and "/ +0.52 |" in md


def _flow_store(E: int = 3, T1: int = 5) -> "Dataset":
    """A flow corpus as the coordinate test writes one: four source channels, the sensor's velocity and log speed."""
    from pokeworld.data import Dataset
    from pokeworld.evaluate.coordinate import CHANNELS

    rng = np.random.default_rng(0)
    proprio = rng.normal(size=(E, T1, 7)).astype(np.float32)
    return Dataset(frames=np.zeros((E, T1, 4, 4), np.uint8), proprio=proprio, touch=np.zeros((E, T1, 7), np.float32),
                   actions=np.zeros((E, T1 - 1, 2), np.float32), labels={}, params={"gamma": np.ones(E, np.float32)},
                   split=np.zeros(E, np.int8),
                   manifest={"kind": "pokeworld", "corpus": "flow", "proprio_channels": list(CHANNELS),
                             "flow": {"source_sha256": "abc", "sensor": {"velocity_r2": 0.9}}})


def test_the_velocity_only_corpus_drops_the_log_speed_and_nothing_else(tmp_path, capsys):
    from pokeworld.data import save
    from pokeworld.errors import ConfigError, DataError
    from pokeworld.evaluate import coordinate

    flow_dir = save(_flow_store(), tmp_path / "flow")
    out = coordinate.build_flow_velocity_corpus(flow_dir, tmp_path / "flow_velocity")
    flow, vel = load(flow_dir), load(out)
    assert vel.manifest["proprio_channels"] == list(coordinate.VELOCITY_CHANNELS)
    assert "log_speed" not in vel.manifest["proprio_channels"] and vel.manifest["corpus"] == "flow_velocity"
    np.testing.assert_array_equal(vel.proprio, flow.proprio[..., :6])  # the same sensor's velocity, same episodes
    assert vel.manifest["flow"]["flow_sha256"] == flow.manifest["content_sha256"]
    assert coordinate.build_flow_velocity_corpus(flow_dir, out) == out and "skipping" in capsys.readouterr().out
    other = _flow_store()
    other.proprio = other.proprio + 1.0  # another flow corpus: its velocity corpus is not this one
    other_dir = save(other, tmp_path / "other_flow")
    with pytest.raises(ConfigError, match="holds a different store"):
        coordinate.build_flow_velocity_corpus(other_dir, out)
    plain = _flow_store()
    plain.manifest["proprio_channels"] = plain.manifest["proprio_channels"][:4]
    with pytest.raises(DataError, match="derives from a flow corpus"):
        coordinate.velocity_only(plain)
