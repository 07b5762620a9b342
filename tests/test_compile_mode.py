"""Whether and how a run is compiled: 'auto' means CUDA graphs on a CUDA device and eager on a CPU, an explicit
setting wins, old configs (booleans) still load and resume, and the trainers hand torch.compile the resolved mode."""

import json

import pytest
import torch

from pokeworld.errors import ConfigError
from pokeworld.train.config import RESUMABLE_FIELDS, TrainConfig, compile_mode_for, make_config

CPU, CUDA = torch.device("cpu"), torch.device("cuda")


def test_auto_is_cuda_graphs_on_cuda_and_eager_on_cpu():
    cfg = make_config("tiny")
    assert (cfg.compile, cfg.compile_mode) == ("auto", "auto")
    assert compile_mode_for(cfg, CUDA) == "reduce-overhead"
    assert compile_mode_for(cfg, torch.device("cuda:1")) == "reduce-overhead"
    assert compile_mode_for(cfg, CPU) is None  # CPU runs stay eager, as before 'auto'
    assert compile_mode_for(make_config("paper"), CUDA) == "reduce-overhead"
    assert compile_mode_for(make_config("tiny", ddp=True), CUDA) is None  # DDP: eager unless asked for


def test_an_explicit_setting_or_mode_wins():
    assert compile_mode_for(make_config("tiny", compile="off"), CUDA) is None
    assert compile_mode_for(make_config("tiny", compile="on"), CPU) == "default"
    assert compile_mode_for(make_config("tiny", compile="on"), CUDA) == "reduce-overhead"
    assert compile_mode_for(make_config("tiny", compile="on", ddp=True), CUDA) == "reduce-overhead"
    assert compile_mode_for(make_config("tiny", compile_mode="default"), CUDA) == "default"
    assert compile_mode_for(make_config("tiny", compile_mode="max-autotune"), CUDA) == "max-autotune"
    assert compile_mode_for(make_config("tiny", compile_mode="max-autotune"), CPU) is None  # auto stays eager
    assert compile_mode_for(make_config("tiny", compile="on", compile_mode="reduce-overhead"), CPU) == "reduce-overhead"


def test_settings_are_validated_and_old_booleans_read_as_on_and_off():
    with pytest.raises(ConfigError, match="compile must be"):
        make_config("tiny", compile="sometimes")
    with pytest.raises(ConfigError, match="compile_mode"):
        make_config("tiny", compile="on", compile_mode="fastest")
    with pytest.raises(ConfigError, match="compile off"):
        make_config("tiny", compile="off", compile_mode="reduce-overhead")
    assert make_config("tiny", compile=True).compile == "on"
    assert make_config("tiny", compile=False).compile == "off"
    # a config.json written before 'auto': compile false, mode 'default'
    old = TrainConfig(compile=False, compile_mode="default")
    assert old.compile == "off" and compile_mode_for(old, CUDA) is None
    assert {"compile", "compile_mode"} <= set(RESUMABLE_FIELDS)  # a run may resume under another setting


def _recording(monkeypatch):
    """torch.compile replaced by a recorder of the mode it is given (the module stays eager: compiling on a CPU
    takes minutes)."""
    seen = []

    def recording_compile(module, mode=None, **kw):
        seen.append(mode)
        return module

    monkeypatch.setattr(torch, "compile", recording_compile)
    return seen


def test_the_trainer_compiles_its_loss_in_the_named_mode_and_not_by_default_on_cpu(monkeypatch, tmp_path,
                                                                                    tiny_dataset):
    from pokeworld.data import save
    from pokeworld.train import single

    seen = _recording(monkeypatch)
    data = save(tiny_dataset, tmp_path / "data")
    single.run(make_config("tiny", data=str(data), out=str(tmp_path / "run"), steps=2, compile="on",
                           compile_mode="reduce-overhead"))
    assert seen == ["reduce-overhead"]
    single.run(make_config("tiny", data=str(data), out=str(tmp_path / "eager"), steps=2))
    assert seen == ["reduce-overhead"]  # the default on a CPU: no torch.compile call at all


def test_a_run_written_before_auto_resumes_under_the_new_default(tmp_path, tiny_dataset):
    from pokeworld.data import save
    from pokeworld.train import single

    data = save(tiny_dataset, tmp_path / "data")
    out = tmp_path / "run"
    single.run(make_config("tiny", data=str(data), out=str(out), steps=4, stop_at=2))
    path = out / "config.json"
    cfg = json.loads(path.read_text())
    assert cfg["compile"] == "auto"  # the setting, not a boolean, is recorded now
    path.write_text(json.dumps({**cfg, "compile": False, "compile_mode": "default"}))  # as older code wrote it
    single.run(make_config("tiny", data=str(data), out=str(out), steps=4))
    assert (out / "DONE").exists()
    assert json.loads(path.read_text())["compile"] == "auto"


