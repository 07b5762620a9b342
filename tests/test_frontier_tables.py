"""Dose-responses and the attribute matrix (paper App. C): shared runs and the tables' arithmetic."""

import json

import pytest

from pokeworld.evaluate import tables
from pokeworld.experiments import all_specs, attributes, controls, dose_glide, dose_touch, frame_averaged, lambda_sweep, \
    merge, report, tokens
from pokeworld.experiments import make_config as map_config
from pokeworld.experiments.dose_glide import specs as exp_dose_glide
from pokeworld.experiments.dose_touch import specs as exp_dose_touch
from pokeworld.experiments.factorial import specs as exp_factorial


def test_a_dose_level_at_the_operating_point_is_the_factorial_run(tmp_path):
    c = map_config("tiny", out=str(tmp_path), experiments=("factorial", "dose_touch", "dose_glide"),
                   variants=("VF", "VFX"))
    vfx = next(s.name for s in exp_factorial(c) if s.train["variant"] == "VFX")
    touch, glide = exp_dose_touch(c), exp_dose_glide(c)
    # the default weights (touch 4, glide 1) carry no override and no tag: they are the factorial's VFX
    assert touch[0].name == vfx and "touch_contact_weight" not in touch[0].train
    assert glide[0].name == vfx and "glide_loss_weight" not in glide[0].train
    assert [s.train["touch_contact_weight"] for s in touch[1:]] == [1.0, 0.25, 0.0]
    assert len({s.name for s in all_specs(c)}) == 2 + 3 + 3  # VF, VFX, three touch and three glide levels


def _run(spec, probes, glide=None):
    return {"train": spec.train, "corpus": spec.corpus, "probes": {"ridge": probes},
            "prediction": {"glide_test": glide or {}}}


def test_dose_tables_put_ours_beside_the_paper(tmp_path):
    c = map_config("tiny", out=str(tmp_path), experiments=("factorial", "dose_touch", "dose_glide"))
    touch, glide = exp_dose_touch(c), exp_dose_glide(c)
    runs = {}
    for i, s in enumerate(touch):
        runs[s.name] = _run(s, {"contact": {"log_k": 0.4 - 0.1 * i, "log_m": 0.2, "gamma": 0.05, "object_pos": 0.9}})
    for i, s in enumerate(glide[1:], 1):
        runs[s.name] = _run(s, {"contact": {"log_k": 0.3, "gamma": 0.01, "object_vel": 0.6},
                                "glide": {"gamma": 0.1 * i}}, {"model": 0.12, "median_gamma": 0.05})
        d = tmp_path / "runs" / s.name
        d.mkdir(parents=True)
        d.joinpath("metrics.jsonl").write_text(json.dumps({"step": 5, "glide_loss_share": 0.5 + 0.1 * i}) + "\n")
    results = {"runs": runs, "experiments": {"dose_touch": [s.name for s in touch], "dose_glide": [s.name for s in glide]},
               "map_config": {"out": str(tmp_path)}, "certificates": {}}
    t = "\n".join(dose_touch.dose_touch_table(results))
    assert "| 4 (default) | +0.40 / +0.50 | +0.20 / +0.29 | +0.05 / +0.12 | +0.90 |" in t
    assert "| 0 | +0.10 / -0.01 |" in t  # the paper's −0.005 at two digits
    g = "\n".join(dose_glide.dose_glide_table(results))
    assert "| 4 | 60% / 65% | +0.10 / +0.15 | +0.01 | 0.120 / 0.108 | 0.050 / 0.054 | +0.30 / +0.34 | +0.60 / +0.79 |" in g
    assert "| 64 | 80% / 97% | +0.30 / +0.27 |" in g
    assert dose_touch.dose_touch_table({"experiments": {}, "runs": {}}) == []


