"""Forecast dependence (slope ratio S) on planted forecasters: the simulator itself scores S = 1, a forecaster that
ignores the parameter S ≈ 0, one that reverses it S < 0; the replay it measures against is the recorded simulator;
the partial slope removes a confounder; bad input is refused with one clear error."""

import numpy as np
import pytest
import torch

from pokeworld.errors import ConfigError, DataError, ModelError
from pokeworld.evaluate.dependence import (
    DependenceConfig,
    Forecast,
    forecast_dependence,
    fresh_corpus,
    partial_slope,
)
from pokeworld.evaluate.forecasters import SimulatorForecaster, XJEPAForecaster
from pokeworld.sim.replay import params_of, physics_of, replay, state_at

CFG = DependenceConfig(bootstrap=100)


@pytest.fixture(scope="module")
def corpus():
    """1,500 unrendered episodes of the default generator: enough glide and push windows for tight intervals (the
    reference forecasters read the privileged state, not the frames)."""
    from pokeworld.sim.generate import make_config, simulate

    return simulate(make_config("tiny", num_episodes=1500, batch_envs=500), progress=False, render=False)


@pytest.fixture(scope="module")
def scored(corpus):
    """S of the simulator and of its planted corruptions, per parameter."""
    physics, eps = physics_of(corpus.manifest), np.arange(corpus.num_episodes)
    return {(p, plant): forecast_dependence(SimulatorForecaster(physics, p, plant), corpus, eps, CFG, (p,))[p]
            for p in ("gamma", "mass", "stiffness") for plant in ("true", "ignore", "reverse")}


@pytest.mark.parametrize("param", ["gamma", "mass", "stiffness"])
def test_the_simulator_itself_scores_one_with_no_forecast_error(scored, param):
    r = scored[param, "true"]
    assert r["windows"] >= 100 and r["slope_simulator"] != 0
    assert r["S"] == pytest.approx(1.0, abs=1e-9)
    assert r["S_interval"] == pytest.approx([1.0, 1.0], abs=1e-9)
    assert r["forecast_error"] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("param", ["gamma", "mass", "stiffness"])
def test_a_forecast_that_ignores_the_parameter_scores_about_zero(scored, param):
    """About, not exactly: the windows are chosen on the true future (no wall in a glide), which ties the context
    state to the true parameter, so even a forecast blind to it keeps a small slope through that state."""
    r = scored[param, "ignore"]
    lo, hi = r["S_interval"]
    assert abs(r["S"]) < 0.3 and -0.8 < lo < hi < 0.8  # mass is the noisiest response (≈ ±0.6 on 1,500 episodes)
    assert r["forecast_error"] > 0  # the forecast is wrong, and S alone would not say how much


@pytest.mark.parametrize("param", ["gamma", "mass", "stiffness"])
def test_a_forecast_with_the_parameter_reversed_scores_below_zero(scored, param):
    r = scored[param, "reverse"]
    assert r["S"] < -0.3 and r["S_interval"][1] < 0


def test_the_expected_drag_slope_is_negative_and_mass_and_stiffness_slopes_have_their_physical_signs(scored):
    """Glide displacement per unit speed falls with γ; a push moves a heavier object less; a stiffer contact
    peaks higher."""
    assert scored["gamma", "true"]["slope_simulator"] < 0
    assert scored["mass", "true"]["slope_simulator"] < 0
    assert scored["stiffness", "true"]["slope_simulator"] > 0


def test_replay_reproduces_the_recorded_episodes(corpus):
    """The truth S is measured against: the simulator continued from a recorded state under the recorded actions
    retraces the recording (touch noise does not act on the dynamics)."""
    eps, t, H = np.arange(50), np.full(50, 10), 16
    out = replay(physics_of(corpus.manifest), state_at(corpus.labels, eps, t), params_of(corpus.params, eps),
                 corpus.actions[eps, 10:10 + H])
    np.testing.assert_allclose(out["object_pos"], corpus.labels["object_pos"][eps, 11:11 + H], atol=1e-5)
    np.testing.assert_array_equal(out["touch"][..., 6] > 0.5, corpus.labels["contact"][eps, 11:11 + H] > 0)


