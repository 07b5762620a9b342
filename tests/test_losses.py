"""SIGReg / Epps–Pulley, masked MSE and Gaussian NLL."""

import os
import socket

import pytest
import torch

from pokeworld.losses import (beta_nll, bounded_logvar, expected_null_ep, gaussian_nll, head_logvar_nll,
                              masked_mse, nll_precision, random_directions, sigreg, sigreg_rows_of, subsample_index)


def test_sigreg_small_for_gaussian_large_for_collapsed_or_scaled():
    g = torch.Generator().manual_seed(0)
    z = torch.randn(4096, 64, generator=g)
    null = sigreg(z, 256, seed=1).item()
    # N-scaled statistic is O(1) under the null (its expectation is ~1.05 for 17 knots on [0, 3])
    assert abs(null - expected_null_ep()) < 0.3
    collapsed = sigreg(torch.zeros(4096, 64) + 1e-3 * z, 256, seed=1).item()
    scaled = sigreg(3.0 * z, 256, seed=1).item()
    shrunk = sigreg(0.3 * z, 256, seed=1).item()
    shifted = sigreg(z + 1.0, 256, seed=1).item()
    for bad in (collapsed, scaled, shrunk, shifted):
        assert bad > 50 * null
    # a rank-1 (dimensionally collapsed) embedding is also penalised
    rank1 = z[:, :1].expand(-1, 64) / 8 ** 0.5 * 1.0
    assert sigreg(rank1, 256, seed=1).item() > 10 * null


def test_sigreg_leading_dims_average_groups():
    z = torch.randn(3, 512, 16)
    per = torch.stack([sigreg(z[i], 64, seed=5) for i in range(3)]).mean()
    assert torch.allclose(sigreg(z, 64, seed=5), per, rtol=1e-5)


def test_directions_seeded_unit_and_resampled():
    a, b, c = random_directions(32, 64, 7), random_directions(32, 64, 7), random_directions(32, 64, 8)
    assert torch.equal(a, b) and not torch.allclose(a, c)
    assert torch.allclose(a.norm(dim=0), torch.ones(64), atol=1e-5)


def test_sigreg_gradient_pushes_toward_isotropy():
    torch.manual_seed(0)
    base = torch.randn(512, 6)
    scales = torch.tensor([0.2, 0.5, 1.0, 2.0, 3.0, 0.3])
    z = (base * scales + 0.5).requires_grad_()
    opt = torch.optim.SGD([z], lr=2.0)

    def aniso(x):
        return x.detach().std(0).log().abs().mean().item() + x.detach().mean(0).abs().mean().item()

    before = aniso(z)
    for step in range(40):
        opt.zero_grad()
        sigreg(z, 32, seed=step).backward()  # per-sample gradients are O(1) thanks to the N scaling
        opt.step()
    assert aniso(z) < 0.6 * before


def test_token_subsampling_uses_max_rows():
    z = torch.randn(10000, 16, requires_grad=True)
    loss = sigreg(z, 32, seed=3, max_rows=512)
    loss.backward()
    assert (z.grad.abs().sum(1) > 0).sum().item() == 512


def test_masked_mse_and_gnll():
    pred, tgt = torch.zeros(2, 3, 4), torch.ones(2, 3, 4)
    tgt[0] = 3.0
    w = torch.tensor([[1.0, 1, 1], [0, 0, 0]])
    assert masked_mse(pred, tgt, w).item() == pytest.approx(9.0)
    assert masked_mse(pred, tgt).item() == pytest.approx(5.0)
    assert gaussian_nll(pred, torch.zeros_like(pred), tgt).item() == pytest.approx(2.5)


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dist_worker(rank, world, port, x_full, q):
    import torch.distributed as dist

    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    torch.set_num_threads(1)
    dist.init_process_group("gloo", rank=rank, world_size=world)
    n = x_full.shape[0] // world
    x = x_full[rank * n:(rank + 1) * n].clone().requires_grad_()
    loss = sigreg(x, 32, seed=11)
    loss.backward()
    q.put((rank, loss.item(), x.grad.numpy().tolist()))
    dist.barrier()
    dist.destroy_process_group()


