"""Long work is never silent (issue #52, item 1): a heartbeat line while a stage runs, the workers' training progress
read from their metrics in the parent, a plan line before a map starts, all silenced by --quiet."""

from __future__ import annotations

import json
import time

from pokeworld import progress
from pokeworld.experiments import stages
from pokeworld.experiments.launch import LaunchOptions, launch, training_status
from pokeworld.experiments.presets import make_config as make_map_config


def _metrics(run, rows):
    run.mkdir(parents=True, exist_ok=True)
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_heartbeat_speaks_while_the_block_runs_and_not_after(capsys):
    state = {"what": "fitting gru"}
    with progress.heartbeat("certify", lambda: state["what"], every=0.05):
        time.sleep(0.18)
        state["what"] = "fitting linear"
        time.sleep(0.12)
    out = capsys.readouterr().out.splitlines()
    assert len(out) >= 3 and all(line.startswith("[certify] still working: fitting ") for line in out)
    assert "fitting gru" in out[0] and "fitting linear" in out[-1] and "so far)" in out[-1]
    time.sleep(0.12)
    assert capsys.readouterr().out == ""  # stopped with the block


def test_quiet_silences_heartbeats(capsys):
    progress.quiet(True)
    try:
        with progress.heartbeat("map", "training", every=0.03):
            time.sleep(0.12)
    finally:
        progress.quiet(False)
    assert capsys.readouterr().out == ""


def test_a_failing_status_never_ends_the_work(capsys):
    with progress.heartbeat("map", lambda: 1 / 0, every=0.03):
        time.sleep(0.1)
    assert "status unavailable: ZeroDivisionError" in capsys.readouterr().out


def test_run_progress_reads_steps_rate_and_time_left(tmp_path):
    run = tmp_path / "VFX"
    assert progress.run_progress("VFX", run, 200) == "VFX waiting"
    _metrics(run, [{"step": 0}, {"step": 100, "steps_per_s": 2.0}])
    assert progress.run_progress("VFX", run, 200) == "VFX 100/200 steps, 2 steps/s, ~50 s left"
    (run / "DONE").write_text("")
    assert progress.run_progress("VFX", run, 200) == "VFX trained, being measured"
    (run / "measure.json").write_text("{}")
    assert progress.run_progress("VFX", run, 200) == "VFX finished"


def test_runs_progress_puts_unfinished_runs_first(tmp_path):
    _metrics(tmp_path / "a", [{"step": 30, "steps_per_s": 1.0}])
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "DONE").write_text("")
    (tmp_path / "b" / "measure.json").write_text("{}")
    line = progress.runs_progress({"a": (tmp_path / "a", 90), "b": (tmp_path / "b", 90)})
    assert line == "training 1/2 runs finished; a 30/90 steps, 1 steps/s, ~1 min 00 s left"


def test_launch_reports_the_workers_training(tmp_path):
    run = tmp_path / "r"
    _metrics(run, [{"step": 5, "steps_per_s": 5.0}])
    status = training_status([{"name": "r", "train": {"out": str(run), "steps": 10}}])
    assert status() == "training 0/1 runs finished; r 5/10 steps, 5 steps/s, ~1 s left"
    assert launch(LaunchOptions(launcher="local", workers=1), [{"x": 1}], lambda j: {"y": j["x"]}) == [{"y": 1}]


def test_map_says_its_plan_first():
    c = make_map_config("tiny", out="unused", experiments=("factorial",), variants=("V", "VFX"), seeds=(0,))
    line = stages.plan_line(c)
    assert line.startswith("[map] plan: ") and "2 runs x " in line and "standard" in line and "--quiet" in line


def test_map_estimates_its_training_from_this_machine(tmp_path):
    c = make_map_config("tiny", out=str(tmp_path / "m"), experiments=("factorial",), variants=("V", "VFX"), seeds=(0,))
    specs = stages.all_specs(c)
    line = stages.training_estimate(c, specs, workers=2, threads=1)
    assert line.startswith("[map] this machine: ") and "s/step per model on 1 thread(s)" in line
    assert "the 2 runs to train take about " in line
    for s in specs:  # once every run is trained there is nothing to estimate
        (tmp_path / "m" / "runs" / s.name).mkdir(parents=True)
        (tmp_path / "m" / "runs" / s.name / "DONE").write_text("")
    assert stages.training_estimate(c, specs, workers=2, threads=1) is None


def test_a_timing_leaves_the_process_as_it_was():
    import torch

    from pokeworld.train import make_config
    from pokeworld.train.speed import seconds_per_step

    threads, state = torch.get_num_threads(), torch.random.get_rng_state()
    assert seconds_per_step(make_config("tiny"), threads=1, steps=1) > 0
    assert torch.get_num_threads() == threads and torch.equal(torch.random.get_rng_state(), state)
