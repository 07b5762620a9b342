"""Per-frame encoders for X-JEPA (paper App. B "Architecture").

* :class:`FrameCNN` — 4-stage stride-2 CNN over two channels: the frame and its
  temporal difference ``x_t − x_{t−1}`` (zero at the first frame of a sequence).
* :class:`VectorMLP` — small MLP for proprioception / touch (already normalised).
* :class:`FusedEncoder` — concatenates the enabled modality features and projects
  them to the latent (128-d), ending in BatchNorm1d. Deliberately no trailing
  LayerNorm: it would pin embeddings to a shell and fight SIGReg's isotropic
  Gaussian target.

Two forms (:data:`ENCODERS`, docs/model.md "Aligned with the released reference"):

* ``reference`` — the authors' released encoder (``exp/e003_motion/model.py``): 3×3 stride-2 convolutions
  with GELU and no normalisation, the flattened map through a ``fuse_dim``-wide (192) bottleneck, proprio /
  touch MLPs ``in -> 64 -> vec_dim`` (96), and a fusion MLP ``fuse_dim + vecs -> fuse_dim -> latent``;
* ``groupnorm`` — this project's first encoder: 4×4 stride-2 convolutions with GroupNorm, 64-wide vector
  MLPs, and one Linear from the flattened map and vector features to the latent.

All modules here work on flattened frames ``(N, ...)``; the sequence bookkeeping
(and the temporal-difference channel) lives in :class:`pokeworld.models.xjepa.XJEPA`.
"""

from __future__ import annotations

import torch
from torch import nn

ENCODERS = ("groupnorm", "reference")
"""Encoder forms (``XJEPA(encoder=...)``, ``TrainConfig.encoder``); see the module docstring."""

REFERENCE_VEC_HIDDEN = 64
"""Hidden width of the reference encoder's proprio / touch MLPs (its output width is ``vec_dim``)."""


class FrameCNN(nn.Module):
    """Four stride-2 stages: (N, 2, S, S) -> (N, C4, S/16, S/16).

    ``norm=True``: Conv(k4, s2, p1) + GroupNorm + GELU per stage (the ``groupnorm`` encoder); ``norm=False``:
    Conv(k3, s2, p1) + GELU (the ``reference`` encoder). Both halve an even side exactly."""

    def __init__(self, channels: tuple[int, ...] = (32, 64, 128, 256), in_ch: int = 2, norm: bool = True):
        super().__init__()
        layers: list[nn.Module] = []
        c_prev = in_ch
        for c in channels:
            if norm:
                layers += [nn.Conv2d(c_prev, c, 4, 2, 1), nn.GroupNorm(min(8, c), c), nn.GELU()]
            else:
                layers += [nn.Conv2d(c_prev, c, 3, 2, 1), nn.GELU()]
            c_prev = c
        self.net = nn.Sequential(*layers)
        self.out_channels = c_prev

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class VectorMLP(nn.Module):
    """Two-layer MLP ``in -> hidden -> out`` with GELU."""

    def __init__(self, in_dim: int, hidden: int = 64, out_dim: int = 64):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(in_dim, hidden), nn.GELU(), nn.Linear(hidden, out_dim), nn.GELU())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class FusedEncoder(nn.Module):
    """Frame (+ proprio) (+ touch) -> latent.

    Global mode: the CNN's last map is flattened (keeps *where* things are) and fused with the vector
    features: ``groupnorm`` projects the concatenation by one Linear to ``latent_dim``; ``reference`` first
    maps the flattened map through a GELU bottleneck of ``fuse_dim``, then fuses by an MLP
    ``fuse_dim + vecs -> fuse_dim -> latent_dim``; both end in BatchNorm1d. With ``pool=True`` the map is
    averaged over space instead, so position is linearly available only if the CNN learns to encode it in its
    channels (the setting in which a latent can discard it).

    Token mode (``tokens=True``): every cell of the last CNN map becomes a token, projected (with the vector
    features broadcast to all tokens and a learned spatial embedding) by Linear + BatchNorm1d to
    ``latent_dim``, in either form. Output (N, S, latent_dim) with S = (image/16)².
    """

    def __init__(self, image_size: int, channels: tuple[int, ...], dp: int, dt: int,
                 use_proprio: bool, use_touch: bool, latent_dim: int = 128, vec_dim: int = 64,
                 tokens: bool = False, pool: bool = False, style: str = "groupnorm", fuse_dim: int = 192):
        super().__init__()
        if style not in ENCODERS:
            raise ValueError(f"unknown encoder {style!r}; choose one of {list(ENCODERS)}")
        reference = style == "reference"
        self.cnn = FrameCNN(channels, norm=not reference)
        self.pool = pool and not tokens
        side = max(1, image_size // (2 ** len(channels)))
        self.num_tokens = side * side
        self.tokens = tokens
        self.use_proprio, self.use_touch = use_proprio, use_touch
        hidden = REFERENCE_VEC_HIDDEN if reference else vec_dim
        self.proprio = VectorMLP(dp, hidden, vec_dim) if use_proprio else None
        self.touch = VectorMLP(dt, hidden, vec_dim) if use_touch else None
        vec = vec_dim * (int(use_proprio) + int(use_touch))
        c = self.cnn.out_channels
        spatial = c * (1 if self.pool else self.num_tokens)
        self.vis = None
        if tokens:
            self.pos = nn.Parameter(torch.zeros(self.num_tokens, c))
            nn.init.normal_(self.pos, std=0.02)
            self.proj = nn.Linear(c + vec, latent_dim)
        elif reference:
            # the vision features come first in the fusion input: a variant without vector inputs is a leading
            # slice of one with them (stacked training embeds variants that way)
            self.vis = nn.Sequential(nn.Linear(spatial, fuse_dim), nn.GELU())
            self.proj = nn.Sequential(nn.Linear(fuse_dim + vec, fuse_dim), nn.GELU(), nn.Linear(fuse_dim, latent_dim))
        else:
            self.proj = nn.Linear(spatial + vec, latent_dim)
        self.norm = nn.BatchNorm1d(latent_dim)

    def forward(self, img: torch.Tensor, proprio: torch.Tensor | None, touch: torch.Tensor | None) -> torch.Tensor:
        """img (N, 2, S, S) float; proprio (N, Dp) / touch (N, Dt) normalised (or None when unused).

        Returns (N, latent) or, in token mode, (N, num_tokens, latent)."""
        fmap = self.cnn(img)  # (N, C, s, s)
        vecs = []
        if self.use_proprio:
            vecs.append(self.proprio(proprio))
        if self.use_touch:
            vecs.append(self.touch(touch))
        if not self.tokens:
            spatial = fmap.mean((2, 3)) if self.pool else fmap.flatten(1)
            if self.vis is not None:
                spatial = self.vis(spatial)
            feats = torch.cat([spatial] + vecs, dim=-1)
            return self.norm(self.proj(feats))
        tok = fmap.flatten(2).transpose(1, 2) + self.pos  # (N, S, C)
        if vecs:
            v = torch.cat(vecs, -1)[:, None, :].expand(-1, tok.shape[1], -1)
            tok = torch.cat([tok, v], -1)
        out = self.proj(tok)
        n, s, d = out.shape
        return self.norm(out.reshape(n * s, d)).reshape(n, s, d)
