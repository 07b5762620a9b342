"""Losses for X-JEPA: SIGReg (Epps–Pulley on random projections), Gaussian NLL, masked MSE, Gaussian KL.

SIGReg ("Sketched Isotropic Gaussian Regularization", LeJEPA / LeWM) pushes the
distribution of embeddings towards an isotropic standard Gaussian. It projects
the N×D embeddings onto K random unit directions and, for every 1-d projection,
compares the empirical characteristic function (ECF)
``phi_N(t) = mean_n exp(i t x_n)`` with the standard normal one ``exp(-t²/2)``:

    EP = N · ∫ |phi_N(t) − exp(−t²/2)|² w(t) dt,     w(t) = exp(−t²/2)

The integrand is even in t, so we integrate over [0, t_max] with the trapezoid
rule (17 knots on [0, 3] by default) and double the weights. The factor N makes
the statistic O(1) under the null (it is the classical Epps–Pulley scaling), so
it is comparable across batch sizes; the loss is the mean over directions (and
over any leading batch dimensions, e.g. time steps).

Distributed correctness (the bug most often reported against LeWM-style code):

* every rank must use the *same* directions — we draw them from a
  ``torch.Generator`` seeded by ``(seed, step)`` only, never from the global RNG,
  so no communication is needed and resumed runs redraw identical directions;
* the statistic must be that of the *global* batch — the ECF is linear in the
  samples, so we all-reduce (average) the per-rank ``cos``/``sin`` means with an
  autograd-aware all-reduce (:class:`_AllReduceSum`) and scale by the
  global N = N_local · world_size. The backward all-reduces gradients, which,
  combined with DDP's gradient averaging, yields exactly the gradient of the
  global statistic (tested in tests/test_losses.py with two gloo processes).
"""

from __future__ import annotations

import torch


def _dist_world() -> int:
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        return dist.get_world_size()
    return 1


class _AllReduceSum(torch.autograd.Function):
    """Sum over ranks whose backward also sums the incoming gradients over ranks.

    Every rank computes the same global loss from the summed value; summing the gradients in
    backward gives each rank ``world ×`` its true local gradient, and DDP's averaging of parameter
    gradients then yields exactly the gradient of the global statistic."""

    @staticmethod
    def forward(ctx, x):
        import torch.distributed as dist

        y = x.clone()
        dist.all_reduce(y, op=dist.ReduceOp.SUM)
        return y

    @staticmethod
    def backward(ctx, g):
        import torch.distributed as dist

        g = g.clone()
        dist.all_reduce(g, op=dist.ReduceOp.SUM)
        return g


def _dist_mean(x: torch.Tensor) -> torch.Tensor:
    """Differentiable average over ranks (identity when not distributed)."""
    world = _dist_world()
    if world == 1:
        return x
    return _AllReduceSum.apply(x.contiguous()) / world


