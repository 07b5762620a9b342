"""A map's output folder under crashes and concurrency: a map killed with SIGKILL while training, while measuring
or while writing its results resumes to the same numbers as an uninterrupted one; two maps started together on
one --out never lose a finished run's record."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from pokeworld import experiments as experiment
from pokeworld.experiments.map import MAP_LOCK_REFUSAL

pytestmark = pytest.mark.slow

ARGS = ["--preset", "tiny", "--workers", "1", "--variants", "V"]


def _map(out, *extra, kill_at="", pause_at="", wait=True):
    env = {k: v for k, v in os.environ.items() if k not in ("POKEWORLD_KILL_AT", "POKEWORLD_PAUSE_AT")}
    env.update({"POKEWORLD_KILL_AT": kill_at} if kill_at else {})
    env.update({"POKEWORLD_PAUSE_AT": pause_at} if pause_at else {})
    cmd = [sys.executable, "-m", "pokeworld.cli", "map", str(out), *ARGS, *extra]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if not wait:
        return proc
    stdout, stderr = proc.communicate(timeout=600)
    return proc.returncode, stdout + stderr


def _numbers(out) -> dict:
    """What results.json measured: every run's probes and prediction, and the certificates (not paths or commands)."""
    res = json.loads((out / "results.json").read_text())
    return {"runs": {n: {"probes": r["probes"], "prediction": r["prediction"]} for n, r in res["runs"].items()},
            "experiments": res["experiments"], "certificates": res["certificates"]}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "map"
    rc, log = _map(out)
    assert rc == 0, log
    return out


@pytest.mark.parametrize("kill_at", ["train_step:7", "measure", "rename:results.json", "rename:results.md"])
def test_a_killed_map_resumes_to_the_same_results(reference, tmp_path, kill_at):
    out = tmp_path / "map"
    shutil.copytree(reference / "data", out / "data")  # same seeded corpus and certificates; saves regenerating
    rc, log = _map(out, kill_at=kill_at)
    assert rc == -signal.SIGKILL, log
    run_dir = out / "runs" / "V-h1-4-16-lam0.02-standard-s0"
    if kill_at.startswith("train_step"):
        assert not (run_dir / "DONE").exists() and (run_dir / "ckpt.pt").exists()
    if kill_at == "measure":
        assert (run_dir / "DONE").exists() and not (run_dir / "measure.json").exists()
    if kill_at == "rename:results.json":  # the finished copy never appeared under its final name
        assert not (out / "results.json").exists()
    rc, log = _map(out)
    assert rc == 0, log
    assert _numbers(out) == _numbers(reference)
    assert not list(out.glob(".results.*.tmp-*"))  # no temporary copy is left behind once finished


def test_two_maps_on_one_out_refuse_then_merge(reference, tmp_path):
    out = tmp_path / "map"
    shutil.copytree(reference / "data", out / "data")
    first = _map(out, pause_at="train_step:10", wait=False)  # holds the folder while the second one starts
    lock = out / ".map.lock"
    deadline = time.time() + 120
    while not (lock.exists() and lock.read_text().strip()) and time.time() < deadline:
        time.sleep(0.05)
    assert lock.read_text().startswith(f"pid {first.pid} on "), "the first map never took the lock"
    rc, log = _map(out, "--variants", "VX_t")  # started while the first holds the folder
    assert rc == 2 and f"in use by another `pokeworld map`: pid {first.pid} on" in log, log
    assert "Traceback" not in log
    stdout, stderr = first.communicate(timeout=600)
    assert first.returncode == 0, stdout + stderr
    rc, log = _map(out, "--variants", "VX_t")  # the refused one, again: its run joins the first one's record
    assert rc == 0, log
    res = json.loads((out / "results.json").read_text())
    assert set(res["experiments"]["factorial"]) == {"V-h1-4-16-lam0.02-standard-s0", "VX_t-h1-4-16-lam0.02-standard-s0"}
    assert res["runs"]["V-h1-4-16-lam0.02-standard-s0"]["probes"] == _numbers(reference)["runs"][
        "V-h1-4-16-lam0.02-standard-s0"]["probes"]
    assert res["provenance"]["carried_over"][0]["runs"] == ["V-h1-4-16-lam0.02-standard-s0"]
    assert "Carried over from an earlier invocation" in (out / "results.md").read_text()


def test_a_stale_map_lock_is_taken_over(tmp_path, capsys):
    from pokeworld.io import dir_lock

    out = tmp_path / "map"
    holder = subprocess.Popen([sys.executable, "-c", "import sys, os, signal; from pokeworld.io import dir_lock\n"
                               "with dir_lock(sys.argv[1], '.map.lock', '{path} {holder}'):\n"
                               " os.kill(os.getpid(), signal.SIGKILL)", str(out)])
    holder.wait(timeout=60)
    assert f"pid {holder.pid} on" in (out / ".map.lock").read_text()  # left behind by the killed holder
    with dir_lock(out, ".map.lock", MAP_LOCK_REFUSAL) as stale:
        assert stale.startswith(f"pid {holder.pid} on")
    assert (out / ".map.lock").read_text() == ""  # a clean exit leaves nothing stale


def test_carry_over_keeps_earlier_runs_and_names_them():
    prov = {"command": "pokeworld map a", "git": "abc"}
    earlier = {"experiments": {"factorial": ["A", "B"], "lambda": ["L"]}, "runs": {"A": {"x": 1}, "B": {"x": 2}, "L": {"x": 3}},
               "certificates": {"standard": "old", "flow": "old-flow"}, "provenance": prov, "planning": {"p": 1}}
    now = {"experiments": {"factorial": ["B", "C"]}, "runs": {"B": {"x": 20}, "C": {"x": 4}},
           "certificates": {"standard": "new"}, "provenance": {"command": "pokeworld map b", "git": "def"}}
    merged = experiment.carry_over(earlier, now)
    assert merged["experiments"] == {"factorial": ["B", "C", "A"], "lambda": ["L"]}
    assert merged["runs"] == {"A": {"x": 1}, "B": {"x": 20}, "C": {"x": 4}, "L": {"x": 3}}  # B measured now wins
    assert merged["certificates"] == {"standard": "new", "flow": "old-flow"} and merged["planning"] == {"p": 1}
    assert merged["provenance"]["carried_over"] == [{"runs": ["A", "L"], "command": "pokeworld map a", "git": "abc"}]
    again = experiment.carry_over(merged, {**now, "experiments": {"factorial": ["A", "B", "C"]},
                                           "runs": {"A": {"x": 10}, "B": {"x": 20}, "C": {"x": 4}},
                                           "provenance": {"command": "pokeworld map c", "git": "ghi"}})
    assert again["provenance"]["carried_over"] == [{"runs": ["L"], "command": "pokeworld map a", "git": "abc"}]
    assert experiment.carry_over(None, now) is now
