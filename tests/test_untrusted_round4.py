"""Untrusted inputs, round 4 (issue #60): what comes back from a GPU allocation (merge_allocations.py, its --plan,
ALLOC_RESUME), checkpoint readers, io's JSON bound and swm-targets. One test per class on planted files; each was
seen failing on the code before the fix. The returned allocation is a real one's records
(tests/allocation_planting.py) with planted edits and members."""

from __future__ import annotations

import gzip
import io
import json
import os
import shlex
import subprocess
import tarfile
import zipfile
from pathlib import Path

import pytest
import torch

from allocation_planting import (FINISHED, PARTIAL, edit_json, member, plant, tiny_checkpoint, with_partial,
                                 current_model, with_partial_current)
from pokeworld import checkpoint
from pokeworld.checkpoint import CheckpointError
from pokeworld.errors import DataError, PokeworldError
from pokeworld.io import record_owned
from pokeworld.remote import allocations
from pokeworld.swm import targets_table as T
from test_swm_targets_table import TARGET, planted_record


def fails(argv: list[str], match: str) -> str:
    """merge_allocations' one-line refusal (SystemExit) matching ``match``."""
    with pytest.raises(SystemExit) as e:
        allocations.main(argv)
    line = str(e.value.code)
    assert line.startswith("error: ") and "\n" not in line and __import__("re").search(match, line), line
    return line


def as_bash(line: str, cwd: Path) -> str:
    """Run a printed command in a real bash, with `bash` itself shadowed by a function printing ALLOC_RESUME and
    its arguments (one a line): what pasting the line would hand gpu_allocation.sh."""
    script = 'bash() { printf "%s\\n" "$ALLOC_RESUME" "$@"; }\n' + line + "\n"
    return subprocess.run(["/bin/bash", "-c", script], cwd=cwd, capture_output=True, text=True, timeout=30).stdout


# ---------------------------------------------------------------------- 1. words printed for a shell


def test_plan_refuses_a_variant_that_is_a_command_and_quotes_every_folder(tmp_path, capsys):
    marker = tmp_path / "pwned"
    hostile = {"variant": f"VF$(touch {marker})", "seed": 0, "steps": 20000}
    bad = plant(tmp_path / "bad", [member(PARTIAL, "ckpt", tiny_checkpoint(config=hostile))], edit=with_partial)
    fails(["--plan", str(bad)], "variant .* is not one of")
    folder = tmp_path / "returned $(touch pwned) 'a b'"
    current = current_model(variant="VF", seed=0, steps=20000)
    plant(folder, [member(PARTIAL, "ckpt", tiny_checkpoint(config=current))], edit=with_partial_current)
    from pokeworld.remote.queue import split_folder_list

    fails(["--plan", str(folder), "--commit", "abc; touch pwned"], "hexadecimal")
    # the planted records are of an earlier environment, whose runs the checkout's plan only names: plan them as
    # their own configuration's, so that the hostile folder is one to resume from
    (tmp_path / "scratch").mkdir()
    returned = allocations.open_allocation(folder, tmp_path / "scratch")
    lines = allocations.plan_lines(allocations.plan([returned], configuration=returned.configuration), "abc1234")
    start = next(x for x in lines if "gpu_lease.sh start" in x)
    printed = as_bash(start.split(" && ", 1)[1], tmp_path).splitlines()  # after the wheels' install
    assert not marker.exists() and not (tmp_path / "pwned").exists()
    # ALLOC_RESUME: one folder, spaces and all, as the device's copy of the checkout holds it
    assert split_folder_list(printed[0]) == [f".resume/{folder.name}"]
    assert printed[1:5] == ["scripts/gpu_lease.sh", "start", "", "VF@0"]
    # the line that copies it in (the folder lies outside the checkout), run in a real bash: the folder, nothing run
    copy = next(x for x in lines if x.startswith("cp -r -- "))
    cwd = tmp_path / "checkout"
    (cwd / ".resume").mkdir(parents=True)
    subprocess.run(["/bin/bash", "-c", copy], cwd=cwd, check=True, timeout=30)
    assert (cwd / ".resume" / folder.name / "records.tar.gz").is_file() and not (cwd / "pwned").exists()


