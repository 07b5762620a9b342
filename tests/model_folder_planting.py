"""Planted exported model folders for the round-5 tests (tests/test_untrusted_round5.py, tests/test_model_folder_fuzz.py):
a tiny store, a tiny VFX run trained and probed on it, its export, and edits of a copy of any of them (config.json's
fields, the weights, a model rebuilt with other input sizes), plus each reader of an exported folder run with its
first long step replaced by a tripwire, so a test sees whether the reader refused before any work."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any, Callable

import torch

from pokeworld.cli import main

CARD, CONFIG, WEIGHTS = "README.md", "config.json", "model.safetensors"


class Worked(Exception):
    """Raised by a tripwire: the reader reached its first long step (it accepted its inputs)."""


def world(root: Path) -> dict[str, Path]:
    """A tiny store, run A (VFX, probed) and its export, under ``root``."""
    store, run, model = root / "store", root / "run", root / "model"
    assert main(["generate", "--preset", "tiny", str(store)]) == 0
    assert main(["train", "--preset", "tiny", "--data", str(store), "--out", str(run), "--seed", "3"]) == 0
    assert main(["probe", "--preset", "tiny", str(run)]) == 0
    assert main(["export", str(run), "--out", str(model)]) == 0
    shutil.copy(run / "measure.json", model / "measure.json")  # as `pokeworld probe MODEL` on its own store writes
    return {"root": root, "store": store, "run": run, "model": model}


def copy_folder(src: Path, dest: Path) -> Path:
    """A copy of the regular files of ``src`` (a run's or a model folder's own files) in the new folder ``dest``."""
    dest.mkdir(parents=True)
    for p in src.iterdir():
        if p.is_file() and not p.is_symlink():
            shutil.copy2(p, dest / p.name)
    return dest


def edit_json(path: Path, change: Callable[[Any], Any]) -> None:
    """``path``'s JSON replaced by ``change(obj)`` (or ``obj`` changed in place when it returns None)."""
    obj = json.loads(path.read_text())
    new = change(obj)
    path.write_text(json.dumps(obj if new is None else new))


def edit_weights(folder: Path, change: Callable[[dict[str, torch.Tensor]], None]) -> None:
    """The folder's weights changed in place by ``change`` (a dict of named tensors) and saved again."""
    from safetensors.torch import load_file, save_file

    state = load_file(folder / WEIGHTS)
    change(state)
    save_file(state, folder / WEIGHTS, metadata={"format": "pokeworld-xjepa-1"})


def rebuilt(folder: Path, **kwargs: Any) -> Path:
    """The folder's model replaced by a consistent one with ``kwargs`` changed (weights of a fresh model of those
    sizes): a model that loads, but whose inputs are other than the store's."""
    from pokeworld.models.xjepa import XJEPA

    cfg = json.loads((folder / CONFIG).read_text())
    cfg["model_kwargs"].update(kwargs)
    (folder / CONFIG).write_text(json.dumps(cfg))
    state = XJEPA(**cfg["model_kwargs"]).state_dict()
    edit_weights(folder, lambda s: (s.clear(), s.update(state)))
    return folder


def a_float_weight(state: dict[str, torch.Tensor]) -> str:
    return next(k for k, v in state.items() if v.is_floating_point() and v.numel() > 1)


def snapshot(folder: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under ``folder`` (relative name -> bytes, modification time): what "nothing changed" compares."""
    return {str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


def written(folder: Path) -> list[str]:
    """The files under ``folder`` other than the ownership record ([] when it does not exist)."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()
                  and p.name != ".pokeworld-owned") if folder.exists() else []


def planted_certificates() -> dict:
    """Certificates for the protocol that pass every gate, so it never computes its own."""
    from pokeworld import certify as C

    est = {"gru": {"contact": {"log_m": 0.8, "gamma": 0.7, "log_k": 0.6}}}
    cert = C.certificate_table(est, ("log_m", "gamma", "log_k"))
    return {"estimators": est, "certificate": cert, "gate": C.gate(cert, est), "counts": {}}


def tripwires(monkeypatch) -> None:
    """Replace the first long step of every reader of a model folder by :class:`Worked`: probe's measurement, plan's
    random controller, forecast-dependence's fresh corpus, the protocol's certificates and probes, swm-plan's
    stable-worldmodel (the extra it needs, before its controllers)."""
    from pokeworld import plan, protocol
    from pokeworld.evaluate import dependence_runs, measure
    from pokeworld.swm import costable

    def worked(*args, **kwargs):
        raise Worked()

    for module, name in ((measure, "measure"), (plan, "control"), (dependence_runs, "fresh_corpus"),
                         (protocol, "resolve_certificates"), (protocol, "run_probes"),
                         (costable, "stable_worldmodel"), (costable, "control")):
        monkeypatch.setattr(module, name, worked)


def read_as(reader: str, folder: Path, w: dict[str, Path], out: Path, capsys) -> str:
    """Run ``reader`` on ``folder`` (store ``w["store"]``, outputs under ``out``): "" when it reached its work (a
    tripwire, or export's success), else its one-line refusal (the test fails on a traceback or a second line)."""
    from pokeworld.errors import PokeworldError
    from pokeworld.protocol import certify_model

    argv = {"probe": ["probe", "--preset", "tiny", str(folder), "--data", str(w["store"])],
            "plan": ["plan", "--preset", "tiny", str(out), "--runs", str(folder), "--data", str(w["store"])],
            "forecast-dependence": ["forecast-dependence", "--preset", "tiny", str(out), "--runs", str(folder),
                                    "--store", str(w["store"])],
            "export": ["export", str(folder), "--out", str(out)],
            "swm-plan": ["swm-plan", "--preset", "tiny", "--plan.out", str(out), "--plan.runs", str(folder),
                         "--plan.data", str(w["store"])]}.get(reader)
    capsys.readouterr()
    try:
        if argv is None:
            certify_model(folder, w["store"], out, certificates=planted_certificates(), preset="tiny")
            return ""
        code = main(argv)
    except Worked:
        return ""
    except PokeworldError as e:  # the API's refusal
        assert "\n" not in str(e), str(e)
        return str(e)
    err = capsys.readouterr().err.strip()
    if code == 0:
        return ""
    assert code == 2 and "Traceback" not in err and len(err.splitlines()) == 1, err
    assert err.startswith(f"pokeworld {reader}: error: "), err
    return err


READERS = ("probe", "plan", "forecast-dependence", "export", "protocol", "swm-plan")
"""Every reader of an exported folder."""
