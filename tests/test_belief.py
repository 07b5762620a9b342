"""The belief objective: KL maths, ELBO gradients, causality of the prior, training, CLI, probes, the map."""

import json

import numpy as np
import pytest
import torch

from pokeworld.data import save
from pokeworld.errors import ConfigError
from pokeworld.losses import gaussian_kl
from pokeworld.models import XJEPA
from pokeworld.train import make_config, synthetic_dataset

SMALL = dict(image_size=16, channels=(4, 8, 8, 8), latent_dim=16, width=16, depth=2, heads=2, vec_dim=8)
B, L = 3, 18


def batch(seed=0):
    g = torch.Generator().manual_seed(seed)
    return dict(frames=torch.randint(0, 256, (B, L, 16, 16), generator=g, dtype=torch.uint8),
                proprio=torch.randn(B, L, 4, generator=g), touch=torch.rand(B, L, 7, generator=g),
                actions=torch.rand(B, L, 2, generator=g) * 2 - 1)


def make(**kw):
    torch.manual_seed(0)
    m = XJEPA("VFX", objective="belief", **{**SMALL, **kw})
    # non-zero AdaLN modulation so the action path is exercised by the causality checks
    for blk in m.predictor.blocks:
        torch.nn.init.normal_(blk.ada[1].weight, std=0.1)
    return m


def test_gaussian_kl_closed_form_and_monte_carlo():
    g = torch.Generator().manual_seed(0)
    mq, mp = torch.randn(5, 4, generator=g), torch.randn(5, 4, generator=g)
    lq, lp = torch.randn(5, 4, generator=g) * 0.5, torch.randn(5, 4, generator=g) * 0.5
    kl = gaussian_kl(mq, lq, mp, lp)
    ref = torch.distributions.kl_divergence(torch.distributions.Normal(mq, (0.5 * lq).exp()),
                                            torch.distributions.Normal(mp, (0.5 * lp).exp())).sum(-1)
    assert kl.shape == (5,) and torch.allclose(kl, ref, atol=1e-5)
    # Monte Carlo: E_q[log q - log p] from 200k samples of the first row
    q = torch.distributions.Normal(mq[0], (0.5 * lq[0]).exp())
    p = torch.distributions.Normal(mp[0], (0.5 * lp[0]).exp())
    x = q.sample((200_000,))
    mc = (q.log_prob(x) - p.log_prob(x)).sum(-1).mean()
    assert float(mc) == pytest.approx(float(kl[0]), rel=0.03, abs=0.01)
    assert torch.allclose(gaussian_kl(mq, lq, mq, lq), torch.zeros(5), atol=1e-6)
    # 1-d known value: KL(N(1, 1) || N(0, 4)) = log 2 + (1 + 1)/8 - 1/2
    one = gaussian_kl(torch.ones(1), torch.zeros(1), torch.zeros(1), torch.full((1,), np.log(4.0)))
    assert float(one) == pytest.approx(np.log(2) + 2 / 8 - 0.5, abs=1e-6)


def test_elbo_gradient_reaches_posterior_prior_conditioning_and_trunk():
    m = make().train()
    loss, terms = m.loss(batch(), sigreg_dirs=8, belief_kl_weight=0.5)
    assert {"kl", "kl_last", "pred_1", "pred_16", "touch", "proprio", "sigreg"} <= set(terms)
    assert float(terms["kl"]) > 0
    loss.backward()
    for name, mod in (("posterior", m.belief.transition), ("posterior out", m.belief.post_out),
                      ("prior", m.belief.prior), ("conditioning", m.belief.inp), ("trunk", m.predictor.blocks)):
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in mod.parameters()), name
    # the KL term alone trains both sides: the posterior, and the prior through the causal trunk
    m.zero_grad()
    b = batch()
    z = m.encode(b["frames"], b["proprio"], b["touch"])
    mu_q, lv_q = m.posterior(z, b["actions"])
    mu_p, lv_p = m.prior(z, b["actions"])
    gaussian_kl(mu_q[:, None], lv_q[:, None], mu_p, lv_p).mean().backward()
    for mod in (m.belief.post_out, m.belief.prior, m.predictor.blocks, m.encoder.proj):
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in mod.parameters())
    assert m.belief.inp.weight.grad is None  # conditioning is the prediction terms' business


def test_prior_and_probed_state_are_causal_posterior_sees_the_future():
    m = make().eval()
    b, t = batch(), 7
    b2 = {k: v.clone() for k, v in b.items()}
    b2["frames"][:, t + 1:] = 255 - b2["frames"][:, t + 1:]
    b2["proprio"][:, t + 1:] += 3.0
    b2["touch"][:, t + 1:] += 3.0
    b2["actions"][:, t + 1:] = -b2["actions"][:, t + 1:]
    with torch.no_grad():
        z1, z2 = (m.encode(x["frames"], x["proprio"], x["touch"]) for x in (b, b2))
        p1, p2 = m.prior(z1, b["actions"]), m.prior(z2, b2["actions"])
        for a, c in zip(p1, p2):
            assert a.shape == (B, L, 8)
            assert torch.allclose(a[:, :t + 1], c[:, :t + 1], atol=1e-6)
            assert not torch.allclose(a[:, t + 1:], c[:, t + 1:])
        h1, h2 = m.features(**b), m.features(**b2)  # the probed state: trunk conditioned on the prior mean
        assert torch.allclose(h1[:, :t + 1], h2[:, :t + 1], atol=1e-6)
        assert not torch.allclose(h1, m.trunk_raw(z1, b["actions"]))  # the belief enters the probed state
        q1 = m.posterior(z1[:, :t + 2], b["actions"][:, :t + 2])
        q2 = m.posterior(z2[:, :t + 2], b2["actions"][:, :t + 2])
        assert q1[0].shape == (B, 8) and not torch.allclose(q1[0], q2[0])  # frame t+1 changes the posterior


