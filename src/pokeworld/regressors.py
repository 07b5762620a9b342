"""Regressors shared by certificates and probes: grouped-CV ridge, early-stopped MLP and GRU.

Every fit takes ``groups`` (episode ids): cross-validation folds and the
early-stopping validation split never put one episode on both sides.

The input's type picks where a fit runs: numpy arrays take the numpy / sklearn path every record was computed
with; torch tensors stay on their device (a GPU measurement's states never leave it) and the same estimators run
there in torch, ridge in float64. On the CPU the two agree to float rounding (tests/test_device_probes.py).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from sklearn.linear_model import Ridge
from sklearn.model_selection import GroupKFold

from .errors import DataError

ALPHAS = tuple(10.0 ** np.arange(-3, 5))


def r2_scores(y_true, y_pred):
    """Per-column coefficient of determination (1 - SSE/SST); can be negative. A tensor among the two: computed
    in float64 on its device and returned as a tensor there."""
    if isinstance(y_true, torch.Tensor) or isinstance(y_pred, torch.Tensor):
        dev = (y_true if isinstance(y_true, torch.Tensor) else y_pred).device
        y_true, y_pred = (torch.as_tensor(y, device=dev).double() for y in (y_true, y_pred))
        y_true, y_pred = y_true.reshape(len(y_true), -1), y_pred.reshape(len(y_pred), -1)
        sse = ((y_true - y_pred) ** 2).sum(0)
        sst = ((y_true - y_true.mean(0)) ** 2).sum(0)
        return 1.0 - sse / sst.clamp_min(1e-12)
    y_true = y_true.reshape(len(y_true), -1)
    y_pred = y_pred.reshape(len(y_pred), -1)
    sse = ((y_true - y_pred) ** 2).sum(0)
    sst = ((y_true - y_true.mean(0)) ** 2).sum(0)
    return 1.0 - sse / np.maximum(sst, 1e-12)


def _all_finite(a) -> bool:
    return bool(torch.isfinite(a).all()) if isinstance(a, torch.Tensor) else bool(np.isfinite(a).all())


def _check(X, Y, groups: np.ndarray) -> None:
    size = X.numel() if isinstance(X, torch.Tensor) else X.size
    if len(X) == 0 or size == 0:
        raise DataError("empty training set: no windows of the requested kind in the fit episodes")
    if len(X) != len(Y) or len(X) != len(groups):
        raise DataError(f"X, Y and groups disagree in length: {len(X)}, {len(Y)}, {len(groups)}")
    if not (_all_finite(X) and _all_finite(Y)):
        raise DataError("non-finite values (NaN/inf) in regression inputs or targets")
    if np.unique(groups).size < 2:
        raise DataError("need windows from at least two episodes to fit with episode-grouped validation")


@dataclass
class Standardizer:
    mean: np.ndarray | torch.Tensor
    std: np.ndarray | torch.Tensor

    @classmethod
    def fit(cls, X) -> "Standardizer":
        if isinstance(X, torch.Tensor):  # numpy's std is the population one (ddof 0); torch's default is not
            return cls(X.mean(0), X.std(0, correction=0) + 1e-6)
        return cls(X.mean(0), X.std(0) + 1e-6)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return (X - self.mean) / self.std


def ridge_path(X: np.ndarray, Y: np.ndarray, X_eval: np.ndarray, alphas) -> list[np.ndarray]:
    """Predictions on ``X_eval`` of intercept ridge fits on (X, Y) for every alpha, from one eigendecomposition.

    The same estimator as ``sklearn.linear_model.Ridge(alpha).fit(X, Y).predict(X_eval)`` (centred X and Y,
    unpenalised intercept), to floating-point precision: with Xc the centred X and Xc = U S V^T, the
    coefficients are V diag(s / (s² + α)) U^T Yc. The decomposition is shared by all alphas — a CV sweep over
    8 alphas costs about one fit instead of eight. Primal (d×d Gram) when d ≤ n, dual (n×n kernel) otherwise.
    Tensors: the same in float64 torch on X's device, returning tensors there.
    """
    if isinstance(X, torch.Tensor):
        xm, ym, lam, basis, proj_y = _ridge_eig(X, Y)
        proj_e = (torch.as_tensor(X_eval, device=X.device).double() - xm) @ basis
        return [proj_e @ (proj_y / (lam + a).clamp_min(1e-300)[:, None]) + ym for a in alphas]
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


def _ridge_eig(X: torch.Tensor, Y) -> tuple[torch.Tensor, ...]:
    """Torch ridge from one eigendecomposition: (xm, ym, lam, basis, proj_y), the coefficients at alpha a being
    basis @ (proj_y / (lam + a)) on centred features. Primal (d ≤ n): basis = V of Xcᵀ Xc = V diag(lam) Vᵀ and
    proj_y = Vᵀ Xcᵀ Yc; dual: basis = Xcᵀ U of Xc Xcᵀ = U diag(lam) Uᵀ and proj_y = Uᵀ Yc (:func:`ridge_path`)."""
    X = X.double()
    Y = torch.as_tensor(Y, device=X.device).double().reshape(len(X), -1)
    xm, ym = X.mean(0), Y.mean(0)
    Xc, Yc = X - xm, Y - ym
    n, d = Xc.shape
    if d <= n:
        lam, V = torch.linalg.eigh(Xc.T @ Xc)
        return xm, ym, lam, V, V.T @ (Xc.T @ Yc)
    lam, U = torch.linalg.eigh(Xc @ Xc.T)
    return xm, ym, lam, Xc.T @ U, U.T @ Yc


def ridge_coefficients(X: torch.Tensor, Y, alpha: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(W (d, k), b (k,)) of the intercept ridge fit on (X, Y) at ``alpha``, in float64 on X's device: the
    estimator of :func:`ridge_path` (and of sklearn's ``Ridge(alpha)``), as weights that predict new rows."""
    xm, ym, lam, basis, proj_y = _ridge_eig(X, Y)
    W = basis @ (proj_y / (lam + alpha).clamp_min(1e-300)[:, None])
    return W, ym - xm @ W


