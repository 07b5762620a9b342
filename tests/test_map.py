"""The identifiability map end to end on the tiny preset, run naming, skipping, and submitit launching."""

import json

import numpy as np
import pytest

from pokeworld.errors import ConfigError
from pokeworld import experiments as experiment
from pokeworld.experiments import attributes, stages
from pokeworld.evaluate.measure import CONTEXT, HORIZON, glide_test
from pokeworld.windows import make_windows


def test_run_names_are_deterministic_and_unique():
    c = experiment.make_config("cpu", experiments=tuple(experiment.EXPERIMENTS))
    a = [s.name for s in experiment.all_specs(c)]
    b = [s.name for s in experiment.all_specs(c)]
    assert a == b and len(a) == len(set(a))
    assert "VFX-h1-4-16-lam0.02-standard-s0" in a  # shared by factorial, lambda and coverage: trained once
    assert "V-h1-lam0.1-standard-motion_channelFalse-s0" in a  # the lazy equilibrium as the release trains it


def test_bad_map_configs_raise():
    with pytest.raises(ConfigError, match="unknown experiments"):
        experiment.make_config("tiny", experiments=("alchemy",))
    with pytest.raises(ConfigError, match="unknown variants"):
        experiment.make_config("tiny", variants=("VZ",))
    with pytest.raises(ConfigError, match="launcher"):
        experiment.make_config("tiny", launcher="kubernetes")
    with pytest.raises(ConfigError, match="unknown attribute corpora"):
        experiment.make_config("tiny", attribute_corpora=("bias9",))


def test_attribute_corpora_pick_the_matrix_cells_to_run():
    c = experiment.make_config("tiny", experiments=("attributes",), attribute_corpora=("bias2.5", "gain"))
    specs = attributes.specs(c)
    assert [(s.corpus, s.measure_corpus) for s in specs] == [("bias2.5", "bias2.5"), ("gain", "gain")]
    full = attributes.specs(experiment.make_config("tiny", experiments=("attributes",)))
    assert {s.name for s in specs} < {s.name for s in full}  # same run names: a subset re-runs those cells


def test_glide_test_references(tiny_dataset):
    ds = tiny_dataset
    w = make_windows(ds, np.arange(ds.num_episodes), CONTEXT + HORIZON, 2)
    truth = w.gather(ds.labels["object_pos"])[:, -1]
    res = glide_test(ds, w, truth, np.arange(ds.num_episodes))
    assert res["windows"] >= 5
    assert res["model"] == 0.0
    assert res["true_gamma"] < 1e-3 < res["median_gamma"] < res["static"]


@pytest.mark.slow
def test_tiny_map_writes_every_artifact_and_skips_on_rerun(tmp_path, capsys):
    out = tmp_path / "map"
    c = experiment.make_config("tiny", out=str(out), workers=1, whole_job_estimate=True)
    experiment.run(c)
    log = capsys.readouterr().out
    # one whole-job estimate from the start, re-estimated at each stage's end, the total in the closing line
    assert "[map] this machine, timed now: " in log and "the whole job takes about " in log
    for stage in ("corpus standard", "certificate linear (standard, contact windows)", "training and measurement",
                  "report"):
        assert f"] {stage} took " in log and "whole job " in log.split(f"] {stage} took ", 1)[1].splitlines()[0]
    closing = [line for line in log.splitlines() if line.startswith("[map] wrote ")][-1]
    assert " in " in closing and "(estimated at the start: " in closing
    for name in ("results.json", "results.md", "identifiability_map.png", "identifiability_map.pdf", "map_config.json",
                 "data/standard/manifest.json", "data/standard/certificates.json"):
        assert (out / name).exists(), name
    res = json.loads((out / "results.json").read_text())
    assert set(res["runs"]) == {"V-h1-4-16-lam0.02-standard-s0", "VX_t-h1-4-16-lam0.02-standard-s0"}
    for r in res["runs"].values():
        assert "contact" in r["probes"]["ridge"] and "log_k" in r["probes"]["ridge"]["contact"]
        assert r["prediction"]["static16"] > 0
        assert r["trained"]["last_logged_step"] > 0 and 0 <= r["trained"]["glide_loss_share"] <= 1  # metrics.jsonl
    for run in (out / "runs").iterdir():
        for f in ("config.json", "metrics.jsonl", "DONE", "measure.json"):
            assert (run / f).exists(), (run, f)
    md = (out / "results.md").read_text()
    assert "| V |" in md and "paper" in md
    assert "(preset `tiny`, environment `reference`," in md  # the record names the environment it ran
    experiment.run(c)  # second run: everything is skipped
    log = capsys.readouterr().out
    assert "already holds this corpus" in log and "up to date" in log
    assert "corpus standard took" not in log  # found done: not timed as if this machine had made it in no time