# ---------------------------------------------------------------------- 2. archive and checkpoint bombs


def pax_bomb(path: Path, declared: int, real: int = 1024) -> None:
    """A records.tar.gz whose first header is a pax record declaring ``declared`` bytes, ``real`` of them there."""
    info = tarfile.TarInfo("map_config.json")
    info.size = 2
    block = bytearray(info.tobuf(format=tarfile.USTAR_FORMAT))
    block[0:100] = b"././@PaxHeader".ljust(100, b"\0")
    block[156:157] = b"x"
    block[124:136] = f"{declared:011o}\0".encode()
    block[148:156] = b" " * 8
    block[148:156] = f"{sum(block):06o}\0 ".encode()
    path.write_bytes(gzip.compress(bytes(block) + b"12 path=ab\n".ljust(real, b"\0")))


def test_archive_headers_are_checked_before_their_data_is_read(tmp_path):
    import tracemalloc

    folder = plant(tmp_path / "bomb")
    pax_bomb(folder / "records.tar.gz", 1 << 30)
    fails([str(folder), "--out", str(tmp_path / "m.json")], "declares 1073741824 bytes.*refused before reading")
    pax_bomb(folder / "records.tar.gz", 32 << 20, 32 << 20)  # a header that does not lie: 32 MiB from 32 KB
    assert (folder / "records.tar.gz").stat().st_size < 100_000
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    tracemalloc.start()
    try:
        with pytest.raises(PokeworldError, match="declares 33554432 bytes"):
            allocations.open_allocation(folder, scratch)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 << 20  # the record was never read into memory
    many = plant(tmp_path / "many")
    with tarfile.open(many / "records.tar.gz", "w:gz", format=tarfile.USTAR_FORMAT) as tar:
        for i in range(5000):
            tar.addfile(tarfile.TarInfo(f"e{i}"), io.BytesIO(b""))
    with pytest.raises(PokeworldError, match="more than 4096 entries"):
        allocations.open_allocation(many, scratch)
    assert not any(p.is_file() for p in scratch.rglob("*"))  # refused before a single entry was written


def test_a_duplicate_member_is_refused_in_the_records_and_read_once_from_the_parts(tmp_path):
    folder = plant(tmp_path / "dup")
    with tarfile.open(folder / "records.tar.gz", "w:gz") as tar:
        for _ in range(2):
            data = b"{}"
            info = tarfile.TarInfo("progress.json")
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    fails([str(folder), "--out", str(tmp_path / "m.json")], "holds 'progress.json' twice")
    from pokeworld.remote.pack import read_stream

    m = member(PARTIAL, "ckpt", tiny_checkpoint())
    parts = plant(tmp_path / "parts", [m, m, member(PARTIAL, "ckpt", tiny_checkpoint(step=9))], edit=with_partial)
    assert [(x.run, x.kind) for x in read_stream(parts)] == [(PARTIAL, "ckpt")]


def deflated(src: bytes) -> bytes:
    """The same torch zip with every record DEFLATE-compressed (torch reads it; it never writes one)."""
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(src)) as zin, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            zout.writestr(info.filename, zin.read(info.filename))
    return out.getvalue()