def test_stacked_groups_compile_their_vmapped_loss_as_their_runs_say(monkeypatch, tmp_path):
    from pokeworld import train
    from pokeworld.data import save
    from pokeworld.train import stacked

    seen = _recording(monkeypatch)
    data = save(train.synthetic_dataset(num_episodes=8, steps=24, size=16, seed=0), tmp_path / "syn")
    kw = dict(data=str(data), steps=2, log_every=1, ckpt_every=2)
    cfgs = [make_config("tiny", out=str(tmp_path / f"a{i}"), variant=v, seed=i, **kw) for i, v in enumerate(("V",))]
    stacked.run(cfgs)
    assert seen == []  # 'auto' on a CPU: eager
    cfgs = [make_config("tiny", out=str(tmp_path / f"b{i}"), variant=v, seed=i, compile="on", **kw)
            for i, v in enumerate(("V", "VFX"))]
    assert all(stacked.stackable(c) for c in cfgs)
    stacked.run(cfgs)
    assert seen == ["default"]  # one compiled loss for the group
    assert all((tmp_path / f"b{i}" / "DONE").exists() for i in range(2))


@pytest.mark.slow
def test_a_compiled_stacked_group_trains_as_its_eager_twin(monkeypatch, tmp_path):
    """The vmapped loss through dynamo and AOTAutograd (inductor's code generation left out: minutes on a CPU)
    logs the eager group's terms: the graph capture itself changes nothing."""
    from pokeworld import train
    from pokeworld.data import save
    from pokeworld.train import stacked

    real = torch.compile
    monkeypatch.setattr(torch, "compile", lambda fn, mode=None, **kw: real(fn, backend="aot_eager"))
    data = save(train.synthetic_dataset(num_episodes=8, steps=24, size=32, seed=0), tmp_path / "syn")
    kw = dict(data=str(data), steps=3, log_every=1, ckpt_every=3, image_size=32, dropout=0.0)
    rows = {}
    for setting in ("off", "on"):
        cfgs = [make_config("tiny", out=str(tmp_path / f"{setting}{i}"), variant=v, seed=i, compile=setting, **kw)
                for i, v in enumerate(("V", "VFX"))]
        stacked.run(cfgs)
        rows[setting] = [[json.loads(x) for x in (tmp_path / f"{setting}{i}" / "metrics.jsonl").read_text()
                          .splitlines()] for i in range(2)]
    for eager, compiled in zip(rows["off"], rows["on"]):
        for a, b in zip(eager[1:], compiled[1:]):
            assert b["loss"] == pytest.approx(a["loss"], rel=1e-4)


def _rows(run):
    return [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]


def test_a_compile_failure_falls_back_to_eager_recorded_and_bit_exact(tiny_dataset, tmp_path, monkeypatch, capsys):
    """A planted compile error at the first step (as inductor raises it) costs the compiled speed, not the run:
    the same batch is taken eagerly, so the weights equal an eager run's, and the metrics say compiled=0."""
    from pokeworld.data import save
    from pokeworld.rundir import load_model
    from pokeworld.train import run

    data = tmp_path / "data"
    save(tiny_dataset, data)
    eager = run(make_config("tiny", data=str(data), out=str(tmp_path / "eager"), steps=6, compile="off"))

    def broken_compile(net, mode=None):
        def compiled(*a, **k):
            raise RuntimeError("BackendCompilerFailed: planted")
        return compiled

    monkeypatch.setattr(torch, "compile", broken_compile)
    fell = run(make_config("tiny", data=str(data), out=str(tmp_path / "fell"), steps=6, compile="on"))
    assert "torch.compile (mode default) failed at the first step (RuntimeError: BackendCompilerFailed: planted)" \
        in capsys.readouterr().out
    a, b = load_model(eager).state_dict(), load_model(fell).state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert {r.get("compiled") for r in _rows(fell) if r["step"] > 0} == {0.0}
    assert {r.get("compiled") for r in _rows(eager) if r["step"] > 0} == {0.0}


def test_a_later_error_is_not_taken_for_a_compile_failure(tiny_dataset, tmp_path, monkeypatch):
    from pokeworld.data import save
    from pokeworld.train import run

    data = tmp_path / "data"
    save(tiny_dataset, data)
    calls = {"n": 0}

    def flaky_compile(net, mode=None):
        def compiled(*a, **k):
            calls["n"] += 1
            if calls["n"] == 3:
                raise RuntimeError("an error in step 3, not a compilation")
            return net(*a, **k)
        return compiled

    monkeypatch.setattr(torch, "compile", flaky_compile)
    with pytest.raises(RuntimeError, match="not a compilation"):
        run(make_config("tiny", data=str(data), out=str(tmp_path / "r"), steps=6, compile="on"))