@pytest.mark.slow
def test_sigreg_distributed_matches_global_batch():
    """Two gloo ranks with half the batch each: same loss as one process on the whole batch, and the
    rank gradients averaged by DDP equal the single-process gradient."""
    import torch.multiprocessing as mp

    world = 2
    x_full = torch.randn(256, 16) * 1.5
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    port = _free_port()
    procs = [ctx.Process(target=_dist_worker, args=(r, world, port, x_full, q)) for r in range(world)]
    for p in procs:
        p.start()
    res = sorted([q.get(timeout=120) for _ in range(world)], key=lambda r: r[0])
    for p in procs:
        p.join(60)
    xr = x_full.clone().requires_grad_()
    ref = sigreg(xr, 32, seed=11)
    ref.backward()
    n = x_full.shape[0] // world
    for rank, loss, grad in res:
        grad = torch.tensor(grad)
        assert loss == pytest.approx(ref.item(), rel=1e-5)
        # DDP averages parameter gradients over ranks: grad / world is the true global gradient
        assert torch.allclose(grad / world, xr.grad[rank * n:(rank + 1) * n], atol=1e-6, rtol=1e-4)


def test_fused_ecf_matches_autograd_through_cos_and_sin():
    from pokeworld.losses import _ecf, ep_knots

    t, _, _ = ep_knots(17, 3.0)
    x = torch.randn(3, 20, 5, dtype=torch.float64, requires_grad=True)
    t64 = t.double()
    assert torch.autograd.gradcheck(lambda v: _ecf(v, t64), (x,))
    xt = x.unsqueeze(-1) * t64
    ref_c, ref_s = torch.cos(xt).mean(-3), torch.sin(xt).mean(-3)
    c, s = _ecf(x, t64)
    torch.testing.assert_close(c, ref_c)
    torch.testing.assert_close(s, ref_s)


# ---------------------------------------------------------------------- SIGReg: per-step or pooled rows


def _readings(z, seed=1, dirs=128, rows=None):
    """(per-step, pooled) SIGReg of (B, L, D) latents as XJEPA.loss computes them."""
    step = sigreg(sigreg_rows_of(z, "step"), dirs, seed=seed).item()
    pooled = sigreg(sigreg_rows_of(z, "pooled"), dirs, seed=seed, max_rows=rows).item()
    return step, pooled


def test_sigreg_pool_rows_layout():
    z = torch.arange(2 * 3 * 4, dtype=torch.float32).reshape(2, 3, 4)
    assert torch.equal(sigreg_rows_of(z, "step")[1], z[:, 1])  # group t holds the B rows of step t
    assert torch.equal(sigreg_rows_of(z, "pooled"), z.reshape(6, 4))
    with pytest.raises(ValueError, match="unknown SIGReg pool"):
        sigreg_rows_of(z, "window")


def test_sigreg_pooled_and_per_step_share_the_null_level_and_pooling_separates_departures():
    """B = 32 windows × L = 24 steps (the cpu preset). Under the null both readings sit at the N-scaled
    expectation ∫(1 − φ²)w ≈ 1.05; a departure's excess over it grows with N, so 768 pooled rows see a
    mild one (scale 1.3) that 32 rows per step barely register."""
    g = torch.Generator().manual_seed(0)
    B, L, D = 32, 24, 32
    reps = [torch.randn(B, L, D, generator=g) for _ in range(4)]
    mean = lambda f: torch.tensor([_readings(f(z), seed=i) for i, z in enumerate(reps)]).mean(0).tolist()
    null_step, null_pool = mean(lambda z: z)
    e0 = expected_null_ep()
    assert abs(null_step - e0) < 0.15 and abs(null_pool - e0) < 0.3
    dep_step, dep_pool = mean(lambda z: 1.3 * z)
    ratio_step, ratio_pool = dep_step / null_step, dep_pool / null_pool
    # measured: step 1.05 -> 2.44 (×2.3), pooled 1.10 -> 28.8 (×26); the excess (×19.9) scales with N: ×24
    assert ratio_step < 3.5 and ratio_pool > 15 and ratio_pool > 6 * ratio_step
    excess = (dep_pool - null_pool) / (dep_step - null_step)
    assert 12 < excess < 40
    # collapsed, shifted and anisotropic latents: far above the null in the pooled reading too
    z = reps[0]
    for bad in (1e-3 * z, z + 1.0, z * torch.linspace(0.3, 3.0, D)):
        s, p = _readings(bad)
        assert p > 20 * null_pool and p > s


