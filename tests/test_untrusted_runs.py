"""A run folder someone else made is untrusted (issue #40): links among its files are refused instead of followed,
special files are refused instead of hanging the reader, damaged config.json / metrics.jsonl / checkpoints get one
line, a checkpoint's model kwargs cannot make pokeworld build a huge model, a bad --out or --data is refused before
anything is written, a crash-torn metrics line does not block resuming, and Ctrl-C says how to resume."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import threading
import time
from pathlib import Path

import pytest
import torch

from pokeworld import checkpoint, rundir
from pokeworld.cli import main as cli_main
from pokeworld.data import save
from pokeworld.errors import ConfigError, DataError
from pokeworld.models.xjepa import XJEPA
from pokeworld.train import make_config, run, synthetic_dataset

RUN_KW = dict(steps=10, variant="VX_t")  # tiny preset: a checkpoint at 5 and 10, a metrics row at 0, 5, 10


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory) -> str:
    d = tmp_path_factory.mktemp("untrusted") / "syn"
    save(synthetic_dataset(num_episodes=8, steps=24, size=32, seed=0), d)
    return str(d)


@pytest.fixture(scope="module")
def finished(data_dir, tmp_path_factory) -> Path:
    return run(make_config("tiny", data=data_dir, out=str(tmp_path_factory.mktemp("fin") / "run"), **RUN_KW))


@pytest.fixture
def shared_run(finished, tmp_path) -> Path:
    """A copy of a finished run, to damage."""
    return Path(shutil.copytree(finished, tmp_path / "shared_run"))


def returns_within(seconds: float, fn, *args):
    """``fn(*args)``'s outcome (value or exception) if it comes within ``seconds``; fails the test on a hang."""
    box: dict = {}

    def target():
        try:
            box["value"] = fn(*args)
        except BaseException as e:  # noqa: BLE001 - handed to the test
            box["error"] = e

    th = threading.Thread(target=target, daemon=True)  # a hung reader must not keep pytest alive
    th.start()
    th.join(seconds)
    assert not th.is_alive(), f"{getattr(fn, '__name__', fn)} hung for {seconds} s"
    if "error" in box:
        raise box["error"]
    return box["value"]


def one_line_cli_error(capsys, argv: list[str]) -> str:
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


# ---------------------------------------------------------------------- 2. links


@pytest.mark.parametrize("name", [".lock", "metrics.jsonl", "ckpt.pt", "final.pt", "config.json", "DONE"])
def test_a_link_among_a_run_folders_files_is_refused_and_its_target_kept(data_dir, tmp_path, name):
    victim = tmp_path / "precious.txt"
    victim.write_text("precious\n")
    out = tmp_path / "run"
    out.mkdir()
    (out / name).symlink_to(victim)
    with pytest.raises(ConfigError, match=f"{name}.*symbolic link"):
        run(make_config("tiny", data=data_dir, out=str(out), **RUN_KW))
    assert victim.read_text() == "precious\n"
    assert not (out / "config.json").exists() or (out / "config.json").is_symlink()


def test_readers_refuse_a_linked_final_pt_naming_it(shared_run, tmp_path, capsys):
    elsewhere = tmp_path / "elsewhere.pt"
    shutil.move(shared_run / "final.pt", elsewhere)
    (shared_run / "final.pt").symlink_to(elsewhere)
    with pytest.raises(ConfigError, match="final.pt is a symbolic link"):
        rundir.load_model(shared_run)
    assert "final.pt is a symbolic link" in one_line_cli_error(capsys, ["probe", str(shared_run)])


# ---------------------------------------------------------------------- 6. special files


@pytest.mark.parametrize("name", ["config.json", "metrics.jsonl", "final.pt"])
def test_a_fifo_in_a_run_folder_is_refused_without_hanging(shared_run, capsys, name):
    (shared_run / name).unlink()
    os.mkfifo(shared_run / name)
    readers = {"config.json": rundir.finished_run_config, "metrics.jsonl": rundir.read_metrics,
               "final.pt": rundir.load_model}
    with pytest.raises(ConfigError, match=f"{name} is a FIFO"):
        returns_within(10, readers[name], shared_run)
    if name != "metrics.jsonl":  # probe reads config.json, then final.pt
        err = returns_within(20, one_line_cli_error, capsys, ["probe", str(shared_run)])
        assert f"{name} is a FIFO" in err