def test_the_partial_slope_removes_a_confounder_that_the_raw_slope_keeps(rng):
    c = rng.normal(size=2000)
    x = c + 0.5 * rng.normal(size=2000)
    y = 2.0 * x + 3.0 * c + 0.01 * rng.normal(size=2000)
    assert partial_slope(y, x, c[:, None]) == pytest.approx(2.0, abs=0.01)
    assert np.polyfit(x, y, 1)[0] > 4.0  # the confounded slope


def test_a_fresh_corpus_repeats_the_store_s_generator_with_other_episodes(tiny_dataset):
    fresh = fresh_corpus(tiny_dataset, 20, 7)
    assert fresh.manifest["config"]["physics"] == tiny_dataset.manifest["config"]["physics"]
    assert fresh.num_episodes == 20 and not np.array_equal(fresh.params["gamma"], tiny_dataset.params["gamma"][:20])


class BrokenForecaster:
    def forecast(self, query):
        n = len(query.state)
        return Forecast(start=np.zeros((n, 2)), end=np.full((n, 3), np.nan), touch_peak=None)


def test_bad_input_is_refused_with_one_clear_error(corpus):
    eps = np.arange(corpus.num_episodes)
    with pytest.raises(ModelError, match="end must be a finite"):
        forecast_dependence(BrokenForecaster(), corpus, eps, CFG, ("gamma",))
    with pytest.raises(ConfigError, match="no forecast response"):
        forecast_dependence(BrokenForecaster(), corpus, eps, CFG, ("friction",))
    with pytest.raises(ConfigError, match="plant must be"):
        SimulatorForecaster(physics_of(corpus.manifest), "gamma", "halve")
    no_labels = corpus.subset(np.arange(10))
    no_labels.labels.pop("finger_vel")
    with pytest.raises(DataError, match="lacks"):
        forecast_dependence(BrokenForecaster(), no_labels, np.arange(10), CFG)


def test_a_forecaster_without_touch_leaves_stiffness_unmeasured_and_says_so(corpus):
    class NoTouch(SimulatorForecaster):
        def forecast(self, query):
            f = super().forecast(query)
            return Forecast(f.start, f.end, None)

    r = forecast_dependence(NoTouch(physics_of(corpus.manifest)), corpus, np.arange(300), CFG, ("stiffness",))
    assert "S" not in r["stiffness"] and "no touch" in r["stiffness"]["note"]


