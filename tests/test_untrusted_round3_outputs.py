"""The output contract (issue #50, items 1, 2, 4, 8): pokeworld replaces or appends to a file only if it recorded
writing it (``.pokeworld-owned``), whatever the command; its temporaries are private folders with unpredictable
names, so a planted link is never written through; every JSON record it reads back goes through one bounded,
regular-file, type-checked reader; a full disk reads as one line and leaves no partial file."""

from __future__ import annotations

import json
import os
import resource
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pokeworld import io
from pokeworld.data import save
from pokeworld.errors import ConfigError, DataError
from pokeworld.train import make_config, run, synthetic_dataset


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory) -> str:
    d = tmp_path_factory.mktemp("round3") / "syn"
    save(synthetic_dataset(num_episodes=8, steps=24, size=32, seed=0), d)
    return str(d)


# ------------------------------------------------------------------ 1. files pokeworld did not write are refused


def test_train_refuses_a_users_metrics_and_weights(data_dir, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "metrics.jsonl").write_text('{"my": "notes"}\n')
    (out / "final.pt").write_bytes(b"my weights")
    with pytest.raises(ConfigError, match=r"metrics\.jsonl exists and pokeworld did not write it"):
        run(make_config("tiny", data=data_dir, out=str(out), steps=4))
    assert (out / "metrics.jsonl").read_text() == '{"my": "notes"}\n'
    assert (out / "final.pt").read_bytes() == b"my weights"
    assert sorted(p.name for p in out.iterdir()) == ["final.pt", "metrics.jsonl"]  # refused before writing anything


def test_a_run_pokeworld_wrote_is_resumed_and_replaced(data_dir, tmp_path):
    out = tmp_path / "ours"
    run(make_config("tiny", data=data_dir, out=str(out), steps=4, stop_at=2))
    assert {"config.json", "metrics.jsonl", "ckpt.pt"} <= io.owned_names(out)
    run(make_config("tiny", data=data_dir, out=str(out), steps=4))  # resumes: replaces its own ckpt.pt
    assert (out / "DONE").exists()


def test_plan_refuses_a_users_plan_md_before_planning(tmp_path, monkeypatch):
    from pokeworld import plan

    out = tmp_path / "plans"
    out.mkdir()
    (out / "plan.md").write_text("my plan")
    monkeypatch.setattr(plan, "plan_runs", lambda *a, **k: pytest.fail("planned before checking the outputs"))
    monkeypatch.setattr(plan, "require_finished_runs", lambda *a, **k: None)
    with pytest.raises(ConfigError, match=r"plan\.md exists and pokeworld did not write it"):
        plan.run(plan.make_config("tiny", runs=["somewhere"], out=str(out)))
    assert (out / "plan.md").read_text() == "my plan"


def test_pairs_refuses_a_users_file_and_writes_no_link(tmp_path):
    from pokeworld.sim import pairs

    out = tmp_path / "pairs"
    out.mkdir()
    (out / "pairs.npz").write_bytes(b"mine")
    with pytest.raises(ConfigError, match="did not write it"):
        pairs.run(pairs.make_config("tiny", out=str(out)))
    assert (out / "pairs.npz").read_bytes() == b"mine"
    (out / "pairs.npz").unlink()
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    for ext in ("png", "pdf"):  # the fixed temporary names an earlier version wrote through
        os.symlink(victim, out / f".pairs.tmp.{ext}")
    pairs.run(pairs.make_config("tiny", out=str(out)))
    assert victim.read_text() == "keep"
    assert (out / "pairs.png").stat().st_size > 0 and not (out / "pairs.png").is_symlink()


def test_rh20t_synth_refuses_a_real_looking_folder(tmp_path):
    from pokeworld.real import synthetic

    root = tmp_path / "RH20T"
    scene = root / "RH20T_cfg7" / "task_0001_user_0001_scene_0001_cfg_0007"
    (scene / "transformed").mkdir(parents=True)
    (scene / "metadata.json").write_text('{"real": true}')
    (scene / "transformed" / "tcp_base.npy").write_bytes(b"real data")
    for overwrite in (False, True):
        with pytest.raises(ConfigError, match="no synthetic corpus of pokeworld's"):
            synthetic.run(synthetic.make_config("tiny", root=str(root), overwrite=overwrite, progress=False))
    assert (scene / "metadata.json").read_text() == '{"real": true}'
    assert sorted(p.name for p in root.iterdir()) == ["RH20T_cfg7"]


def test_write_json_refuses_a_users_file_and_replaces_its_own(tmp_path):
    user = tmp_path / "results.json"
    user.write_text("{}")
    with pytest.raises(ConfigError, match="did not write it"):
        io.write_json(user, {"a": 1})
    assert user.read_text() == "{}"
    ours = tmp_path / "ours.json"
    io.write_json(ours, {"a": 1})
    io.write_json(ours, {"a": 2})
    assert json.loads(ours.read_text()) == {"a": 2}
    with pytest.raises(ConfigError, match="did not write it"):  # appending to a user's log is replacing it too
        io.append_jsonl(user, {"b": 1})


