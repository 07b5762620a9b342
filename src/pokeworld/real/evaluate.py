"""Real-robot metrics of one trained run on a converted RH20T store (paper §5, App. C "Real-robot results").

Every metric is computed twice: on probe-test episodes (IID, split 2) and on entirely held-out tasks
(OOD, split 3); probes are always fit on probe-fit episodes (split 1). The machinery is the
simulator measurement's (:mod:`pokeworld.evaluate.state`, :mod:`.probes`, :mod:`.prediction`): the
same windows, the same leak-free frozen trunk state at the window's last observation, the same
episode-grouped ridge (and optional MLP) probes, the same decoded prediction errors; only the targets
differ.

* ``readout``: R^2 (variance-weighted over components, :func:`r2`) of force (3-d, N), force magnitude and end-effector (TCP) position (3-d, m) at
  the probed observation.
* ``onset``: contact-onset anticipation AUC. The label (``labels/contact_onset``) marks steps with
  ‖F‖ ≤ 10 N whose next 4 steps reach ‖F‖ > 10 N; windows whose last step is already in contact are
  excluded from fit and test, so the score is anticipation, not detection. The score is a ridge
  probe's output (AUC only needs a ranking).
* ``forecast``: R^2 of force at t+Δ (Δ = 1, 4 steps = 0.1, 0.4 s) read from the state at t, against
  persistence (F_{t+Δ} ≈ F_t), with a paired scene-bootstrap 95 % CI of model − persistence; also
  ``persistence_fit``, a ridge from F_t alone (what a state that merely holds F_t reaches).
* ``prediction``: direct and autoregressive 16-step TCP-position errors from 8 context steps
  against static, all decoded through one ridge position decoder fit on encoder latents (cm).
* ``untrained``: all of the above for a randomly initialised copy sharing only the input statistics.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..config import from_preset, to_dict
from ..data import Dataset, load, read_manifest
from ..errors import ConfigError, DataError
from ..evaluate.measure import untrained_copy
from ..evaluate.prediction import position_decoder, prediction_quality
from ..evaluate.probes import fit_predict
from ..evaluate.state import EpisodeLatents, padded_actions, window_states
from ..io import read_json_if_present, write_json
from ..model_inputs import checked_model
from ..run_store import trained_store
from ..rundir import finished_marker, finished_run_config
from ..windows import make_windows

TESTS = {"iid": "probe_test", "ood": "heldout"}
"""Test name -> store split. Probes are fit on ``probe_fit`` for both."""
READOUT_TARGETS = ("force", "force_norm", "tcp_pos")
REQUIRED_LABELS = ("force", "force_norm", "tcp_pos", "contact", "contact_onset")


@dataclass
class RealEvalConfig:
    """Real-robot metrics of one trained run on a converted RH20T store."""

    run_dir: str = "runs/real"
    """Run directory written by ``pokeworld train`` on a converted store."""
    data: str = ""
    """Store to evaluate on (default: the run's training store)."""
    window: int = 16
    """Probe window length (observations); the state at its last observation is read."""
    stride: int = 2
    """Step between probe windows (2: twice the simulator's density, because onsets are rare)."""
    max_windows: int = 20000
    """Cap on probe-fit windows (episode-preserving random subsample); test windows are never capped."""
    mlp: bool = False
    """Also fit early-stopped MLP probes (the tables report ridge)."""
    forecast_deltas: tuple[int, ...] = (1, 4)
    """Force forecasting horizons Δ in steps (10 Hz: 0.1 s, 0.4 s)."""
    context: int = 8
    """Context observations of the prediction test."""
    horizon: int = 16
    """Prediction horizon (steps); the model needs a direct head at this Δ for the direct error."""
    prediction_stride: int = 4
    """Step between prediction windows."""
    bootstrap: int = 1000
    """Paired scene-bootstrap resamples for the forecasting CIs."""
    untrained: bool = True
    """Also evaluate a randomly initialised copy of the model (the untrained-encoder bound)."""
    batch_episodes: int = 64
    """Episodes encoded per forward pass."""
    seed: int = 0
    """Seed for subsampling, MLP probes and the bootstrap."""
    overwrite: bool = False
    """Recompute even if the result file is up to date."""

    def __post_init__(self) -> None:
        if self.window < 2 or self.stride < 1 or self.prediction_stride < 1:
            raise ConfigError("window must be >= 2 and strides >= 1")
        if not self.forecast_deltas or min(self.forecast_deltas) < 1:
            raise ConfigError(f"forecast_deltas must be positive steps, got {self.forecast_deltas}")
        if self.context < 1 or self.horizon < 2:
            raise ConfigError("context must be >= 1 and horizon >= 2")


PRESETS = {"tiny": {"max_windows": 400, "bootstrap": 200, "window": 8, "context": 4},
           "cpu": {}, "paper": {"max_windows": 100000, "mlp": True}}


def make_config(preset: str = "cpu", **overrides) -> RealEvalConfig:
    return from_preset(RealEvalConfig, PRESETS, preset, **overrides)


# --------------------------------------------------------------------------- statistics
def roc_auc(labels: np.ndarray, scores: np.ndarray) -> float | None:
    """Area under the ROC curve (scikit-learn's, ties counted half); None without both classes."""
    from sklearn.metrics import roc_auc_score

    y = np.asarray(labels).astype(bool).ravel()
    if y.all() or not y.any():
        return None
    return float(roc_auc_score(y, np.asarray(scores, float).ravel()))


def r2(y: np.ndarray, pred: np.ndarray) -> float:
    """Variance-weighted R^2 of a (multi-dimensional) target: 1 − Σ_dims SSE / Σ_dims SST.

    Unlike the simulator tables' mean of per-dimension R^2, a component that barely varies (a force axis
    nobody pushes along, a TCP axis the task never moves) cannot swing the score: each component
    counts by its variance, so the readout is the share of the vector's variance explained.
    """
    y = np.asarray(y, float).reshape(len(y), -1)
    p = np.asarray(pred, float).reshape(len(pred), -1)
    sst = ((y - y.mean(0)) ** 2).sum()
    return float(1.0 - ((y - p) ** 2).sum() / max(sst, 1e-12))


def _group_sums(y: np.ndarray, preds: list[np.ndarray], groups: np.ndarray) -> tuple[np.ndarray, dict]:
    """Per-group sufficient statistics of R^2: count, Σy, Σy², and Σ(y − p)² for every prediction."""
    y = y.reshape(len(y), -1)
    _, g = np.unique(groups, return_inverse=True)
    G = g.max() + 1
    add = lambda v: np.stack([np.bincount(g, v[:, j], G) for j in range(v.shape[1])], 1)  # noqa: E731
    stats = {"n": np.bincount(g, minlength=G).astype(float), "sy": add(y), "syy": add(y * y),
             "sse": [add((y - p.reshape(len(p), -1)) ** 2) for p in preds]}
    return g, stats


def paired_bootstrap(y: np.ndarray, pred_a: np.ndarray, pred_b: np.ndarray, groups: np.ndarray,
                     n_boot: int = 1000, seed: int = 0, level: float = 0.95) -> dict:
    """R^2(a) − R^2(b) on the same windows, with a paired group-bootstrap percentile CI.

    Groups (scenes) are resampled with replacement and both R^2 are recomputed on the same resample,
    so the CI is of the *difference*, with the correlation between a and b kept. R^2 is computed
    from per-group sufficient statistics, so a resample costs O(groups), not O(windows).
    Returns ``{"a", "b", "diff", "lo", "hi", "groups", "n_boot"}``.
    """
    g, st = _group_sums(y, [pred_a, pred_b], groups)
    G = len(st["n"])
    if G < 2:
        raise DataError("the bootstrap needs at least two groups (scenes)")
    rng = np.random.default_rng(seed)
    counts = np.stack([np.bincount(rng.integers(0, G, G), minlength=G) for _ in range(n_boot)]).astype(float)

    def r2_from(c: np.ndarray, sse: np.ndarray) -> np.ndarray:
        n, sy, syy = c @ st["n"], c @ st["sy"], c @ st["syy"]
        sst = (syy - sy ** 2 / n[:, None]).sum(1)
        return 1.0 - (c @ sse).sum(1) / np.maximum(sst, 1e-12)

    diffs = r2_from(counts, st["sse"][0]) - r2_from(counts, st["sse"][1])
    a, b = r2(y, pred_a), r2(y, pred_b)
    q = (1 - level) / 2
    return {"a": a, "b": b, "diff": a - b, "lo": float(np.quantile(diffs, q)), "hi": float(np.quantile(diffs, 1 - q)),
            "groups": int(G), "n_boot": int(n_boot)}


# --------------------------------------------------------------------------- metrics
def check_store(ds: Dataset) -> None:
    """Raise DataError unless ``ds`` is a converted real-robot store with every label the metrics need."""
    missing = [k for k in REQUIRED_LABELS if k not in ds.labels]
    if missing:
        raise DataError(f"store lacks labels {missing}: the real-robot metrics need a converted RH20T store "
                        "(`pokeworld rh20t-convert`)")
    for split in ("probe_fit", *TESTS.values()):
        if ds.episodes(split).size == 0:
            raise DataError(f"store has no {split} episodes; the real-robot metrics need splits 1, 2 and 3")


def _groups(ds: Dataset, w) -> np.ndarray:
    """Bootstrap unit per window: the RH20T scene (chunks of one scene are not independent), else the episode."""
    return ds.params["scene_index"][w.episode].astype(int) if "scene_index" in ds.params else w.episode


def evaluate_model(model, ds: Dataset, cfg: RealEvalConfig) -> dict:
    """Every real-robot metric of ``model`` on ``ds`` (see the module docstring)."""
    check_store(ds)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    eps = {"fit": ds.episodes("probe_fit"), **{k: ds.episodes(s) for k, s in TESTS.items()}}
    lat = {k: EpisodeLatents(model, ds, e, cfg.batch_episodes) for k, e in eps.items()}
    acts = padded_actions(ds)
    W = {k: make_windows(ds, e, cfg.window, cfg.stride) for k, e in eps.items()}
    W["fit"] = W["fit"].subsample(cfg.max_windows, rng)
    X = {k: window_states(model, ds, lat[k], w, acts) for k, w in W.items()}
    tests = tuple(TESTS)
    out: dict = {"counts": {k: {"windows": len(w), "episodes": int(np.unique(w.episode).size)} for k, w in W.items()}}
    if np.unique(W["fit"].episode).size < 2:
        raise DataError("the probe-fit split needs windows from at least two episodes")

    # readout of the current force and end-effector position
    T = {k: {name: w.last(ds.labels[name]).reshape(len(w), -1).astype(np.float64) for name in READOUT_TARGETS}
         for k, w in W.items()}
    preds = fit_predict(X["fit"], W["fit"].episode, T["fit"], {k: X[k] for k in tests}, cfg.mlp, cfg.seed)
    out["readout"] = {fam: {name: {k: r2(T[k][name], p[k]) for k in tests} for name, p in per.items()}
                      for fam, per in preds.items()}

    # contact-onset anticipation on steps not yet in contact
    free = {k: w.last(ds.labels["contact"]) <= 0 for k, w in W.items()}
    onset = {k: w.last(ds.labels["contact_onset"]).astype(np.float64)[free[k], None] for k, w in W.items()}
    out["onset"] = {"base_rate": {k: float(onset[k].mean()) if onset[k].size else None for k in tests},
                    "positives": {k: int(onset[k].sum()) for k in W}}
    if free["fit"].sum() >= 2 and onset["fit"].std() > 0:
        sel = free["fit"]
        op = fit_predict(X["fit"][sel], W["fit"].episode[sel], {"onset": onset["fit"]},
                         {k: X[k][free[k]] for k in tests if free[k].any()}, cfg.mlp, cfg.seed)
        for fam, per in op.items():
            out["onset"][fam] = {k: roc_auc(onset[k], per["onset"][k]) if k in per["onset"] else None
                                 for k in tests}

    # future-force forecasting against persistence
    out["forecast"] = forecast(ds, W, X, cfg, tests)

    # decoded 16-step prediction of the end-effector position (cm)
    out["prediction"] = {}
    # one TCP-position decoder serves both test splits (prediction_quality would refit the same one per split)
    dec = None if model.objective == "recon" else position_decoder(ds, lat["fit"], eps["fit"],
                                                                    np.random.default_rng(cfg.seed), "tcp_pos")
    for k, split in TESTS.items():
        try:
            p = prediction_quality(model, ds, lat["fit"], lat[k], cfg.seed, position="tcp_pos", test_split=split,
                                   context=cfg.context, horizon=cfg.horizon, stride=cfg.prediction_stride,
                                   glide=False, decoder=dec)
        except DataError as e:  # episodes shorter than context + horizon
            p = {"note": str(e)}
        out["prediction"][k] = {key: (100.0 * v if isinstance(v, float) else v) for key, v in p.items()}
    out["prediction"]["units"] = "cm"
    return out


def forecast(ds: Dataset, W: dict, X: dict, cfg: RealEvalConfig, tests: tuple[str, ...]) -> dict:
    """Force at t+Δ read from the state at t (ridge, leak-free), against persistence F_t, per Δ and test."""
    T1 = ds.frames.shape[1]
    dmax = max(cfg.forecast_deltas)
    ok = {k: (w.start + w.length - 1 + dmax) < T1 for k, w in W.items()}
    if ok["fit"].sum() < 2 or not all(ok[k].any() for k in tests):
        return {"note": f"no windows leave {dmax} future steps inside an episode"}
    force = ds.labels["force"].astype(np.float64)
    sub = {k: W[k].select(ok[k]) for k in W}
    now = {k: sub[k].last(force) for k in W}
    fut = {d: {k: force[sub[k].episode, sub[k].start + sub[k].length - 1 + d] for k in W}
           for d in cfg.forecast_deltas}
    res: dict = {"deltas_s": {str(d): d / float(ds.manifest.get("hz", 10.0)) for d in cfg.forecast_deltas}}
    Tf = {f"force_t+{d}": fut[d]["fit"] for d in cfg.forecast_deltas}
    preds = fit_predict(X["fit"][ok["fit"]], sub["fit"].episode, Tf, {k: X[k][ok[k]] for k in tests}, False,
                        cfg.seed)["ridge"]
    # the paper's baseline repeats F_t; a ridge from F_t alone (regression to the mean) is the stronger
    # baseline any state holding the current force matches without forecasting anything
    fitted = fit_predict(now["fit"], sub["fit"].episode, Tf, {k: now[k] for k in tests}, False, cfg.seed)["ridge"]
    for d in cfg.forecast_deltas:
        row = {}
        for k in tests:
            y, pm = fut[d][k], preds[f"force_t+{d}"][k]
            bs = paired_bootstrap(y, pm, now[k], _groups(ds, sub[k]), cfg.bootstrap, cfg.seed)
            row[k] = {"model": bs["a"], "persistence": bs["b"], "diff": bs["diff"], "ci": [bs["lo"], bs["hi"]],
                      "persistence_fit": r2(y, fitted[f"force_t+{d}"][k]), "groups": bs["groups"],
                      "windows": int(len(y))}
        res[str(d)] = row
    return res


# --------------------------------------------------------------------------- entry
def evaluate(model, ds: Dataset, cfg: RealEvalConfig, untrained_model=None) -> dict:
    res = {"trained": evaluate_model(model, ds, cfg)}
    if untrained_model is not None:
        res["untrained"] = evaluate_model(untrained_model, ds, cfg)
    return res


def result_path(run_dir: Path, data: str) -> Path:
    """Where a run's evaluation on store ``data`` lives ("" = its training store). Named by the store's folder
    and content hash, so two stores whose folders share a name never overwrite each other."""
    if not data:
        return run_dir / "real_eval.json"
    return run_dir / f"real_eval-{Path(data).name}-{read_manifest(data)['content_sha256'][:8]}.json"


def run(cfg: RealEvalConfig) -> Path:
    """Evaluate ``cfg.run_dir`` on a converted store and write ``real_eval[-<store>].json`` there."""
    run_dir = Path(cfg.run_dir)
    run_cfg = finished_run_config(run_dir)  # refuses an unfinished run
    # the training store found and checked by content (run_store), never a same-named folder under the current one
    data = cfg.data or trained_store(run_dir, "real-eval")
    out = result_path(run_dir, cfg.data)
    key = {"config": to_dict(cfg), "data_sha256": read_manifest(data).get("content_sha256"),
           "final_mtime": finished_marker(run_dir).stat().st_mtime_ns}
    if not cfg.overwrite and (read_json_if_present(out, "a real-data evaluation record") or {}).get("key") == key:
        print(f"[real] {out} is up to date; skipping")
        return out
    # the weights and the store's frames, proprio, touch and action widths and the windows against the model,
    # before the store is read
    model = checked_model(run_dir, data, max(cfg.window, cfg.context + cfg.horizon),
                          f"--window {cfg.window} and --context {cfg.context} with --horizon {cfg.horizon}")
    ds = load(data)
    res = evaluate(model, ds, cfg, untrained_copy(model) if cfg.untrained else None)
    res.update(key=key, run=run_cfg, data=data)
    write_json(out, res)
    print(f"[real] {run_dir.name} on {Path(data).name}: " + summary_line(res["trained"]))
    return out


def summary_line(m: dict) -> str:
    rd = m["readout"]["ridge"]
    parts = [f"force {rd['force']['iid']:+.2f}/{rd['force']['ood']:+.2f}",
             f"pos {rd['tcp_pos']['iid']:+.2f}/{rd['tcp_pos']['ood']:+.2f}"]
    auc = m["onset"].get("ridge", {})
    if auc:
        parts.append("AUC " + "/".join("—" if auc[k] is None else f"{auc[k]:.2f}" for k in TESTS))
    p = m["prediction"]["iid"]
    parts += [f"{k}={p[k]:.1f}cm" for k in ("direct16", "rollout16", "static16") if k in p]
    return " ".join(parts)