def test_an_xjepa_forecast_is_its_decoded_direct_head_and_rollout(tiny_dataset):
    """The X-JEPA adapter answers every query with finite decoded positions and K touch peaks, and its answer does
    not depend on how the queries are batched."""
    from pokeworld.evaluate.dependence import glide_windows, query
    from pokeworld.models.xjepa import XJEPA

    ds = tiny_dataset
    torch.manual_seed(0)
    m = XJEPA(variant="VFX", proprio_dim=4, touch_dim=7, action_dim=2, image_size=16, channels=(4, 8, 8, 8),
              latent_dim=8, width=16, depth=1, heads=2, vec_dim=8, horizons=(1, 16)).eval()
    cfg = DependenceConfig(min_glide_speed=0.0)
    w = glide_windows(ds, np.arange(ds.num_episodes), cfg)
    w = w.select(np.arange(len(w)) < 40)
    q = query(ds, w, w.gather(ds.actions, cfg.context - 1, cfg.horizon), cfg)
    forecaster = XJEPAForecaster(m, ds, batch=256)
    one = forecaster.forecast(q)
    forecaster.batch = 7
    many = forecaster.forecast(q)
    assert one.end.shape == (len(w), 2) and one.touch_peak.shape == (len(w), cfg.touch_steps)
    assert np.isfinite(one.end).all() and np.isfinite(one.touch_peak).all()
    np.testing.assert_allclose(one.end, many.end, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(one.touch_peak, many.touch_peak, rtol=1e-4, atol=1e-5)


def test_the_protocol_reports_a_user_forecaster_s_slope_ratio_beside_its_probes(tmp_path):
    """``certify_model(..., forecaster=...)``: S per parameter beside the readout in protocol.json and .md; the
    simulator as the user's forecaster scores 1."""
    from pokeworld import certify as C
    from pokeworld.protocol import certify_model
    from pokeworld.sim.generate import make_config, simulate

    ds = simulate(make_config("tiny", num_episodes=120, batch_envs=120, split_fractions=(0.2, 0.4, 0.4),
                              physics={"image_size": 16}), progress=False)
    est = {"gru": {"contact": {"log_m": 0.8, "gamma": 0.7, "log_k": 0.6}}}
    cert = C.certificate_table(est, ("log_m", "gamma", "log_k"))
    certs = {"estimators": est, "certificate": cert, "gate": C.gate(cert, est), "counts": {}}

    def proprio_state(frames, proprio, touch, actions):
        return proprio

    res = certify_model(proprio_state, ds, tmp_path, certificates=certs, preset="tiny", kinds=("contact",),
                        forecaster=SimulatorForecaster(physics_of(ds.manifest), "gamma"), dependence_episodes=600)
    assert res["dependence"]["gamma"]["S"] == pytest.approx(1.0, abs=1e-9)
    report = (tmp_path / "protocol.md").read_text()
    assert "## Forecast dependence (slope ratio S)" in report and "+1.00 [+1.00, +1.00]" in report


def test_a_record_measured_with_other_settings_is_not_merged(tmp_path):
    import json

    from pokeworld.evaluate.dependence_runs import make_config, merged_records

    earlier = tmp_path / "earlier.json"
    earlier.write_text(json.dumps({"config": {"store": "", "eval_episodes": 2400, "eval_seed": 1000,
                                              "bootstrap": 1000, "max_windows": 3000, "seed": 0}, "runs": []}))
    assert merged_records(make_config("cpu", merge=(str(earlier),))) != []
    with pytest.raises(ConfigError, match="other settings"):
        merged_records(make_config("cpu", merge=(str(earlier),), eval_episodes=1200))


def test_a_committed_record_merges_by_its_store_s_content_hash_not_its_path(tmp_path):
    """A record whose store is a placeholder (as committed) joins a measurement on a store of the same content
    hash, and is refused for a store of another content."""
    import json

    from pokeworld.data import read_manifest, save
    from pokeworld.evaluate.dependence_runs import make_config, merged_records
    from pokeworld.sim.generate import make_config as generate_config, simulate

    store = tmp_path / "store"
    save(simulate(generate_config("tiny", num_episodes=8, batch_envs=8), progress=False), store)
    sha = read_manifest(store)["content_sha256"]
    settings = {"eval_episodes": 2400, "eval_seed": 1000, "bootstrap": 1000, "max_windows": 3000, "seed": 0}
    earlier = tmp_path / "earlier.json"

    def record(**config):
        earlier.write_text(json.dumps({"config": {"store": "<machine>/data/standard", **settings, **config},
                                       "runs": []}))
        return make_config("cpu", store=str(store), merge=(str(earlier),))

    assert merged_records(record(store_sha256=sha)) != []
    with pytest.raises(ConfigError, match="other settings"):
        merged_records(record(store_sha256="b" * 64))
    with pytest.raises(ConfigError, match="other settings"):  # without a hash the path as given decides, as before
        merged_records(record())


@pytest.mark.slow
def test_the_command_says_its_plan_first_and_writes_a_record_per_run(tmp_path, capsys):
    """`pokeworld forecast-dependence` end to end on a tiny trained run: a plan line before the long first stage,
    a line per run, and a record whose row names the run, its variant and the planted rows beside it."""
    import json

    from pokeworld.cli import main as cli

    store, run, out = tmp_path / "store", tmp_path / "run", tmp_path / "fd"
    assert cli(["generate", "--preset", "tiny", "--out", str(store)]) == 0
    assert cli(["train", "--preset", "tiny", "--variant", "VFX", "--data", str(store), "--out", str(run)]) == 0
    capsys.readouterr()
    assert cli(["forecast-dependence", str(out), "--preset", "tiny", "--runs", str(run), "--eval-episodes", "60",
                "--bootstrap", "20"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("[forecast-dependence]")]
    assert "plan: 1 store(s) x 60 fresh episodes" in lines[0] and "1 run(s)" in lines[0]
    assert lines[1].endswith("planted rows done") and lines[2].startswith(f"[forecast-dependence] {run}:")
    rec = json.loads((out / "forecast_dependence.json").read_text())
    assert [r["variant"] for r in rec["runs"]] == ["VFX"] and list(rec["planted"]) == [str(store)]
    assert rec["environment"] == "reference PokeWorld (the store's manifest)"  # no --environment: the store's
    assert "Environment: reference PokeWorld (the store's manifest)." in (out / "forecast_dependence.md").read_text()
    assert (out / "forecast_dependence.md").is_file() and lines[-1].startswith("[forecast-dependence] wrote ")


def test_the_figure_draws_an_s_outside_its_own_bootstrap_interval(tmp_path):
    """A ratio's percentile interval need not contain its full-sample value (few windows, a slope near zero): the
    figure draws it as it is instead of failing on negative error bars."""
    from pokeworld.evaluate.dependence_runs import figure

    row = {"variant": "VFX", "seed": 0, "steps": 10,
           "dependence": {"gamma": {"S": 8.6, "S_interval": [-5.7, 0.7]}, "mass": {"S": 0.5, "S_interval": [0.2, 0.9]},
                          "stiffness": {"note": "no touch forecast"}},
           "readout": {p: {"contact": 0.1} for p in ("gamma", "mass", "stiffness")}}
    path = figure({"environment": "planted", "runs": [row]}, tmp_path / "fd.png")
    assert path.stat().st_size > 0


def test_the_figure_s_legend_hides_no_point_and_a_bare_panel_warns_nothing(tmp_path, monkeypatch):
    """One legend below the three panels (the γ panel's own covered its points), and none asked of a panel with
    nothing labelled (matplotlib warned "No artists with labels found")."""
    import warnings

    from pokeworld import io
    from pokeworld.evaluate.dependence_runs import figure

    drawn = []
    monkeypatch.setattr(io, "save_figure", lambda fig, out, stem, dpi: drawn.append(fig) or [])
    row = {"variant": "VFX", "seed": 0, "steps": 10,
           "dependence": {"gamma": {"S": 1.04, "S_interval": [0.9, 1.2]}, "mass": {"S": 0.5, "S_interval": [0.2, 0.9]},
                          "stiffness": {"note": "no touch forecast"}},
           "readout": {"gamma": {"contact": 0.9}, "mass": {"contact": 0.1}, "stiffness": {"contact": None}}}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figure({"environment": "planted", "runs": [row]}, tmp_path / "fd.png")
    fig = drawn[0]
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    (legend,) = fig.legends
    box = legend.get_window_extent(renderer)
    assert not any(box.overlaps(ax.get_window_extent(renderer)) for ax in fig.axes)
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels == ["S [95 % episode bootstrap]", "revision's VFX S (paper, not ours)", "readout R² (contact)"]
    parameters = ("gamma", "mass", "stiffness")
    bare = {**row, "variant": "V", "dependence": {p: {"note": "not measured"} for p in parameters},
            "readout": {p: {"contact": None} for p in parameters}}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figure({"environment": "planted", "runs": [bare]}, tmp_path / "bare.png")
    assert drawn[1].legends == []
    import matplotlib.pyplot as plt

    for fig in drawn:  # save_figure, which closes them, was replaced: no figure outlives the test
        plt.close(fig)


def test_the_record_names_the_environment_its_store_was_made_in(tiny_dataset):
    from pokeworld.evaluate.dependence_runs import stores_environment

    assert stores_environment({"data/s": tiny_dataset}, []) == "reference PokeWorld (the store's manifest)"
    old = tiny_dataset.subset(np.arange(4))
    old.manifest = {**tiny_dataset.manifest, "config": {k: v for k, v in tiny_dataset.manifest["config"].items()
                                                        if k != "environment"}}
    # a store made before environments existed names none: it is the calibrated one
    assert stores_environment({"data/s": tiny_dataset, "data/old": old}, []) == \
        "reference PokeWorld (data/s); calibrated PokeWorld (data/old)"
    assert stores_environment({}, [{"environment": "calibrated PokeWorld"}]) == "calibrated PokeWorld"
    assert stores_environment({}, [{"environment": "a"}, {"environment": "b"}]) == ""
