"""The γ intervention ledger's two ledger-only mechanisms (motion channel off, magnitude-weighted motion-forecast
targets), the experiment's shared runs and its table."""

import numpy as np
import pytest
import torch

from pokeworld.errors import ConfigError
from pokeworld.losses import motion_weights
from pokeworld.models import XJEPA
from pokeworld.train import WindowSampler, data_stats, make_config, model_kwargs

HORIZONS = (1, 4, 16)


def _model(ds, **kw) -> XJEPA:
    cfg = make_config("tiny", **kw)
    torch.manual_seed(0)
    m = XJEPA(**model_kwargs(cfg, (ds.proprio.shape[-1], ds.touch.shape[-1], ds.actions.shape[-1])))
    m.set_stats(data_stats(ds, ds.episodes("train")))
    return m.eval()


@pytest.fixture(scope="module")
def batch(tiny_dataset):
    s = WindowSampler(tiny_dataset, tiny_dataset.episodes("train"), 16, 24, torch.device("cpu"), seed=0)
    return s.sample(8)


def test_motion_weights_follow_the_frame_difference():
    f = torch.zeros(2, 4, 3, 3)
    f[0, 2] = 1.0  # frame 2 differs from 1 and 3 by 1 everywhere: m = (0, 0, 1, 1) and (0, 0, 0, 0)
    w = motion_weights(f, 2.0)
    # mean of m over frames 1..3 of both windows = 2/6
    np.testing.assert_allclose(w.numpy(), [[1, 1, 1 + 2 * 3, 1 + 2 * 3], [1, 1, 1, 1]], rtol=1e-6)
    assert torch.equal(motion_weights(f, 0.0), torch.ones(2, 4))
    assert torch.equal(motion_weights(torch.zeros(2, 4, 3, 3), 5.0), torch.ones(2, 4))  # still scene: no weighting


def test_magnitude_weighted_latent_terms_match_a_direct_weighted_mean(tiny_dataset, batch):
    m = _model(tiny_dataset)
    b = batch
    with torch.no_grad():
        _, terms = m.loss(b, sigreg_seed=3, motion_loss_weight=4.0)
        _, plain = m.loss(b, sigreg_seed=3)
        z = m.encode(b["frames"], b["proprio"], b["touch"])
        h = m.trunk(z, b["actions"])
        f = m.prep_frames(b["frames"])[:, :, 0]
        mw = motion_weights(f, 4.0)
        L = z.shape[1]
        for d in HORIZONS:
            err = (m.predict(h, b["actions"], d)[:, :L - d] - z[:, d:]).pow(2).mean(-1)
            w = mw[:, d:]
            assert float(terms[f"pred_{d}"]) == pytest.approx(float((w * err).sum() / w.sum()), rel=1e-5)
            assert float(terms[f"pred_{d}"]) != pytest.approx(float(plain[f"pred_{d}"]), rel=1e-6)
    # the proprio / touch heads are not motion targets: unchanged
    assert float(terms["touch"]) == pytest.approx(float(plain["touch"]), rel=1e-6)
    assert float(terms["proprio"]) == pytest.approx(float(plain["proprio"]), rel=1e-6)


def test_motion_channel_off_zeroes_the_difference_input_only(tiny_dataset, batch):
    on, off = _model(tiny_dataset), _model(tiny_dataset, motion_channel=False)
    x_on, x_off = on.prep_frames(batch["frames"]), off.prep_frames(batch["frames"])
    assert torch.equal(x_on[:, :, 0], x_off[:, :, 0])
    assert x_on[:, :, 1].abs().sum() > 0 and x_off[:, :, 1].abs().sum() == 0
    assert off.config["motion_channel"] is False
    # same weights (same seed): the off model is the on model fed a zero difference channel
    b = batch
    with torch.no_grad():
        z_off = off.encode(b["frames"], b["proprio"], b["touch"])
        x = x_on.clone()
        x[:, :, 1] = 0
        n, L = x.shape[:2]
        z_zeroed = on.encoder(x.reshape(n * L, *x.shape[2:]), on.norm("proprio", b["proprio"]).reshape(n * L, -1),
                              on.norm("touch", b["touch"]).reshape(n * L, -1)).reshape(n, L, -1)
        z_on = on.encode(b["frames"], b["proprio"], b["touch"])
    torch.testing.assert_close(z_off, z_zeroed)
    assert float((z_on - z_off).abs().max()) > 0


def test_config_rejects_motion_weights_without_latent_targets():
    with pytest.raises(ConfigError, match="recon"):
        make_config("tiny", objective="recon", motion_loss_weight=1.0)
    with pytest.raises(ConfigError, match="non-negative"):
        make_config("tiny", motion_loss_weight=-1.0)


def test_ledger_shares_runs_and_labels_every_mechanism(tmp_path):
    from pokeworld.experiments import all_specs, ledger as report
    from pokeworld.experiments import make_config as map_config
    from pokeworld.experiments.ledger import ledger_mechanism, specs as exp_ledger

    c = map_config("tiny", out=str(tmp_path), experiments=("factorial", "controls", "coordinate", "ledger"))
    specs = exp_ledger(c)
    labels = [ledger_mechanism({"train": s.train, "corpus": s.corpus}) for s in specs]
    assert labels == ["single-horizon head", "multi-horizon heads", "no motion input channel", "spatial tokens",
                      "magnitude-weighted motion targets", "frozen flow velocity sensor",
                      "flow sensor with the log-speed coordinate", "glide-enriched loss"]
    names = {s.name for s in all_specs(c)}
    # shared runs train once: the factorial's VFX, the controls' token run and the coordinate run are the ledger's
    assert {specs[1].name, specs[3].name, specs[6].name} <= names
    assert len(names) == len({s.name for s in all_specs(map_config("tiny", out=str(tmp_path),
                                                                   experiments=("factorial", "controls",
                                                                                "coordinate")))}) + 5

    def run(s, gc, gg):
        return {"train": s.train, "corpus": s.corpus, "probes": {"ridge": {"contact": {"gamma": gc, "object_vel": 0.5},
                                                                           "glide": {"gamma": gg}}},
                "prediction": {"glide_test": {"model": 0.2, "median_gamma": 0.05, "uses_gamma": False}}}

    results = {"runs": {s.name: run(s, 0.01 * i, 0.02 * i) for i, s in enumerate(specs)},
               "experiments": {"ledger": [s.name for s in specs]}, "provenance": {"preset": "tiny"},
               "certificates": {"standard": {"estimators": {"drag": {"contact": {"gamma": 0.83}},
                                                            "gru": {"contact": {"gamma": 0.28}, "glide": {"gamma": 0.4}}}}}}
    text = "\n".join(report.ledger_table(results))
    assert "| glide-enriched loss | +0.07 | +0.14 | +0.14 / no gain |" in text
    assert "contact (drag) +0.83, glide (gru) +0.40" in text
    paths = report.ledger_figure(results, tmp_path)
    assert all(p.exists() for p in paths)
    assert report.ledger_table({"experiments": {}, "runs": {}}) == []
