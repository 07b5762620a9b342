"""Training loop: presets, learning on tiny data, exact resume, skip/conflict, NaN guard, loading."""

import json

import numpy as np
import pytest
import torch

from pokeworld.data import save
from pokeworld.errors import ConfigError
from pokeworld.train import PRESETS, TrainConfig, WindowSampler, load_model, make_config, run, synthetic_dataset
from pokeworld.train.config import FIRST_PAPER_MODEL, REFERENCE_MODEL, REFERENCE_OBJECTIVE


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("xj") / "syn"
    save(synthetic_dataset(num_episodes=12, steps=24, size=32, seed=0), d)
    return str(d)


def test_presets_and_validation():
    assert set(PRESETS) == {"tiny", "cpu", "paper", "demo", "cpu_first", "demo_first"}
    # the demo's model is the cpu model at another budget: batch, steps, checkpointing and the paper's vector-
    # encoder width differ; the objective (targets, weights, λ, horizons, window, schedule shape) does not
    objective = set(REFERENCE_OBJECTIVE)
    for cpu, demo in ((make_config("cpu"), make_config("demo")), (make_config("cpu_first"), make_config("demo_first"))):
        differ = {f for f in TrainConfig.__dataclass_fields__ if getattr(cpu, f) != getattr(demo, f)}
        assert differ == {"batch_size", "steps", "vec_dim", "ckpt_every", "log_every"}
    # cpu / demo take the reference's loss weighting and nothing else of its model; the *_first presets are the
    # same sizes with the first objective (the field defaults), which reproduce the records made before
    for new, first in (("cpu", "cpu_first"), ("demo", "demo_first")):
        a, b = make_config(new), make_config(first)
        differ = {f for f in TrainConfig.__dataclass_fields__ if getattr(a, f) != getattr(b, f)}
        assert differ == objective
        assert {k: getattr(a, k) for k in objective} == REFERENCE_OBJECTIVE
        assert all(getattr(b, k) == TrainConfig.__dataclass_fields__[k].default for k in objective)
        assert (a.encoder, a.head_form, a.sigreg_pool, a.grad_clip) == ("groupnorm", "mlp", "step", 1.0)
    demo = make_config("demo")
    # the first paper model's 64-wide encoders (the reference's, the paper preset's now, output 96)
    assert demo.vec_dim == make_config("paper", **FIRST_PAPER_MODEL).vec_dim == 64
    paper = make_config("paper")
    assert {k: getattr(paper, k) for k in REFERENCE_MODEL} == REFERENCE_MODEL
    assert (paper.window, paper.horizons, paper.sigreg_weight, paper.sigreg_dirs, paper.lr) == (24, (1, 4, 16), 0.02, 1024, 3e-4)
    assert make_config("cpu").window == 24
    with pytest.raises(ConfigError, match="VFX"):
        make_config("tiny", variant="nope")
    with pytest.raises(ConfigError, match="window"):
        make_config("tiny", window=16)
    fields = TrainConfig.__dataclass_fields__
    for f in ("variant", "data", "out", "seed", "steps", "batch_size", "window", "horizons", "sigreg_weight",
              "touch_contact_weight", "glide_loss_weight", "image_size", "device", "amp", "ckpt_every",
              "log_every", "tensorboard", "ddp", "objective", "sysid_weight", "tokens"):
        assert f in fields


def test_loss_decreases_on_tiny_data(data_dir, tmp_path):
    cfg = make_config("tiny", data=data_dir, out=str(tmp_path / "r"), steps=60, log_every=10, lr=3e-3,
                      variant="VX_t", tensorboard=True)
    out = run(cfg)
    rows = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [0, 10, 20, 30, 40, 50, 60]
    start, rows = rows[0], rows[1:]
    assert {"glide_frame_share", "glide_loss_share_expected"} <= set(start)
    for k in ("pred_1", "pred_4", "pred_16"):  # the touch term is dominated by batch-of-4 noise
        assert rows[-1][k] < 0.5 * rows[0][k]
    assert {"frames_per_s", "lr", "sigreg", "pred_16", "glide_loss_share"} <= set(rows[0])
    assert (out / "DONE").exists() and (out / "final.pt").exists() and any((out / "tb").iterdir())


