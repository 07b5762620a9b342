"""A device lease as the unit (scripts/gpu_lease.sh, docs/model.md "GPU allocations: a lease"), dry-run at the tiny
preset on this CPU with a kill at each step: the allocation runs detached and survives every command; each command
only collects its latest returned state, so whatever a killed command had collected comes back readable, and the
last command's folder holds the whole lease."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pokeworld.errors import PokeworldError
from pokeworld.remote import allocations, pack as ap

ROOT = Path(__file__).resolve().parents[1]
V, VFX = (f"{v}-h1-4-16-lam0.02-standard-s0" for v in ("V", "VFX"))


def _env(lease: Path) -> dict:
    return {**os.environ, "PYTHON": sys.executable, "PYTHONPATH": str(ROOT / "src"), "ALLOC_PRESET": "tiny",
            "ALLOC_STEPS": "400", "ALLOC_TESTS": "0", "ALLOC_SNAPSHOT_S": "3", "ALLOC_BUDGET_MIN": "8",
            "ALLOC_LEASE_DIR": str(lease), "ALLOC_POLL_S": "1", "ALLOC_COLLECT_S": "400",
            # two runs at once, and weights that take more than one return: parts of 64 KiB, two a command
            "ALLOC_CONCURRENCY": "2", "ALLOC_PART_BYTES": "65536", "ALLOC_PARTS_PER_COMMAND": "2"}


def _returned(out: Path) -> set[tuple[str, str]]:
    try:
        return {(m.run, m.kind) for m in ap.read_stream(out)}
    except (PokeworldError, OSError):
        return set()


def _finished(out: Path) -> list[str]:
    """The runs OUT's records list as finished (none while they are unreadable or not there yet)."""
    import tempfile

    try:
        with tempfile.TemporaryDirectory() as scratch:
            return allocations.open_allocation(out, Path(scratch)).progress.get("finished", [])
    except (PokeworldError, OSError):
        return []