def test_compressed_checkpoint_records_and_repeating_views_are_refused_before_use(tmp_path):
    buf = io.BytesIO()
    torch.save({"w": torch.zeros(1 << 16)}, buf)
    (tmp_path / "deflated.pt").write_bytes(deflated(buf.getvalue()))
    with pytest.raises(CheckpointError, match="is compressed or declares"):
        checkpoint.load(tmp_path / "deflated.pt")
    torch.save({"w": torch.zeros(1, dtype=torch.bfloat16).expand(1 << 20)}, tmp_path / "view.pt")
    with pytest.raises(CheckpointError, match="w declares 1048576 elements but stores 2 bytes"):
        checkpoint.load(tmp_path / "view.pt")
    # the same view as a returned, compacted weight: refused by the merge before expand() converts it to float32
    ck = tiny_checkpoint(optimizer=False)
    name, raw = member(FINISHED, "final", ck)
    packed = torch.load(io.BytesIO(raw), weights_only=True)
    key = next(k for k in packed["checkpoint"]["model"] if packed["checkpoint"]["model"][k].dtype == torch.bfloat16)
    packed["checkpoint"]["model"][key] = torch.zeros(1, dtype=torch.bfloat16).expand(1 << 20)
    buf = io.BytesIO()
    torch.save(packed, buf)
    folder = plant(tmp_path / "view", [member(FINISHED, "final", raw=buf.getvalue())])
    fails([str(folder), "--out", str(tmp_path / "m.json")], "declares 1048576 elements but stores 2 bytes")


# ---------------------------------------------------------------------- 3. one JSON bound


def test_returned_records_are_read_with_ios_json_bound(tmp_path):
    def big(tree: Path) -> None:
        edit_json(tree / "progress.json", lambda p: p.update(padding=" " * (5 << 20)))

    folder = plant(tmp_path / "big", edit=big)
    assert (folder / "records.tar.gz").stat().st_size < 200_000
    fails(["--plan", str(folder)], "progress.json is .* bytes; a map's progress record may be at most 4194304")


# ---------------------------------------------------------------------- 4. an output never replaces an input


def test_no_output_replaces_the_commands_own_input(tmp_path):
    folder = plant(tmp_path / "a")
    manifest = json.loads(tarfile.open(folder / "records.tar.gz").extractfile("data/standard/manifest.json").read())
    cert = tmp_path / "C.json"
    cert.write_text(json.dumps({"estimators": {}, "certificate": {},
                                "dataset": {"content_sha256": manifest["content_sha256"]}}))
    record_owned(cert)  # a certify JSON pokeworld wrote: ownership alone would let the merge replace it
    before = cert.read_bytes()
    fails([str(folder), "--certificates", str(cert), "--out", str(cert), "--no-figure"], "output .*C.json is the input")
    assert cert.read_bytes() == before
    os.link(cert, tmp_path / "hard.json")  # another name of the same file
    fails([str(tmp_path / "a"), "--certificates", str(cert), "--out", str(tmp_path / "hard.json"), "--no-figure"],
          "is the input")
    record = tmp_path / "targets.json"
    record.write_text(json.dumps(planted_record("swm/A", {"g": TARGET}, {"g": True})))
    record_owned(record)  # pokeworld's own file: ownership alone would let it be replaced
    before = record.read_bytes()
    with pytest.raises(PokeworldError, match="is the input"):
        T.run(T.TargetsConfig(records=(str(record),), out=str(tmp_path / "targets")))
    assert record.read_bytes() == before and not (tmp_path / "targets.md").exists()


# ---------------------------------------------------------------------- 5. every output checked before any is written


def test_runs_out_is_checked_before_the_merged_record_is_written(tmp_path):
    folder = plant(tmp_path / "a", [member(FINISHED, "final", tiny_checkpoint(optimizer=False))])
    users = tmp_path / "runs" / FINISHED
    users.mkdir(parents=True)
    (users / "final.pt").write_bytes(b"the user's own weights")
    out = tmp_path / "merged.json"
    fails([str(folder), "--out", str(out), "--no-figure", "--runs-out", str(tmp_path / "runs")],
          "final.pt exists and pokeworld did not write it")
    assert not out.exists() and sorted(p.name for p in users.iterdir()) == ["final.pt"]


def many_factors(n: int) -> dict:
    return planted_record("swm/A", {f"factor{i}": TARGET for i in range(n)}, {f"factor{i}": True for i in range(n)})