def test_resume_matches_uninterrupted(data_dir, tmp_path):
    kw = dict(data=data_dir, steps=10, variant="VFX", dropout=0.1)
    a = run(make_config("tiny", out=str(tmp_path / "a"), **kw))
    b_cfg = make_config("tiny", out=str(tmp_path / "b"), stop_at=5, **kw)
    run(b_cfg)
    assert not (tmp_path / "b" / "DONE").exists()
    assert torch.load(tmp_path / "b" / "ckpt.pt", weights_only=True)["step"] == 5
    b = run(make_config("tiny", out=str(tmp_path / "b"), **kw))
    sa = torch.load(a / "final.pt", weights_only=True)["model"]
    sb = torch.load(b / "final.pt", weights_only=True)["model"]
    for k in sa:
        assert torch.allclose(sa[k].float(), sb[k].float(), atol=1e-6), k
    la = [json.loads(x) for x in (a / "metrics.jsonl").read_text().splitlines()]
    lb = [json.loads(x) for x in (b / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in la] == [r["step"] for r in lb]
    assert la[-1]["loss"] == pytest.approx(lb[-1]["loss"], rel=1e-5)


def test_finished_run_returns_and_conflicts_raise(data_dir, tmp_path):
    cfg = make_config("tiny", data=data_dir, out=str(tmp_path / "r"), steps=3)
    out = run(cfg)
    mtime = (out / "final.pt").stat().st_mtime_ns
    run(cfg)
    assert (out / "final.pt").stat().st_mtime_ns == mtime
    with pytest.raises(ConfigError, match="different config"):
        run(make_config("tiny", data=data_dir, out=str(tmp_path / "r"), steps=3, sigreg_weight=0.1))


def test_a_run_being_trained_elsewhere_is_refused_and_freed_after(data_dir, tmp_path):
    """Two writers on one run directory (an orphaned map worker and a resumed map) would interleave checkpoints."""
    import subprocess
    import sys

    from pokeworld.io import run_lock

    cfg = make_config("tiny", data=data_dir, out=str(tmp_path / "r"), steps=2)
    # another process holds the run directory's lock while we try to train it
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from pokeworld.io import run_lock\n"
                               "with run_lock(sys.argv[1]):\n print('held', flush=True); time.sleep(60)",
                               cfg.out], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(ConfigError, match=f"being trained by pid {holder.pid}"):
            run(cfg)
        assert not (tmp_path / "r" / "ckpt.pt").exists()
    finally:
        holder.kill()
        holder.wait()
    assert (run(cfg) / "DONE").exists()  # the lock died with its holder: no stale lock
    with run_lock(cfg.out):
        pass


def test_nan_loss_stops_with_clear_error(data_dir, tmp_path, monkeypatch):
    from pokeworld.models import XJEPA

    orig = XJEPA.loss

    def bad(self, batch, **kw):
        loss, terms = orig(self, batch, **kw)
        terms["touch"] = torch.tensor(float("nan"))
        return loss * float("nan"), terms

    monkeypatch.setattr(XJEPA, "loss", bad)
    with pytest.raises(FloatingPointError, match=r"step 0.*touch"):
        run(make_config("tiny", data=data_dir, out=str(tmp_path / "nan"), variant="VX_t"))


def test_load_model_takes_raw_arrays_and_controls_run(data_dir, tmp_path):
    from pokeworld.data import load

    out = run(make_config("tiny", data=data_dir, out=str(tmp_path / "s"), steps=2, sysid_weight=0.5, objective="gnll"))
    m = load_model(out)
    assert not m.training and m.sysid_head is not None
    ds = load(data_dir)
    h = m.features(ds.frames[:2, :18], ds.proprio[:2, :18], ds.touch[:2, :18], ds.actions[:2, :18])
    assert h.shape == (2, 18, m.width)
    assert m.sysid(h).shape == (2, 18, 3)
    assert torch.allclose(m.proprio_mean, torch.as_tensor(ds.proprio[ds.episodes("train")].reshape(-1, 4).mean(0)), atol=1e-4)
    for kw in (dict(objective="recon"), dict(tokens=True, image_size=32)):
        run(make_config("tiny", data=data_dir, out=str(tmp_path / str(len(kw)) / kw.get("objective", "tok")), steps=2, **kw))