def test_checkpoint_load_refuses_a_fifo_or_folder_without_hanging(tmp_path):
    os.mkfifo(tmp_path / "pipe.pt")
    with pytest.raises(checkpoint.CheckpointError, match="pipe.pt is a FIFO, not a regular file"):
        returns_within(10, checkpoint.load, tmp_path / "pipe.pt")
    (tmp_path / "dir.pt").mkdir()
    with pytest.raises(checkpoint.CheckpointError, match="dir.pt"):
        checkpoint.load(tmp_path / "dir.pt")


# ---------------------------------------------------------------------- 13. one line for damage


@pytest.mark.parametrize("content, match", [
    ('{"variant": "VX_t", "da', "config.json is not valid JSON"),
    ("[1, 2]", "holds a JSON array, not a JSON object"),
    ('{"variant": "VX_t", "data": 5}', "names no dataset"),
    ("\xff\xfe", "config.json is not valid JSON"),
], ids=["truncated", "a list", "data not a path", "not utf-8"])
def test_a_damaged_config_json_gets_one_line(shared_run, capsys, content, match):
    (shared_run / "config.json").write_bytes(content.encode("latin-1"))
    with pytest.raises(DataError, match=match):
        rundir.finished_run_config(shared_run)
    assert match.split(" ")[-1] in one_line_cli_error(capsys, ["probe", str(shared_run)])


def test_a_damaged_config_json_refuses_resuming_in_one_line(shared_run, data_dir):
    (shared_run / "config.json").write_text("{not json")
    with pytest.raises(DataError, match="config.json is not valid JSON"):
        run(make_config("tiny", data=data_dir, out=str(shared_run), **RUN_KW))


def test_a_damaged_metrics_line_is_named(shared_run):
    lines = (shared_run / "metrics.jsonl").read_text().splitlines()
    (shared_run / "metrics.jsonl").write_text("\n".join([lines[0], "{oops", *lines[1:]]) + "\n")
    with pytest.raises(DataError, match="metrics.jsonl line 2 is not valid JSON"):
        rundir.read_metrics(shared_run)
    (shared_run / "metrics.jsonl").write_text('{"step": "five"}\n')
    with pytest.raises(DataError, match="line 1 is not a metrics row"):
        rundir.last_logged_step(shared_run)


