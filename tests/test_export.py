"""``pokeworld export``: a finished run as a model-hub folder (card with YAML metadata, config.json,
model.safetensors) that probe, plan and the protocol read like the run, and whose weights are checked before use."""

from __future__ import annotations

import json
import os
import shlex
import struct
from pathlib import Path

import pytest
import torch

from pokeworld.checkpoint import CheckpointError
from pokeworld.cli import main, parse_config
from pokeworld.config import to_dict
from pokeworld.errors import PokeworldError
from pokeworld.export import MACHINE_FIELDS, ExportConfig, reproduce_command, run as export
from pokeworld.model_folder import WEIGHTS, is_model_folder
from pokeworld.rundir import load_model, read_run_config


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A tiny store, a tiny VFX run trained on it and probed (its measure.json gives the card's metrics)."""
    root = tmp_path_factory.mktemp("export")
    store, run = root / "store", root / "run"
    assert main(["generate", "--preset", "tiny", str(store)]) == 0
    assert main(["train", "--preset", "tiny", "--data", str(store), "--out", str(run), "--seed", "3"]) == 0
    assert main(["probe", "--preset", "tiny", str(run)]) == 0
    return {"root": root, "store": store, "run": run}


@pytest.fixture(scope="module")
def exported(trained):
    out = trained["root"] / "model"
    export(ExportConfig(run_dir=str(trained["run"]), out=str(out), data_command="pokeworld generate --preset tiny DIR"))
    return out


def front_matter(card: str) -> dict:
    """The YAML metadata between the two ``---`` lines; every value is flow-style YAML (JSON)."""
    head, rest = card.split("---\n", 2)[1:]
    assert rest.startswith("\n# ")
    return {k: json.loads(v) for k, v in (line.split(": ", 1) for line in head.strip().splitlines())}


def test_the_folder_holds_a_card_a_config_and_safetensors(exported, trained):
    assert {p.name for p in exported.iterdir() if not p.name.startswith(".")} == {"README.md", "config.json", WEIGHTS}
    meta = front_matter((exported / "README.md").read_text())
    assert meta["library_name"] == "pokeworld" and meta["license"] == "mit" and "x-jepa" in meta["tags"]
    assert meta["dataset_sha256"] == read_run_config(trained["run"])["data_sha256"]
    measured = json.loads((trained["run"] / "measure.json").read_text())
    metrics = {m["name"]: m["value"] for m in meta["model-index"][0]["results"][0]["metrics"]}
    r2 = measured["probes"]["ridge"]["contact"]
    assert metrics["ridge R² log k (contact windows)"] == pytest.approx(r2["log_k"], abs=1e-4)
    assert metrics["Δ=16 direct-head position error"] == pytest.approx(measured["prediction"]["direct16"], abs=1e-4)
    card = (exported / "README.md").read_text()
    assert "pokeworld generate --preset tiny DIR" in card and "pokeworld train --preset tiny" in card
    assert is_model_folder(exported) and not is_model_folder(trained["run"])


def test_the_exported_weights_are_the_run_s(exported, trained):
    a, b = load_model(trained["run"]), load_model(exported)
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


def test_the_card_s_command_rebuilds_the_run_s_config(trained):
    run_cfg = read_run_config(trained["run"])
    words = shlex.split(reproduce_command(run_cfg))
    assert words[:3] == ["pokeworld", "train", "--preset"]
    cfg = to_dict(parse_config("train", words[2:]))
    differ = {k for k in cfg if k not in MACHINE_FIELDS and k in run_cfg and cfg[k] != run_cfg[k]}
    assert not differ, {k: (cfg[k], run_cfg[k]) for k in differ}
    assert "--seed" in words and words[words.index("--seed") + 1] == "3"


def test_probe_and_plan_read_the_folder(exported, trained, tmp_path, capsys):
    assert main(["probe", "--preset", "tiny", str(exported), "--data", str(trained["store"])]) == 0
    res = json.loads((exported / "measure-store.json").read_text())  # --data names the store: measure-<store>.json
    ours = json.loads((trained["run"] / "measure.json").read_text())
    assert res["probes"]["ridge"]["contact"]["log_k"] == pytest.approx(ours["probes"]["ridge"]["contact"]["log_k"])
    assert main(["plan", "--preset", "tiny", str(tmp_path / "plan"), "--runs", str(exported),
                 "--data", str(trained["store"])]) == 0
    assert (tmp_path / "plan" / "plan.json").exists()


def test_the_protocol_takes_the_folder_s_path(exported, trained, tmp_path):
    from pokeworld import certify as C
    from pokeworld.protocol import certify_model

    est = {"gru": {"contact": {"log_m": 0.8, "gamma": 0.7, "log_k": 0.6}}}
    cert = C.certificate_table(est, ("log_m", "gamma", "log_k"))
    certs = {"estimators": est, "certificate": cert, "gate": C.gate(cert, est), "counts": {}}
    rep = certify_model(exported, trained["store"], tmp_path, certificates=certs, preset="tiny",
                        kinds=("contact",))
    assert rep["model"]["name"] == "model" and rep["model"]["state_dim"] > 0


def copy_folder(src: Path, dest: Path) -> Path:
    dest.mkdir()
    for p in src.iterdir():
        if p.is_file():
            (dest / p.name).write_bytes(p.read_bytes())
    return dest


def test_weights_that_do_not_fit_the_declared_model_are_refused(exported, tmp_path):
    from safetensors.torch import load_file, save_file

    bad = copy_folder(exported, tmp_path / "bad")
    state = load_file(bad / WEIGHTS)
    name = next(k for k, v in state.items() if v.dim() == 2)
    state[name] = torch.zeros(state[name].shape[0] + 1, state[name].shape[1])
    save_file(state, bad / WEIGHTS)
    with pytest.raises(CheckpointError, match="declare"):
        load_model(bad)


def test_a_header_naming_other_than_weights_and_a_linked_file_are_refused(exported, tmp_path):
    odd = copy_folder(exported, tmp_path / "odd")
    header = json.dumps({"x": {"dtype": "STR", "shape": [1], "data_offsets": [0, 1]}}).encode()
    (odd / WEIGHTS).write_bytes(struct.pack("<Q", len(header)) + header + b"a")
    with pytest.raises(CheckpointError, match="not weights of a known type"):
        load_model(odd)
    (odd / WEIGHTS).unlink()
    os.symlink(exported / WEIGHTS, odd / WEIGHTS)
    with pytest.raises(PokeworldError, match="link"):
        load_model(odd)


def test_an_unfinished_run_and_a_foreign_output_folder_are_refused(trained, tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "README.md").write_text("my own notes")
    with pytest.raises(PokeworldError):
        export(ExportConfig(run_dir=str(trained["run"]), out=str(tmp_path / "mine")))
    assert (tmp_path / "mine" / "README.md").read_text() == "my own notes"
    unfinished = copy_folder(trained["run"], tmp_path / "unfinished")
    (unfinished / "DONE").unlink()
    with pytest.raises(PokeworldError, match="not finished"):
        export(ExportConfig(run_dir=str(unfinished), out=str(tmp_path / "x")))
    assert not (tmp_path / "x" / WEIGHTS).exists()