def test_swm_targets_bounds_its_figure_and_writes_all_or_nothing(tmp_path, monkeypatch):
    record = tmp_path / "rec.json"
    record.write_text(json.dumps(many_factors(40)))
    T.run(T.TargetsConfig(records=(str(record),), out=str(tmp_path / "t")))
    from PIL import Image

    width = Image.open(tmp_path / "t.png").size[0]
    assert width <= (2.2 * 24 + 3.5) * 150 + 1  # at most 24 factors drawn
    assert json.loads((tmp_path / "t.json").read_text())["figure_left_out"] == 40 - 24
    assert "16 more are in the table only" in (tmp_path / "t.md").read_text()

    import matplotlib.figure

    def broken(*a, **k):
        raise RuntimeError("std::bad_alloc")

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", broken)
    with pytest.raises(RuntimeError):
        T.run(T.TargetsConfig(records=(str(record),), out=str(tmp_path / "u")))
    assert not list(tmp_path.glob("u.*"))  # the figure failed: neither the JSON nor the markdown was written


# ---------------------------------------------------------------------- 6. a resumed optimizer is checked like a model


def test_a_returned_optimizer_of_the_wrong_shape_or_a_repeating_moment_is_refused(tmp_path):
    ck = tiny_checkpoint()
    state = ck["optimizer"]["state"]
    state[0]["exp_avg"] = torch.zeros(3)
    bad = plant(tmp_path / "shape", [member(PARTIAL, "ckpt", ck)], edit=with_partial)
    fails(["--plan", str(bad)], "optimizer state of parameter 0: exp_avg has shape \\[3\\]")
    ck = tiny_checkpoint()
    first = ck["optimizer"]["state"][0]["exp_avg_sq"]
    ck["optimizer"]["state"][0]["exp_avg_sq"] = torch.full((1,), float("nan")).expand_as(first)
    bad = plant(tmp_path / "view", [member(PARTIAL, "ckpt", ck)], edit=with_partial)
    fails(["--plan", str(bad)], "exp_avg_sq is a view repeating stored numbers|declares .* elements but stores")


def test_train_resume_checks_the_optimizer_state(tmp_path):
    from pokeworld.data import save
    from pokeworld.train import make_config, run, synthetic_dataset

    data, out = tmp_path / "data", tmp_path / "run"
    save(synthetic_dataset(num_episodes=8, steps=24, size=32, seed=0), data)
    run(make_config("tiny", data=str(data), out=str(out), steps=4, ckpt_every=2, variant="V"))
    ck = torch.load(out / "ckpt.pt", weights_only=True)
    first = next(iter(ck["optimizer"]["state"].values()))
    first["exp_avg"] = torch.zeros(*first["exp_avg"].shape, 2)
    for name in ("DONE", "final.pt"):
        (out / name).unlink(missing_ok=True)
    torch.save(ck, out / "ckpt.pt")
    with pytest.raises(CheckpointError, match="ckpt.pt does not fit this run: optimizer state of .*exp_avg has shape"):
        run(make_config("tiny", data=str(data), out=str(out), steps=6, ckpt_every=2, variant="V"))


# ---------------------------------------------------------------------- 7. malformed fields are one line


@pytest.mark.parametrize("change,match", [
    (lambda t: edit_json(t / "progress.json", lambda p: p.update(finished=[5])), "'finished' is not a list of run"),
    (lambda t: edit_json(t / "runs" / FINISHED / "config.json", lambda c: c.update(seed="x")), "seed 'x' is not"),
    (lambda t: (t / "runs" / FINISHED / "config.json").write_text(
        (t / "runs" / FINISHED / "config.json").read_text().replace('"seed": 0', '"seed": 1e400')), "seed 'inf'"),
    (lambda t: edit_json(t / "progress.json", lambda p: p.update(partial={PARTIAL: "x"})), "is 'x', not an integer"),
])
def test_malformed_returned_fields_are_one_line(tmp_path, change, match):
    fails(["--plan", str(plant(tmp_path / "a", edit=change))], match)


