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
    assert line == "runs: 1 of 2 trained, 1 of 2 measured; a 30/90 steps, 1 steps/s, ~1 min 00 s left"


def test_runs_progress_counts_a_run_being_measured_as_trained(tmp_path):
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "DONE").write_text("")
    line = progress.runs_progress({"b": (tmp_path / "b", 90), "c": (tmp_path / "c", 90)})
    assert line == "runs: 1 of 2 trained, 0 of 2 measured; b trained, being measured | c waiting"


def test_launch_reports_the_workers_training(tmp_path):
    run = tmp_path / "r"
    _metrics(run, [{"step": 5, "steps_per_s": 5.0}])
    status = training_status([{"name": "r", "train": {"out": str(run), "steps": 10}}])
    assert status() == "runs: 0 of 1 trained, 0 of 1 measured; r 5/10 steps, 5 steps/s, ~1 s left"
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


class FakeClock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def test_the_whole_job_estimate_weighs_stages_by_cost_and_follows_this_machine_s_pace():
    clock = FakeClock()
    job = progress.JobEstimate({"corpus": 10, "gru": 100, "linear": 1, "train": 300}, now=clock)
    assert job.left() == 411 and job.fraction() == 0
    job.begin("corpus")
    clock.t += 20  # twice the prediction: the machine is at half speed
    line = job.end("corpus")
    assert line.startswith("corpus took 20 s (predicted 10 s); whole job 2% done")
    assert job.pace() == 2.0 and job.left() == 2 * 401
    job.begin("gru")
    clock.t += 100  # half of gru at this pace: progress by cost, not by stage count (1 of 4 would read 25 %)
    assert job.fraction() == (10 + 50) / 411
    clock.t += 200  # gru ran past even the slowed prediction: the pace grows while it runs
    assert job.pace() == (20 + 300) / (10 + 100) and job.left() == job.pace() * 301
    job.end("gru")
    job.skip("linear")  # found done: counts as done, leaves the pace alone
    assert job.pace() == (20 + 300) / 110 and job.fraction() == 111 / 411
    job.begin("train")
    clock.t += 300
    job.end("train")
    assert job.left() == 0 and job.fraction() == 1
    assert job.total() == "in 10 min 20 s (estimated at the start: 6 min 51 s)"  # 20 + 300 + 300 s


def test_a_fast_machine_shortens_the_estimate_and_heartbeats_carry_it(capsys):
    clock = FakeClock()
    job = progress.JobEstimate({"a": 100, "b": 100}, now=clock)
    with progress.whole_job(job):
        with progress.stage("a", "map"):
            clock.t += 50
        assert "[map] a took 50 s (predicted 1 min 40 s); whole job 50% done, ~50 s left" in capsys.readouterr().out
        with progress.stage("not a stage of the job", "certify"):  # a stage the job does not know: silent
            clock.t += 5
        assert capsys.readouterr().out == ""
        with progress.heartbeat("certify", "fitting", every=0.03):
            time.sleep(0.1)
        assert "; whole job 50% done, ~50 s left" in capsys.readouterr().out
    with progress.stage("b", "map"):  # no job any more: nothing is timed or said
        pass
    assert capsys.readouterr().out == "" and "b" not in job.taken


def test_the_demo_estimates_its_whole_job_from_its_stages():
    from pokeworld.experiments.presets import DEMO_REFERENCE_S_PER_STEP, DEMO_STAGE_SECONDS, make_demo_config

    c = make_demo_config("cpu", out="unused")
    assert c.whole_job_estimate
    timed = {"seconds": 300.0, "rates": [2 * DEMO_REFERENCE_S_PER_STEP], "runs": 4, "threads": 1, "workers": 2}
    costs, slow = stages.whole_job_costs(c, ["standard"], ["standard"], timed)
    assert slow == 2.0
    names = list(costs)
    assert names[0] == "corpus standard" and names[-2:] == ["training and measurement", "report"]
    gru = [n for n in names if n.startswith("certificate gru ")]
    # the reference cost, at this machine's (timed) slowdown
    assert len(gru) == 1 and costs[gru[0]] == 2.0 * DEMO_STAGE_SECONDS["certificate gru"]
    assert costs["training and measurement"] > 300.0  # measurement inside the estimate
    line = stages.whole_job_line(progress.JobEstimate(costs), timed, slow)
    assert "2.0x the reference machine's; the whole job takes about " in line and "certificate " in line


def test_a_stage_that_reports_its_work_is_estimated_at_its_own_rate(tmp_path):
    clock = FakeClock()
    job = progress.JobEstimate({"certify": 100, "train": 1000, "report": 10}, now=clock)
    job.covers["train"] = 0.9  # training is 90 % of the stage; measuring the runs the rest
    job.begin("certify")
    clock.t += 200  # at half the predicted speed
    job.end("certify")
    with progress.whole_job(job):
        job.begin("train")
        clock.t += 300
        assert job.left() == 2 * 1000 - 300 + 2 * 10  # no report yet: the prediction at this pace
        _metrics(tmp_path / "a", [{"step": 50}])
        _metrics(tmp_path / "b", [{"step": 50}])
        runs = {"a": (tmp_path / "a", 100), "b": (tmp_path / "b", 100)}
        assert progress.runs_fraction(runs) == 0.5
        progress.report("train", progress.runs_fraction(runs))  # the runs train faster than predicted
    assert job.fraction() == (100 + 1000 * 0.45) / 1110
    assert job.left() == 300 * 0.55 / 0.45 + 2 * 10  # the stage at its own rate, the rest at the pace
    progress.report("train", 1.0)  # no job any more: ignored
    assert job.done_share["train"] == 0.45
