"""X-JEPA architecture: variants, AdaLN-zero, causality, heads, controls."""

import numpy as np
import pytest
import torch

from pokeworld.diagnostics import nll_precision, token_state
from pokeworld.errors import ConfigError
from pokeworld.models import VARIANTS, XJEPA

SMALL = dict(image_size=16, channels=(4, 8, 8, 8), latent_dim=16, width=16, depth=2, heads=2, vec_dim=8)
B, L = 2, 18


def batch(seed=0, size=32):
    g = torch.Generator().manual_seed(seed)
    return dict(frames=torch.randint(0, 256, (B, L, size, size), generator=g, dtype=torch.uint8),
                proprio=torch.randn(B, L, 4, generator=g), touch=torch.rand(B, L, 7, generator=g),
                actions=torch.rand(B, L, 2, generator=g) * 2 - 1, params=torch.randn(B, 3, generator=g))


def make(variant="VFX", **kw):
    torch.manual_seed(0)
    return XJEPA(variant, **{**SMALL, **kw}).eval()


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_variant_inputs_and_heads(variant):
    inputs, targets = VARIANTS[variant]
    m = make(variant)
    assert m.variant == variant and m.horizons == (1, 4, 16) and m.latent_dim == 16 and m.width == 16
    assert set(m.modal_heads.keys()) == {t for t in targets if t != "latent"}
    b = batch()
    z = m.encode(b["frames"], b["proprio"], b["touch"])
    assert z.shape == (B, L, 16)
    z2 = m.encode(b["frames"], b["proprio"] + 1.0, b["touch"] + 1.0)
    assert torch.allclose(z, z2) == (inputs == ("vision",))
    loss, terms = m.train().loss(b, sigreg_dirs=8)
    assert torch.isfinite(loss)
    assert {"pred_1", "pred_4", "pred_16", "sigreg"} <= set(terms)
    assert ("touch" in terms) == ("touch" in targets) and ("proprio" in terms) == ("proprio" in targets)


def test_unknown_variant_lists_choices():
    with pytest.raises(ConfigError, match="VX_t"):
        XJEPA("VT", **SMALL)


def test_adaln_zero_trunk_ignores_actions_at_init():
    m = make()
    b = batch()
    z = m.encode(b["frames"], b["proprio"], b["touch"])
    h1 = m.trunk(z, b["actions"])
    h2 = m.trunk(z, torch.randn_like(b["actions"]) * 5)
    assert torch.equal(h1, h2)
    assert not torch.allclose(h1, m.trunk(z + 1.0, b["actions"]))


@pytest.mark.parametrize("tokens", [False, True])
def test_causality(tokens):
    # tokens at 32 px: a 2 x 2 map, so the block-causal mask over (t, s)-major tokens is exercised (at 16 px
    # the map is 1 x 1 and the token trunk is the plain causal one)
    m = make("VFX", tokens=tokens, horizons=(1,) if tokens else (1, 4, 16), **({"image_size": 32} if tokens else {}))
    assert m.num_tokens == (4 if tokens else 1)
    # give the AdaLN modulation non-zero weights so the action path is exercised too
    for blk in m.predictor.blocks:
        torch.nn.init.normal_(blk.ada[1].weight, std=0.1)
    b, t = batch(), 7
    b2 = {k: v.clone() for k, v in b.items()}
    b2["frames"][:, t + 1:] = 255 - b2["frames"][:, t + 1:]
    b2["proprio"][:, t + 1:] += 3.0
    b2["touch"][:, t + 1:] += 3.0
    b2["actions"][:, t + 1:] = -b2["actions"][:, t + 1:]
    h1 = m.features(b["frames"], b["proprio"], b["touch"], b["actions"])
    h2 = m.features(b2["frames"], b2["proprio"], b2["touch"], b2["actions"])
    assert h1.shape == (B, L, 16)
    assert torch.allclose(h1[:, :t + 1], h2[:, :t + 1], atol=1e-6)
    assert not torch.allclose(h1[:, t + 1:], h2[:, t + 1:])


