"""Numbers are data (issue #50, items 3 and 7): every numeric field of every command's config is checked for type,
finiteness and a sensible range in the config layer (pokeworld.config.check_fields and each class's LIMITS) before
anything is created on disk, and a store manifest's generator config — read back as settings, never covered by the
content hash — goes through the same checks, refused in one DataError line before any heavy work."""

from __future__ import annotations

import dataclasses
import json
import math
import time
import typing
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pokeworld import data
from pokeworld.certificate_curve import CurveConfig
from pokeworld.certify import CertifyConfig
from pokeworld.cli import main
from pokeworld.config import from_dict
from pokeworld.errors import ConfigError, DataError
from pokeworld.evaluate.measure import MeasureConfig
from pokeworld.experiments.config import MapConfig
from pokeworld.plan import PlanConfig
from pokeworld.sim import ParamRanges, PhysicsConfig, PolicyConfig
from pokeworld.sim import generate
from pokeworld.sim.pairs import PairsConfig
from pokeworld.train import TrainConfig, make_config as make_train_config
from pokeworld.train.stacked import StackedConfig

FUZZ = settings(max_examples=50, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    """A real, small store of ``pokeworld generate`` (6 episodes of 24 steps, 16-pixel frames)."""
    out = tmp_path_factory.mktemp("round3cfg") / "tiny"
    generate.run(generate.make_config("tiny", out=str(out), num_episodes=6, batch_envs=6, episode_steps=24,
                                      physics={"image_size": 16}))
    return out


def cli(args: list[str], capsys) -> tuple[int, str]:
    """The exit code and stderr of ``pokeworld ARGS`` (tyro's own refusals exit through SystemExit)."""
    try:
        code = main(args)
    except SystemExit as e:
        code = e.code
    return code, capsys.readouterr().err


# ------------------------------------------------------------------ A. absurd numbers on the command line
GENERATE_CASES = [(["--seed", "-1"], "seed"), (["--num-episodes", "1e12"], "num-episodes"),
                  (["--num-episodes", "1000000000000"], "num_episodes"),
                  (["--split-fractions", "nan", "0.5", "0.5"], "split_fractions"),
                  (["--split-fractions", "0.5", "0.5", "0.5"], "sum to 1"),
                  (["--physics.image-size", "60000"], "image_size"), (["--physics.substeps", "2000000000"], "substeps"),
                  (["--physics.dt", "inf"], "dt"), (["--policy.switch-prob", "nan"], "switch_prob"),
                  (["--num-episodes", "1000000"], "GiB")]


@pytest.mark.parametrize("args,field", GENERATE_CASES)
def test_generate_refuses_absurd_numbers_with_exit_2_and_creates_nothing(args, field, tmp_path, capsys):
    code, err = cli(["generate", "--preset", "tiny", "--out", str(tmp_path / "x"), *args], capsys)
    assert code == 2 and field in " ".join(err.split()) and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # no store, no lock, no temporary folder


@pytest.mark.parametrize("bad,field", [({"seed": -1}, "seed"), ({"num_episodes": 10**12}, "num_episodes"),
                                       ({"split_fractions": (math.nan, 0.5, 0.5)}, "split_fractions"),
                                       ({"physics": {"image_size": 60000}}, "image_size"),
                                       ({"ranges": {"mass": (math.nan, 1.0)}}, "mass"),
                                       ({"num_episodes": 48.5}, "integer")])
def test_generate_refusals_are_one_config_error_line(bad, field):
    with pytest.raises(ConfigError, match=field) as e:
        generate.make_config("tiny", **bad)
    assert "\n" not in str(e.value)


TRAIN_CASES = [(["--lr", "nan"], "lr"), (["--batch-size", "1000000000"], "batch_size"), (["--seed", "-1"], "seed"),
               (["--lr", "inf"], "lr"), (["--weight-decay", "-1"], "weight_decay"), (["--steps", "0"], "steps"),
               (["--dropout", "nan"], "dropout"), (["--image-size", "4096"], "image_size")]


@pytest.mark.parametrize("args,field", TRAIN_CASES)
def test_train_refuses_absurd_numbers_in_one_line_before_the_run_folder_exists(args, field, store, tmp_path,
                                                                                capsys):
    run = tmp_path / "r"
    code, err = cli(["train", "--preset", "tiny", "--data", str(store), "--out", str(run), *args], capsys)
    assert code == 2 and field in err and len(err.strip().splitlines()) == 1
    assert not run.exists() and list(tmp_path.iterdir()) == []


def test_a_refused_batch_size_leaves_no_config_json_to_refuse_the_corrected_command(store, tmp_path, capsys):
    run = tmp_path / "r"
    base = ["train", "--preset", "tiny", "--data", str(store), "--out", str(run), "--steps", "2"]
    assert cli([*base, "--batch-size", "1000000000"], capsys)[0] == 2
    assert cli(base, capsys)[0] == 0 and (run / "DONE").exists()


# ------------------------------------------------------------------ B. the store's manifest is data
def damaged(store: Path, tmp_path: Path, change) -> Path:
    """A copy of ``store`` whose manifest ``change`` edited (the arrays, and so the content hash, untouched)."""
    out = tmp_path / "s"
    out.mkdir()
    (out / "data.h5").write_bytes((store / "data.h5").read_bytes())
    man = json.loads((store / "manifest.json").read_text())
    change(man)
    (out / "manifest.json").write_text(json.dumps(man))
    return out


def physics(name, value):
    return lambda m: m["config"]["physics"].__setitem__(name, value)


MANIFEST_CASES = [(physics("image_size", 60000), "config.physics.image_size"),
                  (physics("substeps", 2e9), "config.physics.substeps"),
                  (lambda m: m.__setitem__("config", [1]), "config"),
                  (physics("dt", "x"), "config.physics.dt"), (physics("dt", math.nan), "config.physics.dt"),
                  (lambda m: m["config"].__setitem__("physics", [1]), "config"),
                  (lambda m: m["config"]["policy"].__setitem__("mode_weights", [1, 2]), "config.policy.mode_weights"),
                  (lambda m: m["config"].__setitem__("num_episodes", "many"), "config.num_episodes"),
                  (lambda m: m["config"].__setitem__("warp", 9), "warp"),
                  (lambda m: m.__setitem__("seed", -1), "seed")]


@pytest.mark.parametrize("change,field", MANIFEST_CASES)
def test_a_damaged_manifest_config_is_one_data_error_naming_the_manifest_and_the_field(change, field, store,
                                                                                       tmp_path):
    path = damaged(store, tmp_path, change)
    with pytest.raises(DataError, match="regenerate the store") as e:
        data.read_manifest(path)
    assert str(path / "manifest.json") in str(e.value) and field in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("change,field", MANIFEST_CASES[:4])
def test_stats_and_certify_refuse_a_damaged_manifest_before_any_work(change, field, store, tmp_path, capsys,
                                                                     monkeypatch):
    path = damaged(store, tmp_path, change)
    monkeypatch.setattr(generate, "simulate", lambda *a, **k: pytest.fail("simulated from a damaged manifest"))
    for args in (["stats", str(path)], ["certify", "--preset", "tiny", str(path), "--fit-episodes", "8"]):
        code, err = cli(args, capsys)
        assert code == 2 and field in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in path.iterdir()) == ["data.h5", "manifest.json"]


