"""Forecast dependence: does a model's *forecast* vary with a hidden parameter as the simulator's outcome does?

Readout (the probes) asks whether a parameter can be read linearly from the model's state; forecast dependence asks
whether the model's predictions *use* it. For each parameter with a simulator-defined response, the simulator's
response and the model's are each regressed on the parameter with the context state and the other parameters as
controls, on the same windows, and the slope ratio

    S = (model's partial slope) / (simulator's partial slope)

is 1 when the forecast depends on the parameter as the world does, 0 when it ignores it and negative when it moves
the wrong way. S says nothing about accuracy (a forecast can carry the right slope around a wrong level), so the
forecast error on the same windows is reported beside it. The responses (docs/design.md, "Forecast dependence"):

* ``gamma`` (drag) — pure-glide windows: the object glides freely (no finger or wall contact, moving) from the
  last context observation through the 16-step future. Response: the 16-step displacement along the context-end
  velocity over the context-end speed (seconds; the simulator's is (1 − e^(−γT))/γ). Regressed on γ.
* ``mass`` — push windows: the object slow with the finger within reach and contact in the context. Two
  programs from the same state: a fixed push (``PUSH`` × the unit finger→object direction, every step) and hold
  (zero actions). Response: the 16-step displacement along the push that the push adds over holding — the
  consequence of the velocity change the push imparts. Regressed on log m.
* ``stiffness`` — the push windows whose push touches the object within ``TOUCH_STEPS`` − 1 steps. Response: the
  peak-force touch channel over the contact-onset step and the next. Regressed on log k.

The truth is the simulator replayed open-loop from the window's recorded state (:func:`pokeworld.sim.replay.replay`)
under the same program the model is given, so truth and forecast answer the same question. Intervals: a bootstrap
over episodes (the windows of one episode share its parameters and move together), both slopes refit on every
resample.

Any forecaster plugs in through :class:`Forecaster`: the X-JEPA adapter
(:class:`pokeworld.evaluate.forecasters.XJEPAForecaster`) and the reference ones the measurement is checked on
(:class:`pokeworld.evaluate.forecasters.SimulatorForecaster`: the simulator itself scores S = 1, one that ignores
the parameter S ≈ 0, one that reverses it S < 0).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..config import SEED, Limit, check_fields
from ..data import Dataset
from ..errors import ConfigError, DataError, ModelError
from ..sim.generate import simulate
from ..sim.generate_config import generator_config
from ..sim.replay import params_of, physics_of, replay, state_at
from ..windows import make_windows, wall_contact
from .state import padded_actions

PARAMETERS = ("gamma", "mass", "stiffness")
"""Parameters with a simulator-defined response, in report order."""
REGRESSOR = {"gamma": "gamma", "mass": "log_m", "stiffness": "log_k"}
"""What each response is regressed on: γ linearly (it is sampled uniformly), m and k in logs (sampled log-uniformly)."""
RESPONSE = {
    "gamma": "16-step displacement along the context-end velocity over the context-end speed (s), pure glides",
    "mass": "16-step displacement along a fixed push minus that under hold (arena units), object slow within reach",
    "stiffness": "peak-force touch channel over the contact-onset step and the next (the store's touch units), push "
                 "reaching the object",
}
PUSH = 0.9
"""Magnitude of the fixed push action (per component of the unit finger→object direction; actions lie in [-1, 1])."""


@dataclass
class ForecastQuery:
    """N context windows and the action program applied after each; what a forecaster is asked.

    A learned forecaster reads only the observations and actions. ``state`` and ``params`` are privileged: they exist
    for the reference forecasters (the simulator and its planted corruptions) that check the measurement."""

    frames: np.ndarray
    """(N, C, H, W) uint8 context frames."""
    proprio: np.ndarray
    """(N, C, Dp) raw proprioception."""
    touch: np.ndarray
    """(N, C, Dt) raw touch (observation t summarises the step that ended at it)."""
    actions: np.ndarray
    """(N, C - 1 + horizon, Da) raw actions; ``actions[:, t]`` is taken after observation t, so the last ``horizon``
    are the program applied from the last context observation on."""
    state: np.ndarray
    """(N, 8) privileged simulator state at the last context observation."""
    params: np.ndarray
    """(N, 6) privileged hidden parameters (:data:`pokeworld.sim.core.PARAM_NAMES` order)."""
    horizon: int
    """Steps forecast after the last context observation."""
    touch_steps: int = 0
    """Future steps whose touch peak is wanted (0: none)."""


@dataclass
class Forecast:
    """A forecaster's answer to a :class:`ForecastQuery`."""

    start: np.ndarray
    """(N, 2) its reading of the object position at the last context observation (a learned model's decoded one)."""
    end: np.ndarray
    """(N, 2) the forecast object position ``horizon`` steps later."""
    touch_peak: np.ndarray | None
    """(N, K) forecast peak-force touch channel after each of the first K future steps, K >= the query's
    ``touch_steps``; None
    when the forecaster cannot forecast touch (the stiffness response is then not measured)."""