@pytest.mark.slow
def test_submitit_local_launcher_runs_jobs(tmp_path):
    out = tmp_path / "map"
    c = experiment.make_config("tiny", out=str(out), variants=("V",), launcher="submitit-local")
    experiment.run(c)
    assert (out / "runs" / "V-h1-4-16-lam0.02-standard-s0" / "measure.json").exists()
    assert list((out / "submitit").iterdir())


@pytest.mark.slow
def test_time_budget_stops_partway_resumes_and_packs(tmp_path, monkeypatch, capsys):
    import tarfile

    from pokeworld import clock as wall
    from pokeworld.models import XJEPA

    clock = {"t": 1e9}  # fake wall clock: every training step takes one minute
    orig = XJEPA.loss

    def slow_loss(model, *a, **kw):
        clock["t"] += 60
        return orig(model, *a, **kw)

    monkeypatch.setattr(XJEPA, "loss", slow_loss)
    monkeypatch.setattr(wall, "wall_clock", lambda: clock["t"])
    out = tmp_path / "map"
    first, second = "V-h1-4-16-lam0.02-standard-s0", "VX_t-h1-4-16-lam0.02-standard-s0"
    # 15 min with no reserve: the first run's 10 steps fit, the second stops after 5 of its 10
    c = experiment.make_config("tiny", out=str(out), workers=1, time_budget_min=15, time_reserve_min=0,
                               pack=str(tmp_path / "slice1.tar.gz"))
    assert experiment.run(c) == out
    prog = json.loads((out / "progress.json").read_text())
    assert prog["finished"] == [first] and prog["partial"] == {second: 5} and not prog["complete"]
    assert (out / "runs" / first / "measure.json").exists()
    assert not (out / "runs" / second / "DONE").exists() and not (out / "results.json").exists()
    assert "1 runs finished, 1 partial" in capsys.readouterr().out
    with tarfile.open(tmp_path / "slice1.tar.gz") as tar:
        names = set(tar.getnames())
    assert {f"runs/{first}/measure.json", f"runs/{second}/metrics.jsonl", f"runs/{second}/config.json",
            "data/standard/certificates.json", "progress.json", "map_config.json"} <= names

    c2 = experiment.make_config("tiny", out=str(out), workers=1, pack=str(tmp_path / "slice2.tar.gz"))
    experiment.run(c2)  # no budget: resumes the partial run and finishes the map
    prog = json.loads((out / "progress.json").read_text())
    assert prog["complete"] and sorted(prog["finished"]) == [first, second]
    assert torch_step(out / "runs" / second / "final.pt") == 10
    with tarfile.open(tmp_path / "slice2.tar.gz") as tar:
        names = set(tar.getnames())
    assert {"results.json", "results.md", "identifiability_map.png", f"runs/{second}/measure.json"} <= names
    assert not [n for n in names if n.endswith((".pt", ".h5", ".npy", ".npz")) or "/tb/" in n], names
    assert all(not n.startswith("data/") or n.endswith(("certificates.json", "manifest.json")) for n in names)

    with pytest.raises(ConfigError, match="time_reserve_min"):
        experiment.make_config("tiny", time_budget_min=1, time_reserve_min=1)
    with pytest.raises(ConfigError, match="tar.gz"):
        experiment.make_config("tiny", pack="results.zip")