def test_npz_and_figure_writers_keep_the_exact_name_and_refuse_a_users_file_or_a_link(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    arrays = {"a": np.arange(5.0), "b": np.eye(2)}
    for compressed in (False, True):
        io.save_npz(tmp_path / f"x{int(compressed)}.npz", arrays, compressed=compressed)
        with np.load(tmp_path / f"x{int(compressed)}.npz") as z:
            assert set(z.files) == {"a", "b"} and np.array_equal(z["b"], np.eye(2))
    io.save_npz(tmp_path / "cache.ok", arrays)  # numpy appends .npz to a bare name; through an open file it cannot
    assert (tmp_path / "cache.ok").is_file() and not (tmp_path / "cache.ok.npz").exists()
    paths = io.save_figure_as(plt.figure(), [tmp_path / "f.png", tmp_path / "f"])
    assert [p.read_bytes()[:4] for p in paths] == [b"\x89PNG"] * 2 and plt.get_fignums() == []
    victim = tmp_path / "victim"
    victim.write_text("keep")
    for suffix, write in ((".npz", lambda p: io.save_npz(p, arrays)), (".png", lambda p: io.save_figure_as(
            plt.figure(), [p]))):
        user, link = tmp_path / f"user{suffix}", tmp_path / f"link{suffix}"
        user.write_text("mine")
        os.symlink(victim, link)
        for final in (user, link):
            with pytest.raises(ConfigError):
                write(final)
        assert victim.read_text() == "keep" and user.read_text() == "mine" and link.is_symlink()
    plt.close("all")


def test_owned_folder_with_record_is_still_verified_as_ours(tmp_path):
    spec = io.OwnedDir(files=(r"data\.h5", r"manifest\.json"))
    with io.atomic_path(tmp_path / "store") as tmp:
        tmp.mkdir()
        (tmp / "data.h5").write_bytes(b"x")
        io.write_json(tmp / "manifest.json", {})
    io.check_owned_dir(tmp_path / "store", spec)  # its ownership record is ours, not a foreign file


# ---------------------------------------------------------------------- 2. temporaries: private and unpredictable


def test_temporary_is_a_private_folder_with_an_unpredictable_name(tmp_path):
    final = tmp_path / "ckpt.pt"
    victim = tmp_path / "victim"
    victim.write_text("keep")
    # every name an attacker could predict from the pid, planted as a link to the victim
    os.symlink(victim, tmp_path / f".ckpt.pt.tmp-{os.getpid()}")
    seen = []
    with io.atomic_path(final) as tmp:
        seen.append(tmp)
        mode = os.lstat(tmp.parent).st_mode
        assert stat.S_ISDIR(mode) and stat.S_IMODE(mode) == 0o700
        assert tmp.parent.parent == tmp_path and tmp.parent.name.startswith(".ckpt.pt.tmp-")
        tmp.write_text("new")
    assert final.read_text() == "new" and victim.read_text() == "keep"
    assert not seen[0].parent.exists()  # the private folder is gone
    with io.atomic_path(tmp_path / "other") as tmp2:
        tmp2.write_text("x")
        assert tmp2.parent.name != seen[0].parent.name


def test_final_name_turned_into_a_link_during_the_write_is_refused(tmp_path):
    final = tmp_path / "out.json"
    victim = tmp_path / "victim"
    victim.write_text("keep")
    with pytest.raises(ConfigError, match="symbolic link"):
        with io.atomic_path(final) as tmp:
            tmp.write_text("new")
            os.symlink(victim, final)
    assert victim.read_text() == "keep"
    assert [p.name for p in tmp_path.iterdir() if ".tmp-" in p.name] == []


def test_a_killed_writers_private_folder_is_cleaned_by_the_next_run(tmp_path):
    stale = io.temporary_folder(tmp_path / "results.json")
    (stale / "results.json").write_text("half")
    user = tmp_path / ".notes.tmp-x"  # not one of our names: stays
    user.write_text("mine")
    assert io.remove_stale_temporaries(tmp_path) == 1
    assert not stale.exists() and user.read_text() == "mine"


# ---------------------------------------------------------------------------- 4. one bounded JSON reader


@pytest.mark.parametrize("content, message", [
    ("[]", "holds a JSON array, not a JSON object"),
    ("{", "not valid JSON"),
    ("[" * 100_000 + "]" * 100_000, "not valid JSON"),
    ('"text"', "holds a JSON string, not a JSON object"),
])
def test_read_json_gives_one_line(tmp_path, content, message):
    p = tmp_path / "certificates.json"
    p.write_text(content)
    with pytest.raises(DataError, match=message) as e:
        io.read_json(p, "a certificate record")
    assert "\n" not in str(e.value)


def test_read_json_refuses_fifo_link_and_oversized(tmp_path):
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    with pytest.raises(DataError, match="FIFO"):
        io.read_json(fifo, "a record")  # returns at once: no blocking open
    real = tmp_path / "real.json"
    real.write_text("{}")
    os.symlink(real, tmp_path / "link.json")
    with pytest.raises(DataError, match="symbolic link"):
        io.read_json(tmp_path / "link.json", "a record")
    big = tmp_path / "big.json"
    big.write_text("[" + ",".join(["[]"] * 2_000_000) + "]")
    with pytest.raises(DataError, match="may be at most"):
        io.read_json(big, "a record")


def test_certify_reads_back_a_damaged_certificates_json_in_one_line(tmp_path):
    from pokeworld import certify

    path = tmp_path / "certificates.json"
    path.write_text("[]")
    with pytest.raises(DataError, match="JSON array"):
        certify.load_gate(path)
    path.unlink()
    os.mkfifo(path)
    with pytest.raises(DataError, match="FIFO"):
        certify.load_gate(path)


# ------------------------------------------------------------------------------------ 8. a full disk


FULL_DISK = r"""
import resource, sys
from pokeworld import io
from pokeworld.errors import ConfigError
resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 16, 1 << 16))
try:
    with io.atomic_path(sys.argv[1]) as tmp:
        tmp.write_bytes(b"x" * (1 << 20))
except ConfigError as e:
    print("REFUSED", e)
"""


def test_file_size_limit_reads_as_one_line_and_leaves_nothing(tmp_path):
    final = tmp_path / "data.h5"
    r = subprocess.run([sys.executable, "-c", FULL_DISK, str(final)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("REFUSED file size limit reached while writing") and r.stdout.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_generate_refuses_a_disk_that_cannot_hold_the_store(tmp_path):
    script = ("import resource, sys\nfrom pokeworld.cli import main\n"
              "resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 16, 1 << 16))\n"
              "sys.exit(main(['generate', '--preset', 'tiny', '--out', sys.argv[1]]))\n")
    out = tmp_path / "store"
    r = subprocess.run([sys.executable, "-c", script, str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode != 0 and r.returncode > 0  # an error exit, not a signal or a crash
    assert "Traceback" not in r.stderr and "Segmentation" not in r.stderr
    assert "file size limit reached" in r.stderr or "no space left" in r.stderr
    assert not out.exists() and [p.name for p in tmp_path.iterdir() if ".tmp-" in p.name] == []


def test_record_is_bounded_and_never_a_link(tmp_path):
    victim = tmp_path / "victim"
    victim.write_text("keep")
    os.symlink(victim, tmp_path / io.OWNED_RECORD)
    with pytest.raises(DataError, match="symbolic link"):
        io.write_json(tmp_path / "x.json", {})
    assert victim.read_text() == "keep"
    np.testing.assert_equal(resource.getrlimit(resource.RLIMIT_FSIZE)[0] != 0, True)


# ------------------------------------------------------- folders written before ownership records existed


def test_a_run_from_before_ownership_records_resumes_and_is_measured(data_dir, tmp_path):
    out = tmp_path / "old"
    run(make_config("tiny", data=data_dir, out=str(out), steps=4, stop_at=2))
    (out / io.OWNED_RECORD).unlink()  # as an earlier pokeworld left it
    run(make_config("tiny", data=data_dir, out=str(out), steps=4))  # its config.json makes it a run: adopted
    assert (out / "DONE").exists() and {"config.json", "ckpt.pt"} <= io.owned_names(out)


def test_a_certificate_record_from_before_ownership_records_is_replaced(tmp_path):
    folder = tmp_path / "store"
    folder.mkdir()
    (folder / "certificates.json").write_text('{"certificate": {}}')
    assert io.adopt_legacy(folder, ["certificates.json", "absent.json"]) == ["certificates.json"]
    io.write_json(folder / "certificates.json", {"certificate": {"new": 1}})
    assert io.adopt_legacy(folder, ["certificates.json"]) == []  # a folder with a record adopts nothing more


def test_generate_cleans_a_killed_writers_temporary_of_its_own_store_only(tmp_path):
    from pokeworld.cli import main

    ours = io.temporary_folder(tmp_path / "store")
    (ours / "store").mkdir()
    (ours / "store" / "data.h5").write_bytes(b"half")
    other = io.temporary_folder(tmp_path / "results.json")  # another output's: not this command's to clean
    assert main(["generate", "--preset", "tiny", "--out", str(tmp_path / "store")]) == 0
    assert not ours.exists() and other.exists()