def test_predict_forecast_rollout_shapes_and_window():
    m = make()
    b = batch()
    h = m.features(b["frames"], b["proprio"], b["touch"], b["actions"])
    for d in m.horizons:
        assert m.predict(h, b["actions"], d).shape == (B, L, 16)
    assert m.forecast(h, b["actions"], 4, "touch").shape == (B, L, 7)
    aw = m.action_window(b["actions"], 4)
    na = m.norm("action", b["actions"])
    assert torch.allclose(aw[:, 3], na[:, 3:7].reshape(B, -1))
    assert torch.equal(aw[:, -1, 2:], torch.zeros(B, 6))  # zero-padded past the window end
    with pytest.raises(ValueError):
        m.predict(h, b["actions"], 2)
    z = m.encode(b["frames"], b["proprio"], b["touch"])
    out = m.rollout(z[:, :5], b["actions"], steps=6)
    assert out.shape == (B, 6, 16)
    # first rollout step equals the direct Δ=1 prediction from the last context state
    h5 = m.trunk(z[:, :5], b["actions"][:, :5])
    assert torch.allclose(out[:, 0], m.predict(h5, b["actions"][:, :5], 1)[:, -1], atol=1e-5)
    out2 = m.rollout(z[:, :5], b["actions"][:, 4:10], steps=6, actions_context=b["actions"][:, :4])
    assert torch.allclose(out, out2)




def naive_rollout(m, z_context, actions, steps):
    """The definition the cached rollout must reproduce: re-run the trunk over the whole grown sequence."""
    seq, outs = z_context, []
    for _ in range(steps):
        L = seq.shape[1]
        h = m.trunk(seq, actions[:, :L])
        outs.append(m.predict(h[:, -1:], actions[:, L - 1:L], 1))
        seq = torch.cat([seq, outs[-1]], 1)
    return torch.cat(outs, 1)


@pytest.mark.parametrize("objective", ["latent", "belief"])
def test_cached_rollout_equals_rerunning_the_grown_sequence(objective):
    m = make("VFX", objective=objective)
    for blk in m.predictor.blocks:  # non-zero action modulation, so a misaligned action would show
        torch.nn.init.normal_(blk.ada[1].weight, std=0.1)
    b = batch()
    z = m.encode(b["frames"], b["proprio"], b["touch"])
    with torch.no_grad():
        ref = naive_rollout(m, z[:, :6], b["actions"], 10)
    out = m.rollout(z[:, :6], b["actions"], steps=10)
    assert torch.allclose(out, ref, atol=1e-5)
    # past the predictor's context the rollout slides its window instead (no cache), still defined
    short = make("VFX", objective=objective, max_len=8)
    assert short.rollout(z[:, :6], b["actions"], steps=5).shape == (B, 5, 16)


def test_incremental_trunk_states_equal_the_full_pass():
    from pokeworld.models.predictor import KVCache

    m = make()
    for blk in m.predictor.blocks:
        torch.nn.init.normal_(blk.ada[1].weight, std=0.1)
    b = batch()
    z = m.encode(b["frames"], b["proprio"], b["touch"])
    full = m.trunk(z, b["actions"])
    cache, parts, t = KVCache(), [], 0
    for n in (5, 1, 3, 1, 8):  # several new steps at once exercises the offset causal mask
        parts.append(m.trunk(z[:, t:t + n], b["actions"][:, t:t + n], cache))
        t += n
    assert cache.length == L
    assert torch.allclose(torch.cat(parts, 1), full, atol=1e-5)
    with pytest.raises(ValueError, match="max_len"):
        m.trunk(z[:, :1].expand(B, 200, 16), torch.zeros(B, 200, 2), cache)
def test_single_horizon_and_raw_frames_are_downsampled():
    m = make("V", horizons=(1,))
    assert set(m.latent_heads.keys()) == {"1"}
    b = batch(size=64)
    z64 = m.encode(b["frames"])
    small = torch.nn.functional.interpolate(b["frames"].float().reshape(-1, 1, 64, 64), size=16, mode="area")
    small = small.round().to(torch.uint8).reshape(B, L, 16, 16)
    assert torch.allclose(z64, m.encode(small), atol=1e-6)


