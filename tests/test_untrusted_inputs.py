"""What probe, plan, map, the map-results merge and swm-import do with runs, records and files they did not make
(issue #40): a run's store is found by its recorded content hash, unfinished runs and misplaced paths are refused
before any work, a NaN never reproduces a number, a damaged earlier results.json is refused before training, and
an import's declared size is bounded before anything is read."""

import json
import math
import os
import shutil

import h5py
import numpy as np
import pytest

from pokeworld import plan, run_store
from pokeworld.cli import main
from pokeworld.data import read_manifest, save
from pokeworld.errors import ConfigError, DataError
from pokeworld.evaluate import measure
from pokeworld.experiments import make_config as make_map_config, map as map_module, merge, stages
from pokeworld.swm.dataset import ImportConfig, export_store, import_dataset
from pokeworld.train import make_config as make_train_config, run as train, synthetic_dataset


def write_store(path, seed):
    save(synthetic_dataset(num_episodes=12, steps=24, size=32, seed=seed), path)
    return path


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    """Two stores of different content (seeds 0 and 1)."""
    root = tmp_path_factory.mktemp("stores")
    return write_store(root / "s0", 0), write_store(root / "s1", 1)


def fake_finished_run(run_dir, data, out=None, record=True):
    """A run folder as training leaves it (config.json, DONE, final.pt), for checks made before a model is read:
    config.json records the store's identity as ``train`` writes it (``record``) or not (a run from before)."""
    run_dir.mkdir(parents=True)
    cfg = {"data": str(data), "out": str(out if out is not None else run_dir), "variant": "VFX"}
    if record:
        run_store.write_run_config(run_dir, cfg)
    else:
        (run_dir / "config.json").write_text(json.dumps(cfg))
    (run_dir / "DONE").write_text("finished 2 steps\n")
    (run_dir / "final.pt").write_bytes(b"")
    return run_dir


# ------------------------------------------------------------------ item 8: a run's store, by content
@pytest.fixture(scope="module")
def unfinished(tmp_path_factory):
    """A tiny run trained one step of two from its own folder with relative paths (data/s, runs/a)."""
    home = tmp_path_factory.mktemp("home")
    write_store(home / "data" / "s", 0)
    before = os.getcwd()
    os.chdir(home)
    try:
        train(make_train_config("tiny", data="data/s", out="runs/a", steps=2, stop_at=1, progress=False))
    finally:
        os.chdir(before)
    return home


def test_training_records_the_resolved_store_path_and_its_content_hash(unfinished):
    cfg = json.loads((unfinished / "runs" / "a" / "config.json").read_text())
    assert cfg["data"] == "data/s"
    assert cfg["data_path"] == str((unfinished / "data" / "s").resolve())
    assert cfg["data_sha256"] == read_manifest(unfinished / "data" / "s")["content_sha256"]


def test_resuming_on_a_store_whose_content_changed_is_refused(unfinished, monkeypatch):
    home = unfinished.parent / "resume"
    shutil.copytree(unfinished, home)
    shutil.rmtree(home / "data" / "s")
    write_store(home / "data" / "s", 1)  # same path, other corpus
    monkeypatch.chdir(home)
    with pytest.raises(DataError, match="sha256"):
        train(make_train_config("tiny", data="data/s", out="runs/a", steps=2, progress=False))
    assert not (home / "runs" / "a" / "DONE").exists()


def test_a_run_probed_from_another_folder_reads_its_own_store(stores, tmp_path, monkeypatch):
    """Relative ``data`` read from elsewhere names another corpus: the recorded hash finds the run's own."""
    home, elsewhere = tmp_path / "home", tmp_path / "elsewhere"
    shutil.copytree(stores[0], home / "data" / "s")
    shutil.copytree(stores[1], elsewhere / "data" / "s")  # another corpus at the same relative path
    monkeypatch.chdir(home)
    run = fake_finished_run(home / "runs" / "a", "data/s", out="runs/a")  # trained in home with relative paths
    monkeypatch.chdir(elsewhere)
    assert run_store.trained_store(run, "probe") == str(home / "data" / "s")
    (home / "data" / "s").rename(home / "data" / "moved")  # only the other corpus is left where it could be
    with pytest.raises(DataError, match="elsewhere/data/s holds"):
        measure.run(measure.make_config("tiny", run_dir=str(run)))