def test_a_truncated_final_pt_gets_one_line(shared_run, capsys):
    raw = (shared_run / "final.pt").read_bytes()
    (shared_run / "final.pt").write_bytes(raw[: len(raw) // 2])
    assert "final.pt" in one_line_cli_error(capsys, ["probe", str(shared_run)])


def test_a_run_folder_without_checkpoints_is_a_config_error(tmp_path):
    (tmp_path / "config.json").write_text("{}")
    with pytest.raises(ConfigError, match="holds no final.pt or ckpt.pt"):
        rundir.load_model(tmp_path)


# ---------------------------------------------------------------------- 5. model kwargs


def _with_kwargs(run_dir: Path, **change) -> Path:
    ck = torch.load(run_dir / "final.pt", weights_only=True)
    ck["model_kwargs"] = {**ck["model_kwargs"], **change}
    torch.save(ck, run_dir / "final.pt")
    return run_dir


def test_kwargs_declaring_a_huge_model_are_refused_before_it_is_built(shared_run, monkeypatch):
    built = []
    monkeypatch.setattr(XJEPA, "load_state_dict", lambda *a, **k: built.append(a))
    _with_kwargs(shared_run, width=4096, latent_dim=4096, heads=1)  # 488 M parameters: a 2 GB model
    t0 = time.perf_counter()
    with pytest.raises(checkpoint.CheckpointError, match=r"declare a model of [\d,]+ parameters.*at most 100,000,000"):
        rundir.load_model(shared_run)
    assert time.perf_counter() - t0 < 5 and not built
    assert (shared_run / "final.pt").stat().st_size < 1_000_000  # a small file declaring gigabytes


@pytest.mark.parametrize("change, match", [
    (dict(width=32), r"declare predictor\..* of shape \[.*32.*\] but the weights hold"),
    (dict(depth=10**6), r"depth=1000000 is outside the allowed 1\.\.64"),
    (dict(horizons=[1] * 1000), r"horizons=.*must list 1\.\.64 integers"),
    (dict(channels=(4, 8, "8", 8)), "channels='8' must be an integer"),
    (dict(evil=1), "unknown model kwarg 'evil'"),
    (dict(width=15, heads=2), "describe no buildable model|declare"),
    (dict(dropout=float("nan")), r"dropout=nan must be a number in \[0\.0, 1\.0\]"),
], ids=["wider", "deep", "many horizons", "str channel", "unknown", "heads do not divide", "nan dropout"])
def test_kwargs_that_do_not_match_the_weights_are_refused_saying_what_was_declared(shared_run, change, match):
    _with_kwargs(shared_run, **change)
    with pytest.raises(checkpoint.CheckpointError, match=match):
        rundir.load_model(shared_run)


def test_a_stride_zero_weight_cannot_declare_more_than_the_file_holds(shared_run):
    ck = torch.load(shared_run / "final.pt", weights_only=True)
    name = "predictor.time_pos"
    ck["model"][name] = torch.zeros(1).expand(*ck["model"][name].shape)
    torch.save(ck, shared_run / "final.pt")
    with pytest.raises(checkpoint.CheckpointError, match="time_pos declares .* elements but stores"):
        rundir.load_model(shared_run)


def test_check_model_kwargs_covers_every_constructor_argument():
    import inspect

    from pokeworld.models.xjepa import MODEL_KWARGS, check_model_kwargs

    assert set(inspect.signature(XJEPA).parameters) == MODEL_KWARGS
    mk = XJEPA(variant="V", channels=[4, 8, 8, 8], image_size=16, latent_dim=8, width=8, depth=1, heads=2).config
    assert check_model_kwargs(mk) == mk


# ---------------------------------------------------------------------- 13. --out, ckpt.pt, Ctrl-C


def test_out_that_is_a_file_is_refused_before_the_data_is_read(tmp_path):
    (tmp_path / "out").write_text("not a folder")
    with pytest.raises(ConfigError, match="out is a file, not a run folder"):
        run(make_config("tiny", data=str(tmp_path / "no_such_data"), out=str(tmp_path / "out"), **RUN_KW))


def test_a_read_only_out_folder_is_refused_before_the_data_is_loaded(data_dir, tmp_path, monkeypatch):
    import pokeworld.train.single as single

    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o555)
    immutable = False
    if os.access(out, os.W_OK):  # root ignores permissions: an immutable folder is read-only for root too
        immutable = subprocess.run(["chattr", "+i", str(out)], capture_output=True).returncode == 0
        if not immutable:
            pytest.skip("cannot make a folder read-only here")
    monkeypatch.setattr(single.data_mod, "load", lambda *a, **k: pytest.fail("data loaded before --out was checked"))
    try:
        with pytest.raises(ConfigError, match="ro is not writable"):
            run(make_config("tiny", data=data_dir, out=str(out), **RUN_KW))
    finally:
        if immutable:
            subprocess.run(["chattr", "-i", str(out)], check=True)
        out.chmod(0o755)


@pytest.mark.parametrize("damage, match", [
    (lambda ck: ck.pop("optimizer"), "'optimizer' is NoneType, expected dict"),
    (lambda ck: ck.update(step="5"), "'step' is str, expected int"),
    (lambda ck: ck["model"].update({"predictor.time_pos": torch.zeros(3)}), "time_pos of shape"),
    (lambda ck: ck["optimizer"].update(param_groups=[]), "does not fit this run"),
    (lambda ck: ck.update(rng={"python": (3, (1, 2), None)}), "does not fit this run"),
], ids=["no optimizer", "str step", "wrong shape", "no param groups", "bad rng"])
def test_a_damaged_ckpt_pt_refuses_resuming_in_one_line(data_dir, tmp_path, damage, match):
    kw = dict(data=data_dir, out=str(tmp_path / "r"), **RUN_KW)
    run(make_config("tiny", stop_at=5, **kw))
    ck = torch.load(tmp_path / "r" / "ckpt.pt", weights_only=True)
    damage(ck)
    torch.save(ck, tmp_path / "r" / "ckpt.pt")
    with pytest.raises(checkpoint.CheckpointError, match=match):
        run(make_config("tiny", **kw))


def _interrupt_at(monkeypatch, at: int) -> None:
    import pokeworld.train.single as single

    real = single.train_step

    def step(model, opt, cfg, batch, step, *a, **k):
        if step == at:
            raise KeyboardInterrupt
        return real(model, opt, cfg, batch, step, *a, **k)

    monkeypatch.setattr(single, "train_step", step)


@pytest.mark.parametrize("at, says", [
    (7, "training stopped at step 7 of 10; re-running resumes from {out}/ckpt.pt at step 5"),
    (3, "training stopped at step 3 of 10; no checkpoint was written yet, so re-running starts again from step 0"),
], ids=["after a checkpoint", "before any checkpoint"])
def test_ctrl_c_says_where_training_stopped_and_how_to_resume(data_dir, tmp_path, monkeypatch, capsys, at, says):
    out = tmp_path / "r"
    argv = ["train", "--preset", "tiny", "--data", data_dir, "--out", str(out), "--variant", "VX_t"]
    _interrupt_at(monkeypatch, at)
    assert cli_main(argv) == 130
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert says.format(out=out) in err and err.endswith(f"to resume, run: pokeworld {' '.join(argv)}")
    monkeypatch.undo()
    assert cli_main(argv) == 0 and (out / "DONE").exists()


def test_a_metrics_line_torn_by_a_crash_does_not_block_resuming(data_dir, tmp_path):
    kw = dict(data=data_dir, out=str(tmp_path / "r"), **RUN_KW)
    out = run(make_config("tiny", stop_at=5, **kw))
    with open(out / "metrics.jsonl", "a") as fh:
        fh.write('{"frames_per_s": 12.5, "lo')  # the crash came mid-write: no closing brace, no newline
    assert rundir.last_logged_step(out) == 5
    run(make_config("tiny", **kw))
    assert [r["step"] for r in rundir.read_metrics(out)] == [0, 5, 10]


# ---------------------------------------------------------------------- 14. inputs before the run folder


def test_a_train_with_a_bad_data_path_leaves_nothing_that_refuses_the_corrected_command(data_dir, tmp_path):
    out = tmp_path / "r"
    with pytest.raises(DataError, match="does not exist"):
        run(make_config("tiny", data=str(tmp_path / "typo"), out=str(out), **RUN_KW))
    assert not out.exists()
    assert (run(make_config("tiny", data=data_dir, out=str(out), **RUN_KW)) / "DONE").exists()


def test_a_store_whose_arrays_fail_to_load_leaves_no_config_json(data_dir, tmp_path):
    broken = Path(shutil.copytree(data_dir, tmp_path / "broken"))
    raw = (broken / "data.h5").read_bytes()
    (broken / "data.h5").write_bytes(raw[: len(raw) // 3])
    out = tmp_path / "r"
    with pytest.raises(DataError, match="data.h5"):
        run(make_config("tiny", data=str(broken), out=str(out), **RUN_KW))
    assert not (out / "config.json").exists()
    assert (run(make_config("tiny", data=data_dir, out=str(out), **RUN_KW)) / "DONE").exists()


def test_a_run_folders_own_config_still_resumes_and_records_json(finished):
    cfg = rundir.read_run_config(finished)
    assert cfg["variant"] == "VX_t" and json.loads((finished / "config.json").read_text()) == cfg
    assert rundir.read_run_config(finished.parent / "absent") is None


def test_training_summary_means_the_logged_glide_share_and_skips_what_is_not_a_number(tmp_path):
    run = tmp_path / "r"
    run.mkdir()
    rows = [{"step": 0, "glide_loss_share": 0.2}, {"step": 50, "glide_loss_share": 0.4}, {"step": 100, "loss": 1.0},
            {"step": 150, "glide_loss_share": True}, {"step": 200, "glide_loss_share": "0.9"}]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert rundir.training_summary(run) == pytest.approx({"last_logged_step": 200, "glide_loss_share": 0.3})
    (run / "metrics.jsonl").write_text('{"step": 0, "loss": 1.0}\n')
    assert rundir.training_summary(run) == {"last_logged_step": 0}  # an objective that logs no share
    assert rundir.training_summary(tmp_path / "absent") == {}