def test_a_valid_manifest_cannot_ask_certify_for_an_oversized_certificate_corpus(store, tmp_path, capsys, monkeypatch):
    path = damaged(store, tmp_path, physics("image_size", 1024))  # in range, but 3,840 such episodes are 243 GiB
    monkeypatch.setattr(generate, "simulate", lambda *a, **k: pytest.fail("simulated an oversized corpus"))
    code, err = cli(["certify", "--preset", "tiny", str(path), "--fit-episodes", "3840"], capsys)
    assert code == 2 and "GiB" in err and len(err.strip().splitlines()) == 1


def test_manifests_are_bounded_at_what_a_real_one_needs(store, tmp_path):
    assert (store / "manifest.json").stat().st_size < 8 << 10 and data.MAX_MANIFEST_BYTES <= 16 << 20
    path = damaged(store, tmp_path, lambda m: m.__setitem__("padding", "x" * data.MAX_MANIFEST_BYTES))
    with pytest.raises(DataError, match="at most"):
        data.read_manifest(path)


# ------------------------------------------------------------------ fuzzing both
def leaves(config: dict, prefix: tuple = ()) -> list[tuple]:
    """Every field path of a manifest's config (into physics, ranges and policy)."""
    out = []
    for key, value in config.items():
        out += leaves(value, (*prefix, key)) if isinstance(value, dict) else [(*prefix, key)]
    return out


