"""Long work is never silent: a heartbeat line while a stage runs, the workers' training progress
read from their metrics in the parent, a plan line before a map starts, all silenced by --quiet; and the demo's
whole-job estimate, kept within twice the true total while a stage stalls, with progress that advances."""

from __future__ import annotations

import functools
import json
import time

import pytest

from pokeworld import certify, progress
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


def test_an_overrunning_stage_lengthens_the_estimate_by_its_own_overrun_only():
    clock = FakeClock()
    job = progress.JobEstimate({"corpus": 10, "gru": 100, "linear": 1, "train": 300}, now=clock)
    assert job.left() == 411 and job.fraction() == 0
    job.begin("corpus")
    clock.t += 20  # twice its prediction
    line = job.end("corpus")
    assert line.startswith("corpus took 20 s (predicted 10 s); whole job 5% done")
    assert job.left() == 401  # the stages ahead keep their predictions: the corpus's overrun is its own
    job.begin("gru")
    clock.t += 25  # within half its prediction: the prediction's remainder
    assert job.running_left() == 75
    clock.t += 275  # three times its prediction, reporting nothing: a remainder that shrinks but stays
    assert job.running_left() == progress.predicted_left(100, 300) == 100 * 3 / 11
    assert job.left() == 301 + 100 * 3 / 11
    job.end("gru")
    job.skip("linear")  # found done: costs nothing
    assert job.left() == 300
    job.begin("train")
    clock.t += 300
    job.end("train")
    assert job.left() == 0 and job.fraction() == 1
    assert job.total() == "in 10 min 20 s (estimated at the start: 6 min 51 s)"  # 20 + 300 + 300 s


def test_predicted_left_never_reaches_zero_and_never_grows():
    left = [progress.predicted_left(40, t) for t in range(0, 400)]
    assert left[0] == 40 and left[20] == 20 and all(a >= b > 0 for a, b in zip(left, left[1:]))
    assert abs(progress.predicted_left(40, 1e6) - 10) < 1e-3  # a quarter of the prediction in the limit


def test_a_stage_s_rate_is_the_median_of_its_latest_intervals():
    rate = progress.StageRate(begun=0.0)
    assert rate.left(0.0) is None
    rate.report(10.0, 0.1)  # the first interval holds the set-up: counted until another exists
    assert rate.left(10.0) == 100 * 0.9 and rate.left(20.0) == 100 * 0.9 - 10  # counted down between reports
    for t, share in ((12.0, 0.2), (14.0, 0.3), (314.0, 0.4), (316.0, 0.5)):  # one interval holds a 300-s stall
        rate.report(t, share)
    rate.report(318.0, 0.5)  # no progress: nothing measured
    assert rate.left(316.0) == pytest.approx(20 * 0.5)  # 2 s per tenth, the stall outvoted
    assert rate.left(1000.0) > 20 * 0.5 / 4  # a stall never counts it down to nothing


def test_heartbeats_carry_the_estimate(capsys):
    clock = FakeClock()
    job = progress.JobEstimate({"a": 100, "b": 100}, now=clock)
    with progress.whole_job(job):
        with progress.stage("a", "map"):
            clock.t += 50
        assert "[map] a took 50 s (predicted 1 min 40 s); whole job 33% done, ~1 min 40 s left" \
            in capsys.readouterr().out
        with progress.stage("not a stage of the job", "certify"):  # a stage the job does not know: silent
            clock.t += 5
        assert capsys.readouterr().out == ""
        with progress.heartbeat("certify", "fitting", every=0.03):
            time.sleep(0.1)
        assert "; whole job 35% done, ~1 min 40 s left" in capsys.readouterr().out
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
    assert "2.0× slower than the reference machine; the whole job takes about " in line and "certificate " in line


def test_the_machine_s_speed_is_said_as_slower_or_faster():
    assert stages.relative_speed(2.6) == "2.6× slower than the reference machine"
    assert stages.relative_speed(0.5) == "2.0× faster than the reference machine"
    assert stages.relative_speed(1.02) == "as fast as the reference machine"


def test_a_stage_that_reports_its_work_is_estimated_at_its_own_rate(tmp_path):
    clock = FakeClock()
    job = progress.JobEstimate({"certify": 100, "train": 1000, "report": 10}, now=clock)
    job.covers["train"] = 0.9  # training is 90 % of the stage; measuring the runs the rest
    job.begin("certify")
    clock.t += 200
    job.end("certify")
    with progress.whole_job(job):
        job.begin("train")
        clock.t += 300
        assert job.left() == 1000 - 300 + 10  # no report yet: its prediction
        _metrics(tmp_path / "a", [{"step": 50}])
        _metrics(tmp_path / "b", [{"step": 50}])
        runs = {"a": (tmp_path / "a", 100), "b": (tmp_path / "b", 100)}
        assert progress.runs_fraction(runs) == 0.5
        progress.report("train", progress.runs_fraction(runs))  # the runs train faster than predicted
    assert job.left() == 300 * 0.55 / 0.45 + 10  # the stage at its own rate, the report at its prediction
    progress.report("train", 1.0)  # no job any more: ignored
    assert job.rate.share == 0.45


