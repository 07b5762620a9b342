"""What a GPU allocation brings back when it is killed, and how the next one resumes (scripts/gpu_allocation.sh at the
tiny preset on this CPU); the return format's limits and checks (pokeworld.remote.pack); the next
allocation's plan (scripts/merge_allocations.py --plan)."""

import io
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import pytest
import torch

from pokeworld import checkpoint, experiments as experiment
from pokeworld.errors import ConfigError, PokeworldError
from pokeworld.record_paths import placeholder
from pokeworld.io import atomic_path
from pokeworld.remote import allocations, pack as ap
from pokeworld.remote.queue import order_queue, parse_token

ROOT = Path(__file__).resolve().parents[1]
V, VFX = (f"{v}-h1-4-16-lam0.02-standard-s0" for v in ("V", "VFX"))
STEPS = 400  # long enough at tiny (~20 steps/s here) for the test to kill the second run part-way


def _env(work: Path, **extra) -> dict:
    return {**os.environ, "PYTHON": sys.executable, "ALLOC_PRESET": "tiny", "ALLOC_STEPS": str(STEPS),
            "ALLOC_TESTS": "0", "ALLOC_SNAPSHOT_S": "3", "ALLOC_BUDGET_MIN": "6", "ALLOC_WORK": str(work), **extra}


def _returned(out: Path) -> set[tuple[str, str]]:
    """(run, kind) of the verified members in ``out`` now (empty while the parts are being written)."""
    try:
        return {(m.run, m.kind) for m in ap.read_stream(out)}
    except (PokeworldError, OSError):
        return set()


