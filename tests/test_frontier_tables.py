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


def test_token_factorial_shares_the_controls_token_run_and_reads_beside_the_global_factorial(tmp_path):
    from pokeworld.experiments.controls import specs as exp_controls
    from pokeworld.experiments.tokens import specs as exp_tokens

    c = map_config("tiny", out=str(tmp_path), experiments=("factorial", "controls", "tokens"), variants=("VF", "VFX"))
    tok = exp_tokens(c)
    assert [s.train["variant"] for s in tok] == ["VF", "VFX"] and all(s.train["tokens"] for s in tok)
    assert tok[1].name in {s.name for s in exp_controls(c)}  # trained once
    assert len({s.name for s in all_specs(c)}) == 2 + 6 + 1  # factorial, controls, the VF token run
    runs = {s.name: _run(s, {"contact": {"log_k": 0.1 * i, "object_pos": 0.9}}) for i, s in enumerate(tok, 5)}
    runs.update({s.name: _run(s, {"contact": {"log_k": 0.2}}) for s in exp_factorial(c)})
    results = {"runs": runs, "certificates": {},
               "experiments": {"tokens": [s.name for s in tok], "factorial": [s.name for s in exp_factorial(c)]}}
    t = "\n".join(tokens.token_factorial_table(results))
    assert "| VFX | +0.60 / +0.62 | +0.20 | — | +0.90 / +0.98 | — |" in t
    assert "| VF | +0.50 / — | +0.20 |" in t
    # MLP probes, where fit, in parentheses beside ridge in both log k columns
    runs[tok[0].name]["probes"]["mlp"] = {"contact": {"log_k": 0.45}}
    for s in exp_factorial(c):
        runs[s.name]["probes"]["mlp"] = {"contact": {"log_k": 0.25}}
    t = "\n".join(tokens.token_factorial_table(results))
    assert "| VF | +0.50 (+0.45) / — | +0.20 (+0.25) |" in t and "| VFX | +0.60 / +0.62 | +0.20 (+0.25) |" in t


def test_lambda_sweep_trains_every_seed_and_reports_their_mean(tmp_path):
    from pokeworld.experiments.lambda_sweep import specs as exp_lambda

    c = map_config("tiny", out=str(tmp_path), experiments=("factorial", "lambda"), seeds=(0, 1), variants=("VFX",),
                   lambdas=(0.3, 0.02))
    specs = exp_lambda(c)
    assert sorted((s.train["sigreg_weight"], s.train["seed"]) for s in specs) == [(0.02, 0), (0.02, 1), (0.3, 0), (0.3, 1)]
    # λ = 0.02 is the operating point: its runs are the factorial's VFX, not retrained
    assert {s.name for s in specs if s.train["sigreg_weight"] == 0.02} <= {s.name for s in exp_factorial(c)}
    runs = {}
    for s in specs:
        k = {0.3: 0.1, 0.02: 0.4}[s.train["sigreg_weight"]] + 0.1 * s.train["seed"]
        runs[s.name] = {**_run(s, {"contact": {"log_k": k, "log_m": 0.2, "object_vel": 0.5}}),
                        "prediction": {"direct16": 0.1}}
    t = "\n".join(lambda_sweep.lambda_table({"runs": runs, "experiments": {"lambda": [s.name for s in specs]},
                                       "certificates": {}}))
    assert "| 0.3 | 2 | +0.15 / +0.12 | +0.20 / +0.12 | +0.50 / +0.54 | 0.100 / 0.128 |" in t
    assert "| 0.02 | 2 | +0.45 / +0.50 |" in t
    assert t.index("| 0.3 |") < t.index("| 0.02 |")  # heaviest regularizer first, as in the paper


def test_an_attribute_corpus_certifies_its_attribute_and_inherits_the_standard_gate():
    from pokeworld.certify import certificate_table, gate
    from pokeworld.experiments.stages import with_standard_gate

    std_est = {"gru": {"contact": {"log_m": 0.66, "gamma": 0.28, "log_k": 0.71}}, "drag": {"contact": {"gamma": 0.83}}}
    std = {"estimators": std_est, "counts": {"contact": {"fit": 10, "test": 9}}}
    std["gate"] = gate(certificate_table(std_est, ("log_m", "gamma", "log_k")), std_est)
    own = {"estimators": {"gru": {"contact": {"bias_x": 0.8, "bias_y": 0.82}}, "linear": {"contact": {"bias_x": 0.1}}},
           "config": {"targets": ["bias_x", "bias_y"]}, "counts": {"contact": {"fit": 7, "test": 6}}}
    merged = with_standard_gate(std, own)
    assert merged["gate"] == std["gate"] and merged["gate_from"] == "standard"
    assert merged["estimators"]["gru"]["contact"] == {"log_m": 0.66, "gamma": 0.28, "log_k": 0.71,
                                                      "bias_x": 0.8, "bias_y": 0.82}
    assert merged["certificate"]["contact"]["gamma"] == {"r2": 0.83, "estimator": "drag"}
    assert merged["certificate"]["contact"]["bias_x"] == {"r2": 0.8, "estimator": "gru"}
    # a failed standard gate is stated once, on the standard corpus, not again per attribute corpus
    std_fail = {**std, "gate": {"log_k": {**std["gate"]["log_k"], "passed": False}}}
    lines = tables.no_claim_lines({"certificates": {"standard": std_fail, "bias0.5": with_standard_gate(std_fail, own)}})
    assert sum("no claim" in ln for ln in lines) == 1