class Forecaster(Protocol):
    """Anything that answers forecast queries."""

    def forecast(self, query: ForecastQuery) -> Forecast: ...


@dataclass
class DependenceConfig:
    """Windows, programs and the bootstrap of the forecast-dependence measurement."""

    context: int = 8
    """Context observations before the forecast (as the decoded prediction test)."""
    horizon: int = 16
    """Steps forecast (the direct head the drag and mass responses read)."""
    touch_steps: int = 9
    """Future steps whose touch the stiffness response reads (contact onset within the first touch_steps − 1)."""
    stride: int = 2
    """Step between candidate windows of an episode."""
    min_glide_speed: float = 0.05
    """Least object speed (arena units / s) over a pure-glide window."""
    rest_speed: float = 0.5
    """Largest object speed (arena units / s) at the last context observation of a push window: slow beside the
    pushing finger (the scripted policy rarely leaves the object fully at rest within reach; its velocity is a
    control)."""
    reach: tuple[float, float] = (0.16, 0.45)
    """Finger-to-object centre distance of a push window (the disks touch at 0.15)."""
    margin: float = 0.22
    """Least distance of a push window's object from every wall (room to be pushed)."""
    max_windows: int = 3000
    """Cap on windows per response (episode-preserving random subsample)."""
    min_windows: int = 30
    """Fewest windows a slope is computed from; fewer: the response is reported as not measured."""
    bootstrap: int = 1000
    """Episode bootstrap resamples for the interval of S."""
    seed: int = 0
    """Seed of the subsample and the bootstrap."""

    LIMITS = {"context": Limit(1, 4096), "horizon": Limit(1, 4096), "touch_steps": Limit(2, 4096),
              "stride": Limit(1, 4096), "min_glide_speed": Limit(0, 1e3), "rest_speed": Limit(0, 1e3),
              "margin": Limit(0, 1e3), "max_windows": Limit(10, 10**7), "min_windows": Limit(5, 10**6),
              "bootstrap": Limit(10, 10**5), "seed": SEED}

    def __post_init__(self) -> None:
        check_fields(self)
        if not 0 <= self.reach[0] < self.reach[1]:
            raise ConfigError(f"reach must be (near, far) with 0 <= near < far, got {self.reach}")
        if self.touch_steps > self.horizon:
            raise ConfigError(f"touch_steps ({self.touch_steps}) must not exceed horizon ({self.horizon})")


# --------------------------------------------------------------------------- windows
def fresh_corpus(ds: Dataset, episodes: int, seed: int) -> Dataset:
    """``episodes`` new episodes from the generator that made ``ds`` (its manifest's config), at ``seed``: windows
    no model was trained or decoded on, as many as the slopes need (the probe-test split alone leaves few push
    windows: the scripted policy seldom leaves the object slow within reach after contact)."""
    base = generator_config(ds.manifest)
    cfg = dataclasses.replace(base, num_episodes=episodes, seed=seed, batch_envs=min(base.batch_envs, episodes))
    return simulate(cfg, progress=False)


def check_store(ds: Dataset) -> None:
    """DataError unless ``ds`` is a simulator store with the labels and parameters the responses read."""
    missing = sorted({"object_pos", "object_vel", "finger_pos", "finger_vel", "contact"} - set(ds.labels))
    missing += sorted({"mass", "gamma", "stiffness"} - set(ds.params))
    if missing:
        raise DataError(f"forecast dependence needs a simulator store (labels and parameters); this one lacks "
                        f"{missing}")