@pytest.fixture(scope="module")
def killed(tmp_path_factory):
    """An allocation of V then VFX, SIGKILLed (its whole process group) once V came back and VFX's checkpoint
    did: within a poll (0.2 s) of a snapshot that was read back whole, well before the next one starts (3 s), since
    a kill while a snapshot is being written may cost that snapshot (docs/model.md, "GPU allocations")."""
    base = tmp_path_factory.mktemp("killed")
    out, work = base / "A", base / "A_work"
    proc = subprocess.Popen(["bash", "scripts/gpu_allocation.sh", str(out), "V", "VFX"], cwd=ROOT,
                            env=_env(work, ALLOC_COMMIT="abc1234"), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    seen: set = set()
    try:
        t0 = time.time()
        while not {(V, "final"), (VFX, "ckpt")} <= seen:
            assert proc.poll() is None, f"the allocation ended before it could be killed ({seen})"
            assert time.time() - t0 < 300, f"no checkpoint of the second run came back ({seen})"
            largest = max((p.stat().st_size for p in out.glob("*") if p.is_file()), default=0)
            assert len([p for p in out.rglob("*") if p.is_file()]) <= 8 and largest <= 16 << 20
            time.sleep(0.2)
            seen = _returned(out)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert not (work / "map" / "runs" / VFX / "DONE").exists(), "the second run finished before the kill"
    return out, base


@pytest.mark.slow
def test_a_killed_allocation_returns_its_finished_run_and_the_cut_runs_checkpoint(killed, tmp_path):
    out, _ = killed
    assert ap.check_return_folder(out) == []
    a = allocations.open_allocation(out, tmp_path)
    assert a.progress["finished"] == [V] and a.weights == {V: "returned"}
    assert 0 < a.checkpoints[VFX] < STEPS
    ck = checkpoint.load(a.root / "runs" / VFX / "ckpt.pt")  # restored in float32, with optimizer and RNG states
    assert ck["step"] == a.checkpoints[VFX] and ck["optimizer"]["state"] and "rng" in ck and "sampler" in ck


@pytest.mark.slow
def test_the_next_allocation_resumes_the_cut_run_and_the_plan_puts_it_first(killed, tmp_path, capsys):
    out, base = killed
    allocations.main(["--plan", str(out), "--commit", "feed123"])
    plan = capsys.readouterr().out.splitlines()
    assert plan[1].startswith("[plan] the queue, in this order (") and (
        "): VFX@0 VF@0 VX_t@0 VX_p@0 VX@0 VFX@1 VF@1 V@1 VX_t@1 VX_p@1 VX@1 VFX@2 " in plan[1])
    # the returned folder lies outside the checkout: the plan copies its contents in (never into an earlier copy),
    # and the device reads that copy
    assert plan[4] == f"cp -r -- {shlex.quote(str(out) + '/.')} .resume/{out.name}"
    assert f'ALLOC_COMMIT=feed123 ALLOC_RESUME=.resume/{out.name} bash scripts/gpu_lease.sh start "$OUT" VFX@0' \
        in plan[7]
    step = allocations.open_allocation(out, tmp_path).checkpoints[VFX]
    carried = tmp_path / "carried"  # the returned files as they travel to the next machine
    shutil.copytree(out, carried)
    out2, work2 = base / "B", base / "B_work"  # a fresh machine: another work folder
    proc = subprocess.run(["bash", "scripts/gpu_allocation.sh", str(out2), "V", "VFX"], cwd=ROOT,
                          env=_env(work2, ALLOC_RESUME=str(carried)), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    log = (out2 / "allocation.log").read_text()
    assert f"restored the checkpoint at step {step}" in log and "queue: VFX@0 (finished earlier: V@0)" in log
    assert f"{VFX}: resuming at step {step}" in log and f"{V}: starting" not in log
    b = allocations.open_allocation(out2, tmp_path)
    assert b.progress["finished"] == [VFX] and b.weights == {VFX: "returned"}
    rows = [json.loads(x) for x in (b.root / "runs" / VFX / "metrics.jsonl").read_text().splitlines()]
    merged, _ = _merge(tmp_path, out, out2)
    assert set(merged["runs"]) == {V, VFX}
    resumed = merged["runs"][VFX]["allocation"]["resumed"]
    # the first allocation's rows are kept, unless the kill fell between its parts and its records (then said)
    kept = resumed.get("metrics_before_resume") == "returned"
    assert (rows[0]["step"] == 0 if kept else rows[0]["step"] >= step) and rows[-1]["step"] == STEPS
    # the record names no machine's paths: the folder resumed from by its placeholder
    assert resumed["step"] == step and resumed["from"] == placeholder(str(carried)) and resumed["git"] == "abc1234"
    assert "bfloat16" in resumed["checkpoint"]


def _merge(tmp_path, *args):
    out = tmp_path / "merged" / "map.json"
    allocations.main([*map(str, args), "--out", str(out), "--no-figure"])
    return json.loads(out.read_text()), out


# ---------------------------------------------------------------------- the return format


def test_parts_stay_within_the_limits_and_only_changed_parts_are_rewritten(tmp_path):
    data = os.urandom(30 << 20)  # a fake 30 MiB pack, in parts of 4 MiB
    written: dict[int, str] = {}
    assert ap.write_parts(tmp_path, data, 4 << 20, written) == 8
    parts = sorted(tmp_path.glob("pack.tar.part*"))
    assert [p.name for p in parts][-1] == "pack.tar.part07" and all(p.stat().st_size <= 4 << 20 for p in parts)
    assert ap.join_parts(tmp_path, ap.ReturnLimits(file_bytes=4 << 20)) == data
    before = {p.name: p.stat().st_mtime_ns for p in parts}
    ap.write_parts(tmp_path, data[:29 << 20] + b"x" * (1 << 20), 4 << 20, written)  # only the last part changes
    after = {p.name: p.stat().st_mtime_ns for p in tmp_path.glob("pack.tar.part*")}
    assert [n for n in before if before[n] != after[n]] == ["pack.tar.part07"]
    assert ap.write_parts(tmp_path, data[:5 << 20], 4 << 20, written) == 2  # a shorter pack: the rest removed
    assert sorted(p.name for p in tmp_path.glob("pack.tar.part*")) == ["pack.tar.part00", "pack.tar.part01"]
    with pytest.raises(ConfigError, match="more than 1 parts"):
        ap.join_parts(tmp_path, ap.ReturnLimits(files=1))
    # the default budget: 4 small files, 3 parts of 15 MiB, one file and one part kept for an interrupted write
    assert ap.stream_budget(ap.ReturnLimits()) == (3, 45 << 20)
    assert ap.tar_size([len(b"abc"), 5000]) == len(ap.tar_bytes([("a", b"abc"), ("b", b"y" * 5000)]))


def test_large_tensors_travel_as_bfloat16_and_come_back_as_float32(tmp_path):
    ck = {"model": {"w": torch.randn(64, 128), "b": torch.randn(64), "n": torch.tensor(3)},
          "optimizer": {"state": {0: {"exp_avg": torch.randn(64, 128), "step": torch.tensor(5.0)}}},
          "rng": {"python": (3, tuple(range(5)), None)}, "step": 7}
    packed = ap.compact(ck)
    assert packed["checkpoint"]["model"]["w"].dtype == torch.bfloat16
    assert packed["checkpoint"]["model"]["b"].dtype == torch.float32  # small tensors exact
    path = tmp_path / "c.pt"
    checkpoint.save(packed, path)
    back = ap.expand(checkpoint.load(path), "c.pt")  # weights-only load
    assert back["model"]["w"].dtype == torch.float32 and torch.allclose(back["model"]["w"], ck["model"]["w"],
                                                                       rtol=1e-2)
    assert torch.equal(back["model"]["b"], ck["model"]["b"]) and back["step"] == 7
    assert back["optimizer"]["state"][0]["exp_avg"].dtype == torch.float32
    with pytest.raises(ConfigError, match="not a compacted checkpoint"):
        ap.expand({"model": {}}, "x.pt")


def _member(run: str, kind: str, data: bytes) -> tuple[str, bytes]:
    return ap.member_name(run, kind, data), data


def test_only_regular_members_matching_their_checksum_are_read(tmp_path):
    good, bad = _member(V, "final", b"weights"), _member(VFX, "final", b"other")
    forged = (bad[0], b"tampered")  # a name whose checksum does not match the bytes
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for name, data in (good, forged, ("../escape.pt", b"x"), (f"runs/../{V}/final.0123456789abcdef.pt", b"x")):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
        link = tarfile.TarInfo(ap.member_name(V, "ckpt", b"z"))
        link.type, link.linkname = tarfile.SYMTYPE, "/etc/passwd"
        tar.addfile(link)
    ap.write_parts(tmp_path, buf.getvalue(), 1 << 20)
    assert [(m.run, m.kind, m.data) for m in ap.read_stream(tmp_path)] == [(V, "final", b"weights")]
    assert not (tmp_path / "escape.pt").exists()


def test_a_kill_between_two_parts_keeps_what_lies_before_the_change(tmp_path):
    first, second = _member(V, "final", os.urandom(3000)), _member(VFX, "ckpt", os.urandom(3000))
    old = ap.tar_bytes([first, second])
    new = ap.tar_bytes([first, _member(VFX, "final", os.urandom(3000))])
    assert new[:3584] == old[:3584]  # the finished run's member: the same bytes in both
    ap.write_parts(tmp_path, old, 2048)
    ap.write_parts(tmp_path, new[:4096], 2048)  # killed after the first two new parts
    for i, piece in enumerate(ap.split_bytes(old, 2048)[2:], 2):
        with atomic_path(ap.part_path(tmp_path, i)) as tmp:
            tmp.write_bytes(piece)  # the old parts after them still there
    assert [(m.run, m.kind) for m in ap.read_stream(tmp_path)] == [(V, "final")]


def test_what_does_not_fit_is_left_out_and_named_never_what_came_back(tmp_path):
    c = experiment.make_config("tiny", out=str(tmp_path / "map"), variants=("V", "VFX"), seeds=(0, 1))
    specs = experiment.all_specs(c)
    finished, cut = [s.name for s in specs if s.seed == 0], next(s.name for s in specs if s.seed == 1)
    for name in [*finished, cut]:
        run = tmp_path / "map" / "runs" / name
        run.mkdir(parents=True)
        (run / "config.json").write_text("{}")
        checkpoint.save({"model": {"w": torch.randn(12000)}, "step": 3}, run / ("ckpt.pt" if name == cut else
                                                                               "final.pt"))
        if name != cut:
            (run / "DONE").write_text("done")
            (run / "measure.json").write_text("{}")
    out = tmp_path / "out"
    out.mkdir()
    limits = ap.ReturnLimits(files=6, part_bytes=32 << 10, total_bytes=1 << 20, small_bytes=0)  # room for one
    index = ap.Packer(c, specs, out, time.time(), limits).pack()
    assert [(m["run"], m["kind"]) for m in index["members"]] == [(finished[0], "final")]
    assert "no room" in index["left_out"][finished[1]] and "no room" in index["checkpoints_left_out"][cut]
    assert ap.check_return_folder(out, limits) == [] and len(list(out.glob("pack.tar.part*"))) == 1


# ---------------------------------------------------------------------- the plan


def _allocation(tmp_path, name, finished, checkpoints, git="abc1234", map_config=None,
                **config) -> allocations.Allocation:
    root = tmp_path / name
    for run in {*finished, *checkpoints}:
        variant, _, seed = run.partition("-s")
        (root / "runs" / run).mkdir(parents=True)
        (root / "runs" / run / "config.json").write_text(json.dumps({"variant": variant, "seed": int(seed), **config}))
    return allocations.Allocation(name, root, {"git": git}, map_config or {}, "0" * 64, {"finished": finished},
                                  checkpoints=checkpoints)


def test_the_plan_and_the_merge_keep_the_first_paper_model_apart_from_the_aligned_one(tmp_path):
    """The paper preset now trains the released reference's objective and model under the same run names: a plan on
    allocations of the first model would skip runs the preset has not trained, and a merge would mix the two."""
    from pokeworld.train.config import REFERENCE_MODEL

    aligned = {k: list(v) if isinstance(v, tuple) else v for k, v in REFERENCE_MODEL.items()}
    paper = {"preset": "paper"}
    first = _allocation(tmp_path, "first", ["VFX-s0"], {}, map_config=paper)  # configs from before the fields
    now = _allocation(tmp_path, "now", ["VF-s0"], {"V-s0": 100}, map_config=paper, **aligned)
    with pytest.raises(ConfigError, match="encoder.*start the next allocation afresh"):
        allocations.plan([first], configuration="")
    with pytest.raises(ConfigError, match="another objective or model than first.*head_form"):
        allocations.plan([first, now], configuration="")
    p = allocations.plan([now], configuration="")
    assert p["finished"] == ["VF@0"] and p["queue"][0] == "V@0"


def test_the_plan_resumes_checkpoints_first_then_follows_the_priority(tmp_path):
    a = _allocation(tmp_path, "A", ["VFX-s0", "VF-s0"], {"V-s0": 500})
    b = _allocation(tmp_path, "B", ["V-s0"], {"VX_p-s0": 100, "VX-s1": 300}, git="def5678")
    p = allocations.plan([a, b], configuration="")
    # V@0 finished in B after A's checkpoint: not resumed; the checkpoints come first, in the priority's order
    assert p["queue"][:12] == ["VX_p@0", "VX@1", "VX_t@0", "VX@0", "VFX@1", "VF@1", "V@1", "VX_t@1", "VX_p@1",
                               "VFX@2", "VF@2", "V@2"]
    assert p["finished"] == ["V@0", "VF@0", "VFX@0"] and p["resume_from"] == ["B"]
    assert p["resume"]["VX_p@0"] == {"step": 100, "from": "B"} and p["commits"] == ["abc1234", "def5678"]
    assert "ALLOC_COMMIT=c0ffee ALLOC_RESUME=.resume/B bash scripts/gpu_lease.sh start \"$OUT\" VX_p@0 VX@1 VX_t@0 " \
        "VX@0 VFX@1 VF@1 V@1 VX_t@1 VX_p@1 VFX@2" in allocations.plan_lines(p, "c0ffee")[-5]
    assert order_queue([parse_token(t) for t in ("V", "VF@1", "VX")], {"VX@0"}, {"VF@1"}) == ["VF@1", "V@0"]
    with pytest.raises(ConfigError, match="VARIANT@SEED"):
        parse_token("VFX@x")
