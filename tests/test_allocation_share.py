"""Several runs at once on one GPU (pokeworld.remote.share): the rates read off metrics rows, the
ramp's decisions, the admission against the deadline and the pausing of runs that did not pay, on planted numbers
(the end-to-end path, two tiny runs at once through the lease, is tests/test_gpu_lease.py)."""

import json
import subprocess
import time
from pathlib import Path

from pokeworld.remote.share import Ramp, RunWatch, ShareConfig, SharedRuns, Slot, Throughput


def _rows(folder: Path, rows: list[dict]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "metrics.jsonl", "a") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")


def test_a_rate_is_the_logged_steps_over_their_own_time_once_warm(tmp_path):
    run = tmp_path / "run"
    w = RunWatch("r", run, 20000, 0.0, warm=2)
    # the compilation row, two warm-up rows (slow), then rows at 100 steps/s
    _rows(run, [{"step": 100, "steps_per_s": 1.0}, {"step": 200, "steps_per_s": 10.0},
                {"step": 300, "steps_per_s": 10.0}])
    w.read(0.0)
    assert not w.rows and w.rate(0.0, 10) is None  # nothing counts yet
    for i, t in enumerate((1.0, 2.0, 3.0, 12.0, 13.0)):
        _rows(run, [{"step": 400 + 100 * i, "steps_per_s": 100.0}])
        w.read(t)
    assert w.step() == 800
    # the rows seen in the last 10 s cover 200 steps at 100 steps/s each: exactly 100 steps/s
    assert abs(w.rate(13.0, 10) - 100.0) < 1e-9
    # a run that stopped logging (measuring) has no rate
    assert w.rate(40.0, 10) is None


def test_throughput_is_pessimistic_where_not_measured():
    tp = Throughput(prior_s_per_step=0.01)
    assert tp.total(1) == 100.0 and tp.total(4) == 100.0  # the prior's one run, no gain assumed
    tp.add(1, 130.0)
    tp.add(2, 170.0)
    assert tp.total(2) == 170.0 and tp.total(4) == 170.0 and tp.per_run(4) == 42.5
    assert tp.table() == {"1": 130.0, "2": 170.0}


def test_the_ramp_doubles_while_it_pays_and_settles_at_the_best_level():
    cfg = ShareConfig(most=8, gain=1.08, samples=2)
    tp, ramp = Throughput(0.01), Ramp(cfg)
    assert ramp.target == 1 and ramp.update(tp) == ""  # nothing measured: no decision
    tp.add(1, 100.0)
    assert ramp.update(tp) == ""  # one sample is not enough
    tp.add(1, 100.0)
    assert "trying 2" in ramp.update(tp) and ramp.target == 2
    tp.add(2, 150.0), tp.add(2, 150.0)
    assert "trying 4" in ramp.update(tp) and ramp.target == 4
    tp.add(4, 140.0), tp.add(4, 140.0)  # four at once is worse than two: back to two, settled
    line = ramp.update(tp)
    assert ramp.settled and ramp.target == 2 and "keeping 2" in line
    tp.add(2, 1000.0)
    assert ramp.update(tp) == "" and ramp.target == 2


def test_the_ramp_stops_at_the_most_allowed():
    cfg = ShareConfig(most=2, samples=1)
    tp, ramp = Throughput(0.01), Ramp(cfg)
    tp.add(1, 100.0)
    ramp.update(tp)
    tp.add(2, 190.0)
    assert "the most allowed" in ramp.update(tp) and ramp.settled and ramp.target == 2
    assert Ramp(ShareConfig(most=1)).settled  # one at a time: no ramp


def _shared(tmp_path, deadline_s: float, overhead_s: float = 10.0) -> SharedRuns:
    return SharedRuns(ShareConfig(most=4, samples=1), time.time() + deadline_s, overhead_s, 0.01,
                      start_step=lambda job: 0, finished=lambda job, result, training: None)