def test_a_checkpoint_step_that_is_not_a_number_is_one_line(tmp_path):
    ck = tiny_checkpoint(step="x")
    fails(["--plan", str(plant(tmp_path / "a", [member(PARTIAL, "ckpt", ck)], edit=with_partial))],
          "its step is 'x', not an integer")


@pytest.mark.parametrize("change,match", [
    (lambda s: s["g"].pop("variants"), r"xjepa.summary\['g'\].variants is not a mapping"),
    (lambda s: s["g"]["variants"]["VX"].update(ridge="0.5"), r"variants.VX.ridge is not a number \('0.5'\)"),
    (lambda s: s.update(g=[1, 2]), r"xjepa.summary\['g'\] is not a mapping"),
    (lambda s: s["g"]["variants"]["V"].update(per_seed=[0.1]), r"per_seed is not a mapping"),
])
def test_malformed_swm_targets_rows_are_one_line(tmp_path, change, match):
    rec = planted_record("swm/A", {"g": TARGET}, {"g": True})
    change(rec["xjepa"]["summary"])
    (tmp_path / "r.json").write_text(json.dumps(rec))
    with pytest.raises(DataError, match=match) as e:
        T.run(T.TargetsConfig(records=(str(tmp_path / "r.json"),), out=str(tmp_path / "t")))
    assert "\n" not in str(e.value) and not list(tmp_path.glob("t.*"))


def test_resume_folders_with_spaces_survive_the_shell_script(tmp_path):
    from pokeworld.remote.queue import folder_list, split_folder_list

    folders = [str(tmp_path / "a b"), str(tmp_path / "c'd"), "$(touch x)"]
    assert split_folder_list(folder_list(folders)) == folders
    assert split_folder_list("/plain/one /plain/two") == ["/plain/one", "/plain/two"]
    assert shlex.split(f"ALLOC_RESUME={shlex.quote(folder_list(folders))}")[0] == f"ALLOC_RESUME={folder_list(folders)}"


# ---------------------------------------------------------------------- staging of swm-certify --workers


def test_worker_parts_lie_in_a_private_folder_never_under_a_predictable_name(tmp_path, monkeypatch):
    """collect_in_parallel's part files (swm's writer opens them following links) are created inside a private
    0700 folder with a random name, removed afterwards; a link planted at the old predictable name is never
    written through. The pool and the merge are stand-ins (stable_worldmodel is not needed)."""
    import dataclasses
    import stat

    from pokeworld.swm import parallel_collect as PC

    @dataclasses.dataclass
    class Share:
        episodes: int = 4
        seed: int = 0

    class InProcess:
        def __init__(self, *a, **k):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def map(self, fn, *its):
            return map(fn, *its)

    seen = []

    def collect(cfg, part: Path) -> Path:
        folder = part.parent
        seen.append((folder, stat.S_IMODE(folder.stat().st_mode)))
        part.write_bytes(b"episodes")
        return part

    victim = tmp_path / "victim"
    victim.write_text("someone else's file")
    corpus = tmp_path / "corpus.h5"
    os.symlink(victim, tmp_path / f"corpus.part-0-{os.getpid()}.h5")  # the name the parts used to have
    monkeypatch.setattr(PC, "ProcessPoolExecutor", InProcess)
    monkeypatch.setattr(PC, "merge", lambda parts, path: (path.write_bytes(b"merged"), 4)[1])
    PC.collect_in_parallel(Share(), corpus, 2, collect)
    assert victim.read_text() == "someone else's file" and corpus.read_bytes() == b"merged"
    assert len(seen) == 2 and all(f.parent == tmp_path and f.name.startswith(".corpus.h5.tmp-") and mode == 0o700
                                  for f, mode in seen)
    assert not seen[0][0].exists()  # the private folder and its parts are gone
