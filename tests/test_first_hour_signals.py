"""A newcomer's first hour (issue #52, items 3 and 6): Ctrl-C or SIGTERM during training checkpoints at the step it
arrives in and a re-run resumes there bit for bit, saying so; ``pokeworld probe`` measures a run with the run's
own preset, and a measurement with other settings keeps the earlier one instead of replacing it silently."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import torch

from pokeworld.cli import main as cli_main
from pokeworld.data import save
from pokeworld.train import make_config, run, synthetic_dataset
from pokeworld.train.loop import TrainingInterrupted


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("signals") / "syn"
    save(synthetic_dataset(num_episodes=12, steps=24, size=32, seed=0), d)
    return str(d)


class OldHandlerRan(Exception):
    """Raised by the handler a test installs before training: training must replace it while it runs (today's
    code does not, so the signal lands here instead of killing pytest) and put it back after."""


def _signal_after_step(monkeypatch, at: int, sig: int) -> None:
    """Send ``sig`` to this process right after the optimisation step from global step ``at``."""
    from pokeworld.train import single

    real = single.train_step

    def step(model, opt, cfg, batch, step, *a, **k):
        out = real(model, opt, cfg, batch, step, *a, **k)
        if step == at:
            os.kill(os.getpid(), sig)
        return out

    monkeypatch.setattr(single, "train_step", step)


def _weights(run_dir: Path) -> dict[str, torch.Tensor]:
    return torch.load(run_dir / "final.pt", weights_only=True)["model"]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_checkpoints_at_the_current_step_and_resuming_is_bit_exact(data_dir, tmp_path, monkeypatch, capsys,
                                                                            sig):
    kw = dict(data=data_dir, steps=10, ckpt_every=5, variant="VFX", dropout=0.1)
    whole = run(make_config("tiny", out=str(tmp_path / "whole"), **kw))

    def old_handler(signum, frame):
        raise OldHandlerRan(signum)

    previous = signal.signal(sig, old_handler)
    try:
        _signal_after_step(monkeypatch, at=2, sig=sig)
        out = tmp_path / "cut"
        with pytest.raises(TrainingInterrupted) as e:
            run(make_config("tiny", out=str(out), **kw))
        # the handler of whoever ran training before it is back
        assert signal.getsignal(sig) is old_handler
    finally:
        signal.signal(sig, previous)
    name = signal.Signals(sig).name
    assert e.value.checkpointed and e.value.exit_code == 128 + sig
    assert str(e.value) == f"interrupted at step 3 by {name}; checkpoint saved: the same command resumes from step 3"
    ck = torch.load(out / "ckpt.pt", weights_only=True)
    assert ck["step"] == 3 and not (out / "DONE").exists()  # step 3 is no periodic checkpoint (every 5)

    monkeypatch.undo()
    capsys.readouterr()
    run(make_config("tiny", out=str(out), **kw))
    assert f"[train] resuming {out} from step 3" in capsys.readouterr().out
    a, b = _weights(whole), _weights(out)
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a), \
        [k for k in a if not torch.equal(a[k], b[k])]


def test_the_cli_ends_on_sigterm_in_one_line_and_the_same_command_resumes(data_dir, tmp_path):
    out = tmp_path / "r"
    argv = ["train", "--preset", "tiny", "--data", data_dir, "--out", str(out), "--steps", "100000",
            "--log-every", "1", "--ckpt-every", "100000", "--variant", "VX_t"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "pokeworld.cli", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    try:
        metrics, deadline = out / "metrics.jsonl", time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:  # a logged row: the loop is running
            rows = metrics.read_text().splitlines() if metrics.exists() else []
            if len(rows) >= 3:
                break
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, (proc.returncode, stderr)
    last = stderr.strip().splitlines()[-1]
    m = re.fullmatch(r"\[train\] interrupted at step (\d+) by SIGTERM; checkpoint saved: the same command resumes "
                     r"from step (\d+)", last)
    assert m and m[1] == m[2] and "Traceback" not in stderr, stderr
    step = int(m[1])
    assert torch.load(out / "ckpt.pt", weights_only=True)["step"] == step
    assert json.loads((out / "metrics.jsonl").read_text().splitlines()[-1])["step"] == step

    # the same command (stopped a step later, to end the test) says where it resumes
    again = subprocess.run([sys.executable, "-m", "pokeworld.cli", *argv, "--stop-at", str(step + 1)],
                           capture_output=True, text=True, env=env, timeout=300, check=False)
    assert again.returncode == 0, again.stderr
    assert f"[train] resuming {out} from step {step}" in again.stdout.splitlines()


def test_stacked_training_checkpoints_every_member_on_sigterm_and_resumes_bit_exact(data_dir, tmp_path,
                                                                                     monkeypatch):
    from pokeworld.train import stacked

    def cfgs(root):
        return [make_config("tiny", data=data_dir, out=str(root / f"m{seed}"), seed=seed, steps=6, ckpt_every=4,
                            dropout=0.0) for seed in (0, 1)]

    whole = stacked.run(cfgs(tmp_path / "whole"))
    real = stacked._StackedRun.step

    def step(self, step):
        out = real(self, step)
        if step == 1:
            os.kill(os.getpid(), signal.SIGTERM)
        return out

    monkeypatch.setattr(stacked._StackedRun, "step", step)
    previous = signal.signal(signal.SIGTERM, lambda *a: (_ for _ in ()).throw(OldHandlerRan()))
    try:
        with pytest.raises(TrainingInterrupted, match="interrupted at step 2 by SIGTERM"):
            stacked.run(cfgs(tmp_path / "cut"))
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert [torch.load(tmp_path / "cut" / f"m{s}" / "ckpt.pt", weights_only=True)["step"] for s in (0, 1)] == [2, 2]
    monkeypatch.undo()
    for a, b in zip(whole, stacked.run(cfgs(tmp_path / "cut"))):
        wa, wb = _weights(a), _weights(b)
        assert all(torch.equal(wa[k], wb[k]) for k in wa)


def test_signal_handlers_go_in_only_in_the_main_thread_and_only_while_training():
    from pokeworld.train.loop import StopSignals

    before = signal.getsignal(signal.SIGTERM)
    with StopSignals():
        assert signal.getsignal(signal.SIGTERM) is not before
    assert signal.getsignal(signal.SIGTERM) is before
    errors = []

    def elsewhere():
        try:
            with StopSignals() as stop:
                assert stop.received is None
        except Exception as e:  # signal.signal outside the main thread raises ValueError
            errors.append(e)

    t = threading.Thread(target=elsewhere)
    t.start()
    t.join()
    assert not errors and signal.getsignal(signal.SIGTERM) is before


# --------------------------------------------------------------------------- probe: the run's own preset
def test_a_runs_training_preset_is_read_from_its_config():
    from pokeworld.config import to_dict
    from pokeworld.evaluate.measure import make_config as measure_config, run_preset, training_preset

    for preset in ("tiny", "cpu", "paper", "demo"):
        assert training_preset(to_dict(make_config(preset))) == preset
    # the *_first presets share their sizes with cpu / demo: they are measured alike
    for preset, sizes in (("cpu_first", "cpu"), ("demo_first", "demo")):
        assert training_preset(to_dict(make_config(preset))) == sizes
    odd = to_dict(make_config("cpu", image_size=16, channels=(2, 2, 2, 2), latent_dim=3, width=5, vec_dim=7))
    assert training_preset(odd) is None
    assert run_preset(measure_config("tiny", run_dir="/nonexistent/run")) == "cpu"  # probe then says what is wrong


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory, tiny_dataset):
    root = tmp_path_factory.mktemp("probe")
    save(tiny_dataset, root / "data")
    return run(make_config("tiny", data=str(root / "data"), out=str(root / "run")))


def _measured(run_dir: Path, name: str = "measure.json") -> dict:
    return json.loads((run_dir / name).read_text())["key"]["config"]


def test_probe_measures_a_tiny_run_with_tiny_settings_and_keeps_the_earlier_record(tiny_run, capsys):
    from pokeworld.evaluate.measure import PRESETS

    assert cli_main(["probe", str(tiny_run)]) == 0
    first = _measured(tiny_run)
    assert first["max_windows"] == PRESETS["tiny"]["max_windows"] and first["mlp"] is False
    assert not (tiny_run / "measure.previous.json").exists()
    capsys.readouterr()

    # other settings, asked for explicitly: measured, said in one line, and the earlier record kept
    assert cli_main(["probe", str(tiny_run), "--max-windows", "300"]) == 0
    said = [line for line in capsys.readouterr().out.splitlines() if "settings differ" in line]
    assert said == [(f"[measure] settings differ from those of the earlier {tiny_run / 'measure.json'} "
                     f"(max_windows 400 → 300); it is kept as {tiny_run / 'measure.previous.json'}")]
    assert _measured(tiny_run)["max_windows"] == 300
    assert _measured(tiny_run, "measure.previous.json") == first

    # the run's own settings again: measured again (not "up to date" with the 300-window record)
    assert cli_main(["probe", str(tiny_run)]) == 0
    assert _measured(tiny_run) == first and _measured(tiny_run, "measure.previous.json")["max_windows"] == 300


# --------------------------------------------------------------------------- help, certify and map at tiny
def test_train_help_lists_the_common_options_first_and_the_rest_as_advanced(capsys):
    with pytest.raises(SystemExit):
        cli_main(["train", "--help"])
    out = capsys.readouterr().out
    assert out.startswith("usage: pokeworld train [--preset tiny|cpu|paper|demo|cpu_first|demo_first]")
    common, advanced = out.split("advanced options")
    assert "--steps" in common and "--lr" in common and "--device" in common
    assert "--gnll-beta" in advanced and "--sigreg-knots" in advanced and "--gnll-beta" not in common


def test_grouped_help_parses_every_flag_as_before():
    import tyro

    from pokeworld.cli import plain_help_registry
    from pokeworld.train import TrainConfig

    args = ["--lr", "0.5", "--window", "20", "--horizons", "1", "4", "--no-tensorboard", "--steps", "7"]
    cfg = tyro.cli(TrainConfig, default=make_config("tiny"), args=args, registry=plain_help_registry())
    assert cfg == make_config("tiny", lr=0.5, window=20, horizons=(1, 4), tensorboard=False, steps=7)


def test_tiny_certify_runs_the_cpu_presets_estimators():
    from pokeworld.certify import make_config as certify_config

    assert certify_config("tiny").estimators == certify_config("cpu").estimators == ("gru", "linear", "drag")


def test_a_tiny_map_ends_with_the_smoke_test_note(tmp_path, capsys):
    from types import SimpleNamespace

    from pokeworld.cli import run_and_report

    def fake_map(cfg):
        print("direct16 1139.529 (no effect at this budget)")
        return tmp_path

    for preset, noted in (("tiny", True), ("cpu", False)):
        run_and_report("map", SimpleNamespace(preset=preset, out=str(tmp_path)), fake_map)
        notes = [line for line in capsys.readouterr().out.splitlines() if line.startswith("Note:")]
        assert bool(notes) == noted and all("smoke-test" in n and "--preset cpu" in n for n in notes)
