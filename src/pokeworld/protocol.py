"""Certify your own model: the certificate-gated probe protocol for any world model (paper §3, App. A, C).

Researchers with their own world model (DreamerV3-, LeWM-, V-JEPA-style, ...) run the same measurement
the paper runs on X-JEPA without touching our training code::

    from pokeworld.protocol import certify_model
    report = certify_model(my_fn, data="out/map/data/standard", out="out/mine", untrained=my_fn_untrained)

The model contract (:class:`StateReader` enforces it). ``model(frames, proprio, touch, actions)`` gets one
batch of observation windows exactly as the store holds them and returns one state vector per step:

=========  ====================  =========================================================================
frames     (B, L, H, W) uint8    grayscale observations
proprio    (B, L, Dp) float32    proprioception at each observation (raw, unnormalised)
touch      (B, L, Dt) float32    touch / force summarising the step that ended at each observation
actions    (B, L, Da) float32    raw actions; ``actions[:, t]`` is the action taken *after* observation t
returns    (B, L, D)             the model's state at each observation (torch tensor or numpy array of
                                 bool / int / float values, finite, |x| <= 1e15)
=========  ====================  =========================================================================

The protocol probes the state at each window's last observation, so a recurrent or bidirectional model
sees nothing after it, except the action taken after it: the scripted policy computes that action from
the privileged object state. The primary readout therefore zeroes that action (raw zeros, the padding
every episode ends with; :func:`pokeworld.evaluate.measure.neutral_last`); the action-conditioned readout
is reported beside it, so a model that reads through the action is visible as a gap between the two.

What it runs, all episode-split (probes fit on probe-fit episodes, held-out R² on probe-test episodes):

1. certificates (:mod:`pokeworld.certify`): loaded from ``certificates.json`` in the store directory when
   it was computed on these bytes, else computed (or reused from ``out``) and written to ``out``;
2. probes (:func:`pokeworld.evaluate.measure.probe_windows`, the loop trained runs go through): ridge and
   MLP on contact / glide / all windows, to log m, γ, log k (and b, g when they vary), object and finger
   state; the action-conditioned ridge readout; the untrained bound when an untrained copy is given;
3. with a ``forecaster`` (:class:`pokeworld.evaluate.dependence.Forecaster`: the model's forecasts of the object
   position and touch under an action program), the forecast dependence: the slope ratio S per parameter beside
   its readout (:mod:`pokeworld.evaluate.dependence`);
4. the report: ``protocol.json``, ``protocol.md`` (a parameter whose gate failed gets † and an explicit
   "no claim" line) and ``protocol.png`` (R² per quantity beside its certificate).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Union

import numpy as np
import torch

from . import __version__, certify as C
from .config import from_preset, to_dict
from .data import Dataset, load
from .errors import ConfigError, DataError, ModelError
from .evaluate import tables as R
from .evaluate.dependence import DependenceConfig, Forecaster, check_store, forecast_dependence, fresh_corpus
from .evaluate.measure import (
    KINDS,
    PARAM_TARGETS,
    READOUT,
    STATE_TARGETS,
    neutral_last,
    padded_actions,
    probe_windows,
)
from .io import (
    check_apart,
    check_outputs,
    hash_arrays,
    read_json,
    read_json_if_present,
    save_figure_as,
    save_text,
    write_json,
)
from .model_inputs import checked_model

CERTIFICATES = "a certificate record (certificates.json)"
PROTOCOL_OUTPUTS = ("protocol.json", "protocol.md", "protocol.png")
"""The report :func:`certify_model` writes in its ``out`` folder (and ``certificates.json`` when it computes them)."""

StateFn = Callable[..., Any]
"""``(frames, proprio, touch, actions) -> (B, L, D)``; an ``nn.Module`` qualifies."""
FIGURE_QUANTITIES = ("log_m", "gamma", "log_k", "object_pos", "object_vel")


@dataclass
class ProtocolConfig:
    """Certificate-gated probes of a user model on a PokeWorld store."""

    window: int = 16
    """Probe window length (observations); the state at its last observation is probed."""
    stride: int = 4
    """Step between probe windows."""
    kinds: tuple[str, ...] = KINDS
    """Window kinds to probe (contact, glide, all); the gate reads contact windows."""
    action_conditioned_kinds: tuple[str, ...] = ("contact",)
    """Window kinds of the secondary, action-conditioned ridge readout (empty: skip it)."""
    max_windows: int = 6000
    """Cap on probe-fit windows per kind (episode-preserving random subsample), as in ``pokeworld probe``."""
    mlp: bool = True
    """Also fit early-stopped MLP probes on the leak-free readout (slower)."""
    targets: tuple[str, ...] = ()
    """Quantities to probe (e.g. log_m, gamma, log_k, object_pos); empty: every one the store labels."""
    batch_windows: int = 256
    """Windows per model call; lower it if the model runs out of memory."""
    inputs: str = "torch"
    """Array type handed to the model: "torch" (tensors) or "numpy" (arrays, e.g. for JAX models)."""
    device: str = ""
    """Device of the input tensors (empty: the module's parameter device; CPU for plain callables)."""
    certify_preset: str = "cpu"
    """Preset of :mod:`pokeworld.certify` used when certificates have to be computed."""
    certify_estimators: tuple[str, ...] = C.ESTIMATORS
    """Certificate estimators to run when computing (the gate reads ``gru``; it must be among them)."""
    seed: int = 0
    """Seed for window subsampling, MLP probes and computed certificates."""
    dependence_episodes: int = 2400
    """Forecast dependence (with a ``forecaster``): fresh episodes simulated from the store's generator for its
    windows; 0: the store's probe-test episodes instead (few push windows: mass and stiffness may go unmeasured)."""
    dependence_bootstrap: int = 1000
    """Episode-bootstrap resamples of the slope ratio S."""

    def __post_init__(self) -> None:
        if self.dependence_episodes < 0 or self.dependence_bootstrap < 10:
            raise ConfigError("dependence_episodes must be >= 0 and dependence_bootstrap >= 10")
        bad = (set(self.kinds) | set(self.action_conditioned_kinds)) - set(KINDS)
        if bad:
            raise ConfigError(f"unknown window kinds {sorted(bad)}; choose from {list(KINDS)}")
        if self.window < 2 or self.stride < 1 or self.batch_windows < 1 or self.max_windows < 10:
            raise ConfigError("window must be >= 2, stride and batch_windows >= 1, max_windows >= 10")
        unknown = set(self.targets) - set(PARAM_TARGETS) - set(STATE_TARGETS)
        if unknown:
            raise ConfigError(f"unknown probe targets {sorted(unknown)}; choose from {[*PARAM_TARGETS, *STATE_TARGETS]}")
        if self.inputs not in ("torch", "numpy"):
            raise ConfigError(f"inputs must be 'torch' or 'numpy', got {self.inputs!r}")
        if C.GATE_ESTIMATOR not in self.certify_estimators:
            # the report puts the paper's rule (the GRU oracle) beside every gate verdict
            raise ConfigError(f"certify_estimators must include {C.GATE_ESTIMATOR!r}, the paper's gate estimator")


PRESETS = {"tiny": {"max_windows": 400, "mlp": False, "certify_preset": "tiny", "dependence_episodes": 300,
                    "dependence_bootstrap": 100}, "cpu": {},
           "paper": {"max_windows": 100000, "certify_preset": "paper"}}


def make_config(preset: str = "cpu", **overrides) -> ProtocolConfig:
    return from_preset(ProtocolConfig, PRESETS, preset, **overrides)


# --------------------------------------------------------------------------- the model contract
MAX_STATE = 1e15
"""Largest state magnitude the protocol accepts.

Every probe standardises the states in the float32 they are read as (:class:`pokeworld.regressors.
Standardizer`): the variance sums squared deviations, each up to (2|x|)², over the N probe-fit windows, and
that sum must stay below float32's maximum (3.4e38) or the standard deviation becomes inf, every
standardised feature 0 and the R² a silent "nothing". At |x| <= 1e15 the sum is finite for N up to 8.5e7
windows, far beyond any ``max_windows``; at 1e20 a single square overflows. No working network's state
comes near 1e15, and nothing is lost by refusing one that does: standardised probes are invariant to the
state's scale, so the user can divide it by a constant."""


class StateReader:
    """Runs a user model on gathered windows and returns its state at each window's last observation.

    Checks the contract on every call and raises :class:`ModelError` naming what came back, because a
    silently reshaped, truncated or overflowing state would turn into a meaningless R² rather than an
    error: one real-valued array (bool, int or float; strings, objects, None and complex numbers are
    refused) of shape (B, L, D) with one D throughout, finite, with |x| <= :data:`MAX_STATE`. An exception
    raised by the model comes back as a ``ModelError`` naming the batch and window it failed on (the
    original chained as its cause); KeyboardInterrupt and SystemExit pass through untouched.
    """

    def __init__(self, model: StateFn, ds: Dataset, cfg: ProtocolConfig, role: str = "model"):
        if not callable(model):
            raise ModelError(f"the {role} must be callable as model(frames, proprio, touch, actions), "
                             f"got {type(model).__name__}")
        self.model, self.ds, self.cfg, self.role = model, ds, cfg, role
        self.acts = padded_actions(ds)
        self.dim: int | None = None
        params = next(model.parameters(), None) if isinstance(model, torch.nn.Module) else None
        self.device = torch.device(cfg.device) if cfg.device else (params.device if params is not None
                                                                    else torch.device("cpu"))

    def __call__(self, w, neutral_last_action: bool = True) -> np.ndarray:
        """(W, D) float32 states at the last observation of the windows ``w``."""
        out = []
        module = self.model if isinstance(self.model, torch.nn.Module) else None
        was_training = module.training if module is not None else False
        if module is not None:
            module.eval()  # dropout / batch statistics would make the probed state depend on the batch
        try:
            with torch.no_grad():
                for i in range(0, len(w), self.cfg.batch_windows):
                    out.append(self._batch(w, i, min(i + self.cfg.batch_windows, len(w)), neutral_last_action))
        finally:
            if module is not None:
                module.train(was_training)
        return np.concatenate(out)

    def _batch(self, windows, lo: int, hi: int, neutral_last_action: bool) -> np.ndarray:
        w = windows.select(np.arange(lo, hi))
        a = w.gather(self.acts)
        if neutral_last_action:
            a = neutral_last(a)
        arrays = (w.gather(self.ds.frames), w.gather(self.ds.proprio).astype(np.float32),
                  w.gather(self.ds.touch).astype(np.float32), a.astype(np.float32))
        if self.cfg.inputs == "torch":
            arrays = tuple(torch.from_numpy(np.ascontiguousarray(x)).to(self.device) for x in arrays)
        try:
            states = self.model(*arrays)
        except Exception as e:  # not BaseException: Ctrl-C and sys.exit must stop the run, not be reported
            raise ModelError(self._raised(e, w, lo, hi, len(windows))) from e
        return self._check(states, len(w), w.length, w.episode)[:, -1]

    def _raised(self, e: Exception, w, lo: int, hi: int, total: int) -> str:
        # the batch and its first window, so the failure can be reproduced on the store's own arrays
        ep, st = int(w.episode[0]), int(w.start[0])
        msg = (f"the {self.role} raised {type(e).__name__}: {e} on windows {lo}..{hi - 1} of {total} "
               f"(episodes {int(w.episode.min())}..{int(w.episode.max())}; first window: episode {ep}, "
               f"steps {st}..{st + w.length - 1})")
        if isinstance(e, (MemoryError, torch.cuda.OutOfMemoryError)):
            msg += f"; lower batch_windows (now {self.cfg.batch_windows})"
        return msg

    def _check(self, out: Any, B: int, L: int, episodes: np.ndarray) -> np.ndarray:
        given = type(out).__name__
        if isinstance(out, torch.Tensor):
            if out.is_complex():
                raise ModelError(self._complex(str(out.dtype)))
            out = out.detach().cpu()
            # float64 stays float64 so that a value beyond float32's range is reported as overflow, not as inf
            out = out.numpy() if out.dtype == torch.float64 else out.float().numpy()
        elif isinstance(out, (tuple, list, dict)):
            raise ModelError(f"the {self.role} returned a {given}; return one (B, L, D) array of "
                             "states (wrap a model with several outputs in a function that picks the state)")
        elif out is None:
            raise ModelError(f"the {self.role} returned None, not a (B, L, D) array of states "
                             "(does its forward end without a return?)")
        try:
            out = np.asarray(out)
        except (TypeError, ValueError) as e:
            raise ModelError(f"the {self.role} returned {given}, not an array of states ({e})") from None
        # numpy would turn numeric strings and objects into floats and drop imaginary parts with only a
        # warning, so a state that is not plainly real-valued is refused rather than converted
        if out.dtype.kind == "c":
            raise ModelError(self._complex(str(out.dtype)))
        if out.dtype.kind not in "biuf":
            raise ModelError(f"the {self.role} returned {given} of dtype {out.dtype}, not numbers; states must be "
                             "bool, int or float (the probes regress on their values)")
        if out.dtype.kind != "f":
            out = out.astype(np.float64)  # exact for bool and int, and |int64.min| does not wrap around
        if out.ndim != 3 or out.shape[:2] != (B, L) or out.shape[2] == 0:
            raise ModelError(f"the {self.role} returned states of shape {tuple(out.shape)} for {B} windows of {L} "
                             f"observations; expected (B={B}, L={L}, D): one state vector per observation")
        if self.dim is None:
            self.dim = int(out.shape[2])
        elif out.shape[2] != self.dim:
            raise ModelError(f"the {self.role} returned state width {out.shape[2]} after {self.dim} earlier; "
                             "the state width must not depend on the batch")
        bad = ~np.isfinite(out)
        if bad.any():
            raise ModelError(f"the {self.role} returned {int(bad.sum())} non-finite state values (NaN/inf) on "
                             f"{self._where(bad, episodes)}; probes on such states are meaningless")
        mag = np.abs(out)
        big = mag > MAX_STATE
        if big.any():
            largest = float(mag.max())
            if largest > float(np.finfo(np.float32).max):
                why = "overflow to inf when the protocol reads states as float32"
            else:
                why = (f"exceed |x| <= {MAX_STATE:.0e}, past which the probes' float32 standardisation can "
                       "overflow (its variance sums squared deviations over the fit windows) and leave the "
                       "probes reading nothing")
            raise ModelError(f"the {self.role} returned {int(big.sum())} state values as large as {largest:.3g} on "
                             f"{self._where(big, episodes)}; they {why}. Divide the state by a constant: every "
                             "probe standardises it, so its scale does not change the R²")
        return out.astype(np.float32)

    def _complex(self, dtype: str) -> str:
        return (f"the {self.role} returned complex states ({dtype}); the probes are real-valued and would drop the "
                "imaginary part, so return real and imaginary parts side by side (torch.view_as_real, flattened)")

    @staticmethod
    def _where(mask: np.ndarray, episodes: np.ndarray) -> str:
        eps = np.unique(episodes[mask.any((1, 2))])
        return f"windows of episodes {eps[:8].tolist()}{' ...' if eps.size > 8 else ''}"


# --------------------------------------------------------------------------- certificates
def _digest(ds: Dataset) -> str:
    # re-hashed rather than read from the manifest: an in-memory Dataset may have been edited since
    return hash_arrays(ds.arrays())


def _certify_config(cfg: ProtocolConfig, data_path: Path | None) -> C.CertifyConfig:
    # the certificate reads the same windows the probes read, so both speak of the same information
    return C.make_config(cfg.certify_preset, data=str(data_path or ""), estimators=tuple(cfg.certify_estimators),
                         window=cfg.window, stride=cfg.stride, seed=cfg.seed)


def resolve_certificates(ds: Dataset, cfg: ProtocolConfig, out: Path, data_path: Path | None = None,
                         certificates: dict | str | Path | None = None) -> dict:
    """The certificates for ``ds`` with the gate (best estimator; the paper's rule beside it), and where they came from.

    Order: ``certificates`` as given (a dict or a certificates.json path; refused when it records a
    different dataset hash); ``<data>/certificates.json`` when computed on these bytes; ``<out>/
    certificates.json`` from an earlier run with the same certify config; else computed and written to
    ``out`` (the store directory is never written).
    """
    digest = _digest(ds)

    def matches(c: dict) -> bool:
        return c.get("dataset", {}).get("content_sha256") == digest

    def entry(c: dict, source: str) -> dict:
        if "certificate" not in c:
            raise DataError(f"certificates from {source} have no 'certificate' table; "
                            "pass the output of pokeworld.certify.certify or a certificates.json")
        return {"certificate": c["certificate"], "gate": C.gate_of(c), "estimators": c.get("estimators", {}),
                "counts": c.get("counts", {}), "config": c.get("config", {}), "source": source}

    if certificates is not None:
        source = "given"
        if not isinstance(certificates, dict):
            source = str(certificates)
            path = Path(certificates)
            if not os.path.lexists(path):
                raise DataError(f"no certificates at {path}; run `pokeworld certify` or leave certificates unset")
            certificates = read_json(path, CERTIFICATES)
        recorded = certificates.get("dataset", {}).get("content_sha256")
        if recorded is not None and recorded != digest:
            raise DataError(f"certificates from {source} were computed on other data (content hash "
                            f"{recorded:.12} != {digest:.12}); recompute them for this store")
        return entry(certificates, source)
    stored = None if data_path is None else read_json_if_present(data_path / "certificates.json", CERTIFICATES)
    if stored is not None:
        if matches(stored):
            return entry(stored, str(data_path / "certificates.json"))
        print(f"[protocol] {data_path / 'certificates.json'} was computed on other data; computing anew")
    ccfg = _certify_config(cfg, data_path)
    cached = out / "certificates.json"
    prev = read_json_if_present(cached, CERTIFICATES)
    if prev is not None:
        if matches(prev) and prev.get("config") == to_dict(ccfg):
            return entry(prev, str(cached))
    computed = C.certify(ds, ccfg)
    computed["dataset"]["content_sha256"] = digest
    write_json(cached, computed)
    return entry(computed, "computed")


# --------------------------------------------------------------------------- the protocol
def _check_splits(ds: Dataset) -> None:
    fit, test = ds.episodes("probe_fit").size, ds.episodes("probe_test").size
    if fit < 5 or test < 5:
        raise DataError(f"the store has {fit} probe-fit and {test} probe-test episodes; the protocol fits probes "
                        f"on probe-fit episodes (split == 1) and scores them on probe-test ones (split == 2) and "
                        f"needs at least 5 of each: generate the store with `pokeworld generate` or set its split")


def run_probes(model: StateFn, ds: Dataset, cfg: ProtocolConfig, untrained: StateFn | None = None) -> dict:
    """Leak-free probes (primary), the action-conditioned ridge readout and the untrained bound.

    Returns the keys ``pokeworld probe`` writes to measure.json for the same readouts: ``readout``,
    ``probes``, ``probes_action_conditioned`` (when requested) and ``untrained`` (when given).
    """
    _check_splits(ds)
    torch.manual_seed(cfg.seed)
    reader = StateReader(model, ds, cfg)
    common = dict(window=cfg.window, stride=cfg.stride, max_windows=cfg.max_windows, seed=cfg.seed,
                  targets=tuple(cfg.targets) or None)
    res: dict = {"readout": READOUT,
                 "probes": probe_windows(ds, lambda w, part: reader(w, True), cfg.kinds, mlp=cfg.mlp, **common)}
    if not res["probes"].get("ridge"):
        raise DataError(f"too few probe windows of every kind {list(cfg.kinds)} (counts "
                        f"{res['probes']['counts']}); the store needs more probe-fit / probe-test episodes")
    if cfg.action_conditioned_kinds:
        res["probes_action_conditioned"] = probe_windows(ds, lambda w, part: reader(w, False),
                                                         cfg.action_conditioned_kinds, mlp=False, **common)
    if untrained is not None:
        bound = StateReader(untrained, ds, cfg, role="untrained model")
        res["untrained"] = probe_windows(ds, lambda w, part: bound(w, True), cfg.kinds, mlp=False, **common)
    res["state_dim"] = reader.dim
    return res


def claims(res: dict, gate: dict, kind: str = "contact") -> dict:
    """Per probed quantity: R² on ``kind`` windows, the gate verdict and whether a claim may be made.

    ``status`` is "claim" for a gated parameter (log m, γ, log k) whose gate passed, "no claim (gate
    failed)" when it failed or was never certified, "not gated" for the rest (object and finger state,
    which the certificate estimators observe directly, and parameters the gate does not cover).
    """
    ridge = res["probes"].get("ridge", {}).get(kind, {})
    out = {}
    for q, r2 in ridge.items():
        e: dict = {"ridge": r2, "mlp": res["probes"].get("mlp", {}).get(kind, {}).get(q),
                   "action_conditioned": res.get("probes_action_conditioned", {}).get("ridge", {}).get(kind, {}).get(q)}
        unt = res.get("untrained", {}).get("ridge", {}).get(kind, {}).get(q)
        if unt is not None:
            e.update(untrained=unt, above_untrained=r2 - unt)
        if q in C.GATES:
            g = gate.get(q)
            e["gate_passed"] = bool(g and g["passed"])
            e["status"] = "claim" if e["gate_passed"] else "no claim (gate failed)"
        else:
            e["status"] = "not gated"
        out[q] = e
    return out


def certify_model(model: Union[StateFn, str, Path], data: Union[str, Path, Dataset], out: Union[str, Path],
                  untrained: StateFn | None = None, *, certificates: dict | str | Path | None = None,
                  name: str | None = None, config: ProtocolConfig | None = None, preset: str = "cpu",
                  forecaster: Forecaster | None = None, **overrides) -> dict:
    """Run the certificate-gated protocol on ``model`` and write the report to ``out``.

    Args:
        model: ``(frames, proprio, touch, actions) -> (B, L, D)`` states (see the module docstring), or the path
            of a finished X-JEPA run or an exported model folder (``pokeworld export``), read through
            :func:`pokeworld.rundir.load_model` and certified through its ``features``.
        data: a store directory (``pokeworld generate`` output) or an in-memory :class:`Dataset`.
        out: report directory (protocol.json, protocol.md, protocol.png; certificates.json when computed).
        untrained: the same architecture at initialisation, for the untrained bound (optional).
        certificates: a certificates dict or certificates.json path (default: found or computed).
        name: label of the model in the report (default: its function / class name).
        forecaster: the model's forecasts (:class:`pokeworld.evaluate.dependence.Forecaster`), for the forecast
            dependence (slope ratio S) per parameter beside its probes; None: readout only.
        config / preset / overrides: a :class:`ProtocolConfig`, or a preset with field overrides.
    Returns:
        The report dictionary also written to ``out/protocol.json``.
    """
    if config is not None and overrides:
        raise ConfigError("pass either config or field overrides, not both")
    cfg = config if config is not None else make_config(preset, **overrides)
    t0 = time.time()
    data_path = None if isinstance(data, Dataset) else Path(data)
    out = Path(out)
    outputs = [out / n for n in PROTOCOL_OUTPUTS] + ([out / "certificates.json"] if certificates is None else [])
    # the outputs never replace or write into what the protocol reads (the store, a certificates file)
    check_apart([data_path, certificates if isinstance(certificates, (str, Path)) else None], outputs)
    # a run or exported folder: its weights (finite, fitting their kwargs) and its inputs against the store's
    # streams and the probe windows, before any data is read (any other string: "not callable")
    if isinstance(model, (str, Path)) and Path(model).is_dir():
        name = name or Path(model).name
        model = checked_model(model, data, cfg.window, f"window={cfg.window}",
                              device=cfg.device or "cpu").features
    ds = data if isinstance(data, Dataset) else load(data)
    _check_splits(ds)  # before the (slow) certificates, so a store without splits fails at once
    if forecaster is not None:
        check_store(ds)  # likewise a store the forecast responses cannot be read from
    # every output checked before the first long step: a protocol.md pokeworld did not write is refused now, not
    # after hours of certificates and probes
    check_outputs(out, *(p.name for p in outputs))
    certs = resolve_certificates(ds, cfg, out, data_path, certificates)
    res = run_probes(model, ds, cfg, untrained)
    if forecaster is not None:
        res["dependence"] = dependence_of(forecaster, ds, cfg)
    name = name or getattr(model, "__name__", type(model).__name__)
    result = {"model": {"name": name, "state_dim": res.pop("state_dim")},
              "protocol": to_dict(cfg),
              "dataset": {"path": str(data_path) if data_path else None, "content_sha256": _digest(ds),
                          "corpus": ds.manifest.get("corpus") or ds.manifest.get("config", {}).get("corpus"),
                          "probe_fit_episodes": int(ds.episodes("probe_fit").size),
                          "probe_test_episodes": int(ds.episodes("probe_test").size)},
              **res, "certificates": certs, "claims": claims(res, certs["gate"]),
              "provenance": {"pokeworld": __version__, "git": R.git_commit(),
                             "seconds": round(time.time() - t0, 1)}}
    write_json(out / "protocol.json", result)
    save_text(out / "protocol.md", markdown(result))
    figure(result, out / "protocol.png")
    print(f"[protocol] {name}: wrote {out / 'protocol.md'}")
    return result


def dependence_of(forecaster: Forecaster, ds: Dataset, cfg: ProtocolConfig) -> dict:
    """The forecaster's slope ratio S per parameter (:mod:`pokeworld.evaluate.dependence`), on fresh episodes from
    the store's generator (``dependence_episodes``) or on the store's probe-test episodes."""
    dep = DependenceConfig(bootstrap=cfg.dependence_bootstrap, seed=cfg.seed)
    if cfg.dependence_episodes:
        fresh = fresh_corpus(ds, cfg.dependence_episodes, cfg.seed + 1000)
        return forecast_dependence(forecaster, fresh, np.arange(fresh.num_episodes), dep)
    return forecast_dependence(forecaster, ds, ds.episodes("probe_test"), dep)


def dependence_lines(result: dict) -> list[str]:
    """The report's forecast-dependence table: readout (ridge, contact) and S side by side per parameter."""
    if "dependence" not in result:
        return []
    lines = ["", "## Forecast dependence (slope ratio S)", "",
             "| parameter | response | readout (ridge, contact) | S [95 % episode bootstrap] | forecast error | "
             "windows |", "|---|---|---|---|---|---|"]
    ridge = result["probes"].get("ridge", {}).get("contact", {})
    for p, v in result["dependence"].items():
        s = (f"{v['S']:+.2f} [{v['S_interval'][0]:+.2f}, {v['S_interval'][1]:+.2f}]" if "S" in v
             else f"— ({v.get('note', 'not measured')})")
        err = f"{v['forecast_error']:.3f}" if "forecast_error" in v else "—"
        lines.append(f"| {p} | {v['response']} | {R.fmt(ridge.get(v['regressor']))} | {s} | {err} | "
                     f"{v.get('windows', 0)} |")
    return lines + ["", "S: the partial slope of the model's forecast response on the parameter over the simulator's "
                    "on the same windows, context state and the other parameters controlled (docs/design.md, "
                    "\"Forecast dependence\"). 1: the forecast depends on the parameter as the world does; 0: it "
                    "ignores it; below 0: it moves the wrong way. Readout and dependence can diverge."]


# --------------------------------------------------------------------------- report
def _results_view(result: dict) -> dict:
    # evaluate.tables' helpers read {"certificates": {corpus: {"gate": ...}}}; the user's store is the corpus
    return {"certificates": {"standard": {"gate": result["certificates"]["gate"]}}}


def markdown(result: dict) -> str:
    """The report: certificate gate, probe table with † on parameters whose gate failed, no-claim lines."""
    view = _results_view(result)
    d, m, cert = result["dataset"], result["model"], result["certificates"]
    cfg = result["protocol"]
    lines = [f"# Certificate-gated probes: {m['name']}", "",
             f"Data: `{d['path'] or 'in-memory dataset'}` (content {d['content_sha256']:.12}; "
             f"{d['probe_fit_episodes']} probe-fit / {d['probe_test_episodes']} probe-test episodes). "
             f"State width {m['state_dim']}; windows of {cfg['window']} observations at stride {cfg['stride']}. "
             f"Certificates: {cert['source']}. pokeworld {result['provenance']['pokeworld']}, "
             f"git {result['provenance']['git']}.", "",
             "## Certificates (contact windows, held-out R²)", "",
             "| parameter | best estimator (gate) | threshold | verdict | GRU oracle (paper's rule) |",
             "|---|---|---|---|---|"]
    for q, g in cert["gate"].items():
        best = f"{g['estimator']} {R.fmt(g['certificate'])}" if "certificate" in g else "—"
        lines.append(f"| {R.LABELS.get(q, q)} | {best} | {g['threshold']:.2f} | {'PASS' if g['passed'] else 'FAIL'} | "
                     f"{R.fmt(g.get('oracle'))} ({'PASS' if g['paper_rule_passed'] else 'FAIL'}) |")
    lines += [""] + [f"- {R.LABELS.get(q, q)}: {g['note']}" for q, g in cert["gate"].items() if not g.get("agree", True)]
    lines += ["", "## Probes (held-out R², leak-free readout)", ""]
    lines += R.no_claim_lines(view)
    kinds = [k for k in KINDS if k in result["probes"].get("ridge", {})]
    cols = [f"ridge {k}" for k in kinds]
    has_mlp = "mlp" in result["probes"]
    cols += [f"MLP {k}" for k in kinds if has_mlp]
    leaky_kinds = list(result.get("probes_action_conditioned", {}).get("ridge", {}))
    cols += [f"action-conditioned {k}" for k in leaky_kinds]
    has_unt = "untrained" in result
    cols += [f"untrained {k}" for k in kinds if has_unt]
    contact_cert = cert["certificate"].get("contact", {})
    lines += ["| quantity | certificate | " + " | ".join(cols) + " |", "|" + "---|" * (len(cols) + 2)]
    quantities = list(dict.fromkeys(q for k in kinds for q in result["probes"]["ridge"][k]))
    for q in quantities:
        mark = R.dagger(R.gate_failed(view, q))
        get = lambda block, fam, k: result.get(block, {}).get(fam, {}).get(k, {}).get(q)  # noqa: E731
        cells = [R.fmt(get("probes", "ridge", k)) + mark for k in kinds]
        cells += [R.fmt(get("probes", "mlp", k)) + mark for k in kinds if has_mlp]
        cells += [R.fmt(get("probes_action_conditioned", "ridge", k)) + mark for k in leaky_kinds]
        cells += [R.fmt(get("untrained", "ridge", k)) for k in kinds if has_unt]
        c = contact_cert.get(q)
        lines.append(f"| {R.LABELS.get(q, q)} | {R.fmt(c['r2']) if c else '—'} | " + " | ".join(cells) + " |")
    lines += ["", "Certificate: the best estimator's contact-window R² from raw observations (object state is "
              "observed by the estimators, so it has none). The gate: the certificate must reach log m / γ / log k ≥ "
              + " / ".join(f"{C.GATES[q]}" for q in ("log_m", "gamma", "log_k")) + " on contact windows; the "
              "paper's rule (the GRU oracle alone) is shown beside it and any disagreement is listed.", "",
              "Readout: every probe reads the model's state at a window's last observation with the action taken "
              "after it replaced by raw zeros (leak-free). The action-conditioned columns feed the real action, "
              "which the scripted policy computed from the object state: a high action-conditioned R² over a low "
              "leak-free one means the state reads the target through the action, not from the observations."]
    if has_unt:
        lines += ["", "Untrained: the same ridge probes on the untrained copy of the model; content is what the "
                  "trained model holds above it."]
    return "\n".join(lines + dependence_lines(result)) + "\n"


#: The figure's lowest R²: a bar below it is cut there and marked with its true value.
FIGURE_R2_FLOOR = -0.1


def figure(result: dict, path: Path) -> Path:
    """Bar chart: R² per quantity (ridge, MLP, untrained) beside its certificate, gate failures marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    view = _results_view(result)
    probes = result["probes"]
    kind = "contact" if "contact" in probes.get("ridge", {}) else next(iter(probes["ridge"]))
    qs = [q for q in FIGURE_QUANTITIES if q in probes["ridge"][kind]]
    cert = result["certificates"]["certificate"].get(kind, {})
    oracle = result["certificates"]["estimators"].get(C.GATE_ESTIMATOR, {}).get(kind, {})
    # both, because the gate reads the best estimator and the paper's rule the GRU oracle: they can disagree
    series = [("certificate (best estimator, gate)", [cert.get(q, {}).get("r2", np.nan) for q in qs], "0.75"),
              ("GRU oracle (paper's rule)", [oracle.get(q, np.nan) for q in qs], "0.4")]
    series.append(("ridge (leak-free)", [probes["ridge"][kind][q] for q in qs], "tab:blue"))
    if "mlp" in probes and kind in probes["mlp"]:
        series.append(("MLP (leak-free)", [probes["mlp"][kind].get(q, np.nan) for q in qs], "tab:cyan"))
    if "untrained" in result and kind in result["untrained"].get("ridge", {}):
        series.append(("untrained ridge", [result["untrained"]["ridge"][kind].get(q, np.nan) for q in qs],
                       "tab:orange"))
    fig, ax = plt.subplots(figsize=(1.5 * len(qs) + 2.5, 3.6))
    width = 0.8 / len(series)
    x = np.arange(len(qs))
    clipped = False
    for i, (label, raw, color) in enumerate(series):
        raw = np.asarray(raw, float)
        vals = np.clip(raw, FIGURE_R2_FLOOR, 1.0)  # strongly negative R² is "nothing"; keep the scale
        hatch = [("//" if R.gate_failed(view, q) and i >= 2 else "") for q in qs]  # the model's bars
        for j, v in enumerate(vals):
            if np.isfinite(v):
                xb = x[j] + (i - (len(series) - 1) / 2) * width
                ax.bar(xb, v, width, color=color, hatch=hatch[j],
                       edgecolor="black" if hatch[j] else color, label=label if j == 0 else None)
                if raw[j] < FIGURE_R2_FLOOR:  # a clipped bar says so, with its true value
                    clipped = True
                    ax.text(xb, FIGURE_R2_FLOOR + 0.005, f"↓{raw[j]:.2f}", rotation=90, ha="center", va="bottom",
                            fontsize=6)
    for j, q in enumerate(qs):
        if q in C.GATES:
            ax.plot([x[j] - 0.4, x[j] + 0.4], [C.GATES[q]] * 2, color="red", lw=1, ls="--")
            if R.gate_failed(view, q):
                ax.text(x[j], 1.03, "gate ✗: no claim", ha="center", fontsize=8, color="red")
    ax.axhline(0, color="black", lw=0.5)
    ax.set_xticks(x, [R.LABELS.get(q, q) for q in qs])
    ax.set_ylim(FIGURE_R2_FLOOR, 1.12)
    ax.set_ylabel("held-out R²")
    ax.set_title(f"{result['model']['name']}: probes vs certificate ({kind} windows; dashed: gate threshold"
                 + (f"; ↓: bar cut at {FIGURE_R2_FLOOR}, its R² printed" if clipped else "") + ")", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    return save_figure_as(fig, [path])[0]


__all__ = ["MAX_STATE", "ProtocolConfig", "PRESETS", "StateReader", "certify_model", "claims", "make_config",
           "markdown", "figure", "resolve_certificates", "run_probes"]