@pytest.mark.parametrize("kw", [dict(objective="gnll"), dict(objective="recon"), dict(sysid=True),
                                dict(tokens=True, horizons=(1,)), dict(tokens=True)])
def test_control_variants_train_step(kw):
    m = make("VFX", **kw).train()
    b = batch()
    loss, terms = m.loss(b, sigreg_dirs=8, token_rows=64, token_dirs=8)
    loss.backward()
    assert torch.isfinite(loss)
    if kw.get("objective") == "recon":
        assert "sigreg" not in terms and "recon_16" in terms and "touch" in terms
        assert all(p.grad is None for p in m.latent_heads.parameters())
    elif kw.get("tokens"):
        z = m.encode(b["frames"], b["proprio"], b["touch"])
        assert z.shape == (B, L, 1, 16) and "sigreg" in terms
    elif kw.get("sysid"):
        assert "sysid" in terms
    else:
        mean, logvar = m.predict(m.trunk(m.encode(b["frames"], b["proprio"], b["touch"]), b["actions"]),
                                 b["actions"], 1, return_logvar=True)
        assert logvar.shape == mean.shape


def test_no_trailing_layernorm_latent_is_batchnormed():
    m = make()
    assert isinstance(m.encoder.norm, torch.nn.BatchNorm1d)


def test_pooled_encoder_builds_and_is_smaller():
    from pokeworld.models import XJEPA

    flat = XJEPA("V", image_size=32, channels=(4, 8, 8, 8), latent_dim=16, width=16, depth=1, heads=2)
    pooled = XJEPA("V", image_size=32, channels=(4, 8, 8, 8), latent_dim=16, width=16, depth=1, heads=2, pool=True)
    frames = torch.rand(2, 3, 32, 32)
    assert pooled.encode(frames).shape == flat.encode(frames).shape == (2, 3, 16)
    assert pooled.encoder.proj.in_features == 8 and flat.encoder.proj.in_features == 8 * 4
    assert pooled.config["pool"] is True


def test_gnll_on_every_head_scores_proprio_and_touch_by_their_own_nll():
    from pokeworld.losses import gaussian_nll

    b = batch()
    lat, every = make("VFX", objective="gnll"), make("VFX", objective="gnll", gnll_heads="all",
                                                                 gnll_variance="free")
    d = 4
    assert lat.modal_heads["touch"][str(d)].net[-1].out_features == 7
    assert every.modal_heads["touch"][str(d)].net[-1].out_features == 14  # mean and log-variance
    h = every.trunk(every.encode(b["frames"], b["proprio"], b["touch"]), b["actions"])
    assert every.forecast(h, b["actions"], d, "touch").shape == (B, L, 7)  # the mean only
    with torch.no_grad():
        _, terms = every.loss(b, sigreg_dirs=8, touch_contact_weight=1.0)
        # the touch term by hand: mean NLL over the horizons of the normalised target
        tgt = every.norm("touch", b["touch"])
        by_hand = torch.stack([gaussian_nll(*every._head_out(h, b["actions"], k, every.modal_heads["touch"][str(k)])
                                            [:, :L - k].chunk(2, -1), tgt[:, k:]) for k in every.horizons]).mean()
        _, terms_lat = lat.loss(b, sigreg_dirs=8)
    assert torch.allclose(terms["touch"], by_hand, atol=1e-5)
    # the latent precision (the NLL's effective weight on latent errors) is reported for gnll runs only
    assert float(terms["latent_precision"]) > 0 and "latent_precision" in terms_lat
    assert "latent_precision" not in make("VFX").loss(b, sigreg_dirs=8)[1]
    with pytest.raises(ConfigError, match="needs objective='gnll'"):
        make("VFX", gnll_heads="all")
    with pytest.raises(ConfigError, match="unknown gnll_heads"):
        make("VFX", objective="gnll", gnll_heads="touch")