def glide_windows(ds: Dataset, episodes: np.ndarray, cfg: DependenceConfig):
    """(context + horizon)-observation windows whose object glides freely from the last context observation on."""
    w = make_windows(ds, episodes, cfg.context + cfg.horizon, cfg.stride)
    c = cfg.context - 1
    contact = w.gather(ds.labels["contact"])[:, c:] > 0
    walls = w.gather(wall_contact(ds))[:, c:]
    speed = np.linalg.norm(w.gather(ds.labels["object_vel"])[:, c:], axis=-1)
    return w.select(~contact.any(1) & ~walls.any(1) & (speed > cfg.min_glide_speed).all(1))


def push_windows(ds: Dataset, episodes: np.ndarray, cfg: DependenceConfig):
    """Context windows ending with the object slow, away from the walls, the finger within reach and out of
    contact, after contact in the context (the evidence about m and k a forecast can use)."""
    w = make_windows(ds, episodes, cfg.context, cfg.stride)
    obj, fin = w.last(ds.labels["object_pos"]), w.last(ds.labels["finger_pos"])
    dist = np.linalg.norm(obj - fin, axis=-1)
    contact = w.gather(ds.labels["contact"]) > 0
    arena = ds.manifest.get("config", {}).get("physics", {}).get("arena", 1.0)
    ok = ((np.linalg.norm(w.last(ds.labels["object_vel"]), axis=-1) <= cfg.rest_speed)
          & (dist >= cfg.reach[0]) & (dist <= cfg.reach[1])
          & ((obj > cfg.margin) & (obj < arena - cfg.margin)).all(-1)
          & ~contact[:, -2:].any(1) & contact[:, :-2].any(1))
    return w.select(ok)


def query(ds: Dataset, w, program: np.ndarray, cfg: DependenceConfig) -> ForecastQuery:
    """The forecast query for windows ``w`` (their first ``context`` observations) under ``program`` (N, H, Da)."""
    C = cfg.context
    ctx = lambda a: w.gather(a, 0, C)  # noqa: E731
    acts = np.concatenate([ctx(padded_actions(ds))[:, :C - 1], program], 1).astype(np.float32)
    t = w.start + C - 1
    return ForecastQuery(frames=ctx(ds.frames), proprio=ctx(ds.proprio), touch=ctx(ds.touch), actions=acts,
                         state=state_at(ds.labels, w.episode, t), params=params_of(ds.params, w.episode),
                         horizon=cfg.horizon, touch_steps=cfg.touch_steps)


def ask(forecaster: Forecaster, q: ForecastQuery) -> Forecast:
    """The forecaster's answer to ``q``, its positions checked: (N, 2) finite arrays, or one ModelError saying so."""
    f = forecaster.forecast(q)
    n = len(q.state)
    for name in ("start", "end"):
        a = np.asarray(getattr(f, name), float)
        if a.shape != (n, 2) or not np.isfinite(a).all():
            raise ModelError(f"the forecaster's {name} must be a finite (N, 2) = ({n}, 2) array of object positions, "
                             f"got shape {a.shape}")
        setattr(f, name, a)
    return f


# --------------------------------------------------------------------------- slopes
def quadratic(features: np.ndarray) -> np.ndarray:
    """The features, their squares and pairwise products: context-state controls for responses that depend on the
    state nonlinearly (whether and when a push connects), so the parameter's slope is not left to carry them."""
    f = np.asarray(features, float)
    i, j = np.triu_indices(f.shape[1])
    return np.column_stack([f, f[:, i] * f[:, j]])


def partial_slope(y: np.ndarray, x: np.ndarray, controls: np.ndarray, weight: np.ndarray | None = None) -> float:
    """Coefficient of ``x`` in the (weighted) least-squares fit y ~ 1 + x + controls."""
    X = np.column_stack([np.ones(len(y)), x, controls])
    if weight is not None:
        s = np.sqrt(weight)
        X, y = X * s[:, None], y * s
    return float(np.linalg.lstsq(X, y, rcond=None)[0][1])


