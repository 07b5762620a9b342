"""Property-based damage to exported model folders: any JSON value at any field of config.json or measure.json, a
NaN, an infinity or a huge number at any weight. Every reader of the folder (probe, plan, forecast-dependence, export,
the protocol) either refuses it in one line before any work, writing nothing, or accepts it and reaches its work
(its first long step is a tripwire, tests/model_folder_planting.py; export, which has no long step, writes a complete
folder with its card): never another exception, a second line, a partial output or a change to the folder it read.
Deterministic (``derandomize``)."""

from __future__ import annotations

import json
import shutil

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from json_damage import paths_of, replaced
from model_folder_planting import (
    CARD,
    CONFIG,
    READERS,
    WEIGHTS,
    copy_folder,
    edit_weights,
    read_as,
    snapshot,
    tripwires,
    world,
    written,
)

SETTINGS = dict(deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
JSON = st.recursive(st.none() | st.booleans() | st.integers(-10**30, 10**30) | st.floats(allow_nan=True)
                    | st.text(max_size=12), lambda inner: st.lists(inner, max_size=3)
                    | st.dictionaries(st.text(max_size=6), inner, max_size=3), max_leaves=6)


@pytest.fixture(scope="module")
def w(tmp_path_factory):
    return world(tmp_path_factory.mktemp("folderfuzz"))


#: Fields the readers take, drawn as often as all the others together: the JSON's root and top-level entries, the
#: training config's and the model's fields, and the measurement's readout, prediction errors and store hash.
FOCUS = {CONFIG: (("train_config",), ("model_kwargs",), ("step",), ("format",)),
         "measure.json": (("probes", "ridge"), ("prediction",), ("key",))}


def damaged(w, base, name: str, data, value):
    """A copy of the exported folder whose file ``name`` holds ``value`` at one of its key paths (drawn from
    ``data``: one of :data:`FOCUS` half the time)."""
    folder = copy_folder(w["model"], base / "model")
    obj = json.loads((folder / name).read_text())
    paths = list(paths_of(obj))
    focus = [p for p in paths if len(p) <= 1 or any(p[:len(f)] == f for f in FOCUS[name])]
    path = data.draw(st.sampled_from(focus) | st.sampled_from(paths), label="path")
    (folder / name).write_text(json.dumps(replaced(obj, path, value)))
    return folder


def every_reader_refuses_or_works(w, folder, base, capsys, readers=READERS) -> None:
    """The property: each reader's one-line refusal leaves nothing written; its acceptance reaches its work (export:
    a complete folder); the folder it read is never changed."""
    before = snapshot(folder)
    for reader in readers:
        out = base / f"out-{reader}"
        err = read_as(reader, folder, w, out, capsys)
        event(f"{reader}: {'refused' if err else 'read'}")
        if reader == "export" and not err:
            assert {p.name for p in out.iterdir()} >= {CARD, CONFIG, WEIGHTS}
        else:
            assert written(out) == [], (reader, err, written(out))
        assert snapshot(folder) == before, reader


@settings(max_examples=60, **SETTINGS)
@given(data=st.data(), value=JSON)
def test_any_value_in_an_exported_config_is_refused_in_one_line_or_read(w, tmp_path_factory, monkeypatch, capsys,
                                                                        data, value):
    tripwires(monkeypatch)
    base = tmp_path_factory.mktemp("config")
    every_reader_refuses_or_works(w, damaged(w, base, CONFIG, data, value), base, capsys)
    shutil.rmtree(base)


@settings(max_examples=40, **SETTINGS)
@given(data=st.data(), value=JSON)
def test_any_value_in_a_folders_measurement_is_refused_in_one_line_or_read(w, tmp_path_factory, monkeypatch, capsys,
                                                                           data, value):
    tripwires(monkeypatch)
    base = tmp_path_factory.mktemp("measure")
    every_reader_refuses_or_works(w, damaged(w, base, "measure.json", data, value), base, capsys,
                                  readers=("export", "forecast-dependence"))
    shutil.rmtree(base)


@settings(max_examples=16, **SETTINGS)
@given(tensor=st.integers(0, 10**6), element=st.integers(0, 10**6),
       value=st.sampled_from([float("nan"), float("inf"), float("-inf"), 1e30]))
def test_any_weight_not_finite_is_refused_in_one_line(w, tmp_path_factory, monkeypatch, capsys, tensor, element,
                                                      value):
    tripwires(monkeypatch)
    base = tmp_path_factory.mktemp("weights")
    folder = copy_folder(w["model"], base / "model")

    def plant(state):
        floats = sorted(k for k, v in state.items() if v.is_floating_point() and v.numel())
        t = state[floats[tensor % len(floats)]].view(-1)
        t[element % t.numel()] = value

    edit_weights(folder, plant)
    every_reader_refuses_or_works(w, folder, base, capsys)
    if value != 1e30:  # a NaN or an infinity is refused by every reader, naming the tensor
        for reader in READERS:
            assert "NaN or infinite" in read_as(reader, folder, w, base / f"again-{reader}", capsys)
    shutil.rmtree(base)