def test_nll_precision_script_reads_planted_log_variances(tiny_dataset):
    """pokeworld.diagnostics.nll_precision (scripts/nll_precision.py) on a model whose log-variance halves are
    planted constants: it must read e^{-s} of the log-variance half (not the mean half) on contact and
    contact-free frames alike."""
    ds = tiny_dataset
    m = make("VFX", objective="gnll", gnll_heads="all", gnll_variance="free", image_size=16,
             proprio_dim=ds.proprio.shape[-1],
             touch_dim=ds.touch.shape[-1], action_dim=ds.actions.shape[-1])
    planted = {"latent": 50.0, "touch": 7.0}
    with torch.no_grad():
        for heads, name in ((m.latent_heads, "latent"), (m.modal_heads["touch"], "touch")):
            for head in heads.values():
                last = head.net[-1]
                half = last.out_features // 2
                last.weight.zero_()
                last.bias[:half] = 3.0  # the mean half: a wrong read would give e^{-3}
                last.bias[half:] = -float(np.log(planted[name]))
    res = nll_precision.precisions(m, ds, windows=32)
    for row in res.values():
        assert 0.0 < row["contact_share"] < 1.0
        for name, p in planted.items():
            assert row[f"{name}_contact"] == pytest.approx(p, rel=1e-5)
            assert row[f"{name}_free"] == pytest.approx(p, rel=1e-5)
    with pytest.raises(ConfigError, match="only for objective='gnll'"):
        nll_precision.precisions(make("VFX", image_size=16), ds, windows=4)


def test_token_state_probe_script_mean_pool_is_the_measured_state(tiny_dataset):
    """pokeworld.diagnostics.token_state (scripts/token_state_probe.py): its 'mean' pool is exactly the state every
    table probes (the trunk state at the last step, leak-free) and 'concat' keeps every token, so the comparison
    between pools is like for like; on planted token states where the signal lives in the difference between tokens,
    the mean reads nothing and the concatenation reads it, so the pooling comparison can come out either way."""
    from pokeworld.evaluate.probes import fit_probes
    from pokeworld.evaluate.state import EpisodeLatents, padded_actions, window_states
    from pokeworld.windows import make_windows

    ds = tiny_dataset
    m = make("VFX", tokens=True, image_size=32, proprio_dim=ds.proprio.shape[-1], touch_dim=ds.touch.shape[-1],
             action_dim=ds.actions.shape[-1])  # 32 px -> a 2 x 2 token map
    eps = ds.episodes("probe_test")[:6]
    lat, acts = EpisodeLatents(m, ds, eps, 8), padded_actions(ds)
    w = make_windows(ds, eps, 8, 4)
    h = window_states(m, ds, lat, w, acts, per_token=True)
    assert h.shape[:2] == (len(w), m.num_tokens) and m.num_tokens > 1
    want = window_states(m, ds, lat, w, acts)
    np.testing.assert_allclose(token_state.pooled(h, "mean"), want, atol=1e-5)
    assert token_state.pooled(h, "concat").shape == (len(w), m.num_tokens * h.shape[-1])
    np.testing.assert_allclose(token_state.pooled(h, "max"), h.max(1))

    rng = np.random.default_rng(0)
    n, S, D = 400, 4, 8
    y = rng.normal(size=(n, 1))
    planted = rng.normal(size=(n, S, D)) * 0.1
    planted[:, 0, 0] += y[:, 0]
    planted[:, 1, 0] -= y[:, 0]  # token 0 carries +y, token 1 carries -y: the mean cancels it
    g = np.arange(n) // 4
    fit, test = slice(0, 300), slice(300, n)
    r2 = {pool: fit_probes(token_state.pooled(planted[fit], pool), g[fit], {"y": y[fit]},
                           token_state.pooled(planted[test], pool), {"y": y[test]}, False, 0)["ridge"]["y"]
          for pool in token_state.POOLS}
    assert r2["concat"] > 0.9 and r2["mean"] < 0.1