def torch_step(path) -> int:
    import torch

    return int(torch.load(path, weights_only=True)["step"])


def test_demo_budget_knobs_are_validated():
    with pytest.raises(ConfigError, match="split_fractions"):
        experiment.make_config("tiny", split_fractions=(0.5, 0.5))
    with pytest.raises(ConfigError, match="train_preset"):
        experiment.make_config("tiny", train_preset="laptop")
    with pytest.raises(ConfigError, match="measure_kinds"):
        experiment.make_config("tiny", measure_kinds=("sideways",))
    demo = experiment.make_demo_config("cpu")
    assert (demo.preset, demo.train_preset, demo.split_fractions, demo.measure_kinds) == (
        "cpu", "demo", (0.4, 0.4, 0.2), ("contact",))
    job = stages.jobs(demo, experiment.all_specs(demo), threads=1)[0]
    assert job["train_preset"] == "demo" and job["preset"] == "cpu"
    assert job["measure"] == {"kinds": ("contact",), "max_windows": 12000}


@pytest.mark.slow
def test_map_budget_knobs_reach_generation_training_and_measurement(tmp_path):
    out = tmp_path / "map"
    c = experiment.make_config("tiny", out=str(out), workers=1, variants=("VX_t",), split_fractions=(0.4, 0.4, 0.2),
                               measure_kinds=("contact",), measure_max_windows=40, train_preset="tiny",
                               train_steps=4)
    experiment.run(c)
    counts = json.loads((out / "data/standard/manifest.json").read_text())["split_counts"]
    n = sum(counts.values())
    for split, share in (("train", 0.4), ("probe_fit", 0.4), ("probe_test", 0.2)):
        assert abs(counts[split] - share * n) <= 1, counts
    run = out / "runs" / "VX_t-h1-4-16-lam0.02-standard-s0"
    m = json.loads((run / "measure.json").read_text())
    assert set(m["probes"]["ridge"]) == {"contact"} and 10 <= m["probes"]["counts"]["contact"]["fit"] <= 40
    assert json.loads((run / "config.json").read_text())["steps"] == 4


def test_map_wide_sigreg_pool_and_gnll_variance_rename_only_the_runs_they_apply_to():
    base = experiment.make_config("cpu", experiments=("lambda", "controls"), seeds=(0,))
    c = experiment.make_config("cpu", experiments=("lambda", "controls"), seeds=(0,), sigreg_pool="pooled",
                               gnll_variance="free")
    names = {s.name: s for s in experiment.all_specs(c)}
    old = {s.name for s in experiment.all_specs(base)}
    assert "VFX-h1-4-16-lam0.3-standard-sigreg_poolpooled-s0" in names
    assert "VFX-h1-4-16-lam0.02-standard-gnll_variancefree-objectivegnll-sigreg_poolpooled-s0" in names
    # the default map's NLL control is the bounded one, named without a tag
    assert "VFX-h1-4-16-lam0.02-standard-objectivegnll-s0" in old
    # token and reconstruction runs have no global SIGReg to pool: unchanged, shared with the default map
    for s in names.values():
        if s.train.get("tokens") or s.train.get("objective") == "recon":
            assert s.name in old and "sigreg_pool" not in s.train
        else:
            assert s.train["sigreg_pool"] == "pooled" and s.name not in old
    assert set(experiment.spec_experiments(c)["lambda"]) <= set(names)
    with pytest.raises(ConfigError, match="sigreg_pool"):
        experiment.make_config("cpu", sigreg_pool="sometimes")
    with pytest.raises(ConfigError, match="gnll_variance"):
        experiment.make_config("cpu", gnll_variance="wild")


