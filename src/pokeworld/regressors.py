"""Regressors shared by certificates and probes: grouped-CV ridge, early-stopped MLP and GRU.

Every fit takes ``groups`` (episode ids): cross-validation folds and the
early-stopping validation split never put one episode on both sides.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch
from sklearn.linear_model import Ridge
from sklearn.model_selection import GroupKFold

from .errors import DataError

ALPHAS = tuple(10.0 ** np.arange(-3, 5))


def r2_scores(y_true: np.ndarray, y_pred: np.ndarray) -> np.ndarray:
    """Per-column coefficient of determination (1 - SSE/SST); can be negative."""
    y_true = y_true.reshape(len(y_true), -1)
    y_pred = y_pred.reshape(len(y_pred), -1)
    sse = ((y_true - y_pred) ** 2).sum(0)
    sst = ((y_true - y_true.mean(0)) ** 2).sum(0)
    return 1.0 - sse / np.maximum(sst, 1e-12)


def _check(X: np.ndarray, Y: np.ndarray, groups: np.ndarray) -> None:
    if len(X) == 0 or X.size == 0:
        raise DataError("empty training set: no windows of the requested kind in the fit episodes")
    if len(X) != len(Y) or len(X) != len(groups):
        raise DataError(f"X, Y and groups disagree in length: {len(X)}, {len(Y)}, {len(groups)}")
    if not (np.isfinite(X).all() and np.isfinite(Y).all()):
        raise DataError("non-finite values (NaN/inf) in regression inputs or targets")
    if np.unique(groups).size < 2:
        raise DataError("need windows from at least two episodes to fit with episode-grouped validation")


@dataclass
class Standardizer:
    mean: np.ndarray
    std: np.ndarray

    @classmethod
    def fit(cls, X: np.ndarray) -> "Standardizer":
        return cls(X.mean(0), X.std(0) + 1e-6)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return (X - self.mean) / self.std


def ridge_path(X: np.ndarray, Y: np.ndarray, X_eval: np.ndarray, alphas) -> list[np.ndarray]:
    """Predictions on ``X_eval`` of intercept ridge fits on (X, Y) for every alpha, from one eigendecomposition.

    The same estimator as ``sklearn.linear_model.Ridge(alpha).fit(X, Y).predict(X_eval)`` (centred X and Y,
    unpenalised intercept), to floating-point precision: with Xc the centred X and Xc = U S V^T, the
    coefficients are V diag(s / (s² + α)) U^T Yc. The decomposition is shared by all alphas — a CV sweep over
    8 alphas costs about one fit instead of eight. Primal (d×d Gram) when d ≤ n, dual (n×n kernel) otherwise.
    """
    X = np.asarray(X, float)
    Y = np.asarray(Y, float).reshape(len(X), -1)
    xm, ym = X.mean(0), Y.mean(0)
    Xc, Yc = X - xm, Y - ym
    Xe = np.asarray(X_eval, float) - xm
    n, d = Xc.shape
    if d <= n:
        lam, V = np.linalg.eigh(Xc.T @ Xc)
        proj_y = V.T @ (Xc.T @ Yc)  # (d, k)
        proj_e = Xe @ V  # (m, d)
        return [proj_e @ (proj_y / np.maximum(lam + a, 1e-300)[:, None]) + ym for a in alphas]
    lam, U = np.linalg.eigh(Xc @ Xc.T)
    proj_y = U.T @ Yc  # (n, k)
    proj_e = (Xe @ Xc.T) @ U  # (m, n)
    return [proj_e @ (proj_y / np.maximum(lam + a, 1e-300)[:, None]) + ym for a in alphas]


class RidgeCV:
    """Ridge with alpha chosen by episode-grouped K-fold CV on standardised features."""

    def __init__(self, alphas=ALPHAS, folds: int = 5):
        self.alphas, self.folds = alphas, folds

    def fit(self, X, Y, groups):
        _check(X, Y, groups)
        X = X.reshape(len(X), -1)
        self.sx = Standardizer.fit(X)
        Xs = self.sx(X)
        Y2 = np.asarray(Y, float).reshape(len(Y), -1)
        folds = min(self.folds, np.unique(groups).size)
        preds = [np.zeros_like(Y2) for _ in self.alphas]
        for tr, va in GroupKFold(folds).split(Xs, Y2, groups):
            for pred, p in zip(preds, ridge_path(Xs[tr], Y2[tr], Xs[va], self.alphas)):
                pred[va] = p
        scores = [np.mean(r2_scores(Y2, pred)) for pred in preds]
        self.alpha = float(self.alphas[int(np.argmax(scores))])
        self.cv_r2 = float(np.max(scores))
        # tiny alphas on collinear raw windows are ill-conditioned by design; CV discards them if they overfit
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*ll-conditioned matrix", module="sklearn")
            self.model = Ridge(alpha=self.alpha).fit(Xs, Y)
        return self

    def predict(self, X):
        return self.model.predict(self.sx(X.reshape(len(X), -1))).reshape(len(X), -1)


class _MLP(torch.nn.Module):
    def __init__(self, d_in, d_out, hidden, layers, dropout):
        super().__init__()
        mods, d = [], d_in
        for _ in range(layers):
            mods += [torch.nn.Linear(d, hidden), torch.nn.GELU(), torch.nn.Dropout(dropout)]
            d = hidden
        mods.append(torch.nn.Linear(d, d_out))
        self.net = torch.nn.Sequential(*mods)

    def forward(self, x):
        return self.net(x.flatten(1))


class _GRU(torch.nn.Module):
    def __init__(self, d_in, d_out, hidden, layers, dropout):
        super().__init__()
        self.gru = torch.nn.GRU(d_in, hidden, num_layers=layers, batch_first=True,
                                dropout=dropout if layers > 1 else 0.0)
        self.head = torch.nn.Linear(hidden, d_out)

    def forward(self, x):
        out, _ = self.gru(x)
        return self.head(out[:, -1])


class TorchRegressor:
    """Early-stopped neural regressor (``arch`` 'mlp' on flattened input or 'gru' over the time axis).

    A fifth of the fit episodes is held out for early stopping (patience on the
    validation MSE); the best-validation weights are kept.
    """

    def __init__(self, arch: str = "mlp", hidden: int = 256, layers: int = 2, dropout: float = 0.1,
                 lr: float = 1e-3, weight_decay: float = 1e-4, epochs: int = 200, batch_size: int = 256,
                 patience: int = 15, seed: int = 0, val_fraction: float = 0.2):
        if arch not in ("mlp", "gru"):
            raise DataError(f"unknown regressor arch {arch!r}")
        self.__dict__.update(locals())
        del self.__dict__["self"]

    def fit(self, X, Y, groups):
        _check(X, Y, groups)
        if self.arch == "gru" and X.ndim != 3:
            raise DataError(f"GRU input must be (N, T, D), got {X.shape}")
        g = torch.Generator().manual_seed(self.seed)
        rng = np.random.default_rng(self.seed)
        ug = np.unique(groups)
        val_groups = rng.choice(ug, max(1, int(round(self.val_fraction * ug.size))), replace=False)
        va = np.isin(groups, val_groups)
        flat = X.reshape(len(X), -1) if self.arch == "mlp" else X.reshape(-1, X.shape[-1])
        self.sx = Standardizer.fit(flat[np.repeat(~va, len(flat) // len(X))] if self.arch == "gru" else flat[~va])
        self.sy = Standardizer.fit(Y[~va])
        Xt = torch.as_tensor(self._prep(X), dtype=torch.float32)
        Yt = torch.as_tensor(self.sy(Y), dtype=torch.float32)
        tr_idx, va_idx = np.flatnonzero(~va), np.flatnonzero(va)
        torch.manual_seed(self.seed)
        d_in = Xt.shape[-1] if self.arch == "gru" else Xt[0].numel()
        cls = _GRU if self.arch == "gru" else _MLP
        self.net = cls(d_in, Yt.shape[1], self.hidden, self.layers, self.dropout)
        opt = torch.optim.AdamW(self.net.parameters(), lr=self.lr, weight_decay=self.weight_decay)
        best, best_state, bad = np.inf, None, 0
        for _ in range(self.epochs):
            self.net.train()
            perm = tr_idx[torch.randperm(tr_idx.size, generator=g).numpy()]
            for i in range(0, perm.size, self.batch_size):
                b = perm[i:i + self.batch_size]
                loss = torch.nn.functional.mse_loss(self.net(Xt[b]), Yt[b])
                opt.zero_grad()
                loss.backward()
                opt.step()
            self.net.eval()
            with torch.no_grad():
                v = torch.nn.functional.mse_loss(self.net(Xt[va_idx]), Yt[va_idx]).item()
            if v < best - 1e-5:
                best, bad = v, 0
                best_state = {k: t.clone() for k, t in self.net.state_dict().items()}
            else:
                bad += 1
                if bad >= self.patience:
                    break
        self.net.load_state_dict(best_state)
        self.val_mse = best
        return self

    def _prep(self, X):
        if self.arch == "mlp":
            return self.sx(X.reshape(len(X), -1))
        return self.sx(X)

    def predict(self, X):
        self.net.eval()
        with torch.no_grad():
            out = self.net(torch.as_tensor(self._prep(X), dtype=torch.float32)).numpy()
        return out * self.sy.std + self.sy.mean
