"""Two MLP probe protocols side by side on one model's predictor states: ours and the one the paper's table used.

Our MLP probe (:class:`pokeworld.regressors.TorchRegressor`) fits one network per parameter and stops each on
its own validation loss. The MLP probe of the authors' release (``exp/e003_motion/train.py``, ``mlp_probe``;
the paper's Table "mlp") fits **one** network for log m, γ and log k together and keeps the test predictions of
the evaluation step whose validation R², *averaged over the three parameters*, is best — evaluated every 200
steps from step 0, after one optimiser step. When two of the three parameters carry nothing the network can
use, their validation R² only falls as it fits them, and the average can be best at step 0, where every output
is near the training mean: all three read ≈ 0, whatever the third parameter's own signal.

:class:`JointMLPProbe` is that protocol, and it records the same run under a second selection rule: each
parameter's predictions at *its own* best validation step (``each``). The two rules share one network and one
training trajectory, so a difference between them is the selection rule alone. :func:`compare` reads one
model's predictor states on two sets of contact windows — the main probe's (every 4th start, ≥ 1 contact frame)
and the released probe's (:func:`release_windows`: starts 8 apart, ≥ 2 contact frames, about a third as many) —
and fits ridge, our per-parameter MLP and both joint rules on each.
"""

from __future__ import annotations

import numpy as np
import torch

from ..data import Dataset
from ..errors import DataError
from ..regressors import Standardizer, r2_scores
from ..sim.fidelity import STARTS, WINDOW
from ..windows import Windows, make_windows
from .probes import KINDS, fit_predict, probe_latents, probe_targets
from .state import padded_actions, window_states

#: The parameters the released probe fits jointly, in its column order.
JOINT_TARGETS = ("log_m", "gamma", "log_k")
#: The protocols :func:`compare` reports, in table order.
PROTOCOLS = ("ridge", "mlp_per_parameter", "mlp_joint_mean", "mlp_joint_each")


