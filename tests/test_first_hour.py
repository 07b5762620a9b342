"""What a newcomer meets first: defaults that chain with no paths typed, a closing line from every command (and
a word when it skips), help without reStructuredText markup and with the positional in its usage line, and
outputs that do not read as wrong (the certify gate's comparison, the tiny plan table's note, the plan figure's
legend, the protocol figure's clipped bars)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from pokeworld.cli import COMMANDS, METAVARS, closing_line, main, plain_text, usage

MARKUP = re.compile(r"``|:[a-z]+:`")


def run_cli(argv, capsys) -> list[str]:
    assert main(argv) == 0, argv
    return capsys.readouterr().out.strip().splitlines()


def test_generate_train_probe_plan_chain_with_no_paths_and_each_says_what_it_wrote(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert run_cli(["generate", "--preset", "tiny"], capsys)[-1].endswith("to data/pokeworld")
    trained = run_cli(["train", "--preset", "tiny"], capsys)[-1]
    assert re.fullmatch(r"\[train\] VFX: 10 steps, loss \d+\.?\d* → runs/xjepa/final\.pt", trained), trained
    assert run_cli(["probe", "--preset", "tiny"], capsys)[-1] == "[probe] wrote runs/xjepa/measure.json"
    planned = run_cli(["plan", "--preset", "tiny"], capsys)
    assert planned[-1].startswith("[plan] wrote ") and planned[-1].endswith("→ out/plan") and "plan.json" in planned[-1]
    assert (tmp_path / "out/plan/plan.md").exists()
    # re-run: nothing recomputed, and each says so instead of printing nothing
    again = run_cli(["train", "--preset", "tiny"], capsys)
    assert again == [f"[train] runs/xjepa was already finished ({trained.split('] ')[1].split(' →')[0]}); "
                     "skipped → runs/xjepa/final.pt"]
    assert "skipping" in run_cli(["generate", "--preset", "tiny"], capsys)[-1]
    assert "up to date" in run_cli(["probe", "--preset", "tiny"], capsys)[-1]


def test_closing_line_names_new_files_or_says_it_skipped(tmp_path):
    import time

    since = time.time() - 0.05
    (tmp_path / "a.json").write_text("{}")
    (tmp_path / "b.md").write_text("")
    assert closing_line("x", None, tmp_path, since) == f"[x] wrote a.json, b.md → {tmp_path}"
    skipped = closing_line("x", None, tmp_path, time.time() + 10)
    assert skipped == f"[x] {tmp_path} is up to date; skipped (nothing recomputed)"
    assert closing_line("x", None, tmp_path / "a.json", since) == f"[x] wrote {tmp_path / 'a.json'}"


@pytest.mark.parametrize("name", list(COMMANDS))
def test_help_has_no_markup_and_its_usage_line_shows_the_positional(name, capsys):
    with pytest.raises(SystemExit) as e:
        main([name, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert not MARKUP.search(out), MARKUP.search(out)
    cmd = COMMANDS[name]
    if cmd.positional:
        metavar = cmd.metavar or METAVARS.get(cmd.positional, cmd.positional.upper())
        assert out.startswith(f"usage: pokeworld {name} [{metavar}]"), out.splitlines()[0]
    assert not MARKUP.search(usage())


def test_lewm_help_lists_its_options_and_how_to_install_the_extra(capsys):
    import importlib.util

    with pytest.raises(SystemExit) as e:
        main(["swm-certify-lewm", "--help"])
    assert e.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "--embed-dim" in out and "--compare-runs" in out
    if importlib.util.find_spec("stable_worldmodel") is None:
        assert "Needs the swm extra, not installed here; in an environment of its own" in out
        assert ".venv-swm/bin/pip install -e '.[swm]'" in out


def test_plain_text_keeps_the_words_of_roles_and_literals():
    assert plain_text("see :func:`make_config` and ``pokeworld train``; :class:`~.loop.Trainee`, "
                      ":data:`pokeworld.train.PRESETS`") == \
        "see make_config and pokeworld train; Trainee, pokeworld.train.PRESETS"


def test_certify_prints_the_comparison_that_holds():
    from pokeworld.certify import format_table

    gate = {"log_m": {"estimator": "linear", "certificate": -0.059, "threshold": 0.4, "passed": False,
                      "oracle": 0.2, "paper_rule_passed": False, "agree": True},
            "log_k": {"estimator": "gru", "certificate": 0.9, "threshold": 0.25, "passed": True,
                      "oracle": 0.9, "paper_rule_passed": True, "agree": True}}
    text = format_table({"estimators": {}, "counts": {}, "gate": gate})
    assert "gate log_m: best estimator linear -0.059 < 0.4 -> FAIL (paper's rule: GRU oracle 0.200 < 0.4 -> FAIL)" \
        in text
    assert "gate log_k: best estimator gru 0.900 >= 0.25 -> PASS (paper's rule: GRU oracle 0.900 >= 0.25 -> PASS)" \
        in text


def test_a_degenerate_plan_table_says_it_is_expected_and_a_normal_one_does_not():
    from pokeworld.plan import table_lines

    row = {"reach": 0.0, "median_improvement": 0.0, "mean_improvement": 0.0, "object_moved": 0.0, "spearman": 0.3,
           "topk_overlap": 0.2, "topk_chance": 0.125, "spread_ratio": 2.0, "within_r2": -5.0}
    assert not any(line.startswith("Note:") for line in table_lines({"VFX": row}))
    for bad in ({"topk_overlap": float("nan")}, {"within_r2": -1700.0}):
        lines = table_lines({"VFX": {**row, **bad}})
        assert lines[-1].startswith("Note:") and "tiny preset" in lines[-1], bad


def test_plan_figure_names_its_markers(tmp_path, monkeypatch):
    import matplotlib.figure

    from pokeworld import plan

    legends = []
    real = matplotlib.figure.Figure.legend
    monkeypatch.setattr(matplotlib.figure.Figure, "legend",
                        lambda self, *a, **k: legends.append(k) or real(self, *a, **k))
    n, t = 2, 5
    path = np.linspace([0.2, 0.2], [0.5, 0.5], t + 1)[None].repeat(n, 0)
    ep = {"object_path": path, "finger_path": path, "distance": np.full((n, t + 1), 0.4)}
    planned = {"episodes": {"random": ep, "V": ep, "VFX": ep}, "setup": {"goal": np.full((n, 2), 0.8)}}
    plan.figure(planned, tmp_path, 0.1)
    labels = {h.get_label() for k in legends for h in k.get("handles", [])}
    assert {"goal region", "object start", "finger path"} <= labels and any("object path" in x for x in labels)


def test_protocol_figure_marks_bars_it_clips(tmp_path, monkeypatch):
    import matplotlib.axes

    from pokeworld import protocol

    texts = []
    real = matplotlib.axes.Axes.text
    monkeypatch.setattr(matplotlib.axes.Axes, "text", lambda self, x, y, s, *a, **k: texts.append(s) or
                        real(self, x, y, s, *a, **k))
    result = {"probes": {"ridge": {"contact": {"log_m": 0.3, "gamma": -1.73, "log_k": 0.2}}},
              "certificates": {"certificate": {"contact": {q: {"r2": 0.9} for q in ("log_m", "gamma", "log_k")}},
                               "estimators": {}, "gate": {}},
              "model": {"name": "m"}}
    protocol.figure(result, tmp_path / "f.png")
    assert "↓-1.73" in texts and (tmp_path / "f.png").exists()
    texts.clear()
    result["probes"]["ridge"]["contact"]["gamma"] = -0.05  # within the axis: nothing to mark
    protocol.figure(result, tmp_path / "g.png")
    assert not any(t.startswith("↓") for t in texts)