def test_token_models_keep_the_shared_multi_horizon_heads(tmp_path):
    """Paper §3: every variant shares the Δ ∈ {1, 4, 16} heads; tokens add dense Δ = 1 prediction on top. A token
    model built by the trainer has them, and each horizon's latent and touch heads receive gradient."""
    from pokeworld.data import save
    from pokeworld.train import load_model, make_config, model_kwargs, run, synthetic_dataset

    cfg = make_config("tiny", tokens=True, image_size=32, variant="VFX")
    assert model_kwargs(cfg, (4, 7, 2))["horizons"] == (1, 4, 16)
    m = make("VFX", tokens=True, image_size=32).train()
    loss, terms = m.loss(batch(), sigreg_dirs=8, token_rows=64, token_dirs=8)
    loss.backward()
    assert {"pred_1", "pred_4", "pred_16", "touch", "proprio", "sigreg"} <= set(terms)
    for d in ("1", "4", "16"):
        for head in (m.latent_heads[d], m.modal_heads["touch"][d]):
            assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in head.parameters()), d
    # Δ = 1 is the dense token target: it differs from predicting the token-mean latent
    z = m.encode(batch()["frames"], batch()["proprio"], batch()["touch"])
    assert z.shape[2] == m.num_tokens == 4
    save(synthetic_dataset(num_episodes=6, steps=24, size=32, seed=0), tmp_path / "syn")
    out = run(make_config("tiny", tokens=True, image_size=32, data=str(tmp_path / "syn"), out=str(tmp_path / "r"),
                          steps=3))
    assert load_model(out).horizons == (1, 4, 16)


def test_sigreg_pool_step_and_pooled_rows_in_the_loss():
    """The loss's SIGReg term is the per-step statistic (default: each step's B rows, averaged over time) or,
    pooled, one statistic over the B·L rows, subsampled to sigreg_rows from the step's seed — the same subset
    a trainer passes in drawn on the host. Nothing else in the loss changes."""
    from pokeworld.losses import sigreg, subsample_index

    m, b = make("VFX"), batch()
    kw = dict(sigreg_dirs=8, sigreg_seed=3)
    with torch.no_grad():
        z = m.encode(b["frames"], b["proprio"], b["touch"])
        _, step = m.loss(b, **kw)
        _, pooled = m.loss(b, sigreg_pool="pooled", sigreg_rows=20, **kw)
        _, hosted = m.loss(b, sigreg_pool="pooled", sigreg_rows=20, sigreg_row_index=subsample_index(B * L, 20, 3),
                           **kw)
        _, every = m.loss(b, sigreg_pool="pooled", sigreg_rows=4096, **kw)
        _, ignored = m.loss(b, sigreg_row_index=subsample_index(B * L, 20, 3), **kw)  # per-step: no subset
    assert torch.equal(step["sigreg"], sigreg(z.transpose(0, 1), 8, seed=3))
    assert torch.equal(pooled["sigreg"], sigreg(z.reshape(B * L, -1)[subsample_index(B * L, 20, 3)], 8, seed=3))
    assert torch.equal(hosted["sigreg"], pooled["sigreg"])
    assert torch.equal(every["sigreg"], sigreg(z.reshape(B * L, -1), 8, seed=3))
    assert torch.equal(ignored["sigreg"], step["sigreg"])
    assert len({float(step["sigreg"]), float(pooled["sigreg"]), float(every["sigreg"])}) == 3
    for k in step:
        if k != "sigreg":
            assert torch.equal(step[k], every[k]), k