def test_sigreg_pooled_sees_time_correlated_rows_that_per_step_does_not():
    """What pooling changes besides N: rows of one window are not independent samples. A latent constant
    over each window is N(0, I) at every step (per-step statistic at the null), but pooled it is 32 distinct
    rows counted 24 times, so the statistic is ~24× the null: the pooled regulariser also asks the latents
    of a window to differ."""
    g = torch.Generator().manual_seed(2)
    z = torch.randn(32, 1, 32, generator=g).expand(32, 24, 32)
    step, pooled = _readings(z)
    assert abs(step - expected_null_ep()) < 0.3
    assert 12 < pooled / step < 40


def test_sigreg_row_subsample_is_seeded_and_deterministic():
    a, b, c = subsample_index(768, 100, 5), subsample_index(768, 100, 5), subsample_index(768, 100, 6)
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert a.shape == (100,) and a.unique().numel() == 100 and int(a.max()) < 768
    assert subsample_index(768, 768, 5) is None and subsample_index(768, None, 5) is None
    z = torch.randn(768, 16)
    ref = sigreg(z[a], 32, seed=5)
    assert torch.equal(sigreg(z, 32, seed=5, max_rows=100), ref)  # the subset sigreg draws is subsample_index's
    assert torch.equal(sigreg(z, 32, seed=5, rows=a), ref)  # and a host-drawn one gives the same statistic
    assert not torch.equal(sigreg(z, 32, seed=5, rows=c), ref)


# ---------------------------------------------------------------------- Gaussian NLL variance options


def test_bounded_logvar_caps_precision_and_keeps_a_gradient():
    raw = torch.tensor([-50.0, -8.0, -3.0, -0.1, 0.0, 0.1, 3.0, 50.0], requires_grad=True)
    s = bounded_logvar(raw, 2.0)
    assert float(s.detach().abs().max()) <= 2.0  # tanh rounds to ±1 far out: the bound is reached, not crossed
    assert float(nll_precision(s.detach()).max()) <= float(torch.exp(torch.tensor(2.0)))
    torch.testing.assert_close(s[3:6], raw[3:6].detach(), atol=1e-3, rtol=0)  # identity near 0
    s.sum().backward()
    # beyond where a hard clamp at ±2 would stop all gradient, the bound still passes one back
    assert raw.grad[2] > 0.1 and raw.grad[6] > 0.1
    hard = raw.detach().clone().requires_grad_()
    hard.clamp(-2, 2).sum().backward()
    assert hard.grad[2] == 0


