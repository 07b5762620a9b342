"""Causal transformer predictor with zero-initialised AdaLN action conditioning (DiT "adaLN-zero").

Each block computes, for every token t with conditioning vector c_t = embed(action_t):

    (shift1, scale1, gate1, shift2, scale2, gate2) = Linear(SiLU(c_t))     # zero-initialised
    x = x + gate1 * Attn(LN(x) * (1 + scale1) + shift1)                     # causal attention
    x = x + gate2 * MLP(LN(x) * (1 + scale2) + shift2)

Because the modulation Linear is zero-initialised, every block is the identity at
initialisation and the trunk output cannot depend on the actions; gradients still
reach the modulation weights (the attention/MLP outputs are non-zero), so the
conditioning is learned from the first step.

Causality: attention uses a causal mask over time; in token mode (``tokens_per_step
= S > 1``) the sequence is (t, s)-major and the mask is block-causal: token (t, s)
sees every token of steps ≤ t.

Incremental decoding (:class:`KVCache`, global latents only): because state t depends on steps ≤ t
only and the time embedding is absolute, appending steps never changes the keys and values of earlier
ones, so an autoregressive rollout can feed one new step at a time against the cached keys/values of
every layer instead of re-running the whole grown sequence (16 steps from 8 context: 24 step-passes
instead of 248). Same numbers up to float summation order.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class KVCache:
    """Per-layer attention keys and values of the steps fed so far (:meth:`CausalPredictor.forward` with
    ``cache=``); ``length`` is the number of steps they cover, i.e. the time index of the next step."""

    def __init__(self) -> None:
        self.k: list[torch.Tensor | None] = []
        self.v: list[torch.Tensor | None] = []
        self.length = 0


class AdaLNBlock(nn.Module):
    def __init__(self, width: int, heads: int, cond_dim: int, dropout: float = 0.1, mlp_ratio: int = 4):
        super().__init__()
        if width % heads:
            raise ValueError(f"width {width} must be divisible by heads {heads}")
        self.heads = heads
        self.norm1 = nn.LayerNorm(width, elementwise_affine=False, eps=1e-6)
        self.norm2 = nn.LayerNorm(width, elementwise_affine=False, eps=1e-6)
        self.qkv = nn.Linear(width, 3 * width)
        self.out = nn.Linear(width, width)
        self.mlp = nn.Sequential(nn.Linear(width, mlp_ratio * width), nn.GELU(), nn.Dropout(dropout),
                                 nn.Linear(mlp_ratio * width, width))
        self.drop = nn.Dropout(dropout)
        self.dropout = dropout
        self.ada = nn.Sequential(nn.SiLU(), nn.Linear(cond_dim, 6 * width))
        nn.init.zeros_(self.ada[1].weight)
        nn.init.zeros_(self.ada[1].bias)

    def forward(self, x: torch.Tensor, c: torch.Tensor, mask: torch.Tensor | None,
                cache: tuple[KVCache, int] | None = None) -> torch.Tensor:
        """``cache`` = (cache, this block's index): attend to the cached keys/values of earlier steps too, and
        append this call's (global latents, so ``mask`` is None)."""
        b, n, w = x.shape
        sh1, sc1, g1, sh2, sc2, g2 = self.ada(c).chunk(6, dim=-1)
        y = self.norm1(x) * (1 + sc1) + sh1
        q, k, v = self.qkv(y).view(b, n, 3, self.heads, w // self.heads).permute(2, 0, 3, 1, 4)
        p = self.dropout if self.training else 0.0
        past = 0
        if cache is not None:
            kv, i = cache
            if i < len(kv.k) and kv.k[i] is not None:
                past = kv.k[i].shape[2]
                k, v = torch.cat([kv.k[i], k], 2), torch.cat([kv.v[i], v], 2)
            if i < len(kv.k):
                kv.k[i], kv.v[i] = k, v
            else:
                kv.k.append(k)
                kv.v.append(v)
        if past and n == 1:  # one new step sees every cached one
            a = F.scaled_dot_product_attention(q, k, v, dropout_p=p)
        elif past:  # new step i (time past + i) sees times ≤ past + i
            allowed = torch.arange(past + n, device=x.device)[None, :] <= past + torch.arange(n, device=x.device)[:, None]
            a = F.scaled_dot_product_attention(q, k, v, attn_mask=allowed, dropout_p=p)
        elif mask is None:
            a = F.scaled_dot_product_attention(q, k, v, is_causal=True, dropout_p=p)
        else:
            a = F.scaled_dot_product_attention(q, k, v, attn_mask=mask, dropout_p=p)
        a = a.transpose(1, 2).reshape(b, n, w)
        x = x + g1 * self.drop(self.out(a))
        y = self.norm2(x) * (1 + sc2) + sh2
        return x + g2 * self.drop(self.mlp(y))


class CausalPredictor(nn.Module):
    """Latents (B, L, S, D) + per-step actions (B, L, Da) -> states (B, L, S, width).

    ``S`` is 1 for global latents. Actions at step t condition every token of step t.
    """

    def __init__(self, latent_dim: int, action_dim: int, width: int = 192, depth: int = 4, heads: int = 8,
                 dropout: float = 0.1, max_len: int = 128, tokens_per_step: int = 1):
        super().__init__()
        self.width, self.max_len, self.tokens_per_step = width, max_len, tokens_per_step
        self.inp = nn.Linear(latent_dim, width)
        self.time_pos = nn.Parameter(torch.zeros(max_len, width))
        nn.init.normal_(self.time_pos, std=0.02)
        self.space_pos = nn.Parameter(torch.zeros(tokens_per_step, width)) if tokens_per_step > 1 else None
        if self.space_pos is not None:
            nn.init.normal_(self.space_pos, std=0.02)
        self.act = nn.Sequential(nn.Linear(action_dim, width), nn.SiLU(), nn.Linear(width, width))
        self.drop = nn.Dropout(dropout)
        self.blocks = nn.ModuleList([AdaLNBlock(width, heads, width, dropout) for _ in range(depth)])
        self.norm = nn.LayerNorm(width)

    def forward(self, z: torch.Tensor, actions: torch.Tensor, cache: KVCache | None = None) -> torch.Tensor:
        """``cache``: the steps in ``z`` follow the ``cache.length`` steps fed before (same batch); their states
        attend to those too, and the cache grows by L. Global latents (S = 1) only."""
        b, L, s, _ = z.shape
        t0 = 0 if cache is None else cache.length
        if t0 + L > self.max_len:
            raise ValueError(f"sequence length {t0 + L} exceeds the predictor's max_len {self.max_len}")
        if cache is not None and s > 1:
            raise ValueError("incremental decoding (cache) is for global latents (one token per step)")
        x = self.inp(z) + self.time_pos[t0:t0 + L, None, :]
        if self.space_pos is not None:
            x = x + self.space_pos[None, None]
        c = self.act(actions)[:, :, None, :].expand(b, L, s, self.width)
        x = self.drop(x).reshape(b, L * s, self.width)
        c = c.reshape(b, L * s, self.width)
        mask = None
        if s > 1:
            step = torch.arange(L, device=z.device).repeat_interleave(s)
            mask = step[None, :] <= step[:, None]  # (L*s, L*s) True = attend
        for i, blk in enumerate(self.blocks):
            x = blk(x, c, mask, None if cache is None else (cache, i))
        if cache is not None:
            cache.length = t0 + L
        return self.norm(x).reshape(b, L, s, self.width)
