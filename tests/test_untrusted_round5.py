"""Untrusted inputs, round 5: exported model folders and the readers that take them (probe, plan,
forecast-dependence, export, the protocol), forecast-dependence's --merge and certify_model's outputs. One test per
class, each over every reader that has it; each refusal is one line naming the file and the field, before any work
(the readers' first long steps are tripwires, tests/model_folder_planting.py), and nothing is written."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from model_folder_planting import (
    CARD,
    CONFIG,
    READERS,
    WEIGHTS,
    a_float_weight,
    copy_folder,
    edit_json,
    edit_weights,
    planted_certificates,
    read_as,
    rebuilt,
    snapshot,
    tripwires,
    world,
    written,
)
from pokeworld.cli import main
from pokeworld.errors import PokeworldError


@pytest.fixture(scope="module")
def w(tmp_path_factory):
    return world(tmp_path_factory.mktemp("round5"))


# ---------------------------------------------------------------------- 1. an export never replaces another run


def second_run(w, dest: Path) -> Path:
    """Run B: a finished training run of its own (another seed)."""
    assert main(["train", "--preset", "tiny", "--data", str(w["store"]), "--out", str(dest), "--seed", "4"]) == 0
    return dest


@pytest.mark.parametrize("what", ["a finished run", "a run's config.json alone", "a user's files", "a file",
                                  "a link to an export"])
def test_an_export_replaces_nothing_but_an_earlier_export(w, tmp_path, capsys, what):
    out = tmp_path / "out"
    if what == "a finished run":
        second_run(w, out)
    elif what == "a run's config.json alone":
        out.mkdir()
        shutil.copy(w["run"] / CONFIG, out / CONFIG)
    elif what == "a user's files":
        out.mkdir()
        (out / CARD).write_text("my notes")
    elif what == "a file":
        out.write_text("mine")
    else:
        os.symlink(w["model"], out)
    before = snapshot(out) if out.is_dir() and not out.is_symlink() else out.read_bytes() if out.is_file() else None
    model_before = snapshot(w["model"])
    err = read_as("export", w["run"], w, out, capsys)
    assert "--out" in err or str(out) in err, err
    after = snapshot(out) if out.is_dir() and not out.is_symlink() else out.read_bytes() if out.is_file() else None
    assert after == before and snapshot(w["model"]) == model_before
    if what == "a finished run":  # B still loads as B's own model
        from pokeworld.rundir import load_model, read_run_config

        assert read_run_config(out)["seed"] == 4 and load_model(out) is not None


def test_an_export_replaces_an_earlier_export_card_last(w, tmp_path, monkeypatch, capsys):
    out = copy_folder(w["model"], tmp_path / "model")  # an earlier export, its ownership record with it
    assert main(["export", str(w["run"]), "--out", str(out)]) == 0
    # an export stopped between the weights and the card: the earlier card is gone, so no reader takes the folder
    import pokeworld.export as export

    def stopped(path, text):
        raise KeyboardInterrupt("stopped before the card")

    monkeypatch.setattr(export, "save_text", stopped)
    with pytest.raises(KeyboardInterrupt):
        export.run(export.ExportConfig(run_dir=str(w["run"]), out=str(out)))
    monkeypatch.undo()
    assert not (out / CARD).exists() and (out / WEIGHTS).exists()
    tripwires(monkeypatch)
    for reader in (r for r in READERS if r != "export"):
        err = read_as(reader, out, w, tmp_path / f"out-{reader}", capsys)
        assert "did not finish" in err and CARD in err, (reader, err)
        assert written(tmp_path / f"out-{reader}") == []


# ---------------------------------------------------------------------- 2. malformed fields, before any work


def variant_list(folder):
    edit_json(folder / CONFIG, lambda c: c["train_config"].update(variant=["VFX"]))


def seed_text(folder):
    edit_json(folder / CONFIG, lambda c: c["train_config"].update(seed="x"))


def image_size_text(folder):
    edit_json(folder / CONFIG, lambda c: c["train_config"].update(image_size="64"))


def horizons_words(folder):
    edit_json(folder / CONFIG, lambda c: c["train_config"].update(horizons=["a", "b"]))


def negative_step(folder):
    edit_json(folder / CONFIG, lambda c: c.update(step=-1))


def nan_weight(folder):
    edit_weights(folder, lambda s: s[a_float_weight(s)].view(-1).__setitem__(0, float("nan")))


def inf_weight(folder):
    edit_weights(folder, lambda s: s[a_float_weight(s)].view(-1).__setitem__(-1, float("inf")))


def no_card(folder):
    (folder / CARD).unlink()


DAMAGE = {  # damage -> (what the line names, whether export reads it: the store-fit ones are no export's business)
    "variant a list": (variant_list, "train_config.variant", True),
    "seed a string": (seed_text, "train_config.seed", True),
    "image_size a string": (image_size_text, "train_config.image_size", True),
    "horizons not integers": (horizons_words, "train_config.horizons", True),
    "a negative step": (negative_step, "'step'", True),
    "a NaN weight": (nan_weight, "NaN or infinite", True),
    "an inf weight": (inf_weight, "NaN or infinite", True),
    "no card": (no_card, "did not finish", True),
    "frames larger than the store's": (lambda f: rebuilt(f, image_size=128), "image_size", False),
    "touch of another width": (lambda f: rebuilt(f, touch_dim=5), "touch_dim", False),
    "proprio of another width": (lambda f: rebuilt(f, proprio_dim=3), "proprio_dim", False),
    "actions of another width": (lambda f: rebuilt(f, action_dim=3), "action_dim", False),
}


@pytest.mark.parametrize("reader", READERS)
@pytest.mark.parametrize("damage", list(DAMAGE))
def test_every_reader_refuses_a_malformed_folder_before_any_work(w, tmp_path, monkeypatch, capsys, damage, reader):
    plant, named, export_reads = DAMAGE[damage]
    folder = copy_folder(w["model"], tmp_path / "model")
    plant(folder)
    before = snapshot(folder)
    tripwires(monkeypatch)
    out = tmp_path / "out"
    err = read_as(reader, folder, w, out, capsys)
    if reader == "export" and not export_reads:
        assert err == "" and (out / CARD).is_file()  # a model of other sizes exports; the store's readers refuse it
        return
    assert named in err and str(folder) in err, err
    assert written(out) == [] and snapshot(folder) == before


@pytest.mark.parametrize("reader", ["export", "forecast-dependence"])
@pytest.mark.parametrize("field, value", [("probes.ridge.contact.log_k", "high"), ("probes.ridge.contact", [0.5]),
                                          ("probes", "none"), ("prediction.direct16", [0.3]),
                                          ("key.data_sha256", 5)])
def test_a_measure_json_field_of_the_wrong_type_is_one_line_before_anything_is_written(
        w, tmp_path, monkeypatch, capsys, reader, field, value):
    run = tmp_path / "run"
    shutil.copytree(w["run"], run)

    def damage(m):
        *parents, last = field.split(".")
        for key in parents:
            m = m[key]
        m[last] = value

    edit_json(run / "measure.json", damage)
    tripwires(monkeypatch)
    out = tmp_path / "out"
    err = read_as(reader, run, w, out, capsys)
    assert f"measure.json: its {field} is" in err, err
    assert not out.exists() or written(out) == []


# ---------------------------------------------------------------------- 3. options outside what the model takes


@pytest.mark.parametrize("reader, options, named", [
    ("plan", ["--context", "200", "--settle", "200"], "--context 200 with --settle 200"),
    ("probe", ["--window", "200"], "--window 200"),
    ("probe", ["--context", "150"], "--context 150"),
])
def test_options_the_model_cannot_take_are_refused_before_any_work(w, tmp_path, monkeypatch, capsys, reader, options,
                                                                   named):
    tripwires(monkeypatch)
    out = tmp_path / "out"
    head = [reader, "--preset", "tiny"] + ([str(out), "--runs", str(w["model"])] if reader == "plan" else
                                           [str(w["model"])])
    capsys.readouterr()
    assert main(head + ["--data", str(w["store"]), *options]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and named in err and "max_len" in err and "128" in err, err
    assert written(out) == [] and not (w["model"] / "measure-store.json").exists()


def test_a_window_the_model_cannot_take_is_refused_by_the_protocol_before_any_work(w, tmp_path, monkeypatch):
    from pokeworld.protocol import certify_model

    tripwires(monkeypatch)
    with pytest.raises(PokeworldError, match="window=200 .* max_len"):
        certify_model(w["model"], w["store"], tmp_path / "out", certificates=planted_certificates(), preset="tiny",
                      window=200)
    assert written(tmp_path / "out") == []


# ---------------------------------------------------------------------- 4. every input and output before the work


CELL = {"S": 1.0, "S_interval": [0.9, 1.1], "slope_model": 1.0, "slope_simulator": 1.0, "forecast_error": 0.1,
        "windows": 40, "episodes": 10}


def merge_record(store: str) -> dict:
    """A forecast-dependence record of one run measured elsewhere, with the tiny preset's settings on ``store``."""
    from pokeworld.evaluate.dependence import PARAMETERS
    from pokeworld.evaluate.dependence_runs import SETTINGS, make_config
    from pokeworld.evaluate.forecasters import PLANTS

    cfg = make_config("tiny", store=store)
    row = {"run": "elsewhere/run", "variant": "VFX", "seed": 0, "steps": 10, "store": store,
           "dependence": {p: dict(CELL) for p in PARAMETERS},
           "readout": {p: {"contact": 0.1, "glide": None} for p in PARAMETERS}}
    return {"config": {k: getattr(cfg, k) for k in SETTINGS}, "runs": [row],
            "planted": {store: {plant: {p: dict(CELL) for p in PARAMETERS} for plant in PLANTS}}}