def slope_ratio(truth: np.ndarray, model: np.ndarray, x: np.ndarray, controls: np.ndarray, episode: np.ndarray,
                resamples: int, rng: np.random.Generator) -> dict:
    """Both partial slopes, S = model / simulator, and S's 95 % episode-bootstrap percentile interval."""
    true_slope, model_slope = partial_slope(truth, x, controls), partial_slope(model, x, controls)
    groups, inverse = np.unique(episode, return_inverse=True)
    ratios = []
    for _ in range(resamples):
        counts = np.bincount(rng.integers(0, len(groups), len(groups)), minlength=len(groups))
        wgt = counts[inverse].astype(float)
        keep = wgt > 0
        t = partial_slope(truth[keep], x[keep], controls[keep], wgt[keep])
        m = partial_slope(model[keep], x[keep], controls[keep], wgt[keep])
        ratios.append(m / t if t != 0 else np.nan)
    ratios = np.asarray(ratios)
    ratios = ratios[np.isfinite(ratios)]
    lo, hi = (np.percentile(ratios, [2.5, 97.5]) if ratios.size else (np.nan, np.nan))
    return {"slope_simulator": true_slope, "slope_model": model_slope,
            "S": model_slope / true_slope if true_slope != 0 else float("nan"),
            "S_interval": [float(lo), float(hi)], "episodes": int(len(groups))}


# --------------------------------------------------------------------------- responses
def _regressor(ds: Dataset, param: str, episodes: np.ndarray) -> np.ndarray:
    v = np.asarray(ds.params[{"gamma": "gamma", "mass": "mass", "stiffness": "stiffness"}[param]], float)[episodes]
    return v if param == "gamma" else np.log(v)


def _others(ds: Dataset, param: str, episodes: np.ndarray) -> np.ndarray:
    """The other two parameters as controls (in their regression scale)."""
    return np.column_stack([_regressor(ds, p, episodes) for p in PARAMETERS if p != param])


def _glide_response(ds: Dataset, forecaster: Forecaster, w, physics, cfg: DependenceConfig) -> dict:
    C, H = cfg.context, cfg.horizon
    program = w.gather(ds.actions, C - 1, H).astype(np.float32)
    q = query(ds, w, program, cfg)
    truth = replay(physics, q.state, q.params, program)["object_pos"][:, -1]
    f = ask(forecaster, q)
    v0 = q.state[:, 6:8]
    speed = np.linalg.norm(v0, axis=-1)
    along = v0 / speed[:, None]
    y_true = ((truth - q.state[:, 4:6]) * along).sum(-1) / speed
    y_model = ((np.asarray(f.end) - np.asarray(f.start)) * along).sum(-1) / speed
    controls = np.column_stack([quadratic(speed[:, None]), _others(ds, "gamma", w.episode)])
    error = float(np.linalg.norm(np.asarray(f.end) - truth, axis=-1).mean())
    return {"truth": y_true, "model": y_model, "controls": controls, "error": error,
            "controls_named": ["context-end speed", "log m", "log k"]}


def _push_geometry(q: ForecastQuery) -> tuple[np.ndarray, np.ndarray]:
    d = q.state[:, 4:6] - q.state[:, 0:2]
    dist = np.linalg.norm(d, axis=-1)
    return d / dist[:, None], dist


def push_program(ds: Dataset, w, cfg: DependenceConfig) -> np.ndarray:
    """The fixed push from each push window's last context observation: ``PUSH`` × unit(object − finger)."""
    d = w.last(ds.labels["object_pos"]) - w.last(ds.labels["finger_pos"])
    unit = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return np.repeat((PUSH * unit)[:, None], cfg.horizon, 1).astype(np.float32)


def _push_responses(ds: Dataset, forecaster: Forecaster, w, physics, cfg: DependenceConfig) -> dict:
    """The mass and stiffness responses of the push windows (one push and one hold forecast each)."""
    push = push_program(ds, w, cfg)
    q_push, q_hold = query(ds, w, push, cfg), query(ds, w, np.zeros_like(push), cfg)
    true_push = replay(physics, q_push.state, q_push.params, push)
    true_hold = replay(physics, q_hold.state, q_hold.params, np.zeros_like(push))
    f_push, f_hold = ask(forecaster, q_push), ask(forecaster, q_hold)
    unit, dist = _push_geometry(q_push)
    fin_v, obj_v = q_push.state[:, 2:4], q_push.state[:, 6:8]
    context = quadratic(np.column_stack([dist, np.linalg.norm(fin_v, axis=-1), (fin_v * unit).sum(-1),
                                         (obj_v * unit).sum(-1), unit]))
    mass = {"truth": ((true_push["object_pos"][:, -1] - true_hold["object_pos"][:, -1]) * unit).sum(-1),
            "model": ((np.asarray(f_push.end) - np.asarray(f_hold.end)) * unit).sum(-1),
            "controls": np.column_stack([context, _others(ds, "mass", w.episode)]),
            "error": float(np.linalg.norm(np.asarray(f_push.end) - true_push["object_pos"][:, -1], axis=-1).mean()),
            "controls_named": ["distance", "finger speed", "finger velocity along the push",
                               "object velocity along the push", "push direction x", "push direction y", "γ",
                               "log k"]}
    return {"mass": mass, "stiffness": _stiffness(ds, true_push["touch"], f_push, w, context, cfg)}