def test_attribute_matrix_scores_readout_over_the_recurrent_certificate(tmp_path):
    c = map_config("tiny", out=str(tmp_path), experiments=("factorial", "attributes"), variants=("VFX",))
    specs = {s.name: s for s in all_specs(c)}
    runs = {}
    for name, s in specs.items():
        if s.corpus == "standard":
            runs[name] = _run(s, {"contact": {"log_k": 0.45, "gamma": 0.03}})
        elif s.corpus == "gain":
            runs[name] = _run(s, {"contact": {"gain": -0.01}})
        else:  # the bias corpora: the model reads half of each component's recurrent certificate
            runs[name] = _run(s, {"contact": {"bias_x": 0.3, "bias_y": 0.5}})
    est = lambda **kw: {e: {"contact": v} for e, v in kw.items()}  # noqa: E731
    bias = est(linear={"bias_x": 0.2, "bias_y": 0.4}, gru={"bias_x": 0.8, "bias_y": 0.8},
               gru_geom={"bias_x": 0.7, "bias_y": None})
    certs = {"standard": {"estimators": est(linear={"log_k": 0.1, "gamma": 0.0}, gru={"log_k": 0.6, "gamma": 0.3},
                                            gru_geom={"log_k": 0.9, "gamma": 0.2}, drag={"gamma": 0.8})},
             "bias0.5": {"estimators": bias}, "bias1.5": {"estimators": bias}, "bias2.5": {"estimators": bias},
             "gain": {"estimators": est(linear={"gain": -0.02}, gru={"gain": 0.6})}}
    results = {"runs": runs, "certificates": certs,
               "experiments": {"factorial": [n for n, s in specs.items() if s.experiment == "factorial"],
                               "attributes": [n for n, s in specs.items() if s.experiment == "attributes"]}}
    t = "\n".join(attributes.attribute_matrix_table(results))
    assert "| fast × ratio | stiffness k | +0.10 / +0.00 | +0.90 (gru_geom) / +0.87 | +0.45 / 0.50–0.62 | +0.50 / 0.60–0.70 |" in t
    # 2-d bias: mean of components; gru_geom is missing a component, so gru (0.8) is the recurrent certificate
    assert "| slow × linear, b ∈ ±1.5 | force bias | +0.30 / +0.51 | +0.80 (gru) / +0.96 | +0.40 / +0.39 | +0.50 / +0.41 |" in t
    assert "| slow × ratio, gated | drag γ | +0.00 / +0.00 | +0.30 (gru) / +0.89 | +0.03 / +0.13 | +0.10 / +0.15 |" in t
    assert "| slow × ratio, ungated | actuation gain g | -0.02 / -0.01 | +0.60 (gru) / +0.69 | -0.01 / -0.01 |" in t
    assert "physics-informed certificate: +0.80" in t
    assert set(attributes.ATTRIBUTES) == {key for key, *_ in attributes.ATTRIBUTE_CELLS}


def test_controls_table_shows_the_mlp_probe_in_parentheses(tmp_path):
    from pokeworld.experiments.controls import specs as exp_controls

    specs = exp_controls(map_config("tiny", out=str(tmp_path), experiments=("controls",)))
    runs = {s.name: {"train": s.train, "corpus": s.corpus, "prediction": {},
                     "probes": {"ridge": {"contact": {"log_k": 0.3}},
                                **({"mlp": {"contact": {"log_k": 0.4}}} if i == 0 else {})}}
            for i, s in enumerate(specs)}
    results = {"runs": runs, "experiments": {"controls": [s.name for s in specs]}, "certificates": {}}
    t = "\n".join(tables.simple_table(results, "controls", "Controls", controls.control_key, controls.CONTROLS))
    assert "| VFX+sysid | +0.30 (+0.40) / +0.91 |" in t  # sysid run: ridge (MLP) / paper
    assert "| VFX-gnll | +0.30 / +0.49 |" in t  # no MLP fit: ridge alone


def test_controls_rows_name_a_gnll_variance_other_than_the_default():
    """A Gaussian-NLL run trained with a non-default variance (``pokeworld map --gnll-variance free``) gets a row
    that says which, with no paper value beside it; the default's row is the paper's control."""
    from pokeworld.experiments.runs import with_map_training

    gnll = {"objective": "gnll", "variant": "VFX"}
    assert controls.control_key({"train": gnll}) == "VFX-gnll"
    assert controls.control_key({"train": {**gnll, "gnll_heads": "all"}}) == "VFX-gnll (every head)"
    assert controls.control_key({"train": {**gnll, "gnll_variance": "free"}}) == "VFX-gnll (free variance)"
    assert (controls.control_key({"train": {**gnll, "gnll_heads": "all", "gnll_variance": "beta"}})
            == "VFX-gnll (every head, beta variance)")
    c = map_config("tiny", experiments=("controls",), gnll_variance="free")
    rows = {controls.control_key({"train": with_map_training(c, s).train}) for s in controls.specs(c)}
    assert {"VFX-gnll (free variance)", "VFX-gnll (every head, free variance)"} <= rows