def test_sampler_batch_carries_glide_mask(data_dir):
    from pokeworld.data import load

    ds = load(data_dir)
    ep = ds.episodes("train")
    s = WindowSampler(ds, ep, 16, 18, torch.device("cpu"), seed=0)
    b = s.sample(16)
    assert b["frames"].shape == (16, 18, 16, 16) and b["frames"].dtype == torch.uint8
    np.testing.assert_array_equal(b["actions"].shape, (16, 18, 2))
    # the synthetic store has no object_vel label: glide frames fall back to "touch contact flag off"
    assert b["glide"].dtype == torch.bool and b["glide"].shape == (16, 18)
    assert torch.equal(b["glide"], b["touch"][..., 6] <= 0.5)
    assert 0 < float(b["glide"].float().mean()) < 1


def test_sigreg_pool_and_gnll_variance_options_validate_and_reach_the_loss():
    from pokeworld.train import loss_kwargs, model_kwargs

    cfg = make_config("tiny")
    assert (cfg.sigreg_pool, cfg.sigreg_rows, cfg.gnll_variance, cfg.gnll_beta, cfg.gnll_logvar_bound) == (
        "step", 4096, "bounded", 0.5, 2.0)
    kw = loss_kwargs(make_config("tiny", sigreg_pool="pooled", sigreg_rows=768))
    assert (kw["sigreg_pool"], kw["sigreg_rows"]) == ("pooled", 768)
    assert loss_kwargs(make_config("tiny", objective="gnll", gnll_variance="beta", gnll_beta=1.0))["gnll_beta"] == 1.0
    # 'free' was the default before 'bounded': configs and checkpoints of latent-objective runs written then record it
    assert model_kwargs(make_config("tiny", gnll_variance="free"), (4, 7, 2))["gnll_variance"] == "free"
    mk = model_kwargs(make_config("tiny", objective="gnll", gnll_variance="bounded", gnll_logvar_bound=3.0), (4, 7, 2))
    assert (mk["gnll_variance"], mk["gnll_logvar_bound"]) == ("bounded", 3.0)
    for bad, match in ((dict(sigreg_pool="window"), "unknown sigreg_pool"),
                       (dict(sigreg_rows=768), "applies to sigreg_pool='pooled' with global latents"),
                       (dict(sigreg_pool="pooled", sigreg_rows=0), "sigreg_rows must be"),
                       (dict(sigreg_pool="pooled", sigreg_rows=768, tokens=True, image_size=32), "not tokens=True"),
                       (dict(sigreg_pool="pooled", sigreg_rows=768, objective="recon"), "not objective='recon'"),
                       (dict(gnll_variance="beta"), "needs objective='gnll'"),
                       (dict(objective="gnll", gnll_variance="student"), "unknown gnll_variance"),
                       (dict(objective="gnll", gnll_variance="beta", gnll_beta=1.5),
                        r"gnll_beta must be a finite number in \[0, 1\]"),
                       (dict(objective="gnll", gnll_beta=0.9), "applies to gnll_variance='beta' only"),
                       (dict(objective="gnll", gnll_variance="free", gnll_logvar_bound=3.0),
                        "applies to gnll_variance='bounded' only"),
                       (dict(objective="gnll", gnll_variance="bounded", gnll_logvar_bound=0.0), "positive")):
        with pytest.raises(ConfigError, match=match):
            make_config("tiny", **bad)


def test_cli_flags_parse_to_the_new_fields():
    import tyro

    cfg = tyro.cli(TrainConfig, default=make_config("tiny"), args=[
        "--sigreg-pool", "pooled", "--sigreg-rows", "768", "--objective", "gnll", "--gnll-variance", "beta",
        "--gnll-beta", "1.0"])
    assert (cfg.sigreg_pool, cfg.sigreg_rows, cfg.gnll_variance, cfg.gnll_beta) == ("pooled", 768, "beta", 1.0)
    cfg = tyro.cli(TrainConfig, default=make_config("tiny"), args=[
        "--objective", "gnll", "--gnll-variance", "bounded", "--gnll-logvar-bound", "3.0"])
    assert (cfg.gnll_variance, cfg.gnll_logvar_bound) == ("bounded", 3.0)