def ep_knots(num_knots: int = 17, t_max: float = 3.0, device=None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Knots ``t`` (K,), integration weights ``w`` (K,) including the Gaussian weighting and the
    ×2 for the negative half-line, and the target ECF ``exp(-t²/2)``."""
    t = torch.linspace(0.0, t_max, num_knots, device=device, dtype=torch.float32)
    dt = t_max / (num_knots - 1)
    trap = torch.full((num_knots,), dt, device=device, dtype=torch.float32)
    trap[0] = trap[-1] = dt / 2
    phi = torch.exp(-0.5 * t * t)
    return t, 2.0 * trap * phi, phi


class _ECF(torch.autograd.Function):
    """Empirical characteristic function (mean over dim -3 of cos / sin of ``x ⊗ t``) with a fused backward.

    Autograd through ``cos``/``sin`` recomputes both transcendentals in the backward pass; the
    derivative of each is the other, so keeping the forward values halves that work. This is the
    regulariser's hot spot (≈ 20 % of a ``cpu``-preset step). Written in the ``setup_context`` form with
    a generated vmap rule so the same function also runs under ``torch.vmap`` (stacked ensembles,
    :mod:`pokeworld.train.stacked`); that form cannot stash intermediates on ``ctx``, so the cos/sin
    tensors come back as extra, non-differentiable outputs, which :func:`_ecf` drops."""

    generate_vmap_rule = True

    @staticmethod
    def forward(x, t):
        xt = x.unsqueeze(-1) * t  # (..., N, K, knots)
        c, s = torch.cos(xt), torch.sin(xt)
        return c.mean(-3), s.mean(-3), c, s

    @staticmethod
    def setup_context(ctx, inputs, output):
        x, t = inputs
        ctx.mark_non_differentiable(output[2], output[3])
        ctx.save_for_backward(output[2], output[3], t)
        ctx.n = x.shape[-2]

    @staticmethod
    def backward(ctx, grad_cos, grad_sin, _grad_c, _grad_s):
        c, s, t = ctx.saved_tensors
        gc = (grad_cos * t / ctx.n).unsqueeze(-3)
        gs = (grad_sin * t / ctx.n).unsqueeze(-3)
        return (c * gs - s * gc).sum(-1), None


def _ecf(x: torch.Tensor, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean cos and sin of ``x ⊗ t`` over dim -3 (:class:`_ECF`), with and without ``torch.vmap``."""
    return _ECF.apply(x, t)[:2]


def epps_pulley(x: torch.Tensor, num_knots: int = 17, t_max: float = 3.0,
                reference_rows: int | None = None) -> torch.Tensor:
    """Epps–Pulley normality statistic of 1-d samples along dim -2.

    Args:
        x: (..., N, K) — N samples of K independent 1-d projections.
        reference_rows: scale the integral by this count instead of N. The statistic is N-scaled, so at a
            fixed weight its pull on the encoder grows with the batch; a fixed reference count makes a weight λ
            mean the same strength at any batch (e.g. the paper's batch 128 at our batch 32: 4× the pull).
            The ECF (and so the gradient's direction) is still the mean over the N rows there are.
    Returns:
        (..., K) statistic ``N · ∫ |ECF − φ|² w``, averaged ECF over ranks when distributed
        (N is then the global sample count, or ``reference_rows``).
    """
    t, w, phi = ep_knots(num_knots, t_max, x.device)
    cos_m, sin_m = _ecf(x.float(), t)  # (..., K, knots) each
    cos_m, sin_m = _dist_mean(cos_m), _dist_mean(sin_m)
    err = (cos_m - phi) ** 2 + sin_m ** 2  # (..., K, knots)
    n = reference_rows if reference_rows else x.shape[-2] * _dist_world()
    return (err @ w) * n


def random_directions(dim: int, num: int, seed: int, device=None) -> torch.Tensor:
    """(dim, num) unit directions drawn from a generator seeded only by ``seed``.

    Seeding from (run seed, step) makes directions identical on every rank and on resume."""
    g = torch.Generator(device="cpu")
    g.manual_seed(int(seed) % (2 ** 63 - 1))
    a = torch.randn(dim, num, generator=g)
    a = a / a.norm(dim=0, keepdim=True)
    return a.to(device) if device is not None else a


def subsample_index(n: int, max_rows: int | None, seed: int) -> torch.Tensor | None:
    """Row subset of :func:`sigreg`: ``max_rows`` of ``n`` row indices (CPU int64), or None when every row is kept.

    A random permutation from a CPU generator seeded by ``seed`` only (the step's SIGReg seed), so it is the
    same on every rank (each rank takes those positions of its own rows), after resume, and when a trainer
    draws it on the host ahead of the step (:func:`pokeworld.train.sigreg_row_index`)."""
    if max_rows is None or n <= max_rows:
        return None
    g = torch.Generator(device="cpu")
    g.manual_seed((int(seed) * 7919 + 17) % (2 ** 63 - 1))
    return torch.randperm(n, generator=g)[:max_rows]


def sigreg(z: torch.Tensor, num_dirs: int = 1024, seed: int = 0, num_knots: int = 17,
           t_max: float = 3.0, max_rows: int | None = None, directions: torch.Tensor | None = None,
           rows: torch.Tensor | None = None, reference_rows: int | None = None) -> torch.Tensor:
    """SIGReg loss: mean Epps–Pulley statistic of ``z`` projected on ``num_dirs`` random unit directions.

    Args:
        z: (..., N, D) embeddings; leading dims are independent groups (e.g. time steps, as in
           LeWM: the statistic is computed per time step over the batch and then averaged).
        num_dirs: number of random directions (1024 for global latents, 256 for tokens).
        seed: directions seed; pass a function of (run seed, step) so they are resampled every
           step but shared across ranks.
        max_rows: if set and N > max_rows, use a random subset of ``max_rows`` rows (token-level
           subsampling, 4096 in the paper). The subset uses the same seeded generator
           (:func:`subsample_index`).
        directions: (D, num_dirs) unit directions to use instead of drawing them from ``seed``; the
           trainer's fast path passes ``random_directions(D, num_dirs, seed)`` uploaded ahead of time.
        rows: row indices (int64, on ``z``'s device) to use instead of drawing the subset from ``seed``
           and ``max_rows``; trainers pass ``subsample_index(N, max_rows, seed)`` drawn on the host (the
           stacked trainer one per member, which an integer seed under ``torch.vmap`` could not give).
        reference_rows: the statistic at this sample count instead of the rows' own (:func:`epps_pulley`);
           None or 0 keeps N.
    Returns:
        scalar loss (float32, computed outside autocast).
    """
    with torch.autocast(device_type=z.device.type, enabled=False):
        z = z.float()
        if rows is None:
            rows = subsample_index(z.shape[-2], max_rows, seed)
            rows = None if rows is None else rows.to(z.device)
        if rows is not None:
            z = z.index_select(-2, rows)
        a = random_directions(z.shape[-1], num_dirs, seed, z.device) if directions is None else directions.float()
        return epps_pulley(z @ a, num_knots, t_max, reference_rows).mean()


SIGREG_POOLS = ("step", "pooled")
"""Which latent rows one SIGReg statistic is computed over (global-latent models): 'step' — per time step over
the batch, the statistics averaged over time (LeWM's reading); 'pooled' — one statistic over all batch × time
rows, subsampled to a row budget (the reading of the paper's "4096 subsampled rows"). docs/design.md
"SIGReg: per-step or pooled rows"."""


def sigreg_rows_of(z: torch.Tensor, pool: str) -> torch.Tensor:
    """The row groups SIGReg sees for (B, L, D) latents: (L, B, D) for 'step', (B·L, D) for 'pooled'."""
    if pool == "step":
        return z.transpose(0, 1)
    if pool == "pooled":
        return z.reshape(-1, z.shape[-1])
    raise ValueError(f"unknown SIGReg pool {pool!r}; choose one of {list(SIGREG_POOLS)}")


def masked_mse(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Mean squared error over the last dim, then weighted mean over the remaining dims.

    Args:
        pred, target: (..., D).
        weight: optional (...) non-negative per-row weights (0 masks a row out).
    """
    err = (pred.float() - target.float()).pow(2).mean(-1)
    if weight is None:
        return err.mean()
    weight = weight.float()
    return (err * weight).sum() / weight.sum().clamp_min(1e-8)


def gaussian_nll(mean: torch.Tensor, logvar: torch.Tensor, target: torch.Tensor,
                 weight: torch.Tensor | None = None, min_logvar: float = -8.0, max_logvar: float = 8.0) -> torch.Tensor:
    """Heteroscedastic Gaussian NLL ``0.5·(exp(-s)(y-μ)² + s)`` (constant dropped), s clamped.

    Shapes as :func:`masked_mse`; ``logvar`` has the shape of ``mean``."""
    s = logvar.float().clamp(min_logvar, max_logvar)
    nll = 0.5 * (torch.exp(-s) * (target.float() - mean.float()).pow(2) + s)
    nll = nll.mean(-1)
    if weight is None:
        return nll.mean()
    weight = weight.float()
    return (nll * weight).sum() / weight.sum().clamp_min(1e-8)


LOGVAR_RANGE = (-8.0, 8.0)
"""Clamp of the belief objective's log-variances, shared by the KL and the reparameterised sample."""

GNLL_VARIANCES = ("free", "bounded", "beta", "per_head")
DEFAULT_GNLL_VARIANCE = "bounded"
"""The NLL heads' variance unless a run names another: free precisions ran to their clamp and reweighted frames
~2,000× (docs/results/deviations_cpu.md §5; docs/design.md "Gaussian NLL: variance parameterisation")."""
"""How the ``gnll`` objective parameterises its variances (docs/design.md "Gaussian NLL: variance
parameterisation"): 'free' — a per-element, per-frame log-variance head output clamped to
:data:`LOGVAR_RANGE` (:func:`gaussian_nll`); 'bounded' — the same output squashed smoothly into
[−b, b] (:func:`bounded_logvar`); 'beta' — free log-variances, the per-element NLL reweighted by
stop_gradient(σ^{2β}) (:func:`beta_nll`); 'per_head' — one learned log-variance scalar per head
(:func:`head_logvar_nll`)."""


def nll_precision(logvar: torch.Tensor) -> torch.Tensor:
    """Precision e^{-s} with which :func:`gaussian_nll` weighs a squared error (s clamped as there)."""
    return torch.exp(-logvar.float().clamp(*LOGVAR_RANGE))


def bounded_logvar(raw: torch.Tensor, bound: float = 2.0) -> torch.Tensor:
    """Log-variance ``b·tanh(raw / b)`` in (−b, b): the precision never exceeds e^b (e² ≈ 7.4 at b = 2).

    A hard clamp has zero gradient beyond its edge, so a head pushed there stays there whatever the data
    say; the tanh is the identity near 0 (slope 1 − (s/b)²), so small log-variances are what the free head
    would output, and its gradient shrinks smoothly towards the bound instead of vanishing at it."""
    b = float(bound)
    return b * torch.tanh(raw.float() / b)


def beta_nll(mean: torch.Tensor, logvar: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None,
             beta: float = 0.5, min_logvar: float = LOGVAR_RANGE[0],
             max_logvar: float = LOGVAR_RANGE[1]) -> torch.Tensor:
    """β-NLL (Seitzer et al. 2022): the per-element Gaussian NLL times stop_gradient(σ^{2β}), s clamped.

    ``sg(e^{βs}) · 0.5·(e^{-s}(y−μ)² + s)``. Its gradient in μ is ``e^{(β−1)s}(μ−y)``: β = 0 is the
    plain NLL (precision-weighted), β = 1 the MSE gradient ½·∂(y−μ)² whatever σ is, so a frame the model
    calls predictable no longer gains weight e^{-s} on its mean; σ itself still gets the NLL's gradient
    (scaled), so its optimum σ² = E(y−μ)² is unchanged. Shapes as :func:`gaussian_nll`."""
    s = logvar.float().clamp(min_logvar, max_logvar)
    nll = 0.5 * (torch.exp(-s) * (target.float() - mean.float()).pow(2) + s)
    nll = (torch.exp(float(beta) * s).detach() * nll).mean(-1)
    if weight is None:
        return nll.mean()
    weight = weight.float()
    return (nll * weight).sum() / weight.sum().clamp_min(1e-8)


def beta_nll_weight(logvar: torch.Tensor, beta: float) -> torch.Tensor:
    """Weight e^{(β−1)s} with which :func:`beta_nll` weighs a squared error on the mean (s clamped as there)."""
    return torch.exp((float(beta) - 1.0) * logvar.float().clamp(*LOGVAR_RANGE))


def head_logvar_nll(mean: torch.Tensor, logvar: torch.Tensor, target: torch.Tensor,
                    weight: torch.Tensor | None = None) -> torch.Tensor:
    """Homoscedastic Gaussian NLL of one head: a single log-variance s (any shape broadcastable to ``mean``;
    a 0-d learned scalar per head) shared by every element and frame the head predicts.

    ``0.5·(e^{-s}·mse + s)`` with mse the (weighted) mean squared error, minimised at s = log mse: s tracks
    the head's own error level, so the head's terms are rescaled against the other heads (horizons,
    modalities) but no frame or latent dimension is reweighted against another. Clamped as
    :func:`gaussian_nll`, of which it is the broadcast case."""
    return gaussian_nll(mean, logvar.expand_as(mean), target, weight)


def gaussian_kl(mu_q: torch.Tensor, logvar_q: torch.Tensor, mu_p: torch.Tensor, logvar_p: torch.Tensor,
                min_logvar: float = LOGVAR_RANGE[0], max_logvar: float = LOGVAR_RANGE[1]) -> torch.Tensor:
    """KL(q || p) of diagonal Gaussians, summed over the last dim (nats); log-variances clamped.

    ``0.5 · Σ_d [s_p − s_q + (e^{s_q} + (μ_q − μ_p)²) e^{−s_p} − 1]`` with s = log σ². Shapes broadcast;
    returns the broadcast shape without the last dim (the caller chooses how to average it).
    """
    sq = logvar_q.float().clamp(min_logvar, max_logvar)
    sp = logvar_p.float().clamp(min_logvar, max_logvar)
    d2 = (mu_q.float() - mu_p.float()).pow(2)
    return 0.5 * (sp - sq + (sq.exp() + d2) * torch.exp(-sp) - 1.0).sum(-1)


def glide_weights(glide: torch.Tensor, weight: float) -> torch.Tensor:
    """Per-frame prediction-loss weights: ``weight`` on glide frames (``glide`` True), 1 elsewhere."""
    return 1.0 + (float(weight) - 1.0) * glide.float()


def motion_weights(frames: torch.Tensor, alpha: float) -> torch.Tensor:
    """Per-frame weights of magnitude-weighted motion-forecast targets: ``1 + α · m_t / mean(m)``.

    Args:
        frames: (B, L, S, S) float frames as the encoder sees them (downsampled, in [0, 1]).
        alpha: α ≥ 0; 0 gives all-ones weights.
    Returns:
        (B, L) float weights, no gradient. m_t is the mean absolute temporal difference of frame t (0 at the
        first frame of a window, which has no previous frame); mean(m) is over the batch's frames 1…L−1, so a
        frame with the batch's mean motion weighs 1 + α and a still frame 1.
    """
    with torch.no_grad():
        f = frames.float()
        m = (f[:, 1:] - f[:, :-1]).abs().flatten(2).mean(-1)  # (B, L-1)
        m = torch.cat([torch.zeros_like(m[:, :1]), m], 1)
        return 1.0 + float(alpha) * m / m[:, 1:].mean().clamp_min(1e-8)


def glide_loss_share(glide: torch.Tensor, weight: float, horizons) -> torch.Tensor:
    """Share of the prediction-loss weight mass on glide target frames, Σ w·glide / Σ w.

    Args:
        glide: (B, L) bool glide mask of a batch of windows.
        weight: the glide-frame loss weight W (1 elsewhere).
        horizons: prediction horizons Δ; the targets of horizon Δ are frames Δ..L-1.
    Returns:
        scalar: the share per horizon (pooled over the batch's target frames), averaged over the
        horizons shorter than L — each horizon's loss is its own weighted mean, so this is the
        glide share of the loss the optimiser sees. With base share s it is W·s / (W·s + 1 − s).
    """
    L = glide.shape[1]
    shares = []
    for d in horizons:
        if d >= L:
            continue
        g = glide[:, d:].float()
        w = glide_weights(glide[:, d:], weight)
        shares.append((w * g).sum() / w.sum().clamp_min(1e-8))
    if not shares:
        raise ValueError(f"no horizon in {tuple(horizons)} is shorter than the window ({L})")
    return torch.stack(shares).mean()


def expected_null_ep(num_knots: int = 17, t_max: float = 3.0) -> float:
    """Expected EP statistic for N(0,1) samples: N·E|ECF−φ|² = ∫ (1 − φ(t)²) w(t) dt."""
    t, w, phi = ep_knots(num_knots, t_max)
    return float(((1 - phi ** 2) * w).sum())


__all__ = ["sigreg", "epps_pulley", "random_directions", "ep_knots", "masked_mse", "gaussian_nll", "gaussian_kl",
           "glide_weights", "motion_weights", "glide_loss_share", "expected_null_ep", "subsample_index",
           "sigreg_rows_of", "SIGREG_POOLS", "GNLL_VARIANCES", "DEFAULT_GNLL_VARIANCE", "bounded_logvar", "beta_nll", "beta_nll_weight",
           "head_logvar_nll", "nll_precision"]