def test_probe_and_plan_refuse_a_store_whose_content_is_not_the_runs(stores, tmp_path):
    data = tmp_path / "data"
    shutil.copytree(stores[0], data)
    run = fake_finished_run(tmp_path / "run", data)
    shutil.rmtree(data)
    shutil.copytree(stores[1], data)  # replaced in place by another corpus
    h0, h1 = (read_manifest(s)["content_sha256"][:12] for s in stores)
    with pytest.raises(DataError, match=f"{h0}.*{h1}"):
        measure.run(measure.make_config("tiny", run_dir=str(run)))
    with pytest.raises(DataError, match=f"{h0}.*{h1}"):
        plan.run(plan.make_config("tiny", runs=(str(run),), out=str(tmp_path / "plan")))
    assert not (tmp_path / "plan").exists()
    shutil.rmtree(data)
    with pytest.raises(DataError, match="no longer there"):
        measure.run(measure.make_config("tiny", run_dir=str(run)))


def test_runs_without_a_recorded_hash_resolve_beside_their_training_folder_else_warn_once(stores, tmp_path,
                                                                                           monkeypatch, capsys):
    home = tmp_path / "home"
    shutil.copytree(stores[0], home / "data" / "s")
    anchored = fake_finished_run(home / "runs" / "a", "data/s", out="runs/a", record=False)
    unknown = fake_finished_run(home / "runs" / "b", "data/s", out=str(home / "runs" / "b"), record=False)
    monkeypatch.chdir(tmp_path)
    assert run_store.trained_store(anchored, "probe") == str(home / "data" / "s")
    assert capsys.readouterr().out == ""
    for _ in range(2):
        assert run_store.trained_store(unknown, "probe") == "data/s"
    assert capsys.readouterr().out.count("warning") == 1


# ------------------------------------------------------------------ item 9: plan checks every run first
def test_plan_refuses_an_unfinished_run_with_the_line_probe_uses(unfinished, tmp_path):
    run = unfinished / "runs" / "a"
    with pytest.raises(ConfigError, match="has not finished training") as probe_error:
        measure.run(measure.make_config("tiny", run_dir=str(run)))
    with pytest.raises(ConfigError, match="has not finished training") as plan_error:
        plan.run(plan.make_config("tiny", runs=(str(run),), out=str(tmp_path / "p")))
    assert str(plan_error.value) == str(probe_error.value)
    done_without_final = tmp_path / "half"
    shutil.copytree(run, done_without_final)
    (done_without_final / "DONE").write_text("finished\n")  # DONE, but only ckpt.pt: not a finished model
    with pytest.raises(ConfigError, match="has not finished training"):
        plan.run(plan.make_config("tiny", runs=(str(done_without_final),), out=str(tmp_path / "p")))