def _job(tmp_path, name: str, steps: int = 1000) -> dict:
    return {"name": name, "train_preset": "tiny", "train": {"out": str(tmp_path / name), "steps": steps}}


def test_a_run_that_cannot_finish_even_alone_is_not_started_and_one_that_would_slow_others_waits(tmp_path):
    import pokeworld.remote.share as share

    now = time.time()
    # 1000 steps at the prior's 100 steps/s: 10 s + 10 s of overhead
    s = _shared(tmp_path, 15.0)
    assert "even alone" in s.admit(_job(tmp_path, "a"), now)
    s = _shared(tmp_path, 60.0)
    assert s.admit(_job(tmp_path, "a"), now) == "go"
    # a run training with 4,000 steps left: with the total flat at 100 steps/s, the newcomer's 1,000 more steps make
    # 50 s of work and 10 s of overhead: over the 60 s left, so it waits; with 200 s left it goes
    s.ramp.target = 2
    w = RunWatch("b", tmp_path / "b", 5000, now)
    w.first_step = 1000
    s.slots.append(Slot(_job(tmp_path, "b", 5000), w, process=None, conn=None, started_at_step=0))
    assert s.admit(_job(tmp_path, "a"), now) == "wait"
    s.deadline = now + 200
    assert s.admit(_job(tmp_path, "a"), now) == "go"
    assert share  # the module under test


class _Proc:
    def __init__(self, popen):
        self.pid = popen.pid


def _state(pid: int) -> str:
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]


def test_runs_beyond_the_settled_level_are_paused_and_resumed_as_others_end(tmp_path):
    s = _shared(tmp_path, 600.0)
    procs = [subprocess.Popen(["sleep", "60"]) for _ in range(3)]
    try:
        for i, p in enumerate(procs):
            s.slots.append(Slot(_job(tmp_path, f"r{i}"), RunWatch(f"r{i}", tmp_path / f"r{i}", 1000, 0.0),
                                _Proc(p), None, 0))
        s.ramp.target, s.ramp.settled = 1, True  # more than one at once did not pay
        s.balance()
        assert [x.paused for x in s.slots] == [False, True, True]
        time.sleep(0.2)
        assert [_state(p.pid) for p in procs] == ["S", "T", "T"]
        assert s.admit(_job(tmp_path, "new"), time.time()) == "wait"  # paused runs go first
        s.slots.pop(0)  # the training one ended: the oldest paused one resumes, the other stays paused
        s.balance()
        assert [x.paused for x in s.slots] == [False, True]
        time.sleep(0.2)
        assert [_state(p.pid) for p in procs[1:]] == ["S", "T"]
    finally:
        for p in procs:
            p.kill()
            p.wait()


def test_finish_times_play_the_work_out_at_the_measured_rates():
    from pokeworld.remote.share import finish_times

    tp = Throughput(0.01)
    tp.add(1, 100.0)
    tp.add(2, 150.0)
    # alone: 10 s of overhead, then 1,000 steps at 100 steps/s
    assert finish_times([(1000, 10.0)], tp, 4) == [20.0]
    # two at once share 150 steps/s (75 each): the first ends its 750 steps at 10 s, the second runs alone
    # after it (250 steps left at 100 steps/s)
    a, b = finish_times([(750, 0.0), (1000, 0.0)], tp, 4)
    assert abs(a - 10.0) < 1e-9 and abs(b - 12.5) < 1e-9
    # at most one at once: the second waits for the first
    a, b = finish_times([(750, 0.0), (1000, 0.0)], tp, 1)
    assert abs(a - 7.5) < 1e-9 and abs(b - 17.5) < 1e-9
    # more at once than measured: no gain assumed beyond the best measured total
    assert abs(max(finish_times([(1500, 0.0)] * 4, tp, 4)) - 40.0) < 1e-9
    assert finish_times([(0, 0.0)], tp, 4) == [0.0] and finish_times([], tp, 4) == []
