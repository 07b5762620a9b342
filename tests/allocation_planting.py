"""Planted returned allocations for the round-4 tests: the records a real H100 allocation returned
(tests/data/allocation_h100: records.tar.gz and device.json of a paper-preset allocation that finished VFX at seed 0),
edited as a test asks, beside a pack whose members are a tiny model's compacted checkpoints (cheap to build, and
accepted by the merge: a member is checked against the model its own kwargs declare)."""

from __future__ import annotations

import io
import json
import shutil
import tarfile
from pathlib import Path
from typing import Any, Callable

import torch

from pokeworld.models.xjepa import XJEPA
from pokeworld.remote.pack import compact, member_name, tar_bytes
from pokeworld.train.optimizer_state import optimizer_params

DATA = Path(__file__).resolve().parent / "data" / "allocation_h100"
FINISHED = "VFX-h1-4-16-lam0.02-standard-s0"
"""The run the real allocation finished (its config, metrics and measurement are in the records)."""
PARTIAL = "VF-h1-4-16-lam0.02-standard-s0"
"""A run the real allocation did not start: planted checkpoints resume it."""


def tiny_checkpoint(optimizer: bool = True, step: int = 5, config: dict | None = None) -> dict[str, Any]:
    """A checkpoint of a tiny X-JEPA (weights, kwargs, step; with ``optimizer`` an AdamW state after one step,
    grouped as training groups it), and ``config`` as a run's config.json."""
    torch.manual_seed(0)
    model = XJEPA(variant="VF", channels=[4, 8, 8, 8], image_size=16, latent_dim=8, width=8, depth=1, heads=2)
    ck: dict[str, Any] = {"model": model.state_dict(), "model_kwargs": model.config, "step": step,
                          "config": config or {"variant": "VF", "seed": 0, "steps": 20000}}
    if optimizer:
        opt = torch.optim.AdamW([{"params": g} for g in optimizer_params(model)], lr=1e-3)
        sum((p ** 2).sum() for p in model.parameters()).backward()
        opt.step()
        ck["optimizer"] = opt.state_dict()
    return ck


def member(run: str, kind: str, ck: dict[str, Any] | None = None, raw: bytes | None = None) -> tuple[str, bytes]:
    """A pack member: ``ck`` compacted and serialised (or ``raw`` bytes as they are), named by its sha256."""
    if raw is None:
        buf = io.BytesIO()
        torch.save(compact(ck), buf)
        raw = buf.getvalue()
    return member_name(run, kind, raw), raw


def records_tree(dest: Path) -> Path:
    """The real allocation's records unpacked into ``dest`` (to be edited)."""
    with tarfile.open(DATA / "records.tar.gz") as tar:
        tar.extractall(dest, filter="data")
    return dest


def pack_tree(tree: Path, pack: Path) -> None:
    """``tree`` packed as a records.tar.gz."""
    with tarfile.open(pack, "w:gz") as tar:
        for p in sorted(tree.rglob("*")):
            if p.is_file():
                tar.add(p, arcname=str(p.relative_to(tree)))


def plant(dest: Path, members: list[tuple[str, bytes]] = (), edit: Callable[[Path], None] | None = None) -> Path:
    """A returned allocation folder at ``dest``: device.json, records.tar.gz (edited by ``edit`` on the unpacked
    tree when given) and, with ``members``, pack.tar.part00."""
    dest.mkdir(parents=True)
    shutil.copy(DATA / "device.json", dest / "device.json")
    if edit is None:
        shutil.copy(DATA / "records.tar.gz", dest / "records.tar.gz")
    else:
        tree = records_tree(dest.parent / f".{dest.name}-records")
        edit(tree)
        pack_tree(tree, dest / "records.tar.gz")
        shutil.rmtree(tree)
    if members:
        (dest / "pack.tar.part00").write_bytes(tar_bytes(list(members)))
    return dest


def edit_json(path: Path, change: Callable[[dict], None]) -> None:
    obj = json.loads(path.read_text())
    change(obj)
    path.write_text(json.dumps(obj))


def with_partial(tree: Path, run: str = PARTIAL, step: int = 5) -> None:
    """Records that list ``run`` as cut short at ``step`` (its checkpoint then resumes)."""
    def change(prog: dict) -> None:
        prog["partial"] = {run: step}
        prog["pending"] = [n for n in prog["pending"] if n != run]

    edit_json(tree / "progress.json", change)


def current_model(**config) -> dict:
    """``config`` with the objective-and-model fields the `paper` preset trains now (the real allocation predates the
    aligned model, which `--plan` refuses to build on)."""
    from pokeworld.train.config import PRESETS, REFERENCE_MODEL, field_defaults

    now = {**field_defaults(), **PRESETS["paper"]}
    return {**{k: list(v) if isinstance(v, tuple) else v for k, v in now.items() if k in REFERENCE_MODEL}, **config}


def with_partial_current(tree: Path) -> None:
    """:func:`with_partial` on records whose runs trained the current model (:func:`current_model`)."""
    with_partial(tree)
    for path in (tree / "runs").glob("*/config.json"):
        edit_json(path, lambda cfg: cfg.update(current_model()))
