"""Every ``pokeworld`` command line of the README runs as written, and every row of the command table in
docs/commands.md runs as written (with ``--preset tiny`` and tiny paths), so both stay true; the positional forms
the table uses are the ones each command's usage line shows.

One generated store and two trained runs are shared by all rows (module fixture). Rows that need the swm extra or
RH20T data, and the two whole-pipeline rows that take most of a minute even at tiny, are skipped with the reason
and the test that covers them instead; a new row is run unless it is added to SKIPPED.
"""

from __future__ import annotations

import importlib
import re
import shlex
from pathlib import Path

import pytest

from pokeworld.cli import COMMANDS, _flag_arity, command_prog, main, split_args

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
COMMANDS_PAGE = ROOT / "docs" / "commands.md"

SKIPPED = {
    "certify-curve": "certifies at several corpus sizes, a minute even at tiny; tests/test_certificate_corpus.py",
    "map": "the whole pipeline, most of a minute at tiny; tests/test_map.py runs the tiny map",
    "demo": "the whole pipeline, most of a minute at tiny; tests/test_map.py runs the tiny map",
    "swm-collect": "needs the swm extra; tests/swm/ runs the bridge in .venv-swm",
    "swm-certify": "needs the swm extra; tests/swm/test_certify_env.py runs it at tiny in .venv-swm",
    "rh20t-convert": "needs RH20T data; tests/test_rh20t*.py convert synthetic scenes",
    "rh20t-synth": "writes RH20T-layout videos, ten seconds and more at tiny; tests/test_rh20t_synth.py",
    "real": "needs converted RH20T stores; tests/test_real.py",
    "real-eval": "needs a converted RH20T store; tests/test_real.py",
}


def table_commands() -> list[str]:
    """The command line of each row of the command table in docs/commands.md (its first code span)."""
    return [m[1] for m in re.finditer(r"^\| `(pokeworld [^`]+)`", COMMANDS_PAGE.read_text(), re.M)]


def readme_command_lines() -> list[str]:
    """Every ``pokeworld`` command in the README's shell blocks, in order (``&&`` chains split, continuations
    joined)."""
    blocks = re.findall(r"```bash\n(.*?)```", README.read_text(), re.S)
    commands = []
    for block in blocks:
        text = block.replace("\\\n", " ")
        for line in text.splitlines():
            commands += [c.strip() for c in line.split("#", 1)[0].split("&&") if c.strip().startswith("pokeworld ")]
    return commands


def test_readme_commands_run_in_order(tmp_path, monkeypatch, capsys):
    """The README's own lines, as a newcomer types them in an empty folder (the demo is tests/test_map.py's)."""
    lines = readme_command_lines()
    assert "pokeworld demo" in lines and len(lines) >= 5, lines
    monkeypatch.chdir(tmp_path)
    for line in lines:
        if line == "pokeworld demo":
            continue
        assert main(shlex.split(line)[1:]) == 0, line
        last = capsys.readouterr().out.strip().splitlines()[-1]
        assert last.startswith("[") and ("wrote" in last or "→" in last), (line, last)


ROWS = table_commands()


def test_the_table_is_found_and_every_skip_names_a_row():
    names = [shlex.split(c)[1] for c in ROWS]
    assert {"generate", "train", "probe", "plan", "stats", "certify"} <= set(names)
    assert set(SKIPPED) <= set(names)


@pytest.fixture(scope="module")
def shared(tmp_path_factory):
    """A tiny store and two tiny trained runs (V and VFX, both with the Δ = 4 / 16 heads the planner reads)."""
    root = tmp_path_factory.mktemp("readme")
    store, run_a, run_b = root / "store", root / "runs" / "VFX", root / "runs" / "V"
    assert main(["generate", "--preset", "tiny", str(store)]) == 0
    assert main(["train", "--preset", "tiny", "--data", str(store), "--out", str(run_a)]) == 0
    assert main(["train", "--preset", "tiny", "--variant", "V", "--data", str(store), "--out", str(run_b)]) == 0
    return {"root": root, "DIR": str(store), "RUN": str(run_a), "RUN1": str(run_a), "RUN2": str(run_b)}


def concrete(line: str, shared: dict, fresh: Path) -> list[str]:
    """``line``'s arguments with ``--preset tiny`` and the shared paths; what the row writes goes to ``fresh``."""
    name, *args = shlex.split(line)[1:]
    writes_store = name == "generate"
    out = []
    for prev, tok in zip([name, *args], args):
        if prev == "--preset":
            tok = "tiny"
        elif tok in ("OUT", "ROOT") or prev == "--out" or (writes_store and tok == "DIR"):
            tok = str(fresh / tok.lower())
        elif tok in shared:
            tok = shared[tok]
        elif tok.startswith("docs/"):  # a committed record the row reads, wherever pytest runs from
            tok = str(ROOT / tok)
        out.append(tok)
    if COMMANDS[name].make and "--preset" not in out:
        out = ["--preset", "tiny", *out]
    return [name, *out]


@pytest.mark.parametrize("line", ROWS, ids=[shlex.split(r)[1] for r in ROWS])
def test_readme_command_runs(line, shared, tmp_path, capsys):
    name = shlex.split(line)[1]
    if name in SKIPPED:
        pytest.skip(SKIPPED[name])
    argv = concrete(line, shared, tmp_path)
    assert main(argv) == 0, argv
    out = capsys.readouterr().out.strip().splitlines()
    assert out, argv
    last = out[-1]  # every command ends with what it wrote where
    assert last.startswith("[") and ("wrote" in last or "→" in last or "skipping" in last), (argv, last)


@pytest.mark.parametrize("line", ROWS, ids=[shlex.split(r)[1] for r in ROWS])
def test_readme_positional_is_the_one_usage_shows(line):
    name, *args = shlex.split(line)[1:]
    cmd = COMMANDS[name]
    if cmd.positional is None:
        return
    cls = getattr(importlib.import_module(cmd.config_module or cmd.module), cmd.config)
    _, parsed = split_args([a for a in args if a != "[...]"], cmd.positional, _flag_arity(cls))
    flag = f"--{cmd.positional.replace('_', '-')}"
    if flag in parsed and flag not in args:  # the row gives the positional bare: the usage line must name it so
        assert f"[{parsed[parsed.index(flag) + 1]}]" in command_prog(name), (line, command_prog(name))