def test_belief_config_validation():
    with pytest.raises(ConfigError, match="belief"):
        XJEPA("VFX", objective="beleif", **SMALL)
    with pytest.raises(ConfigError, match="belief_dim"):
        make_config("tiny", objective="belief", belief_dim=0)
    with pytest.raises(ConfigError, match="non-negative"):
        make_config("tiny", objective="belief", belief_kl_weight=-1.0)
    with pytest.raises(ConfigError, match="latent"):
        make_config("tiny", objective="belief", tokens=True)
    with pytest.raises(ValueError, match="belief"):
        XJEPA("VFX", **SMALL).prior(torch.zeros(1, 4, 16), torch.zeros(1, 4, 2))


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("belief") / "syn"
    save(synthetic_dataset(num_episodes=12, steps=24, size=32, seed=0), d)
    return str(d)


def test_belief_training_decreases_the_loss_at_tiny(data_dir, tmp_path):
    from pokeworld.cli import main

    out = tmp_path / "r"
    assert main(["train", "--preset", "tiny", "--objective", "belief", "--data", data_dir, "--out", str(out),
                 "--steps", "60", "--log-every", "10", "--lr", "3e-3"]) == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["objective"] == "belief" and cfg["belief_dim"] == 8
    rows = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()][1:]
    assert [r["step"] for r in rows] == [10, 20, 30, 40, 50, 60]
    # the touch term is dominated by batch-of-4 noise, so the total is compared over the last two rows
    assert (rows[-1]["loss"] + rows[-2]["loss"]) / 2 < rows[0]["loss"]
    for k in ("pred_1", "pred_4", "pred_16", "proprio"):  # at 16 px the tiny CNN cannot train (docs/model.md)
        assert (rows[-1][k] + rows[-2][k]) / 2 < 0.8 * rows[0][k], k
    assert all(np.isfinite(r["kl"]) and r["kl"] >= 0 for r in rows)


@pytest.mark.slow
def test_tiny_map_runs_the_belief_experiment(tmp_path):
    from pokeworld import experiments as experiment

    out = tmp_path / "map"
    c = experiment.make_config("tiny", out=str(out), workers=1, experiments=("belief",), certify_estimators=("drag",))
    experiment.run(c)
    res = json.loads((out / "results.json").read_text())
    names = res["experiments"]["belief"]
    assert len(names) == 5 and set(names) == set(res["runs"])
    objectives = sorted((r["train"].get("objective", "latent"), r["train"].get("window", 0),
                         r["train"].get("sysid_weight", 0)) for r in res["runs"].values())
    assert objectives == [("belief", 0, 0), ("belief", 65, 0), ("latent", 0, 0), ("latent", 0, 0.5), ("latent", 65, 0)]
    # whole-episode runs keep the standard runs' frames per step (tiny: 4 × 18 -> max(2, round(72 / 65)))
    assert {r["train"].get("batch_size") for r in res["runs"].values() if r["train"].get("window") == 65} == {2}
    for name, r in res["runs"].items():
        m = json.loads((out / "runs" / name / "measure.json").read_text())
        assert ("probes_belief" in m) == (r["train"].get("objective") == "belief") == ("probes_belief" in m["readout"])
        long = r["train"].get("window") == 65
        assert m["key"]["config"]["window"] == (48 if long else 16)
        assert m["prediction"]["static16"] > 0 and "direct16" in m["prediction"]
        if not long:  # whole-episode runs give one prefix window per episode: too few on the tiny corpus
            assert "gamma" in m["probes"]["ridge"]["contact"]
            if "probes_belief" in m:
                assert {"prior_mean", "posterior_mean"} <= set(m["probes_belief"])
    md = (out / "results.md").read_text()
    assert "## Belief objective" in md
    for label in ("VFX latent, standard windows", "VFX belief, standard windows", "VFX latent, whole episodes",
                  "VFX belief, whole episodes", "VFX latent + system-ID head (supervised), standard windows"):
        assert f"| {label}, seed 0 |" in md
    assert "| certificate (best estimator) |" in md


def test_belief_probes_read_a_planted_episode_latent_and_not_noise(tiny_dataset):
    """Planted: latents carry each episode's γ; a posterior that passes them on must read γ ≈ 1, a prior that
    outputs noise ≈ 0, through the same windows, split and ridge probes the map uses."""
    import torch

    from pokeworld.evaluate import measure

    ds = tiny_dataset
    gamma = ds.params["gamma"].astype(np.float32)

    class Latents:  # stands in for EpisodeLatents: every step's latent holds the episode's γ
        def gather(self, w):
            return np.repeat(gamma[w.episode][:, None, None], w.length, 1).repeat(4, 2)

    class Stub:
        def posterior(self, z, a):
            return z[:, -1, :2] + 0.01 * torch.randn(z.shape[0], 2), None

        def prior(self, z, a):
            return torch.randn(z.shape[0], z.shape[1], 2), None

    cfg = measure.make_config("tiny", kinds=("all",))
    res = measure.probe_belief(Stub(), ds, cfg, (Latents(), Latents()))
    assert res["posterior_mean"]["ridge"]["all"]["gamma"] > 0.9
    assert res["prior_mean"]["ridge"]["all"]["gamma"] < 0.2