ANY_VALUE = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70), st.sampled_from([-1, 0, 1, 3, 2**32]),
                      st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=4),
                      st.lists(st.one_of(st.integers(-5, 10**12), st.floats(allow_nan=True)), max_size=4),
                      st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


@FUZZ
@given(pick=st.integers(0, 10**6), value=ANY_VALUE, whole=st.sampled_from([False] * 9 + [True]))
def test_any_value_in_a_manifest_config_is_accepted_within_bounds_or_one_data_error(store, tmp_path_factory, pick,
                                                                                      value, whole):
    man = json.loads((store / "manifest.json").read_text())
    paths = leaves(man["config"])
    if whole:
        man["config"] = value
    else:
        *parents, key = paths[pick % len(paths)]
        node = man["config"]
        for p in parents:
            node = node[p]
        node[key] = value
    path = tmp_path_factory.mktemp("fuzz")
    (path / "data.h5").write_bytes(b"")  # read_manifest checks the manifest only
    (path / "manifest.json").write_text(json.dumps(man))
    start = time.monotonic()
    try:
        read = data.read_manifest(path)
    except DataError as e:
        assert "\n" not in str(e) and "regenerate the store" in str(e)
    else:  # accepted: a config whose store is bounded
        cfg = generate.generator_config(read)
        assert generate.store_bytes(cfg.num_episodes, cfg.episode_steps, cfg.physics.image_size) <= \
            data.MAX_STORE_BYTES and cfg.physics.substeps <= 1000
    assert time.monotonic() - start < 5


NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-2**64, 2**64),
                    st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -1.0, 0, 0.0, 1, 2**31, 10**12]))


def numeric_fields(cls) -> list[str]:
    hints = typing.get_type_hints(cls)
    return [f.name for f in dataclasses.fields(cls) if hints[f.name] in (int, float)]


GENERATE_FIELDS = [((), n) for n in numeric_fields(generate.GenerateConfig)] + \
    [((group,), n) for group, cls in (("physics", PhysicsConfig), ("policy", PolicyConfig), ("ranges", ParamRanges))
     for n in numeric_fields(cls)]


@FUZZ
@given(where=st.sampled_from(GENERATE_FIELDS), value=NUMBERS)
def test_any_generate_number_gives_a_valid_config_or_one_config_error(where, value):
    (group, name) = where
    overrides = {group[0]: {name: value}} if group else {name: value}
    try:
        cfg = generate.make_config("tiny", **overrides)
    except ConfigError as e:
        assert "\n" not in str(e)
    else:
        held = getattr(getattr(cfg, group[0]) if group else cfg, name)
        assert math.isfinite(held) and not (isinstance(value, float) and math.isnan(value))


@FUZZ
@given(name=st.sampled_from(numeric_fields(TrainConfig)), value=NUMBERS)
def test_any_train_number_gives_a_valid_config_or_one_config_error(name, value):
    try:
        cfg = make_train_config("tiny", **{name: value})
    except ConfigError as e:
        assert "\n" not in str(e)
    else:
        assert math.isfinite(getattr(cfg, name))


# ------------------------------------------------------------------ the mechanism covers every command's numbers
COMMAND_CONFIGS = [generate.GenerateConfig, PhysicsConfig, ParamRanges, PolicyConfig, TrainConfig, StackedConfig,
                   CertifyConfig, CurveConfig, MeasureConfig, MapConfig, PairsConfig, PlanConfig]


@pytest.mark.parametrize("cls", COMMAND_CONFIGS, ids=lambda c: c.__name__)
def test_every_numeric_field_of_every_command_config_declares_its_range(cls):
    limits = {k: v for klass in reversed(cls.__mro__) for k, v in vars(klass).get("LIMITS", {}).items()}
    hints = typing.get_type_hints(cls)
    numeric = [f.name for f in dataclasses.fields(cls)
               if hints[f.name] in (int, float) or (typing.get_origin(hints[f.name]) is tuple
                                                    and set(typing.get_args(hints[f.name])) & {int, float})]
    assert numeric and not set(numeric) - set(limits), sorted(set(numeric) - set(limits))


def test_wrong_types_from_a_file_are_one_config_error():
    for bad in ({"physics": {"dt": "x"}}, {"policy": 5}, {"ranges": {"gain": "ab"}}, {"seed": True},
                {"split_fractions": [0.5, 0.5]}):
        with pytest.raises(ConfigError) as e:
            from_dict(generate.GenerateConfig, bad)
        assert "\n" not in str(e.value)