# ---------------------------------------------------------------------------------------------- a planted job
GRU = certify.certify_stage("out/demo/data/standard", "contact", "gru")
GRU_GEOM = certify.certify_stage("out/demo/data/standard", "contact", "gru_geom")
TRAINING = "training and measurement"
PLANTED_COSTS = {"corpus standard": 26.0, GRU: 44.0, GRU_GEOM: 39.0, "certificate linear": 2.6,
                 "certificate drag": 2.6, TRAINING: 600.0, "report": 13.0}
"""The demo's stage predictions on a machine whose timed step is 2.6× the reference's."""


class SteppingClock(FakeClock):
    """A fake clock that moves a second at a time and, at every second, reads the job's estimate as a heartbeat
    would: (elapsed, estimated total, share done)."""

    def __init__(self):
        super().__init__()
        self.job: progress.JobEstimate | None = None
        self.seen: list[tuple[float, float, float]] = []

    def advance(self, seconds: float) -> None:
        end = self.t + seconds
        while self.t < end:
            self.t = min(end, self.t + 1.0)
            elapsed = self.t - self.job.started
            self.seen.append((elapsed, elapsed + self.job.left(), self.job.fraction()))


class PlantedFit:
    """A certificate's GRU fit on the stepping clock: improves for ``best`` epochs, stops ``patience`` epochs
    later, ``epoch_s`` seconds an epoch, and stalls ``stall_s`` seconds after epoch ``stall_after``."""

    def __init__(self, clock, best, patience, epoch_s, stall_after, stall_s, on_epoch):
        self.clock, self.best, self.patience, self.epoch_s = clock, best, patience, epoch_s
        self.stall_after, self.stall_s, self.on_epoch = stall_after, stall_s, on_epoch

    def fit(self):
        self.clock.advance(3.0)  # the windows' features, before the first epoch
        for epoch in range(1, self.best + self.patience + 1):
            self.clock.advance(self.epoch_s)
            if epoch == self.stall_after:
                self.clock.advance(self.stall_s)
            self.on_epoch(epoch, max(0, epoch - self.best))


class FakeCPU:
    """This process's CPU seconds on a fake clock: ``share`` CPU seconds per wall second from now on."""

    def __init__(self, clock, share: float = 1.0):
        self.clock, self.share, self.used, self.at = clock, share, 0.0, clock.t

    def __call__(self) -> float:
        self.used += self.share * (self.clock.t - self.at)
        self.at = self.clock.t
        return self.used

    def set(self, share: float) -> None:
        self()
        self.share = share


def run_planted_job(clock: SteppingClock, stalled: str, stall_s: float, cpu: FakeCPU | None = None) -> float:
    """The demo's stages on ``clock``, ``stalled`` stopping for ``stall_s`` seconds half-way; its true total. With
    ``cpu`` the estimate also measures the CPU share (at the timing's share: nobody else came)."""
    cfg = certify.make_config("cpu", epochs=60, separate_targets=False)
    contention = progress.Contention(1.0, elsewhere=(TRAINING,), cpu=cpu, now=clock, threads=lambda: 1) if cpu else None
    job = clock.job = progress.JobEstimate(PLANTED_COSTS, now=clock, contention=contention)
    job.covers[TRAINING] = 0.85
    pause = {name: stall_s if name == stalled else 0.0 for name in PLANTED_COSTS}
    with progress.whole_job(job):
        with progress.stage("corpus standard", "map"):
            clock.advance(30.0 + pause["corpus standard"])
        for name, best, epoch_s in ((GRU, 18, 2.5), (GRU_GEOM, 12, 2.2)):
            with progress.stage(name, "certify"):  # certify's own path: its regressors report their epochs
                make = certify.epoch_reporting(functools.partial(PlantedFit, clock, best, cfg.patience, epoch_s,
                                                                 8, pause[name]), name, 1, cfg)
                make().fit()
        for name, seconds in (("certificate linear", 4.0), ("certificate drag", 3.0)):
            with progress.stage(name, "certify"):
                clock.advance(seconds)
        with progress.stage(TRAINING, "map"):
            for beat in range(1, 25):  # 720 s of training, its steps read every 30 s as the heartbeat does
                clock.advance(30.0 + (pause[TRAINING] if beat == 12 else 0.0))
                progress.report(TRAINING, beat / 24)
            clock.advance(110.0)  # measuring the runs, which reports nothing
        with progress.stage("report", "map"):
            clock.advance(15.0)
    return clock.t - job.started