def test_plan_with_the_output_among_the_runs_is_one_line_before_any_planning(stores, tmp_path, monkeypatch, capsys):
    good = fake_finished_run(tmp_path / "good", stores[0])
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(plan, "control", lambda *a, **k: pytest.fail("planned before the runs were checked"))
    assert main(["plan", "--preset", "tiny", "--runs", str(good), "results"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "results does not exist" in err and "before --runs" in err


# ------------------------------------------------------------------ item 10: merging map results
def record(ridge: dict, mlp: dict | None = None) -> dict:
    probes = {"ridge": {"contact": ridge}} | ({"mlp": {"contact": mlp}} if mlp else {})
    run = {"experiment": "factorial", "corpus": "standard", "train": {"variant": "V"}, "probes": probes,
           "prediction": {"static16": 0.1}}
    return {"experiments": {"factorial": ["r"]}, "runs": {"r": run}, "certificates": {},
            "map_config": {"experiments": ["factorial"]}, "provenance": {"command": "pokeworld map"}}


@pytest.mark.parametrize("new", [{"log_k": math.nan, "gamma": 0.5}, {"gamma": 0.5}, {"log_k": None, "gamma": 0.5}])
def test_a_nan_or_missing_number_never_reproduces_a_finite_one(new):
    base = record({"log_k": 0.8, "gamma": 0.5})
    with pytest.raises(ConfigError, match="log_k"):
        merge.merge(base, record(new), ["factorial"], tol=1e-4)
    merged, rec = merge.merge(base, record(new), ["factorial"], tol=1e-4, replace_differing=True)
    # explicitly replaced, and named as such (in words: JSON has no infinity)
    assert rec["runs_replaced_differing"] == {"r": "a base number is missing or NaN"}


def test_a_reproduced_run_keeps_every_number_the_base_held():
    base = record({"log_k": 0.8, "gamma": 0.5}, mlp={"log_k": 0.9, "gamma": 0.6})
    new = record({"log_k": 0.8, "gamma": 0.5, "log_m": 0.3}, mlp={"gamma": math.nan})
    merged, rec = merge.merge(base, new, ["factorial"], tol=1e-4)
    probes = merged["runs"]["r"]["probes"]
    assert rec["runs_replaced_reproduced"] == ["r"]
    assert probes["mlp"]["contact"] == {"log_k": 0.9, "gamma": 0.6}
    assert probes["ridge"]["contact"] == {"log_k": 0.8, "gamma": 0.5, "log_m": 0.3}


def test_merge_reads_damaged_records_as_one_error_line(tmp_path):
    good, bad = tmp_path / "good.json", tmp_path / "bad.json"
    good.write_text(json.dumps(record({"log_k": 0.8})))
    bad.write_text('{"runs": [')
    with pytest.raises(SystemExit, match="bad.json is not .*a results record"):
        merge.main([str(good), str(bad), "--experiments", "factorial", "--out", str(tmp_path / "m.json")])
    bad.write_text(json.dumps({**record({"log_k": 0.8}), "runs": {"r": {"probes": {}}}}))
    with pytest.raises(SystemExit, match="run r: 'experiment' is missing"):
        merge.main([str(good), str(bad), "--experiments", "factorial", "--out", str(tmp_path / "m.json")])
    assert not (tmp_path / "m.json").exists()


# ------------------------------------------------------------------ item 11: a damaged earlier results.json
@pytest.mark.parametrize("content, problem", [
    ("{not json", "valid JSON"),
    (json.dumps({**record({"log_k": 0.8}), "runs": {"r": {**record({"log_k": 0.8})["runs"]["r"],
                                                         "probes": {"ridge": {"contact": {"log_k": math.nan}}}}}}),
     "probes.ridge.contact.log_k is nan"),
    (json.dumps({**record({"log_k": 0.8}), "experiments": {"factorial": "r"}}), "experiments.factorial"),
    (json.dumps({k: v for k, v in record({"log_k": 0.8}).items() if k != "runs"}), "'runs' is missing"),
])
def test_a_damaged_earlier_results_json_is_refused_before_any_training(tmp_path, monkeypatch, content, problem):
    out = tmp_path / "map"
    out.mkdir()
    (out / "results.json").write_text(content)
    monkeypatch.setattr(stages, "ensure_corpus", lambda *a: pytest.fail("the map started work"))
    with pytest.raises(ConfigError, match=f"results.json is not .*{problem}.*move it aside"):
        map_module.run(make_map_config("tiny", out=str(out), workers=1))
    assert (out / "results.json").read_text() == content  # left as it was


# ------------------------------------------------------------------ item 13: numbers, measure.json, outputs
@pytest.mark.parametrize("bad", [dict(episodes=-1), dict(steps=0), dict(iterations=0), dict(context=0),
                                 dict(goal_radius=math.nan), dict(goal_radius=0.6), dict(seed=-1)])
def test_nonsensical_plan_numbers_are_refused_at_config_time(bad):
    with pytest.raises(ConfigError, match=next(iter(bad))):
        plan.make_config("tiny", **bad)


@pytest.mark.parametrize("bad", [dict(stride=0), dict(max_windows=0), dict(batch_episodes=-2), dict(seed=-1),
                                 dict(kinds=())])
def test_nonsensical_measure_numbers_are_refused_at_config_time(bad):
    with pytest.raises(ConfigError, match=next(iter(bad))):
        measure.make_config("tiny", **bad)


@pytest.mark.parametrize("content", ["{half", "[1, 2]", '{"key": [1]}', '{"key": {"config": 3}}'])
def test_a_malformed_measure_json_is_one_line_not_a_traceback(stores, tmp_path, content):
    run = fake_finished_run(tmp_path / "run", stores[0])
    (run / "measure.json").write_text(content)
    with pytest.raises(ConfigError, match="measure.json is not .*a measurement pokeworld wrote.*--overwrite"):
        measure.run(measure.make_config("tiny", run_dir=str(run)))


def test_an_output_that_cannot_be_written_is_refused_before_planning_or_mapping(stores, tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    run = fake_finished_run(tmp_path / "run", stores[0])
    monkeypatch.setattr(plan, "control", lambda *a, **k: pytest.fail("planned before the output was checked"))
    with pytest.raises(ConfigError, match="a_file"):
        plan.run(plan.make_config("tiny", runs=(str(run),), out=str(blocker / "plan")))
    monkeypatch.setattr(stages, "ensure_corpus", lambda *a: pytest.fail("the map started work"))
    with pytest.raises(ConfigError, match="a_file"):
        map_module.run(make_map_config("tiny", out=str(blocker / "map"), workers=1))


# ------------------------------------------------------------------ item 5: swm-import reads what it needs, bounded
@pytest.fixture(scope="module")
def exported(stores, tmp_path_factory):
    from pokeworld.data import load

    return export_store(load(stores[0]), tmp_path_factory.mktemp("swm") / "pw.h5")


def with_column(exported, out, name, shape, dtype):
    """A copy of the export plus a declared (never written, gzip-chunked) column: a file of a few kilobytes that
    declares ``shape`` × ``dtype`` bytes."""
    shutil.copy(exported, out)
    with h5py.File(out, "a") as f:
        f.create_dataset(name, shape=shape, dtype=dtype, chunks=(1, *shape[1:]), compression="gzip")
    return out


def test_swm_import_leaves_columns_it_does_not_use_unread(exported, tmp_path):
    rows = 12 * 25
    big = with_column(exported, tmp_path / "junk.h5", "junk", (rows, 1 << 20, 64), np.float32)  # declares 75 GiB
    ds = import_dataset(ImportConfig(source=str(big)))
    assert ds.num_episodes == 12 and "junk" not in ds.labels


def test_swm_import_bounds_the_total_declared_bytes_before_reading(exported, tmp_path):
    with pytest.raises(ConfigError, match="max_gib"):
        ImportConfig(source=str(exported), max_gib=0)
    small = r"declare 0\.000\d+ GiB in all \(largest, GiB: pixels.*over the allowed .* GiB.*--max-gib"
    with pytest.raises(DataError, match=small):
        import_dataset(ImportConfig(source=str(exported), max_gib=1e-6))
    # proprio and touch each declared at 300 × 2^20 float64 ≈ 2.3 GiB: under a 4 GiB cap per column, but together
    # over the 4 GiB budget; refused before a byte of them is read
    bomb = tmp_path / "bomb.h5"
    shutil.copy(exported, bomb)
    with h5py.File(bomb, "a") as f:
        for name in ("proprio", "touch"):
            del f[name]
            f.create_dataset(name, shape=(12 * 25, 1 << 20), dtype=np.float64, chunks=(1, 1 << 16),
                             compression="gzip")
    with pytest.raises(DataError, match=r"declare 4\.69 GiB in all.*allowed 4 GiB.*--max-gib"):
        import_dataset(ImportConfig(source=str(bomb)))
