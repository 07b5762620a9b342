"""Property-based damage to what a GPU allocation returns and to swm-targets' records (issue #60): any JSON value
at any field of the returned records, damaged bytes in records.tar.gz, any JSON value at any field of an
swm-certify record. Each reader (``merge_allocations.py --plan``'s: open the allocation, plan, print the command;
``swm-targets``': load, summarise, write the table) either succeeds or ends in one ``ConfigError`` / ``DataError``
line: never another exception, a hang or a printed word that is not a known run. Deterministic (``derandomize``)."""

from __future__ import annotations

import json
import shlex
import shutil
import tempfile
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from allocation_planting import FINISHED, PARTIAL, member, plant, tiny_checkpoint, with_partial
from json_damage import paths_of, replaced
from pokeworld.errors import PokeworldError
from pokeworld.remote import allocations
from pokeworld.remote.queue import parse_token
from pokeworld.swm import targets_table as T
from test_swm_targets_table import INPUT, TARGET, planted_record

SETTINGS = dict(deadline=None, derandomize=True, max_examples=60,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
JSON = st.recursive(st.none() | st.booleans() | st.integers(-10**30, 10**30) | st.floats(allow_nan=True)
                    | st.text(max_size=12), lambda inner: st.lists(inner, max_size=3)
                    | st.dictionaries(st.text(max_size=6), inner, max_size=3), max_leaves=6)
RECORDS = ("progress.json", "device.json", "map_config.json", f"runs/{FINISHED}/config.json",
           "data/standard/manifest.json", "returned.json")


def plan_or_refuse(folder: Path) -> None:
    """The --plan reader on ``folder``: a plan whose printed words are known runs, or a PokeworldError."""
    with tempfile.TemporaryDirectory() as scratch:
        try:
            p = allocations.plan([allocations.open_allocation(folder, Path(scratch))])
            line = allocations.plan_lines(p, "abc")[-1]
        except PokeworldError as e:
            assert "\n" not in str(e)
            return
    words = shlex.split(line)
    for w in words[words.index("OUT") + 1:]:
        parse_token(w)  # every run word printed is a known variant at an integer seed


@settings(**SETTINGS)
@given(record=st.sampled_from(RECORDS), pick=st.integers(0, 10**6), value=JSON)
def test_any_value_in_a_returned_record_plans_or_is_one_line(tmp_path_factory, record, pick, value):
    base = tmp_path_factory.mktemp("fuzz")

    def edit(tree: Path) -> None:
        with_partial(tree)  # a checkpoint to resume, then the damage
        path = tree / record
        obj = json.loads(path.read_text())
        paths = list(paths_of(obj))
        path.write_text(json.dumps(replaced(obj, paths[pick % len(paths)], value)))

    plan_or_refuse(plant(base / "a", [member(PARTIAL, "ckpt", CKPT)], edit=edit))
    shutil.rmtree(base)


CKPT = tiny_checkpoint()


@settings(**SETTINGS)
@given(offsets=st.lists(st.integers(0, 10**6), min_size=1, max_size=4), byte=st.integers(0, 255),
       cut=st.integers(0, 10**6) | st.none())
def test_damaged_records_archive_plans_or_is_one_line(tmp_path_factory, offsets, byte, cut):
    base = tmp_path_factory.mktemp("fuzz")
    folder = plant(base / "a")
    raw = bytearray((folder / "records.tar.gz").read_bytes())
    for o in offsets:
        raw[o % len(raw)] = byte
    (folder / "records.tar.gz").write_bytes(bytes(raw[:cut % len(raw)] if cut is not None else raw))
    plan_or_refuse(folder)
    shutil.rmtree(base)


@settings(**SETTINGS)
@given(pick=st.integers(0, 10**6), value=JSON)
def test_any_value_in_an_swm_certify_record_tabulates_or_is_one_line(tmp_path_factory, pick, value):
    base = tmp_path_factory.mktemp("fuzz")
    rec = planted_record("swm/A", {"g": TARGET, "m": INPUT}, {"g": True, "m": False})
    rec["factor_effects"] = {"g": {"inert": False}}
    paths = list(paths_of(rec))
    (base / "r.json").write_text(json.dumps(replaced(rec, paths[pick % len(paths)], value)))
    try:
        summary = T.summarise({"r": T.load_factorial(base / "r.json")})
        T.markdown(summary)
    except PokeworldError as e:
        assert "\n" not in str(e)
    shutil.rmtree(base)