def test_beta_nll_beta_one_has_the_mse_gradient_on_the_mean_and_beta_zero_is_the_nll():
    g = torch.Generator().manual_seed(0)
    y = torch.randn(3, 5, 6, generator=g)
    logvar = torch.randn(3, 5, 6, generator=g) * 2
    w = torch.rand(3, 5, generator=g)

    def grad_mean(fn):
        mu = torch.randn(3, 5, 6, generator=torch.Generator().manual_seed(1)).requires_grad_()
        fn(mu).backward()
        return mu.grad

    g_beta1 = grad_mean(lambda mu: beta_nll(mu, logvar, y, w, beta=1.0))
    g_mse = grad_mean(lambda mu: masked_mse(mu, y, w))
    torch.testing.assert_close(g_beta1, 0.5 * g_mse)  # σ no longer reweights the mean's errors
    g_nll = grad_mean(lambda mu: gaussian_nll(mu, logvar, y, w))
    assert not torch.allclose(g_nll, 0.5 * g_mse, rtol=0.1)  # the plain NLL does reweight them
    torch.testing.assert_close(grad_mean(lambda mu: beta_nll(mu, logvar, y, w, beta=0.0)), g_nll)
    mu = torch.zeros_like(y)
    assert torch.equal(beta_nll(mu, logvar, y, w, beta=0.0), gaussian_nll(mu, logvar, y, w))
    # the variance's stationary point stays σ² = (y − μ)² for any β
    s = (y - mu).pow(2).log().requires_grad_()
    beta_nll(mu, s, y, beta=0.5).backward()
    assert float(s.grad.abs().max()) < 1e-6


def test_per_head_log_variance_converges_to_the_noise_variance():
    """One learned log-variance per head, fitted with the mean by plain SGD on planted data y = a·x + σ·ε,
    σ = 0.7: e^s converges to σ² = 0.49 (the NLL's optimum is the head's mean squared error)."""
    g = torch.Generator().manual_seed(0)
    x = torch.randn(2048, 4, generator=g)
    a_true = torch.tensor([1.0, -2.0, 0.5, 0.0])
    sigma = 0.7
    y = (x @ a_true)[:, None] + sigma * torch.randn(2048, 1, generator=g)
    a = torch.zeros(4, requires_grad=True)
    s = torch.zeros((), requires_grad=True)
    opt = torch.optim.SGD([a, s], lr=0.5)
    for _ in range(300):
        opt.zero_grad()
        head_logvar_nll((x @ a)[:, None], s, y).backward()
        opt.step()
    assert float(s.detach().exp()) == pytest.approx(sigma ** 2, rel=0.05)
    torch.testing.assert_close(a.detach(), a_true, atol=0.05, rtol=0)
    # the homoscedastic NLL is the broadcast case of the per-element one
    torch.testing.assert_close(head_logvar_nll(x, s.detach(), x * 0.5),
                               gaussian_nll(x, s.detach().expand_as(x), x * 0.5))


def test_sigreg_at_a_reference_row_count_scales_the_statistic_not_its_direction():
    """The statistic is N-scaled: at batch 32 a reference count of 128 is exactly 4× the pull (the paper's batch at
    the same λ), with the same gradient direction; 0 / None keep the rows' own count."""
    from pokeworld.losses import sigreg

    z = (torch.randn(32, 16, generator=torch.Generator().manual_seed(0)) * 1.7 + 0.3).requires_grad_(True)
    own = sigreg(z, 64, seed=3)
    (g_own,) = torch.autograd.grad(own, z)
    ref = sigreg(z, 64, seed=3, reference_rows=128)
    (g_ref,) = torch.autograd.grad(ref, z)
    assert ref.item() == pytest.approx(4 * own.item(), rel=1e-5)
    torch.testing.assert_close(g_ref, 4 * g_own, rtol=1e-4, atol=1e-7)
    assert sigreg(z, 64, seed=3, reference_rows=32).item() == pytest.approx(own.item(), rel=1e-6)
    assert sigreg(z, 64, seed=3, reference_rows=0).item() == pytest.approx(own.item(), rel=1e-6)


def test_the_training_config_carries_the_reference_rows_into_the_loss():
    from pokeworld.errors import ConfigError
    from pokeworld.train import loss_kwargs
    from pokeworld.train.config import make_config

    assert loss_kwargs(make_config("tiny", sigreg_reference_rows=128))["sigreg_reference_rows"] == 128
    assert loss_kwargs(make_config("tiny"))["sigreg_reference_rows"] == 0
    with pytest.raises(ConfigError, match="sigreg_reference_rows"):
        make_config("tiny", sigreg_reference_rows=-1)