MERGE_DAMAGE = {
    "a row without dependence": (lambda r: r["runs"][0].pop("dependence"), "runs[0].dependence"),
    "a config that is a list": (lambda r: r.update(config=[]), "config"),
    "S a string": (lambda r: r["runs"][0]["dependence"]["gamma"].update(S="1.0"), "runs[0].dependence.gamma.S"),
    "an interval of one number": (lambda r: r["runs"][0]["dependence"]["mass"].update(S_interval=[1.0]),
                                  "runs[0].dependence.mass.S_interval"),
    "runs a table": (lambda r: r.update(runs={}), "runs"),
    "a variant that is a list": (lambda r: r["runs"][0].update(variant=["VFX"]), "runs[0].variant"),
    "a readout that is a string": (lambda r: r["runs"][0]["readout"]["gamma"].update(contact="high"),
                                   "runs[0].readout.gamma.contact"),
    "a planted cell missing": (lambda r: next(iter(r["planted"].values()))["true"].pop("stiffness"),
                               "true.stiffness"),
}


@pytest.mark.parametrize("damage", list(MERGE_DAMAGE))
def test_a_malformed_merge_record_is_refused_before_any_work(w, tmp_path, monkeypatch, capsys, damage):
    change, named = MERGE_DAMAGE[damage]
    rec = merge_record(str(w["store"]))
    change(rec)
    (tmp_path / "earlier.json").write_text(json.dumps(rec))
    tripwires(monkeypatch)
    out = tmp_path / "out"
    capsys.readouterr()
    assert main(["forecast-dependence", "--preset", "tiny", str(out), "--runs", str(w["model"]), "--store",
                 str(w["store"]), "--merge", str(tmp_path / "earlier.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "earlier.json: its " in err and f"{named} must" in err, err
    assert not out.exists()


def test_a_well_formed_merge_record_is_joined(w, tmp_path):
    from pokeworld.evaluate.dependence_runs import make_config, run

    (tmp_path / "earlier.json").write_text(json.dumps(merge_record(str(w["store"]))))
    run(make_config("tiny", runs=(), store=str(w["store"]), merge=(str(tmp_path / "earlier.json"),),
                    out=str(tmp_path / "out")))
    rec = json.loads((tmp_path / "out" / "forecast_dependence.json").read_text())
    assert [r["run"] for r in rec["runs"]] == ["elsewhere/run"]


@pytest.mark.parametrize("output", ["protocol.md", "protocol.json", "protocol.png", "certificates.json"])
def test_the_protocol_refuses_an_output_it_may_not_replace_before_any_work(w, tmp_path, monkeypatch, output):
    from pokeworld.protocol import certify_model

    out = tmp_path / "out"
    out.mkdir()
    (out / output).write_text("the user's own")
    tripwires(monkeypatch)
    given = None if output == "certificates.json" else planted_certificates()
    with pytest.raises(PokeworldError, match=f"{output} exists and pokeworld did not write it"):
        certify_model(w["model"], w["store"], out, certificates=given, preset="tiny")
    assert sorted(p.name for p in out.iterdir()) == [output] and (out / output).read_text() == "the user's own"


def test_the_protocol_never_writes_into_the_store_it_reads(w, tmp_path, monkeypatch):
    from pokeworld.protocol import certify_model

    tripwires(monkeypatch)
    before = snapshot(w["store"])
    with pytest.raises(PokeworldError, match="lies inside the input"):
        certify_model(w["model"], w["store"], w["store"], certificates=planted_certificates(), preset="tiny")
    assert snapshot(w["store"]) == before


def test_probe_refuses_a_measurement_it_may_not_replace_before_any_work(w, tmp_path, monkeypatch, capsys):
    # the folder's measure.json came with it (copied, not written by pokeworld here) and is out of date: probe
    # would measure, keep it as measure.previous.json and only then be refused replacing it
    folder = copy_folder(w["model"], tmp_path / "model")
    edit_json(folder / "measure.json", lambda m: m["key"].update(final_mtime=1, config={**m["key"]["config"],
                                                                                        "stride": 8}))
    before = snapshot(folder)
    tripwires(monkeypatch)
    capsys.readouterr()
    assert main(["probe", "--preset", "tiny", str(folder)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "measure.json exists and pokeworld did not write it" in err, err
    assert snapshot(folder) == before