def test_frame_averaged_section_sets_the_model_beside_the_factorial_vfx(tmp_path):
    c = map_config("tiny", out=str(tmp_path), experiments=("factorial", "frame_averaged"), variants=("VFX",),
                   seeds=(0, 1))
    specs = {s.name: s for s in all_specs(c)}
    runs = {}
    for name, s in specs.items():
        k = 0.2 if s.corpus == "frame_averaged" else 0.3 + 0.1 * s.seed  # factorial seeds read 0.3 and 0.4
        runs[name] = _run(s, {"contact": {"log_k": k, "gamma": 0.0}})
        runs[name]["prediction"]["direct16"] = 0.1
    est = lambda k_lin, k_gru: {"linear": {"contact": {"log_k": k_lin}}, "gru": {"contact": {"log_k": k_gru}}}  # noqa: E731
    cert = lambda k: {"contact": {"log_k": {"r2": k}}}  # noqa: E731
    results = {"runs": runs, "experiments": {e: [n for n, s in specs.items() if s.experiment == e]
                                             for e in ("factorial", "frame_averaged")},
               "certificates": {"standard": {"certificate": cert(0.8), "estimators": est(0.2, 0.8)},
                                "frame_averaged": {"certificate": cert(0.6), "estimators": est(0.05, 0.6)}}}
    t = "\n".join(frame_averaged.frame_averaged_lines(results))
    assert "sub-step touch: ours +0.80 (paper 0.87); with frame-averaged touch: ours +0.60" in t
    assert "| linear | +0.20 | +0.05 |" in t and "| gru | +0.80 | +0.60 |" in t
    assert "| sub-step touch (factorial) | +0.35 | — | +0.00 | — | — | 0.100 |" in t  # mean over the two seeds
    assert "| frame-averaged touch | +0.20 | — | +0.00 | — | — | 0.100 |" in t
    assert frame_averaged.frame_averaged_lines({"certificates": {}, "runs": {}, "experiments": {}}) == []


def test_merge_script_folds_in_reproduced_runs_and_refuses_ones_that_do_not_reproduce(tmp_path):
    """pokeworld.experiments.merge (scripts/merge_map_results.py): a re-trained run replaces the base's only when
    its ridge numbers agree; new runs and experiments are added; one mismatch writes nothing."""

    def run(k, mlp=None):
        r = {"train": {"variant": "VFX", "seed": 0}, "probes": {"ridge": {"contact": {"log_k": k, "log_m": 0.1}}}}
        if mlp is not None:
            r["probes"]["mlp"] = {"contact": {"log_k": mlp}}
        return r

    base = {"runs": {"a": run(0.35), "b": run(0.2)}, "experiments": {"controls": ["a", "b"]}, "certificates": {"x": 1},
            "map_config": {"experiments": ["controls"]}, "provenance": {"command": "old", "git": "g0"}}
    new = {"runs": {"a": run(0.35 + 1e-6, mlp=0.37), "c": run(0.5)}, "experiments": {"controls": ["a"], "tokens": ["c"]},
           "certificates": {"x": 2}, "map_config": {"experiments": ["controls", "tokens"]},
           "provenance": {"command": "new", "git": "g1"}}
    merged, rec = merge.merge(base, new, ["controls", "tokens"], 1e-4)
    assert merged["runs"]["a"]["probes"]["mlp"]["contact"]["log_k"] == 0.37  # the MLP numbers came in
    assert merged["runs"]["b"] == base["runs"]["b"] and merged["certificates"] == {"x": 1}
    assert merged["experiments"] == {"controls": ["a", "b"], "tokens": ["c"]}
    assert rec["runs_replaced_reproduced"] == ["a"] and rec["runs_added"] == ["c"]
    assert merged["provenance"]["merged"][0]["git"] == "g1" and "merged" not in base["provenance"]
    new_pl = {**new, "experiments": {**new["experiments"], "planning": ["a"]}, "planning": {"summary": 1},
              "runs": {"a": run(0.35)}}  # a ridge-only re-run of a run whose MLP numbers the merged record holds
    again = merge.merge(merged, new_pl, ["planning"], 1e-4)[0]
    assert again["planning"] == {"summary": 1} and again["runs"]["a"]["probes"]["mlp"]["contact"]["log_k"] == 0.37
    line = report.merged_lines(merged["provenance"])[0]
    assert line.startswith("Merged in from `new` (git g1), experiments controls, tokens: 1 re-trained run reproduced")
    assert line.endswith("1 run added.")

    bj, nj, out = tmp_path / "base.json", tmp_path / "new.json", tmp_path / "merged.json"
    bj.write_text(json.dumps(base))
    new["runs"]["a"] = run(0.30)  # does not reproduce
    nj.write_text(json.dumps(new))
    with pytest.raises(SystemExit, match="do not reproduce"):
        merge.main([str(bj), str(nj), "--experiments", "controls", "--out", str(out)])
    assert not out.exists()
    assert merge.main([str(bj), str(tmp_path / "nope.json"), "--experiments", "controls", "--out", str(out)]) == 2
    # asked to, a differing run replaces the record's whole row and the report names it with its difference
    assert merge.main([str(bj), str(nj), "--experiments", "controls", "--out", str(out), "--replace-differing"]) == 0
    got = json.loads(out.read_text())
    assert got["runs"]["a"]["probes"]["ridge"]["contact"]["log_k"] == 0.30
    rec = got["provenance"]["merged"][0]
    assert rec["runs_replaced_differing"] == {"a": pytest.approx(0.05)} and rec["runs_replaced_reproduced"] == []
    assert "`a` did not reproduce (largest ridge difference 0.0500)" in report.merged_lines(got["provenance"])[0]