@pytest.mark.parametrize("measured_share", [False, True])
@pytest.mark.parametrize("stalled", [GRU, TRAINING, "corpus standard"])
def test_a_planted_job_whose_stage_stalls_stays_within_twice_its_true_total(stalled, measured_share, capsys):
    """A stage that stalls (its process waiting, or working longer than predicted at a full core) lengthens the
    estimate by its own overrun only, with or without the CPU share measured."""
    clock = SteppingClock()
    true_total = run_planted_job(clock, stalled, stall_s=300.0, cpu=FakeCPU(clock) if measured_share else None)
    estimates = [total for _, total, _ in clock.seen]
    assert true_total / 2 <= min(estimates) and max(estimates) <= 2 * true_total, (true_total, min(estimates),
                                                                                 max(estimates))
    assert clock.job.left() == 0 and clock.job.fraction() == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("[map] corpus standard took ") and lines[-1].startswith("[map] report took ")


def test_progress_advances_within_a_stage():
    clock = SteppingClock()
    run_planted_job(clock, GRU, stall_s=300.0)
    shares = [share for _, _, share in clock.seen]
    assert all(a <= b for a, b in zip(shares, shares[1:])) and clock.job.fraction() == 1.0  # never back
    # within the stalled GRU certificate (from 33 s to about 6 min 30 s) progress never stands still for a heartbeat
    inside = [share for elapsed, _, share in clock.seen if 40 <= elapsed <= 380]
    assert all(b > a for a, b in zip(inside, inside[30:]))


def test_a_certificate_fit_reports_its_epochs():
    import numpy as np

    from pokeworld.regressors import TorchRegressor

    seen = []
    rng = np.random.default_rng(0)
    X, groups = rng.normal(size=(60, 4, 3)), np.repeat(np.arange(12), 5)
    TorchRegressor("gru", hidden=4, layers=1, epochs=6, patience=2,
                   on_epoch=lambda e, stale: seen.append((e, stale))).fit(X, X[:, -1, :1], groups)
    assert [e for e, _ in seen] == list(range(1, len(seen) + 1))
    assert seen[-1][0] == 6 or seen[-1][1] == 2  # the cap or early stopping ended it


def test_a_machine_that_others_come_to_share_after_the_timing_lengthens_every_stage_ahead():
    """Timed at a full core, then other work takes three quarters of the CPU: every stage takes 4× its prediction.
    Once the stage running here has run 10 s at a quarter share, the estimate holds the stages ahead at 4× and stays
    within twice the true total from there on; without the share measured it reads a quarter of it."""
    for measured in (True, False):
        clock = SteppingClock()
        cpu = FakeCPU(clock, share=0.25)  # the others arrived just after the timing
        contention = progress.Contention(1.0, elsewhere=("train",), cpu=cpu, now=clock, threads=lambda: 1)
        job = clock.job = progress.JobEstimate({"certify": 100.0, "train": 600.0, "report": 10.0}, now=clock,
                                               contention=contention if measured else None)
        with progress.whole_job(job):
            with progress.stage("certify", "map"):
                clock.advance(400.0)
            with progress.stage("train", "map"):
                for beat in range(1, 81):  # 2,400 s of training, its steps read every 30 s
                    clock.advance(30.0)
                    progress.report("train", beat / 80)
            with progress.stage("report", "map"):
                clock.advance(40.0)
        true_total = clock.t - job.started
        late = [total for elapsed, total, _ in clock.seen if elapsed >= 15]
        if measured:
            assert all(true_total / 2 <= t <= 2 * true_total for t in late), (true_total, min(late), max(late))
            assert contention.slowdown() == pytest.approx(4.0)
        else:
            assert min(late) < true_total / 2


def test_a_machine_that_others_leave_after_the_timing_shortens_the_estimate():
    clock = FakeClock()
    cpu = FakeCPU(clock, share=0.5)
    contention = progress.Contention(0.5, cpu=cpu, now=clock, threads=lambda: 2)
    contention.begin("a")
    clock.t += 20
    assert contention.slowdown() == pytest.approx(2.0)  # two threads at half a core each: half the timing's share
    contention.end("a")
    cpu.set(2.0)
    contention.begin("b")
    clock.t += 5
    assert contention.slowdown() == pytest.approx(2.0)  # too short to read: the last stage's share holds
    clock.t += 20
    assert contention.slowdown() == pytest.approx(0.5)
    contention.end("b")
    contention.begin("elsewhere")
    assert contention.slowdown() == pytest.approx(0.5)
