"""Fast training path (train.py ``fast``/``compile``/``channels_last``) and wall-clock deadlines.

The fast path exists for GPUs, where its benefit (no host sync per step) is measured by
benchmarks/train_fast_path.py; on CPU these tests check that it computes the same thing.
"""

import copy
import json

import pytest
import torch

from pokeworld import clock, train
from pokeworld.train import loop
from pokeworld.data import save
from pokeworld.errors import ConfigError
from pokeworld.models import XJEPA
from pokeworld.train import (WindowSampler, compiled, loss_kwargs, make_config, model_kwargs, run,
                             sigreg_directions, sigreg_seed, synthetic_dataset, use_fast_path)

CPU = torch.device("cpu")
# at the tiny preset's 16 px the CNN's last map is 1×1 and its GroupNorm (one channel per group) zeroes the
# CNN's gradient, leaving rounding noise that Adam turns into lr-sized sign steps; 32 px gives a live CNN
LIVE_CNN = dict(image_size=32)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fp") / "syn"
    save(synthetic_dataset(num_episodes=12, steps=24, size=32, seed=0), d)
    return str(d)


def _rows(run_dir):
    return [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()][1:]


def _model_and_sampler(cfg, non_blocking=False):
    ds = synthetic_dataset(num_episodes=12, steps=24, size=32, seed=0)
    ep = ds.episodes("train")
    sampler = WindowSampler(ds, ep, cfg.image_size, cfg.window, CPU, seed=5, non_blocking=non_blocking)
    torch.manual_seed(0)
    model = XJEPA(**model_kwargs(cfg, (4, 7, 2)))
    model.set_stats(train.data_stats(ds, ep))
    return model.train(), sampler


def _loss_and_grads(model, batch, **kw):
    torch.manual_seed(123)  # the same dropout masks on both sides
    model.zero_grad(set_to_none=True)
    loss, terms = model.loss(batch, **kw)
    loss.backward()
    return loss.detach(), terms, {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}


def test_fast_setting_is_cuda_only_by_default_and_validated():
    cfg = make_config("tiny")
    assert cfg.fast == "auto" and cfg.compile == "auto" and not cfg.channels_last and cfg.deadline == 0
    assert not use_fast_path(cfg, CPU) and use_fast_path(cfg, torch.device("cuda"))
    assert use_fast_path(make_config("tiny", fast="on"), CPU)
    assert not use_fast_path(make_config("tiny", fast="off"), torch.device("cuda"))
    with pytest.raises(ConfigError, match="fast"):
        make_config("tiny", fast="yes")


def test_fast_path_samples_the_same_windows_and_gives_the_same_loss():
    cfg = make_config("tiny", **LIVE_CNN)
    plain, s_plain = _model_and_sampler(cfg)
    fast, s_fast = _model_and_sampler(cfg, non_blocking=True)
    fast.to(memory_format=torch.channels_last)
    convs = [p for p in fast.parameters() if p.dim() == 4]
    assert convs and all(p.is_contiguous(memory_format=torch.channels_last) and not p.is_contiguous() for p in convs)
    kw = loss_kwargs(cfg)
    for step in (0, 7):
        a, b = s_plain.sample(cfg.batch_size), s_fast.sample(cfg.batch_size)
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
        # plain: directions drawn inside SIGReg from the seed; fast: drawn by the trainer and passed in
        lp, tp, gp = _loss_and_grads(plain, a, sigreg_seed=sigreg_seed(cfg, step), **kw)
        lf, tf, gf = _loss_and_grads(fast, b, sigreg_seed=sigreg_seed(cfg, step),
                                     sigreg_directions=sigreg_directions(cfg, step, CPU, non_blocking=True), **kw)
        torch.testing.assert_close(lf, lp, rtol=1e-5, atol=1e-6)
        assert tf.keys() == tp.keys()
        for k in tp:
            torch.testing.assert_close(tf[k], tp[k], rtol=1e-5, atol=1e-6, msg=k)
        assert gf.keys() == gp.keys()
        # the layouts sum the convolutions in different orders; conv biases ahead of a GroupNorm have an
        # exactly-zero true gradient, so tolerances are relative to the largest gradient, not per element
        scale = max(float(g.abs().max()) for g in gp.values())
        for n in gp:
            torch.testing.assert_close(gf[n], gp[n], rtol=1e-4, atol=1e-4 * scale, msg=n)
    # a different step really draws different directions (the test above is not vacuous)
    assert not torch.equal(sigreg_directions(cfg, 0, CPU), sigreg_directions(cfg, 7, CPU))