def _command(args: list[str], env: dict) -> subprocess.Popen:
    return subprocess.Popen(["bash", "scripts/gpu_lease.sh", *args], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


def _kill_when(proc: subprocess.Popen, done, what: str, limit_s: float = 400) -> None:
    """SIGKILL the command's whole process group once ``done()`` holds (as a device's time limit would)."""
    t0 = time.time()
    try:
        while not done():
            assert proc.poll() is None, f"the command ended before {what}: {proc.stdout.read()[-2000:]}"
            assert time.time() - t0 < limit_s, f"no {what} within {limit_s} s"
            time.sleep(0.2)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _alive(lease: Path) -> bool:
    pid = int((lease / "pid").read_text())
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.slow
def test_a_lease_survives_a_kill_of_each_command_and_its_last_folder_holds_every_run(tmp_path):
    lease, env = tmp_path / "lease", _env(tmp_path / "lease")
    out1, out2, out3, out4, again_out = (tmp_path / f"out{i}" for i in range(1, 6))
    for i in range(1, 5):
        (tmp_path / f"s{i}").mkdir()  # scratch folders the returned packs are unpacked into
    try:
        # 1. start and collect, killed once the first run came back
        start = _command(["start", str(out1), "V", "VFX"], env)
        # a collect copies the weight parts before the records (nothing is listed finished without its weights), so
        # the first run is back once both are: killed between the two, the run would be weights without a record
        _kill_when(start, lambda: (V, "final") in _returned(out1) and _finished(out1) == [V], "the first run back")
        assert _alive(lease), "the detached allocation died with the command that started it"
        # the lease runs a copy of the repository's own files, never a virtual environment or output beside them
        assert (lease / "repo" / "scripts" / "gpu_allocation.sh").is_file()
        assert not any((lease / "repo" / d).exists() for d in (".venv", ".venv-swm", ".git", "out"))
        a = allocations.open_allocation(out1, tmp_path / "s1")
        assert a.progress["finished"] == [V] and a.weights == {V: "returned"}
        assert ap.check_return_folder(out1) == []
        # 2. collect, killed once it has collected anything
        collect = _command(["collect", str(out2)], env)
        _kill_when(collect, lambda: (out2 / "records.tar.gz").exists(), "a collected state")
        assert allocations.open_allocation(out2, tmp_path / "s2").progress["finished"][0] == V
        # a second start on the same machine does not start a second allocation
        again = subprocess.run(["bash", "scripts/gpu_lease.sh", "start", str(again_out)], cwd=ROOT, env={
            **env, "ALLOC_COLLECT_S": "0"}, capture_output=True, text=True, timeout=120)
        assert again.returncode == 0 and ("already runs" in again.stdout or "has ended" in again.stdout)
        # collect until the allocation ends, then 3. the final collect
        rest = subprocess.run(["bash", "scripts/gpu_lease.sh", "collect", str(out3)], cwd=ROOT, env=env,
                              capture_output=True, text=True, timeout=600)
        assert rest.returncode == 0 and "the allocation is not running" in rest.stdout, rest.stdout[-2000:]
        final = subprocess.run(["bash", "scripts/gpu_lease.sh", "final", str(out4)], cwd=ROOT, env=env,
                               capture_output=True, text=True, timeout=120)
        assert final.returncode == 0 and "has ended" in final.stdout
    finally:
        if (lease / "pid").exists() and _alive(lease):
            os.killpg(int((lease / "pid").read_text()), signal.SIGKILL)
    # the weights came back over several returns (two parts a command): no one folder holds them all, every
    # folder is one a device returns whole, and the lease's folders together are one allocation with both runs
    outs = [out1, out2, again_out, out3, out4]
    assert all(ap.check_return_folder(o) == [] and not (o / ".incoming").exists() for o in outs)
    assert all(len(list(o.glob("pack.tar.part*"))) <= 2 for o in outs)
    [last] = allocations.open_allocations(outs, tmp_path / "s4")
    assert sorted(last.progress["finished"]) == sorted([V, VFX])
    assert last.weights == {V: "returned", VFX: "returned"}
    merged = allocations.merge_allocations([last])
    assert set(merged["runs"]) == {V, VFX}


def test_the_lease_runs_from_any_folder_and_a_failed_start_is_not_marked_started(tmp_path):
    """The checkout is the script's own, whatever the current folder; a start whose allocation does not run
    leaves the lease free for the next start."""
    lease = tmp_path / "lease"
    env = {**_env(lease), "PYTHON": str(tmp_path / "no-python"), "ALLOC_COLLECT_S": "0"}
    other = tmp_path / "elsewhere"
    other.mkdir()
    (other / "big.bin").write_bytes(b"x" * 1000)
    r = subprocess.run(["bash", str(ROOT / "scripts" / "gpu_lease.sh"), "start", str(tmp_path / "o")], cwd=other,
                       env=env, capture_output=True, text=True, timeout=120)
    assert (lease / "repo" / "scripts" / "gpu_allocation.sh").is_file()  # the checkout, not the current folder
    assert not (lease / "repo" / "big.bin").exists()
    assert r.returncode == 3 and "did not start" in r.stdout and not (lease / "started").exists()


def test_the_lease_refuses_a_bad_mode_or_a_state_inside_out(tmp_path):
    bad = subprocess.run(["bash", "scripts/gpu_lease.sh", "begin", str(tmp_path / "o")], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "start, collect or final" in bad.stderr
    inside = subprocess.run(["bash", "scripts/gpu_lease.sh", "final", str(tmp_path / "o")], cwd=ROOT,
                            env={**os.environ, "ALLOC_LEASE_DIR": str(tmp_path / "o" / "lease")},
                            capture_output=True, text=True, timeout=60)
    assert inside.returncode == 2 and "must not lie inside OUT" in inside.stderr