class JointMLPProbe:
    """One MLP for several targets, the released probe's protocol (defaults are the release's settings).

    d → ``hidden[0]`` → ``hidden[1]`` → k with GELU, no dropout; AdamW (``lr``, ``weight_decay``); ``steps``
    optimiser steps on batches of ``batch_size`` rows drawn with replacement; the last ``val_fraction`` of the
    fit episodes (in the order they first appear) held out for validation; inputs and targets standardised on
    the rest. Every ``every`` steps, from step 0, the validation R² of each target is computed with the test
    predictions: ``mean`` keeps the predictions at the best mean over targets (the release's rule), ``each`` keeps
    each target's at its own best step.
    """

    def __init__(self, hidden: tuple[int, int] = (256, 128), lr: float = 1e-3, weight_decay: float = 1e-3,
                 steps: int = 4001, batch_size: int = 256, every: int = 200, val_fraction: float = 0.15,
                 seed: int = 0, val_block: int = 0):
        if steps < 1 or every < 1 or not 0 < val_fraction < 1:
            raise DataError(f"JointMLPProbe needs steps ≥ 1, every ≥ 1 and 0 < val_fraction < 1; got {steps}, "
                            f"{every}, {val_fraction}")
        self.hidden, self.lr, self.weight_decay = hidden, lr, weight_decay
        self.steps, self.batch_size, self.every = steps, batch_size, every
        self.val_fraction, self.seed, self.val_block = val_fraction, seed, val_block

    def split(self, groups: np.ndarray) -> np.ndarray:
        """The validation mask: the last ``val_fraction`` of the episodes in their order of first appearance (the
        release's), or with ``val_block`` b > 0 the b-th such block counted back from the end (other episodes
        validate, the rule unchanged)."""
        _, first = np.unique(groups, return_index=True)
        order = groups[np.sort(first)]
        n_val = max(1, int(round(self.val_fraction * order.size)))
        if order.size - n_val < 1:
            raise DataError(f"JointMLPProbe needs at least two episodes, got {order.size}")
        end = order.size - self.val_block * n_val
        if self.val_block < 0 or end - n_val < 0:
            raise DataError(f"JointMLPProbe: validation block {self.val_block} is outside {order.size} episodes "
                            f"({order.size // n_val} blocks of {n_val})")
        return np.isin(groups, order[end - n_val:end])

    def fit_predict(self, X: np.ndarray, Y: np.ndarray, groups: np.ndarray, X_test: np.ndarray) -> dict:
        """``{"mean": (N_test, k), "each": (N_test, k), "mean_step": int, "each_step": [int] * k, "curve": [...]}``:
        the test predictions kept under each selection rule, the step each was taken at, and every evaluation's
        ``{"step", "val_r2": [k]}`` (what the rules chose from)."""
        X, Y = np.asarray(X, np.float64).reshape(len(X), -1), np.asarray(Y, np.float64).reshape(len(Y), -1)
        if len(X) != len(Y) or len(X) != len(groups) or not (np.isfinite(X).all() and np.isfinite(Y).all()):
            raise DataError("JointMLPProbe: X, Y and groups must be finite and of one length")
        va = self.split(np.asarray(groups))
        sx, sy = Standardizer.fit(X[~va]), Standardizer.fit(Y[~va])
        xt, yt = (torch.as_tensor(a, dtype=torch.float32) for a in (sx(X[~va]), sy(Y[~va])))
        xv, xe = (torch.as_tensor(sx(a), dtype=torch.float32) for a in (X[va], np.asarray(X_test, np.float64)
                                                                          .reshape(len(X_test), -1)))
        torch.manual_seed(self.seed)
        h1, h2 = self.hidden
        net = torch.nn.Sequential(torch.nn.Linear(X.shape[1], h1), torch.nn.GELU(), torch.nn.Linear(h1, h2),
                                  torch.nn.GELU(), torch.nn.Linear(h2, Y.shape[1]))
        opt = torch.optim.AdamW(net.parameters(), self.lr, weight_decay=self.weight_decay)
        gen = torch.Generator().manual_seed(self.seed)
        k = Y.shape[1]
        best_mean, best_each = -np.inf, np.full(k, -np.inf)
        out = {"mean": None, "each": np.zeros((len(xe), k)), "mean_step": -1, "each_step": [-1] * k, "curve": []}
        for step in range(self.steps):
            idx = torch.randint(0, len(xt), (self.batch_size,), generator=gen)
            loss = (net(xt[idx]) - yt[idx]).pow(2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            if step % self.every:
                continue
            with torch.no_grad():
                r2v = r2_scores(Y[va], net(xv).double().numpy() * sy.std + sy.mean)
                pred = net(xe).double().numpy() * sy.std + sy.mean
            out["curve"].append({"step": step, "val_r2": [float(v) for v in r2v]})
            if r2v.mean() > best_mean:
                best_mean, out["mean"], out["mean_step"] = float(r2v.mean()), pred, step
            for j in np.flatnonzero(r2v > best_each):
                best_each[j], out["each"][:, j], out["each_step"][j] = r2v[j], pred[:, j], step
        return out


def protocol_scores(Xf, gf, Tf: dict, Xt, Tt: dict, seed: int = 0, joint: JointMLPProbe | None = None) -> dict:
    """R² on the test windows of every protocol (:data:`PROTOCOLS`) for each of :data:`JOINT_TARGETS` in ``Tf``,
    and the steps the joint rules kept: ``{"r2": {protocol: {target: r2}}, "joint_steps": {...}}``."""
    names = [t for t in JOINT_TARGETS if t in Tf]
    if not names:
        raise DataError(f"none of {', '.join(JOINT_TARGETS)} varies in this store; nothing to compare")
    r2: dict = {p: {} for p in PROTOCOLS}
    # ridge and our MLP exactly as the main probe fits them (one of each per parameter)
    ours = fit_predict(Xf, gf, {n: Tf[n] for n in names}, {"test": Xt}, mlp=True, seed=seed)
    for family, protocol in (("ridge", "ridge"), ("mlp", "mlp_per_parameter")):
        r2[protocol] = {n: float(r2_scores(Tt[n], ours[family][n]["test"]).mean()) for n in names}
    Yf = np.concatenate([Tf[n] for n in names], 1)
    Yt = np.concatenate([Tt[n] for n in names], 1)
    res = (joint or JointMLPProbe(seed=seed)).fit_predict(Xf, Yf, gf, Xt)
    for rule in ("mean", "each"):
        r2[f"mlp_joint_{rule}"] = dict(zip(names, map(float, r2_scores(Yt, res[rule]))))
    steps = {"mean": res["mean_step"], "each": dict(zip(names, res["each_step"]))}
    return {"r2": r2, "joint_steps": steps}


def release_windows(ds: Dataset, episodes: np.ndarray) -> Windows:
    """The released probe's contact windows of ``episodes``: 16 observations from each of its starts (its frame j
    is our observation j + 1: :data:`pokeworld.sim.fidelity.STARTS`), kept when ≥ 2 of them are in contact."""
    episodes = np.asarray(episodes)
    starts = 1 + np.asarray(STARTS)
    ep, st = np.repeat(episodes, starts.size), np.tile(starts, episodes.size)
    w = Windows(ep, st, WINDOW, np.zeros(ep.size, bool), np.zeros(ep.size, bool))
    if "contact" not in ds.labels:
        raise DataError(f"the released probe's windows need labels/contact; this store has {sorted(ds.labels)}")
    w.contact = (w.gather(ds.labels["contact"]) > 0).reshape(len(w), WINDOW, -1).any(2).sum(1) >= 2
    return w.kind("contact")


def selection_runs(Xf, gf, Yf, Xt, Yt, seeds: int, names: tuple[str, ...] = JOINT_TARGETS,
                   steps: int = 4001, vary: str = "seed") -> dict:
    """The released rule (:class:`JointMLPProbe`, best mean validation R²) refit with probe seeds 0 … ``seeds`` − 1
    on one set of states: which step each seed keeps, the test R² it then reports, and the validation margin the
    choice rested on (best mean validation R² minus step 0's). The release fixes one seed (0); a rule whose reading
    moves between "at chance" and "reads the parameter" with the seed alone makes that one reading a draw.
    With ``vary="validation"`` run i keeps probe seed 0 and validates on the i-th block of episodes instead
    (:meth:`JointMLPProbe.split`): which episodes happen to validate, the draw a corpus of its own makes. ``steps``
    is the release's 4,001 unless a test shortens it."""
    if seeds < 1 or vary not in ("seed", "validation"):
        raise DataError(f"selection_runs needs at least one probe seed and vary 'seed' or 'validation', got {seeds}, "
                        f"{vary!r}")
    runs = []
    for seed in range(seeds):
        probe = JointMLPProbe(steps=steps, seed=seed) if vary == "seed" else \
            JointMLPProbe(steps=steps, seed=0, val_block=seed)
        res = probe.fit_predict(Xf, Yf, gf, Xt)
        val = {c["step"]: float(np.mean(c["val_r2"])) for c in res["curve"]}
        runs.append({"seed": seed, "kept_step": res["mean_step"],
                     "r2": dict(zip(names, map(float, r2_scores(Yt, res["mean"])))),
                     "val_margin_over_step0": val[res["mean_step"]] - val[0],
                     "val_curve": [{"step": c["step"], "val_r2": dict(zip(names, c["val_r2"]))}
                                   for c in res["curve"]]})
    at_zero = [r for r in runs if r["kept_step"] == 0]
    return {"seeds": seeds, "vary": vary, "runs": runs, "kept_step_0": len(at_zero),
            "r2_range": {n: [min(r["r2"][n] for r in runs), max(r["r2"][n] for r in runs)] for n in names}}


def release_states(model, ds: Dataset, cfg) -> dict:
    """``model``'s predictor states of the released probe's windows (:func:`release_windows`) and their targets:
    ``{"Xf", "gf", "Yf", "Xt", "Yt", "names", "counts"}``, what :func:`selection_stability` refits on."""
    lat_fit, lat_test = probe_latents(model, ds, cfg)
    acts = padded_actions(ds)
    wf, wt = release_windows(ds, ds.episodes("probe_fit")), release_windows(ds, ds.episodes("probe_test"))
    Tf, Tt = probe_targets(ds, wf), probe_targets(ds, wt)
    names = tuple(t for t in JOINT_TARGETS if t in Tf)
    if not names:
        raise DataError(f"none of {', '.join(JOINT_TARGETS)} varies in this store; nothing to refit")
    return {"Xf": window_states(model, ds, lat_fit, wf, acts), "gf": wf.episode,
            "Yf": np.concatenate([Tf[n] for n in names], 1), "Xt": window_states(model, ds, lat_test, wt, acts),
            "Yt": np.concatenate([Tt[n] for n in names], 1), "names": names,
            "counts": {"fit": len(wf), "test": len(wt)}}


def selection_stability(states: dict, seeds: int, blocks: int = 0, seed: int = 0) -> dict:
    """:func:`selection_runs` on :func:`release_states`, with ridge on the same states beside it: the release's
    reading of one model under ``seeds`` probe seeds and, with ``blocks`` > 0, under that many validation blocks
    (key ``"validation"``). ``seed`` is the ridge's (the main probe's) seed."""
    st, names = states, states["names"]
    ridge = fit_predict(st["Xf"], st["gf"], {n: st["Yf"][:, [j]] for j, n in enumerate(names)}, {"test": st["Xt"]},
                        mlp=False, seed=seed)["ridge"]
    out = selection_runs(st["Xf"], st["gf"], st["Yf"], st["Xt"], st["Yt"], seeds, names) if seeds else {}
    if blocks:
        out["validation"] = selection_runs(st["Xf"], st["gf"], st["Yf"], st["Xt"], st["Yt"], blocks, names,
                                           vary="validation")
    out.update(ridge={n: float(r2_scores(st["Yt"][:, [j]], ridge[n]["test"]).mean()) for j, n in enumerate(names)},
               counts=st["counts"])
    return out


def compare(model, ds: Dataset, cfg, joint: JointMLPProbe | None = None) -> dict:
    """:func:`protocol_scores` on ``model``'s predictor states, per window set: ``ours`` (the main probe's contact
    windows, subsampling and states; ``cfg`` a :class:`~pokeworld.evaluate.measure.MeasureConfig`) and
    ``release`` (:func:`release_windows` of the same splits, the same states). The encoder latents are read once."""
    lat_fit, lat_test = probe_latents(model, ds, cfg)
    acts = padded_actions(ds)
    fit_eps, test_eps = ds.episodes("probe_fit"), ds.episodes("probe_test")
    rng = np.random.default_rng([cfg.seed, KINDS.index("contact")])  # the main probe's generator for this kind
    sets = {"ours": (make_windows(ds, fit_eps, cfg.window, cfg.stride).kind("contact").subsample(cfg.max_windows, rng),
                     make_windows(ds, test_eps, cfg.window, cfg.stride).kind("contact")),
            "release": (release_windows(ds, fit_eps), release_windows(ds, test_eps))}
    out = {}
    for name, (wf, wt) in sets.items():
        if len(wf) < 10 or len(wt) < 10:
            raise DataError(f"too few contact windows to probe ({name}: {len(wf)} fit, {len(wt)} test)")
        Xf, Xt = window_states(model, ds, lat_fit, wf, acts), window_states(model, ds, lat_test, wt, acts)
        res = protocol_scores(Xf, wf.episode, probe_targets(ds, wf), Xt, probe_targets(ds, wt), cfg.seed, joint)
        out[name] = {**res, "counts": {"fit": len(wf), "test": len(wt)}}
    return out