def _plant_logvar_bias(m, value):
    """Zero the last layer of every gnll head and set its log-variance half's bias to ``value``."""
    with torch.no_grad():
        heads = list(m.latent_heads.values()) + [h for mh in m.modal_heads.values() for h in mh.values()]
        for head in heads:
            last = head.net[-1]
            last.weight.zero_()
            last.bias[last.out_features // 2:] = value


def test_gnll_variance_free_is_bit_identical_to_the_clamped_per_element_nll():
    """'free' (the default before 'bounded') is the objective of the NLL runs recorded then: the default's parameters,
    and each latent term is gaussian_nll of the head's (mean, log-variance) halves, bit for bit; the proprio/touch
    terms likewise with gnll_heads='all'. The default squashes the same log-variance half, so its terms differ."""
    from pokeworld.losses import gaussian_nll

    b = batch()
    default, free = make("VFX", objective="gnll", gnll_heads="all"), make("VFX", objective="gnll", gnll_heads="all",
                                                                          gnll_variance="free")
    sd, sf = default.state_dict(), free.state_dict()
    assert sd.keys() == sf.keys() and all(torch.equal(sd[k], sf[k]) for k in sd)
    assert free.latent_heads["4"].net[-1].out_features == 2 * 16 and free.latent_logvar is None
    with torch.no_grad():
        _, terms = free.loss(b, sigreg_dirs=8, touch_contact_weight=1.0)
        _, terms_default = default.loss(b, sigreg_dirs=8, touch_contact_weight=1.0)
        z = free.encode(b["frames"], b["proprio"], b["touch"])
        h = free.trunk(z, b["actions"])
        for d in free.horizons:
            mean, lv = free._head_out(h, b["actions"], d, free.latent_heads[str(d)]).chunk(2, -1)
            assert torch.equal(terms[f"pred_{d}"], gaussian_nll(mean[:, :L - d], lv[:, :L - d], z[:, d:])), d
        tgt = free.norm("touch", b["touch"])
        touch = torch.stack([gaussian_nll(*free._head_out(h, b["actions"], d, free.modal_heads["touch"][str(d)])
                                          [:, :L - d].chunk(2, -1), tgt[:, d:]) for d in free.horizons]).mean()
    assert torch.equal(terms["touch"], touch)
    assert default.gnll_variance == "bounded" and terms.keys() == terms_default.keys()
    assert not torch.equal(terms["pred_4"], terms_default["pred_4"])
    assert "latent_weight" not in terms


def test_gnll_variance_bounded_caps_every_precision_at_e_to_the_bound():
    """A head driven to log-variance −50: the free head's precision runs to the clamp e^8, the bounded head's
    never exceeds e^2, on the latent and the proprio/touch heads alike."""
    b = batch()
    free = make("VFX", objective="gnll", gnll_heads="all", gnll_variance="free")
    bounded = make("VFX", objective="gnll", gnll_heads="all")  # the default
    cap = float(torch.exp(torch.tensor(2.0)))
    for m in (free, bounded):
        _plant_logvar_bias(m, -50.0)
    with torch.no_grad():
        _, t_free = free.loss(b, sigreg_dirs=8)
        _, t_bounded = bounded.loss(b, sigreg_dirs=8)
        h = bounded.trunk(bounded.encode(b["frames"], b["proprio"], b["touch"]), b["actions"])
        for d in bounded.horizons:
            _, lv = bounded.predict(h, b["actions"], d, return_logvar=True)
            _, lv_touch = bounded.forecast(h, b["actions"], d, "touch", return_logvar=True)
            assert float(torch.exp(-lv).max()) <= cap and float(torch.exp(-lv_touch).max()) <= cap
    assert float(t_free["latent_precision"]) == pytest.approx(float(torch.exp(torch.tensor(8.0))), rel=1e-5)
    assert float(t_bounded["latent_precision"]) == pytest.approx(cap, rel=1e-5)
    # a wider bound lets it go further
    wide = make("VFX", objective="gnll", gnll_variance="bounded", gnll_logvar_bound=4.0)
    _plant_logvar_bias(wide, -50.0)
    with torch.no_grad():
        assert float(wide.loss(b, sigreg_dirs=8)[1]["latent_precision"]) == pytest.approx(
            float(torch.exp(torch.tensor(4.0))), rel=1e-5)


def test_gnll_variance_beta_scores_beta_nll_and_reports_its_weight():
    from pokeworld.losses import beta_nll

    b = batch()
    m = make("VFX", objective="gnll", gnll_variance="beta")
    _plant_logvar_bias(m, -3.0)  # precision e^3 everywhere
    with torch.no_grad():
        _, half = m.loss(b, sigreg_dirs=8, gnll_beta=0.5)
        _, one = m.loss(b, sigreg_dirs=8, gnll_beta=1.0)
        z = m.encode(b["frames"], b["proprio"], b["touch"])
        h = m.trunk(z, b["actions"])
        mean, lv = m.predict(h, b["actions"], 4, return_logvar=True)
    assert torch.equal(half["pred_4"], beta_nll(mean[:, :L - 4], lv[:, :L - 4], z[:, 4:], beta=0.5))
    e = float(torch.exp(torch.tensor(3.0)))
    assert float(half["latent_precision"]) == pytest.approx(e, rel=1e-5)  # the stated precision e^{-s}
    assert float(half["latent_weight"]) == pytest.approx(e ** 0.5, rel=1e-5)  # the weight the mean sees
    assert float(one["latent_weight"]) == pytest.approx(1.0)  # β = 1: the MSE's weight whatever σ


def test_gnll_variance_per_head_owns_one_log_variance_per_head():
    """'per_head': heads output the mean only; one scalar log-variance per horizon (and per proprio/touch head
    with gnll_heads='all') is what predict/forecast report, the loss trains and the state_dict gains — only
    with this option."""
    b = batch()
    m = make("VFX", objective="gnll", gnll_heads="all", gnll_variance="per_head").train()
    assert m.latent_heads["4"].net[-1].out_features == 16 and m.modal_heads["touch"]["4"].net[-1].out_features == 7
    keys = set(m.state_dict())
    added = {f"latent_logvar.{d}" for d in (1, 4, 16)} | {f"modal_logvar.{mod}.{d}" for mod in ("proprio", "touch")
                                                          for d in (1, 4, 16)}
    assert added <= keys
    for other in (make("VFX", objective="gnll", gnll_heads="all"), make("VFX")):
        assert not any("logvar" in k for k in other.state_dict())
    with torch.no_grad():
        m.latent_logvar["4"].fill_(-float(np.log(50.0)))
    h = m.trunk(m.encode(b["frames"], b["proprio"], b["touch"]), b["actions"])
    mean, lv = m.predict(h, b["actions"], 4, return_logvar=True)
    assert lv.shape == mean.shape and torch.equal(lv, torch.full_like(lv, -float(np.log(50.0))))
    loss, terms = m.loss(b, sigreg_dirs=8)
    loss.backward()
    for p in list(m.latent_logvar.values()) + [p for d in m.modal_logvar.values() for p in d.values()]:
        assert p.grad is not None and p.grad != 0
    # mean over horizons of e^{-s}: (50 + 1 + 1) / 3
    assert float(terms["latent_precision"]) == pytest.approx(52.0 / 3, rel=1e-5)
    with pytest.raises(ConfigError, match="needs objective='gnll'"):
        make("VFX", gnll_variance="per_head")
    with pytest.raises(ConfigError, match="unknown gnll_variance"):
        make("VFX", objective="gnll", gnll_variance="student")


def test_head_layers_deepens_every_direct_head_and_trains(tmp_path):
    """``head_layers`` sets the hidden layers of every direct Δ head (latent, touch, proprio); the default keeps
    the one-hidden-layer heads every recorded run has, a deeper model trains and reloads, and 0 is refused."""
    from pokeworld.data import save
    from pokeworld.errors import ConfigError
    from pokeworld.train import load_model, make_config, run, synthetic_dataset

    def linears(head):
        return sum(isinstance(x, torch.nn.Linear) for x in head.net)

    shallow, deep = make("VFX"), make("VFX", head_layers=3)
    for d in ("1", "4", "16"):
        assert linears(shallow.latent_heads[d]) == 2
        for heads in (deep.latent_heads, deep.modal_heads["touch"], deep.modal_heads["proprio"]):
            assert linears(heads[d]) == 4
    loss, _ = deep.train().loss(batch(), sigreg_dirs=8)
    loss.backward()
    assert all(p.grad is not None for p in deep.latent_heads["16"].parameters())
    save(synthetic_dataset(num_episodes=6, steps=24, size=16, seed=0), tmp_path / "syn")
    out = run(make_config("tiny", head_layers=2, data=str(tmp_path / "syn"), out=str(tmp_path / "r"), steps=2))
    assert linears(load_model(out).latent_heads["16"]) == 3
    with pytest.raises(ConfigError, match="head_layers"):
        make_config("tiny", head_layers=0)
    with pytest.raises(ConfigError, match="hidden layer"):
        XJEPA("VFX", **{**SMALL, "head_layers": 0})
