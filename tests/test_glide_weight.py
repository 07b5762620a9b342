"""Glide-frame loss weight (paper App. C, dose-response 1): share of the loss, exact weighting, gradients, logging."""

import json

import numpy as np
import pytest
import torch

from pokeworld.data import save
from pokeworld.errors import ConfigError
from pokeworld.losses import glide_loss_share
from pokeworld.models import XJEPA
from pokeworld.train import WindowSampler, data_stats, make_config, model_kwargs, run
from pokeworld.windows import glide_frames

HORIZONS = (1, 4, 16)


def share_at(s: float, w: float) -> float:
    return w * s / (w * s + 1 - s)


@pytest.fixture(scope="module")
def sampler(tiny_dataset):
    return WindowSampler(tiny_dataset, tiny_dataset.episodes("train"), 16, 24, torch.device("cpu"), seed=0)


def test_paper_dose_numbers_follow_from_the_loss_weight():
    # App. C: 32% at weight 1 -> 65/88/97% at 4/16/64, the loss-mass reading of the weights
    assert [round(share_at(0.32, w), 2) for w in (4, 16, 64)] == [0.65, 0.88, 0.97]


def test_sampler_glide_mask_is_the_window_definition(tiny_dataset, sampler):
    ds = tiny_dataset
    ep = ds.episodes("train")
    np.testing.assert_array_equal(sampler.glide_np, glide_frames(ds)[ep])
    assert not sampler.glide_np[ds.labels["contact"][ep] > 0].any()  # a contact frame never glides
    b = sampler.sample(32)
    assert b["glide"].shape == (32, 24) and b["glide"].dtype == torch.bool


def test_realised_share_rises_with_weight_as_predicted(sampler):
    batches = [sampler.sample(64)["glide"] for _ in range(40)]
    measured = {w: np.mean([float(glide_loss_share(g, w, HORIZONS)) for g in batches]) for w in (0.0, 1.0, 4.0, 16.0)}
    s = measured[1.0]
    assert 0.1 < s < 0.9, "the tiny simulated corpus should hold glide and non-glide frames"
    assert measured[0.0] == 0.0
    assert measured[1.0] < measured[4.0] < measured[16.0]
    for w in (4.0, 16.0):
        assert measured[w] == pytest.approx(share_at(s, w), abs=0.01)
    # the corpus-level expectation reported at the start of a run agrees with the batches
    exp1, exp4 = sampler.glide_share(HORIZONS, 1.0), sampler.glide_share(HORIZONS, 4.0)
    assert exp1["glide_loss_share_expected"] == pytest.approx(exp1["glide_frame_share"])
    assert exp1["glide_frame_share"] == pytest.approx(s, abs=0.02)
    assert exp4["glide_loss_share_expected"] == pytest.approx(measured[4.0], abs=0.02)


def _model(ds, variant="VFX", **kw) -> XJEPA:
    cfg = make_config("tiny", variant=variant, **kw)
    ep = ds.episodes("train")
    torch.manual_seed(0)
    m = XJEPA(**model_kwargs(cfg, (ds.proprio.shape[-1], ds.touch.shape[-1], ds.actions.shape[-1])))
    m.set_stats(data_stats(ds, ep))
    return m.eval()  # no dropout: two loss calls see the same network


def test_weight_one_is_the_unweighted_loss(tiny_dataset, sampler):
    m = _model(tiny_dataset)
    b = sampler.sample(8)
    old = {k: v for k, v in b.items() if k != "glide"}
    with torch.no_grad():
        l_old, t_old = m.loss(old, sigreg_seed=3)
        l_new, t_new = m.loss(b, sigreg_seed=3, glide_loss_weight=1.0)
    assert float(l_new) == float(l_old)
    assert "glide_loss_share" not in t_old and 0 < float(t_new["glide_loss_share"]) < 1
    with pytest.raises(ValueError, match="glide"):
        m.loss(old, glide_loss_weight=4.0)


@pytest.mark.parametrize("w", [0.0, 4.0])
def test_weighted_terms_match_a_direct_weighted_mean(tiny_dataset, sampler, w):
    m = _model(tiny_dataset)
    b = sampler.sample(8)
    g = b["glide"].float()
    with torch.no_grad():
        _, terms = m.loss(b, sigreg_seed=3, glide_loss_weight=w, touch_contact_weight=4.0)
        z = m.encode(b["frames"], b["proprio"], b["touch"])
        h = m.trunk(z, b["actions"])
        L = z.shape[1]
        touch = []
        for d in HORIZONS:
            gw = 1 + (w - 1) * g[:, d:]
            err = (m.predict(h, b["actions"], d)[:, :L - d] - z[:, d:]).pow(2).mean(-1)
            assert float(terms[f"pred_{d}"]) == pytest.approx(float((gw * err).sum() / gw.sum()), rel=1e-5)
            cw = 1 + 3 * (b["touch"][:, d:, 6] > 0.5).float()
            e_t = (m.forecast(h, b["actions"], d, "touch", raw=False)[:, :L - d] - m.norm("touch", b["touch"])[:, d:])
            e_t = e_t.pow(2).mean(-1)
            touch.append(float((cw * gw * e_t).sum() / (cw * gw).sum()))
    assert float(terms["touch"]) == pytest.approx(np.mean(touch), rel=1e-5)
    assert float(terms["glide_loss_share"]) == pytest.approx(float(glide_loss_share(b["glide"], w, HORIZONS)))