def test_pooled_sigreg_row_subset_is_drawn_on_the_host_from_the_step_seed():
    from pokeworld.losses import subsample_index
    from pokeworld.train import sigreg_row_index, sigreg_seed

    cfg = make_config("tiny", sigreg_pool="pooled", sigreg_rows=32)  # 4 windows × 18 steps = 72 rows
    cpu = torch.device("cpu")
    idx = sigreg_row_index(cfg, 7, cpu)
    assert torch.equal(idx, subsample_index(72, 32, sigreg_seed(cfg, 7)))
    assert torch.equal(idx, sigreg_row_index(cfg, 7, cpu)) and not torch.equal(idx, sigreg_row_index(cfg, 8, cpu))
    assert sigreg_row_index(make_config("tiny"), 7, cpu) is None  # per-step: no subset
    assert sigreg_row_index(make_config("tiny", sigreg_pool="pooled", sigreg_rows=72), 7, cpu) is None  # all rows


@pytest.mark.parametrize("kw", [dict(sigreg_pool="pooled", sigreg_rows=32),
                                dict(objective="gnll", gnll_heads="all", gnll_variance="per_head"),
                                dict(objective="gnll", gnll_variance="bounded"),
                                dict(objective="gnll", gnll_variance="beta")])
def test_tiny_runs_with_the_new_options_train_record_and_load(data_dir, tmp_path, kw):
    out = run(make_config("tiny", data=data_dir, out=str(tmp_path / "r"), steps=4, log_every=2, **kw))
    rows = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert np.isfinite(rows[-1]["loss"]) and "sigreg" in rows[-1]
    if kw.get("objective") == "gnll":  # every variance parameterisation records its latent precision
        assert rows[-1]["latent_precision"] > 0
        assert ("latent_weight" in rows[-1]) == (kw["gnll_variance"] == "beta")
    m = load_model(out)
    assert m.gnll_variance == kw.get("gnll_variance", "bounded")
    assert (m.latent_logvar is not None) == (kw.get("gnll_variance") == "per_head")


def test_runs_recorded_before_the_options_resume_unchanged(data_dir, tmp_path):
    """A config.json written before sigreg_pool / gnll_variance existed lacks them: it means per-step SIGReg
    (still the default) and free variances (the default then; 'bounded' now), so it resumes with
    gnll_variance='free' and conflicts with any other reading, the new default included."""
    kw = dict(data=data_dir, out=str(tmp_path / "old"), steps=4, objective="gnll", gnll_variance="free")
    run(make_config("tiny", stop_at=2, **kw))
    path = tmp_path / "old" / "config.json"
    old = json.loads(path.read_text())
    new_fields = ("sigreg_pool", "sigreg_rows", "gnll_variance", "gnll_beta", "gnll_logvar_bound")
    path.write_text(json.dumps({k: v for k, v in old.items() if k not in new_fields}))
    for bad in (dict(sigreg_pool="pooled"), dict(gnll_variance="bounded"), dict(gnll_variance="beta")):
        with pytest.raises(ConfigError, match="different config"):
            run(make_config("tiny", **{**kw, **bad}))
    assert (run(make_config("tiny", **kw)) / "DONE").exists()
    # its checkpoint, written before the kwarg existed, loads as the free-variance model it is
    from pokeworld import checkpoint

    for name in ("final.pt", "ckpt.pt"):
        ck = checkpoint.load(tmp_path / "old" / name)
        del ck["model_kwargs"]["gnll_variance"]
        torch.save(ck, tmp_path / "old" / name)
    assert load_model(tmp_path / "old").gnll_variance == "free"


def test_status_lines_report_step_loss_speed_and_time_left(data_dir, tmp_path, capsys):
    """Runs the map launches have no progress bar (parallel workers would tear it): they print a status line every
    ``status_every`` seconds instead; a run with the default prints none."""
    run(make_config("tiny", data=data_dir, out=str(tmp_path / "quiet"), steps=4))
    assert "[train" not in capsys.readouterr().out
    run(make_config("tiny", data=data_dir, out=str(tmp_path / "loud"), steps=10), status_every=1e-9)
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("[train loud]")]
    assert len(lines) == 10 and lines[-1].startswith("[train loud] step 10/10")
    assert "loss" in lines[-1] and "steps/s" in lines[-1] and "min left" in lines[-1]