class RidgeCV:
    """Ridge with alpha chosen by episode-grouped K-fold CV on standardised features.

    Numpy inputs: numpy CV over :func:`ridge_path` and an sklearn ``Ridge`` refit. Tensor inputs: the same
    estimator in float64 torch on their device (standardiser, folds, alpha choice, the refit as
    :func:`ridge_coefficients`); ``predict`` then returns tensors there. The folds are sklearn's GroupKFold of
    ``groups`` on the host either way, so both paths see the same splits.
    """

    def __init__(self, alphas=ALPHAS, folds: int = 5):
        self.alphas, self.folds = alphas, folds

    def fit(self, X, Y, groups):
        if isinstance(X, torch.Tensor):
            return self._fit_torch(X, Y, np.asarray(groups))
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

    def _fit_torch(self, X: torch.Tensor, Y, groups: np.ndarray):
        _check(X, Y, groups)
        X = X.reshape(len(X), -1).double()
        Y2 = torch.as_tensor(Y, device=X.device).double().reshape(len(X), -1)
        self.sx = Standardizer.fit(X)
        Xs = self.sx(X)
        folds = min(self.folds, np.unique(groups).size)
        preds = [torch.zeros_like(Y2) for _ in self.alphas]
        # the folds depend on the groups alone: computed on the host, then used as index tensors on the device
        for tr, va in GroupKFold(folds).split(np.zeros((len(X), 1)), groups=groups):
            tr, va = torch.as_tensor(tr, device=X.device), torch.as_tensor(va, device=X.device)
            for pred, p in zip(preds, ridge_path(Xs[tr], Y2[tr], Xs[va], self.alphas)):
                pred[va] = p
        # the one copy to the host per fit: a CV score per alpha, to choose it as the numpy path does
        scores = torch.stack([r2_scores(Y2, pred).mean() for pred in preds]).tolist()
        self.alpha = float(self.alphas[int(np.argmax(scores))])
        self.cv_r2 = float(np.max(scores))
        self.coef, self.intercept = ridge_coefficients(Xs, Y2, self.alpha)
        self.model = None
        return self

    def predict(self, X):
        if self.model is None:
            Xt = torch.as_tensor(X, device=self.coef.device).double()
            return self.sx(Xt.reshape(len(Xt), -1)) @ self.coef + self.intercept
        return self.model.predict(self.sx(X.reshape(len(X), -1))).reshape(len(X), -1)

    def affine(self) -> tuple:
        """(W (d, k), b (k,)) with ``predict(X) == X @ W + b`` up to float rounding: the standardisation folded
        into the fitted weights, so the decoder can run as one matrix product wherever X lives. Float64 numpy
        arrays after a numpy fit, tensors on the fit's device after a tensor fit."""
        if self.model is None:
            W = self.coef / self.sx.std[:, None]
            return W, self.intercept - self.sx.mean @ W
        mean, std = np.asarray(self.sx.mean, float), np.asarray(self.sx.std, float)
        coef = np.asarray(self.model.coef_, float).reshape(-1, len(mean)).T  # sklearn: (k, d), or (d,) for 1-d Y
        W = coef / std[:, None]
        return W, np.atleast_1d(np.asarray(self.model.intercept_, float)) - mean @ W


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
    validation MSE); the best-validation weights are kept. Tensor inputs train and predict on their device
    (the split and the batch order are drawn on the host as for arrays, so both see the same ones).
    ``on_epoch(epochs_done, stale)`` is called after every epoch, ``stale`` the epochs since the best validation
    loss (the fit stops when it reaches ``patience``): a caller's progress report times the fit by its epochs.
    """

    def __init__(self, arch: str = "mlp", hidden: int = 256, layers: int = 2, dropout: float = 0.1,
                 lr: float = 1e-3, weight_decay: float = 1e-4, epochs: int = 200, batch_size: int = 256,
                 patience: int = 15, seed: int = 0, val_fraction: float = 0.2,
                 on_epoch: Callable[[int, int], None] | None = None):
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
        keep = ~va
        if isinstance(X, torch.Tensor):  # targets and the fit mask join the states on their device
            Y = torch.as_tensor(Y, device=X.device).double()
            keep = torch.as_tensor(keep, device=X.device)
        flat = X.reshape(len(X), -1) if self.arch == "mlp" else X.reshape(-1, X.shape[-1])
        rows = keep.repeat_interleave(len(flat) // len(X)) if isinstance(keep, torch.Tensor) else np.repeat(
            keep, len(flat) // len(X))
        self.sx = Standardizer.fit(flat[rows] if self.arch == "gru" else flat[keep])
        self.sy = Standardizer.fit(Y[keep])
        Xt = torch.as_tensor(self._prep(X), dtype=torch.float32)
        Yt = torch.as_tensor(self.sy(Y), dtype=torch.float32)
        tr_idx, va_idx = np.flatnonzero(~va), np.flatnonzero(va)
        torch.manual_seed(self.seed)
        d_in = Xt.shape[-1] if self.arch == "gru" else Xt[0].numel()
        cls = _GRU if self.arch == "gru" else _MLP
        # initialised on the CPU, then moved: the same initial weights on every device
        self.net = cls(d_in, Yt.shape[1], self.hidden, self.layers, self.dropout).to(Xt.device)
        opt = torch.optim.AdamW(self.net.parameters(), lr=self.lr, weight_decay=self.weight_decay)
        best, best_state, bad = np.inf, None, 0
        for epoch in range(1, self.epochs + 1):
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
            if self.on_epoch is not None:
                self.on_epoch(epoch, bad)
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
        """Predictions in target units: a tensor on the fit's device after a tensor fit, else an array."""
        self.net.eval()
        on_device = isinstance(self.sy.mean, torch.Tensor)
        if on_device:
            X = torch.as_tensor(X, device=self.sy.mean.device)
        with torch.no_grad():
            out = self.net(torch.as_tensor(self._prep(X), dtype=torch.float32))
        return (out if on_device else out.numpy()) * self.sy.std + self.sy.mean