def test_weight_zero_removes_glide_frames_from_the_gradient(tiny_dataset, sampler):
    # VX: proprio and touch are prediction targets only, so their gradient is exactly the target frames' pull
    m = _model(tiny_dataset, variant="VX")
    b = sampler.sample(8)
    g = b["glide"]
    assert g[:, 1:].any() and (~g[:, 1:]).any()

    def grads(w):
        p = b["proprio"].clone().requires_grad_(True)
        t = b["touch"].clone().requires_grad_(True)
        loss, _ = m.loss(dict(b, proprio=p, touch=t), sigreg_weight=0.0, glide_loss_weight=w)
        loss.backward()
        return p.grad.abs().sum(-1), t.grad.abs().sum(-1)

    for gr in grads(0.0):
        assert float(gr[g].abs().max()) == 0.0  # perturbing glide frames cannot change the loss
        assert float(gr[:, 1:][~g[:, 1:]].abs().max()) > 0
    for gr in grads(1.0):
        assert float(gr[:, 1:][g[:, 1:]].abs().max()) > 0


def test_run_logs_expected_and_realised_share(tiny_dataset, tmp_path):
    data = tmp_path / "sim"
    save(tiny_dataset, data)
    out = run(make_config("tiny", data=str(data), out=str(tmp_path / "r"), steps=4, log_every=2, window=24,
                          glide_loss_weight=4.0))
    rows = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [0, 2, 4]
    s = rows[0]["glide_frame_share"]
    assert 0.1 < s < 0.9
    # per-horizon shares averaged, so the formula at the mean s holds to second order
    assert rows[0]["glide_loss_share_expected"] == pytest.approx(share_at(s, 4.0), abs=5e-3)
    assert all(0 <= r["glide_loss_share"] <= 1 for r in rows[1:])
    assert json.loads((out / "config.json").read_text())["glide_loss_weight"] == 4.0


def test_config_validation_and_retired_sampling_weight(tiny_dataset, tmp_path):
    with pytest.raises(ConfigError, match="non-negative"):
        make_config("tiny", glide_loss_weight=-1.0)
    with pytest.raises(ConfigError):
        make_config("tiny", glide_episode_weight=4.0)
    data = tmp_path / "sim"
    save(tiny_dataset, data)
    cfg = make_config("tiny", data=str(data), out=str(tmp_path / "r"), steps=2)
    out = run(cfg)
    conf = json.loads((out / "config.json").read_text())
    conf.pop("glide_loss_weight")
    # a run made before the loss weight existed, with the uniform sampler: same behaviour, accepted
    (out / "config.json").write_text(json.dumps(dict(conf, glide_episode_weight=1.0)))
    run(cfg)
    (out / "config.json").write_text(json.dumps(dict(conf, glide_episode_weight=4.0)))
    with pytest.raises(ConfigError, match="glide_episode_weight"):
        run(cfg)


def test_dose_glide_sweeps_the_loss_weight_and_reads_the_realised_share(tmp_path):
    from pokeworld.experiments import make_config as map_config
    from pokeworld.experiments.dose_glide import realised_glide_share, specs as exp_dose_glide

    specs = exp_dose_glide(map_config("tiny", out=str(tmp_path)))
    assert [s.train.get("glide_loss_weight", 1.0) for s in specs] == [1.0, 4.0, 16.0, 64.0]
    run_dir = tmp_path / "runs" / specs[1].name
    run_dir.mkdir(parents=True)
    rows = [{"step": 0, "glide_frame_share": 0.32}, {"step": 2, "glide_loss_share": 0.6},
            {"step": 4, "glide_loss_share": 0.7}]
    (run_dir / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    results = {"map_config": {"out": str(tmp_path)}, "runs": {s.name: {"train": s.train} for s in specs}}
    assert realised_glide_share(results, results["runs"][specs[1].name]) == pytest.approx(0.65)  # mean of the steps
    assert realised_glide_share(results, results["runs"][specs[0].name]) is None  # the run is not on disk


@pytest.mark.parametrize("kw", [dict(objective="gnll"), dict(objective="recon"), dict(tokens=True, image_size=32)])
def test_other_objectives_weight_glide_targets(tiny_dataset, kw):
    s = WindowSampler(tiny_dataset, tiny_dataset.episodes("train"), kw.get("image_size", 16), 18,
                      torch.device("cpu"), seed=1)
    m = _model(tiny_dataset, **kw)
    b = s.sample(4)
    with torch.no_grad():
        l1, _ = m.loss(b, sigreg_seed=0, glide_loss_weight=1.0)
        l0, t0 = m.loss(b, sigreg_seed=0, glide_loss_weight=0.0)
        lf, _ = m.loss(dict(b, glide=torch.zeros_like(b["glide"])), sigreg_seed=0, glide_loss_weight=0.0)
    assert torch.isfinite(l0) and float(t0["glide_loss_share"]) == 0.0
    assert float(l0) != float(l1)  # glide targets left the loss
    assert float(lf) == pytest.approx(float(l1), rel=1e-5)  # with no glide frames the weight is moot
