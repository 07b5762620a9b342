"""SIGReg / Epps–Pulley, masked MSE and Gaussian NLL."""

import os
import socket

import pytest
import torch

from pokeworld.losses import epps_pulley, expected_null_ep, gaussian_nll, masked_mse, random_directions, sigreg


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
