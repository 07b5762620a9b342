"""Stacked training (pokeworld.train.stacked) with pooled SIGReg and the Gaussian-NLL variance options: one
vmapped step equals the members' separate steps."""

from pathlib import Path

import numpy as np
import pytest
import torch

from pokeworld import train
from pokeworld.train.stacked import StackedGroup


def _dataset():
    ds = train.synthetic_dataset(num_episodes=12, steps=24, size=32, seed=0)
    ds.touch[..., :6] += np.random.default_rng(1).normal(0, 0.1, ds.touch[..., :6].shape).astype(np.float32)
    return ds


@pytest.mark.parametrize("kw", [dict(sigreg_pool="pooled", sigreg_rows=32),
                                dict(objective="gnll", gnll_heads="all", gnll_variance="per_head"),
                                dict(objective="gnll", gnll_variance="beta", gnll_beta=1.0),
                                dict(encoder="reference", head_form="reference", sensor_horizons=(1, 4),
                                     latent_horizon_weights=(1.0, 0.5), sensor_horizon_weights=(0.5, 0.25),
                                     contact_weighting="frames", sigreg_pool="pooled", sigreg_knots=9,
                                     sigreg_t_max=5.0)])
def test_one_stacked_step_equals_the_separate_steps_with_the_new_options(kw):
    """Each member's pooled-SIGReg row subset is its separate run's (drawn on the host from its own seed and
    the step; inside vmap the loss has no per-member seed), and per-head log-variances stack like any
    parameter: same loss and terms per member."""
    ds = _dataset()
    members = [dict(variant="VFX", seed=0, sigreg_weight=0.02), dict(variant="VFX", seed=1, sigreg_weight=0.3),
               dict(variant="VX_t", seed=2)]
    cfgs = [train.make_config("tiny", data="unused", out=f"/nonexistent/m{i}", image_size=32, dropout=0.0, **m, **kw)
            for i, m in enumerate(members)]
    g = StackedGroup(cfgs, torch.device("cpu"), fast=False, ds=ds)
    step = 3
    batch, dirs, skw = g.sample(cfgs[0].batch_size), g.directions(step), g.step_kw(step)
    subsampled = kw.get("sigreg_pool") == "pooled" and "sigreg_rows" in kw  # else every row: nothing to draw
    assert ("sigreg_row_index" in skw) == subsampled
    if subsampled:
        rows = skw["sigreg_row_index"]
        assert rows.shape == (3, 32) and not torch.equal(rows[0], rows[1])  # per member, from its own seed
    with torch.no_grad():
        loss, terms = g.vloss(g.params, g.buffers, batch, dirs, skw)
        for i, (c, m) in enumerate(zip(cfgs, g.members)):
            mine = {k: v[i] for k, v in batch.items()}
            extra = {}
            idx = train.sigreg_row_index(c, step, torch.device("cpu"))
            if idx is not None:
                extra["sigreg_row_index"] = idx
            m.train()
            ref, ref_terms = m.loss(mine, sigreg_directions=dirs[i], sigreg_seed=train.sigreg_seed(c, step),
                                    **extra, **train.loss_kwargs(c))
            torch.testing.assert_close(loss[i], ref, rtol=1e-5, atol=1e-6)
            for k in ref_terms:
                torch.testing.assert_close(terms[k][i], ref_terms[k], rtol=1e-5, atol=1e-6, msg=k)
    if kw.get("gnll_variance") == "per_head":
        assert {"latent_logvar.1", "modal_logvar.touch.16", "modal_logvar.proprio.4"} <= set(g.params)


def test_stacked_pooled_run_trains_and_matches_its_separate_run_terms(tmp_path):
    """End to end on the tiny preset: a stacked pooled member's first logged SIGReg term equals its separate
    run's (dropout 0, so the runs agree to float rounding)."""
    import json

    from pokeworld.train import stacked as train_stacked
    from pokeworld.data import save

    save(_dataset(), tmp_path / "syn")
    base = dict(data=str(tmp_path / "syn"), image_size=32, dropout=0.0, steps=2, log_every=1, ckpt_every=2,
                sigreg_pool="pooled", sigreg_rows=32)
    stk = [train.make_config("tiny", out=str(tmp_path / "stk" / f"m{s}"), seed=s, **base) for s in (0, 1)]
    train_stacked.run(stk)
    alone = train.run(train.make_config("tiny", out=str(tmp_path / "alone"), seed=1, **base))
    rows = lambda d: [json.loads(x) for x in (Path(d) / "metrics.jsonl").read_text().splitlines()]
    a, b = rows(stk[1].out)[1], rows(alone)[1]
    assert a["sigreg"] == pytest.approx(b["sigreg"], rel=1e-4)
    assert a["loss"] == pytest.approx(b["loss"], rel=1e-4)