def test_control_runs_subset_re_runs_only_the_named_cells():
    """`--control-runs gnll gnll_every_head` (the NLL rows after a change of the variance) trains those two runs
    only, with the names the full controls map gives them; an unknown name is refused before anything runs."""
    full = {s.name for s in experiment.all_specs(experiment.make_config("cpu", experiments=("controls",), seeds=(0,)))}
    sub = experiment.make_config("cpu", experiments=("controls",), seeds=(0,), control_runs=("gnll", "gnll_every_head"))
    names = [s.name for s in experiment.all_specs(sub)]
    assert len(full) == 6 and set(names) < full
    assert names == ["VFX-h1-4-16-lam0.02-standard-objectivegnll-s0",
                     "VFX-h1-4-16-lam0.02-standard-gnll_headsall-objectivegnll-s0"]
    with pytest.raises(ConfigError, match="unknown control runs"):
        experiment.make_config("cpu", control_runs=("gnll", "dropout"))


@pytest.mark.slow
def test_stacked_map_trains_its_runs_as_one_group_and_measures_each(tmp_path, capsys):
    """The GPU options (stack, certify_alongside) on the tiny map: the runs train as one stacked group, the
    certificates computed in the background process equal those computed in this one."""
    import shutil

    out = tmp_path / "map"
    c = experiment.make_config("tiny", out=str(out), workers=1, stack=True, certify_alongside=True)
    experiment.run(c)
    log = capsys.readouterr().out
    assert "2 runs as 1 stacked group(s) of [2] members" in log and "background process" in log
    res = json.loads((out / "results.json").read_text())
    assert set(res["runs"]) == {"V-h1-4-16-lam0.02-standard-s0", "VX_t-h1-4-16-lam0.02-standard-s0"}
    for name, r in res["runs"].items():
        rows = [json.loads(x) for x in (out / "runs" / name / "metrics.jsonl").read_text().splitlines()]
        assert rows[-1]["stacked_members"] == 2  # trained in the group, not alone
        assert "log_k" in r["probes"]["ridge"]["contact"]
    fresh = tmp_path / "fresh"
    shutil.copytree(out / "data" / "standard", fresh / "data" / "standard")
    (fresh / "data" / "standard" / "certificates.json").unlink()
    here = stages.ensure_certificates(experiment.make_config("tiny", out=str(fresh)), "standard")
    assert res["certificates"]["standard"]["certificate"] == here["certificate"]
    experiment.run(c)  # finished: nothing is trained again
    assert "stacked group" not in capsys.readouterr().out
    with pytest.raises(ConfigError, match="launcher local"):
        experiment.make_config("tiny", stack=True, launcher="submitit-local")


def test_map_wide_sigreg_reference_rows_rename_global_latent_runs_only():
    from pokeworld import experiments as ex

    c = ex.make_config("cpu", experiments=("lambda", "controls"), sigreg_reference_rows=128, seeds=(0,))
    specs = {s.name: s for s in ex.all_specs(c)}
    lam = [s for s in specs.values() if s.experiment == "lambda"]
    assert lam and all(s.train["sigreg_reference_rows"] == 128 and "sigreg_reference_rows128" in s.name for s in lam)
    for s in specs.values():  # token and reconstruction runs have no global-latent statistic to rescale
        if s.train.get("tokens") or s.train.get("objective") == "recon":
            assert "sigreg_reference_rows" not in s.train
    plain = ex.make_config("cpu", experiments=("lambda",), seeds=(0,))
    assert not any("sigreg_reference_rows" in s.name for s in ex.all_specs(plain))


def test_a_record_from_before_environments_reads_as_the_calibrated_one():
    from pokeworld.config import to_dict
    from pokeworld.experiments.report import markdown

    prov = {"command": "pokeworld map", "preset": "tiny", "pokeworld": "0.1.0", "git": "abc1234"}
    now = to_dict(experiment.make_config("tiny"))
    before = {k: v for k, v in now.items() if k != "environment"}
    record = {"provenance": prov, "runs": {}, "certificates": {}, "experiments": {}}
    assert "environment `calibrated`" in markdown({**record, "map_config": before})
    assert "environment `reference`" in markdown({**record, "map_config": now})
