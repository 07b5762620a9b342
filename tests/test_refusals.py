"""Every refusal points to a fix that exists (issue #52, item 2): for each mistake a newcomer makes, the CLI answers
with one line, and every flag that line names is one the command accepts, every `pokeworld X` it names is a
command, and following its advice makes the command run."""

from __future__ import annotations

import importlib
import importlib.util
import re
import shlex

import pytest

from pokeworld.cli import COMMANDS, _flag_arity, main

# (command line, a word the refusal must contain); {d} is a tiny store, {r} a tiny finished run, {f} a plain file,
# {t} a fresh folder
MISTAKES = [
    ("stats {f}", "is a file, not a dataset folder"),
    ("train --preset tiny --data {f} --out {t}/r", "is a file, not a dataset folder"),
    ("train --preset tiny --data {t}/missing --out {t}/r", "does not exist"),
    ("probe {f}", "is a file, not a run folder"),
    ("probe {t}/nonexistent", "does not exist"),
    ("plan {t}/p --runs {t}/nonexistent", "does not exist"),
    ("map --preset tiny --out {f}", "choose another output path"),
    ("demo --out {f}", "choose another output path"),
    ("generate --preset tiny --out {f}", "file"),
    ("certify --preset tiny {t}/missing", "does not exist"),
    ("train --preset tiny --data {d} --out {r} --variant VF", "--"),
    ("swm-collect --out {t}/c.h5", "environment of its own"),
]


def _named_flags(message: str) -> list[str]:
    return sorted(set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*(?:\.[a-z0-9-]+)?", message)))


def _accepted_flags(name: str) -> set[str]:
    cmd = COMMANDS[name]
    cls = getattr(importlib.import_module(cmd.config_module or cmd.module), cmd.config)
    return set(_flag_arity(cls)) | {"--preset", "--help"}


@pytest.fixture(scope="module")
def paths(tmp_path_factory):
    root = tmp_path_factory.mktemp("refusals")
    store, run = root / "store", root / "run"
    assert main(["generate", "--preset", "tiny", "--out", str(store)]) == 0
    assert main(["train", "--preset", "tiny", "--data", str(store), "--out", str(run), "--steps", "4"]) == 0
    notes = root / "notes.txt"
    notes.write_text("a user's notes\n")
    return {"d": str(store), "r": str(run), "f": str(notes), "t": str(root)}


@pytest.mark.parametrize("line, word", MISTAKES, ids=[m[0].split()[0] + "-" + str(i) for i, m in enumerate(MISTAKES)])
def test_a_refusal_is_one_line_and_names_only_fixes_that_exist(line, word, paths, capsys):
    argv = shlex.split(line.format(**paths))
    if argv[0].startswith("swm-") and importlib.util.find_spec("stable_worldmodel") is not None:
        pytest.skip("the swm extra is installed here: nothing to refuse")
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2, (argv, err)
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"pokeworld {argv[0]}: error: "), err
    assert word in lines[0], lines[0]
    unknown = [f for f in _named_flags(lines[0]) if f not in _accepted_flags(argv[0])
               and not any(f in _accepted_flags(c) for c in re.findall(r"`pokeworld ([a-z0-9-]+)", lines[0]))]
    assert not unknown, f"{lines[0]} names flags {argv[0]} does not accept: {unknown}"
    for named in re.findall(r"`pokeworld ([a-z0-9-]+)", lines[0]):
        assert named in COMMANDS, lines[0]


def test_the_store_hash_refusal_names_each_folder_once(paths, tmp_path, capsys):
    import json
    import shutil

    run = shutil.copytree(paths["r"], tmp_path / "run")
    store = tmp_path / "other"
    assert main(["generate", "--preset", "tiny", "--seed", "7", "--out", str(store)]) == 0
    cfg = json.loads((run / "config.json").read_text())
    shutil.rmtree(paths["t"] + "/moved", ignore_errors=True)
    # the run's store now holds other content under the same path
    moved = shutil.move(cfg["data"], paths["t"] + "/moved")
    try:
        shutil.copytree(store, cfg["data"])
        capsys.readouterr()
        assert main(["probe", "--preset", "tiny", str(run)]) == 2
        err = capsys.readouterr().err
        digest = json.loads((store / "manifest.json").read_text())["content_sha256"][:12]
        assert err.count(f"holds {digest}") == 1, err
    finally:
        shutil.rmtree(cfg["data"])
        shutil.move(moved, cfg["data"])


def test_following_the_advice_runs(paths, tmp_path):
    """The advice of the first refusal above (name the dataset folder) makes the command run."""
    assert main(["stats", paths["d"]]) == 0
    assert main(["train", "--preset", "tiny", "--data", paths["d"], "--out", str(tmp_path / "r"), "--steps",
                 "2"]) == 0
