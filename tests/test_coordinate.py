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