def test_fast_and_plain_training_runs_agree_and_sync_only_at_log_steps(data_dir, tmp_path, monkeypatch):
    kw = dict(data=data_dir, steps=10, variant="VFX", **LIVE_CNN)
    a = run(make_config("tiny", out=str(tmp_path / "plain"), fast="off", **kw))
    checks = []
    orig = loop.check_finite
    monkeypatch.setattr(loop, "check_finite", lambda *args: (checks.append(args[2]), orig(*args))[1])
    b = run(make_config("tiny", out=str(tmp_path / "fast"), fast="on", channels_last=True, **kw))
    assert checks == [5, 10]  # log_every = ckpt_every = 5 in the tiny preset: no per-step host sync
    ra, rb = _rows(a), _rows(b)
    assert [r["step"] for r in ra] == [r["step"] for r in rb] == [5, 10]
    for x, y in zip(ra, rb):
        for k in ("loss", "sigreg", "pred_1", "touch", "proprio", "grad_norm"):
            assert y[k] == pytest.approx(x[k], rel=1e-4, abs=1e-6), k
    sa = torch.load(a / "final.pt", weights_only=True)["model"]
    sb = torch.load(b / "final.pt", weights_only=True)["model"]
    # biases that a normalisation removes (conv -> GroupNorm, proj -> BatchNorm, and that BatchNorm's running
    # mean of them) have an exactly-zero true gradient: Adam turns its rounding into lr-sized sign steps
    model = XJEPA(**torch.load(a / "final.pt", weights_only=True)["model_kwargs"])
    normalised_away = {f"{n}.bias" for n, m in model.named_modules() if isinstance(m, torch.nn.Conv2d)}
    normalised_away |= {"encoder.proj.bias", "encoder.norm.running_mean"}
    assert normalised_away <= set(sa)
    for k in set(sa) - normalised_away:  # fused vs foreach AdamW and the two conv layouts differ only by rounding
        torch.testing.assert_close(sb[k].float(), sa[k].float(), rtol=1e-4, atol=1e-5, msg=k)
    # a run may switch path between slices (fast is a resumable field) ...
    run(make_config("tiny", out=str(tmp_path / "fast"), fast="off", channels_last=True, **kw))
    # ... but not memory layout, which the checkpointed optimizer state carries
    with pytest.raises(ConfigError, match="channels_last"):
        run(make_config("tiny", out=str(tmp_path / "fast"), fast="on", **kw))


@pytest.mark.slow
def test_compiled_and_eager_losses_agree():
    cfg = make_config("tiny", dropout=0.0)  # inductor draws dropout masks from its own RNG
    model, sampler = _model_and_sampler(cfg)
    batch = sampler.sample(cfg.batch_size)
    kw = dict(loss_kwargs(cfg), sigreg_seed=sigreg_seed(cfg, 3), sigreg_directions=sigreg_directions(cfg, 3, CPU))
    le, te, ge = _loss_and_grads(model, batch, **kw)
    twin = copy.deepcopy(model)
    twin.loss = compiled(twin.loss)
    try:
        lc, tc, gc = _loss_and_grads(twin, batch, **kw)
    except Exception as e:  # no C++ toolchain / unsupported platform: nothing to compare on this machine
        pytest.skip(f"torch.compile does not work on this CPU: {type(e).__name__}: {e}")
    torch.testing.assert_close(lc, le, rtol=1e-4, atol=1e-5)
    for k in te:
        torch.testing.assert_close(tc[k], te[k], rtol=1e-4, atol=1e-5, msg=k)
    for n in ge:
        torch.testing.assert_close(gc[n], ge[n], rtol=1e-3, atol=1e-5, msg=n)


def test_train_step_calls_a_loss_wrapper_without_asking_its_truth_value():
    """``torch.compile`` returns a module wrapper whose ``len()`` (hence truth value) raises TypeError in torch
    2.13; ``train_step`` must call the wrapper it is given, not test it, or ``--compile`` training crashes."""
    cfg = make_config("tiny")
    model, sampler = _model_and_sampler(cfg)
    calls = []

    class NoTruthValue:
        def __call__(self, *a, **kw):
            calls.append(1)
            return model(*a, **kw)

        def __len__(self):
            raise TypeError("XJEPA does not support len()")

    opt = train.make_optimizer(model, cfg)
    loss, _ = train.train_step(model, opt, cfg, sampler.sample(cfg.batch_size), 0, CPU, loss_kwargs(cfg),
                               loss_fn=NoTruthValue())
    assert calls == [1] and torch.isfinite(loss)


class FakeClock:
    """Wall clock that advances one minute per training step (each call of XJEPA.loss)."""

    def __init__(self, monkeypatch, start=1e9):
        self.t = start
        orig = XJEPA.loss

        def loss(model, *a, **kw):
            self.t += 60
            return orig(model, *a, **kw)

        monkeypatch.setattr(XJEPA, "loss", loss)
        monkeypatch.setattr(clock, "wall_clock", lambda: self.t)


def test_deadline_checkpoints_partway_and_resume_matches_uninterrupted(data_dir, tmp_path, monkeypatch):
    clock = FakeClock(monkeypatch)
    kw = dict(data=data_dir, steps=10, variant="VX_t")
    full = run(make_config("tiny", out=str(tmp_path / "full"), **kw))
    sliced = tmp_path / "sliced"
    run(make_config("tiny", out=str(sliced), deadline=clock.t + 3 * 60, **kw))
    assert not (sliced / "DONE").exists()
    assert torch.load(sliced / "ckpt.pt", weights_only=True)["step"] == 3
    assert _rows(sliced)[-1]["step"] == 3
    run(make_config("tiny", out=str(sliced), deadline=clock.t, **kw))  # out of time before starting: a no-op
    assert torch.load(sliced / "ckpt.pt", weights_only=True)["step"] == 3
    run(make_config("tiny", out=str(sliced), **kw))
    assert (sliced / "DONE").exists()
    sa = torch.load(full / "final.pt", weights_only=True)["model"]
    sb = torch.load(sliced / "final.pt", weights_only=True)["model"]
    for k in sa:
        assert torch.allclose(sa[k].float(), sb[k].float(), atol=1e-6), k
    assert _rows(sliced)[-1]["loss"] == pytest.approx(_rows(full)[-1]["loss"], rel=1e-5)
