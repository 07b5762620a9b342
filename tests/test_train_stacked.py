"""Stacked ensembles (pokeworld.train.stacked): M runs in one vmapped step equal M separate runs."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from pokeworld import train
from pokeworld.train import stacked as train_stacked
from pokeworld.data import save
from pokeworld.errors import ConfigError
from pokeworld.models import XJEPA
from pokeworld.train.stacked import embed_state, plan_groups, superset_variant

# 32 px keeps the CNN alive (at tiny's 16 px its GroupNorm zeroes the CNN gradient, see test_fast_path);
# dropout 0 because stacked members draw their own masks, not their separate runs' masks
BASE = dict(image_size=32, dropout=0.0, steps=4, log_every=2, ckpt_every=2)


def _dataset():
    """The synthetic corpus with noise on the touch force channels: its touch is otherwise zero in most
    windows, a batch-constant feature that the encoder's BatchNorm removes, leaving the touch MLP a
    true gradient of zero whose rounding Adam would turn into lr-sized steps (as for the biases below)."""
    ds = train.synthetic_dataset(num_episodes=12, steps=24, size=32, seed=0)
    ds.touch[..., :6] += np.random.default_rng(1).normal(0, 0.1, ds.touch[..., :6].shape).astype(np.float32)
    return ds


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("stk") / "syn"
    save(_dataset(), d)
    return str(d)


def _cfgs(data_dir, root, **kw):
    """Two VFX members (different seed and λ: per-member windows, directions and loss weights) and a V
    member (embedded into VFX: zero input MLPs, zero forecasting heads)."""
    members = [dict(variant="VFX", seed=0, sigreg_weight=0.02), dict(variant="VFX", seed=1, sigreg_weight=0.3),
               dict(variant="V", seed=2)]
    return [train.make_config("tiny", data=data_dir, out=str(root / f"m{i}"), **BASE, **m, **kw)
            for i, m in enumerate(members)]


def _rows(d):
    return [json.loads(x) for x in (d / "metrics.jsonl").read_text().splitlines()]


def _final(d):
    return torch.load(d / "final.pt", map_location="cpu", weights_only=True)["model"]


def _init_state(run_dir):
    ck = torch.load(run_dir / "final.pt", map_location="cpu", weights_only=True)
    torch.manual_seed(ck["config"]["seed"])  # as train.run before construction
    return XJEPA(**ck["model_kwargs"]).state_dict()


def _assert_same_run(a, b, rtol=1e-4, atol=1e-5):
    ra, rb = _rows(a), _rows(b)
    assert [r["step"] for r in ra] == [r["step"] for r in rb] == [0, 2, 4]
    for x, y in zip(ra[1:], rb[1:]):
        terms = set(x) - {"frames_per_s", "steps_per_s", "stacked_members"}
        assert terms <= set(y) and "loss" in terms and "grad_norm" in terms
        for k in terms:
            assert y[k] == pytest.approx(x[k], rel=rtol, abs=atol), k
    fa, fb = _final(a), _final(b)
    assert fa.keys() == fb.keys()
    # biases that a normalisation removes (conv -> GroupNorm, proj -> BatchNorm, and that BatchNorm's running
    # mean of them) have an exactly-zero true gradient: Adam turns its rounding into lr-sized sign steps
    model = train.load_model(a)
    normalised_away = {f"{n}.bias" for n, m in model.named_modules() if isinstance(m, torch.nn.Conv2d)}
    normalised_away |= {"encoder.proj.bias", "encoder.norm.running_mean"}
    assert normalised_away <= set(fa)
    # Adam divides by the gradient's own scale, so an element whose true gradient is ~0 by cancellation
    # turns rounding into an lr-sized step; hence per tensor: the two runs' difference is a small fraction
    # of what training moved the weights (a wrong batch, λ, clip or optimizer state gives O(1))
    init = _init_state(a)
    moved = 0
    for k in set(fa) - normalised_away:
        if not fa[k].is_floating_point() or k.endswith(("_mean", "_std", "running_var")):
            torch.testing.assert_close(fb[k], fa[k], rtol=rtol, atol=atol, msg=k)
            continue
        step = (fa[k] - init[k]).norm()
        if step > 0:
            moved += 1
            assert (fb[k] - fa[k]).norm() <= 0.02 * step, k
        else:
            torch.testing.assert_close(fb[k], fa[k], rtol=0, atol=0, msg=k)
    assert moved > 20


#: the paper preset's objective and model (the released reference's; train.config.REFERENCE_MODEL) at tiny sizes
REFERENCE_FORM = dict(encoder="reference", head_form="reference", sensor_horizons=(1, 4),
                      latent_horizon_weights=(1.0, 0.5), sensor_horizon_weights=(0.5, 0.25),
                      contact_weighting="frames", sigreg_pool="pooled", sigreg_knots=9, sigreg_t_max=5.0, grad_clip=5.0)


@pytest.mark.parametrize("form", [{}, REFERENCE_FORM], ids=["first", "reference"])
def test_one_stacked_step_equals_the_separate_steps(form):
    """Same windows, same loss and the same gradients on the same batch (the issue's numerics check); the V
    member embeds into VFX under either encoder form (the reference's fusion MLP reads the vision bottleneck first,
    so V's fusion weights are a leading slice of VFX's)."""
    from pokeworld.train.stacked import StackedGroup

    ds = _dataset()
    cfgs = _cfgs("unused", Path("/nonexistent"), **form)
    g = StackedGroup(cfgs, torch.device("cpu"), fast=False, ds=ds)
    assert g.super_variant == "VFX" and set(g.member_kw) == {"sigreg_weight", "proprio_weight", "touch_weight"}
    batch, dirs = g.sample(cfgs[0].batch_size), g.directions(3)
    loss, terms = g.vloss(g.params, g.buffers, batch, dirs, g.member_kw)
    loss.sum().backward()
    for i, (c, m) in enumerate(zip(cfgs, g.members)):
        alone = train.WindowSampler(ds, ds.episodes("train"), c.image_size, c.window, torch.device("cpu"),
                                    seed=c.seed * 1000 + 1).sample(c.batch_size)
        mine = {k: v[i] for k, v in batch.items()}
        assert mine.keys() == alone.keys() and all(torch.equal(mine[k], alone[k]) for k in alone)
        torch.testing.assert_close(dirs[i], train.sigreg_directions(c, 3, torch.device("cpu")))
        m.zero_grad(set_to_none=True)
        ref, ref_terms = m.loss(mine, sigreg_directions=dirs[i], **train.loss_kwargs(c))
        ref.backward()
        torch.testing.assert_close(loss[i].detach(), ref.detach(), rtol=1e-5, atol=1e-6)
        assert set(ref_terms) <= set(terms)
        for k in ref_terms:
            torch.testing.assert_close(terms[k][i], ref_terms[k], rtol=1e-5, atol=1e-6, msg=k)
        own = dict(m.named_parameters())
        # conv biases ahead of a GroupNorm have an exactly-zero true gradient, so tolerances are relative
        # to the member's largest gradient, not per element (as tests/test_fast_path.py)
        scale = max(float(p.grad.abs().max()) for p in own.values() if p.grad is not None)
        for n, p in g.params.items():
            gs = p.grad[i]
            if n not in own:  # a part of the superset the V member lacks: exactly zero gradient
                assert gs.abs().max() == 0, n
                continue
            gr = own[n].grad if own[n].grad is not None else torch.zeros_like(own[n])
            lead = tuple(slice(0, k) for k in gr.shape)
            sub, rest = gs[lead], gs.clone()
            rest[lead] = 0
            assert rest.abs().max() == 0, n  # the zero-padded columns get no gradient
            torch.testing.assert_close(sub, gr, rtol=1e-4, atol=1e-4 * scale, msg=n)


def test_stacked_members_equal_their_separate_runs(data_dir, tmp_path):
    sep = _cfgs(data_dir, tmp_path / "sep")
    stk = _cfgs(data_dir, tmp_path / "stk")
    for c in sep:
        train.run(c)
    assert plan_groups(stk) == [[0, 1, 2]]
    outs = train_stacked.run(stk)
    for c, out in zip(sep, outs):
        for f in ("config.json", "metrics.jsonl", "ckpt.pt", "final.pt", "DONE"):
            assert (out / f).exists(), f
        assert json.loads((out / "config.json").read_text()) == json.loads(
            (tmp_path / "sep" / out.name / "config.json").read_text().replace("/sep/", "/stk/"))
        _assert_same_run(tmp_path / "sep" / out.name, out)
        assert _rows(out)[-1]["stacked_members"] == 3
    # the V member is saved in its own layout and loads as a V model
    m = train.load_model(outs[2])
    assert m.variant == "V" and "touch" not in m.modal_heads and m.encoder.proprio is None
    assert "touch" not in _rows(outs[2])[-1] and "touch" in _rows(outs[0])[-1]
    # the planted difference is visible: the two VFX members trained apart
    assert not torch.allclose(_final(outs[0])["encoder.proj.weight"], _final(outs[1])["encoder.proj.weight"])
    # finished runs return at once
    before = (outs[0] / "final.pt").stat().st_mtime_ns
    train_stacked.run(stk)
    assert (outs[0] / "final.pt").stat().st_mtime_ns == before


def test_stacked_checkpoint_resumes_stacked_and_alone(data_dir, tmp_path):
    train_stacked.run(_cfgs(data_dir, tmp_path / "full"))
    part = _cfgs(data_dir, tmp_path / "part", stop_at=2)
    train_stacked.run(part)
    assert all((tmp_path / "part" / f"m{i}" / "ckpt.pt").exists() for i in range(3))
    assert not (tmp_path / "part" / "m0" / "DONE").exists()
    # members 0 and 1 resume stacked; member 2 (the embedded V) resumes alone with train.run
    resumed = _cfgs(data_dir, tmp_path / "part")
    train_stacked.run(resumed[:2])
    train.run(resumed[2])
    for i in range(3):
        _assert_same_run(tmp_path / "full" / f"m{i}", tmp_path / "part" / f"m{i}")


def test_grouping_and_superset():
    mk = lambda **kw: train.make_config("tiny", out=f"/tmp/x{len(kw)}{sorted(kw.items())}", **kw)  # noqa: E731
    cfgs = [mk(seed=0), mk(seed=1, sigreg_weight=0.1), mk(variant="V"), mk(lr=1e-2), mk(sysid_weight=0.5)]
    assert plan_groups(cfgs) == [[0, 1, 2], [3], [4]]
    assert plan_groups(cfgs, mix_variants=False) == [[0, 1], [2], [3], [4]]
    assert plan_groups(cfgs, max_members=2) == [[0, 1], [2], [3], [4]]
    assert superset_variant(["V"]) == "V"
    assert superset_variant(["V", "VX_p"]) == "VX_p"
    assert superset_variant(["VF", "VX_p"]) == "VFX"
    assert superset_variant(["VX_p", "VX_t"]) == "VX"
    with pytest.raises(ConfigError, match="tokens"):
        plan_groups([mk(tokens=True)])
    with pytest.raises(ConfigError, match="output directory"):
        plan_groups([mk(seed=0), mk(seed=0)])
    e = embed_state({"w": torch.ones(2, 3)}, {"w": torch.empty(2, 5), "b": torch.empty(4)})
    assert e["w"][:, :3].eq(1).all() and e["w"][:, 3:].eq(0).all() and e["b"].eq(0).all()
    with pytest.raises(ConfigError, match="embed"):
        embed_state({"w": torch.ones(3, 3)}, {"w": torch.empty(2, 5)})


def test_cli_trains_a_grid(data_dir, tmp_path):
    from pokeworld.cli import main

    out = tmp_path / "grid"
    rc = main(["train-stacked", "--preset", "tiny", "--data", data_dir, "--out", str(out), "--variants", "V", "VX_t",
               "--seeds", "0", "1", "--steps", "2"])
    assert rc == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["VX_t_s0", "VX_t_s1", "V_s0", "V_s1"]
    assert all((out / n / "DONE").exists() for n in names)
    assert train.load_model(out / "VX_t_s1").variant == "VX_t"