def _stiffness(ds: Dataset, touch: np.ndarray, f: Forecast, w, context: np.ndarray, cfg: DependenceConfig) -> dict:
    K = cfg.touch_steps
    flag = touch[:, :K - 1, 6] > 0.5
    onset = np.where(flag.any(1), flag.argmax(1), -1)
    ok = onset >= 0
    if f.touch_peak is None:
        return {"note": "the forecaster forecasts no touch", "windows": int(ok.sum())}
    pred = np.asarray(f.touch_peak, float)
    if pred.ndim != 2 or pred.shape[0] != len(onset) or pred.shape[1] < K or not np.isfinite(pred).all():
        raise ModelError(f"the forecaster's touch_peak must be a finite (N, >= {K}) array, got shape {pred.shape}")
    rows = np.flatnonzero(ok)
    steps = np.stack([onset[ok], onset[ok] + 1], 1)
    y_true = touch[rows[:, None], steps, 2].max(1)
    y_model = pred[rows[:, None], steps].max(1)
    return {"truth": y_true, "model": y_model, "rows": rows,
            "controls": np.column_stack([context[rows], np.eye(K - 1)[onset[rows]][:, 1:],
                                         _others(ds, "stiffness", w.episode[rows])]),
            "error": float(np.abs(y_model - y_true).mean()),
            "controls_named": ["distance", "finger speed", "finger velocity along the push",
                               "object velocity along the push", "push direction x", "push direction y",
                               "onset step", "log m", "γ"]}


def _score(param: str, r: dict, ds: Dataset, episode: np.ndarray, cfg: DependenceConfig, rng) -> dict:
    n = len(r.get("truth", ()))
    base = {"response": RESPONSE[param], "regressor": REGRESSOR[param], "windows": r.get("windows", n)}
    if "note" in r:
        return base | {"note": r["note"]}
    if n < cfg.min_windows:
        return base | {"note": f"{n} windows, fewer than min_windows = {cfg.min_windows}: not measured"}
    x = _regressor(ds, param, episode)
    out = slope_ratio(r["truth"], r["model"], x, r["controls"], episode, cfg.bootstrap, rng)
    return base | out | {"forecast_error": r["error"], "controls": r["controls_named"]}


def forecast_dependence(forecaster: Forecaster, ds: Dataset, episodes: np.ndarray,
                        cfg: DependenceConfig | None = None, parameters: tuple[str, ...] = PARAMETERS) -> dict:
    """S, its interval, both slopes and the forecast error per parameter, on windows of ``episodes``."""
    cfg = cfg or DependenceConfig()
    unknown = sorted(set(parameters) - set(PARAMETERS))
    if unknown:
        raise ConfigError(f"no forecast response is defined for {unknown}; choose from {list(PARAMETERS)}")
    check_store(ds)
    physics = physics_of(ds.manifest)
    rng = np.random.default_rng(cfg.seed)
    out: dict = {}
    if "gamma" in parameters:
        w = glide_windows(ds, episodes, cfg).subsample(cfg.max_windows, rng)
        r = _glide_response(ds, forecaster, w, physics, cfg) if len(w) else {"truth": ()}
        out["gamma"] = _score("gamma", r, ds, w.episode, cfg, rng)
    if {"mass", "stiffness"} & set(parameters):
        w = push_windows(ds, episodes, cfg).subsample(cfg.max_windows, rng)
        rs = _push_responses(ds, forecaster, w, physics, cfg) if len(w) else {"mass": {"truth": ()},
                                                                               "stiffness": {"truth": ()}}
        for p in ("mass", "stiffness"):
            if p in parameters:
                ep = w.episode[rs[p]["rows"]] if "rows" in rs[p] else w.episode
                out[p] = _score(p, rs[p], ds, ep, cfg, rng)
    return out


__all__ = ["DependenceConfig", "Forecast", "ForecastQuery", "Forecaster", "PARAMETERS", "PUSH", "REGRESSOR",
           "RESPONSE", "check_store", "forecast_dependence", "fresh_corpus", "glide_windows", "partial_slope", "push_program", "push_windows",
           "query", "slope_ratio"]
