"""Measure one trained run: probes on the frozen predictor state, prediction quality, functional glide test.

Everything is episode-split: probes are fit on probe-fit episodes and scored by
held-out R^2 on probe-test episodes (paper §3 "Measurement", §4, App. C).

* Probes: ridge (alpha by episode-grouped CV) and an early-stopped MLP, from the
  predictor state at the last observation of 16-step windows, to log m, gamma,
  log k (and b, g when present), object position and velocity, finger position and
  the object-minus-finger position (the composition probes, App. C); on contact,
  glide and all windows.
* Leak-free readout: trunk state t is conditioned on the action taken *after*
  observation t, and the scripted policy computes that action from the privileged
  object state. The primary probes (``probes``) therefore read the state with the
  last window step's action replaced by the neutral action (raw zeros, the padding
  every training episode ends with); the action-conditioned readout is kept as a
  labelled secondary (``probes_action_conditioned``, ridge only).
* Prediction: from ``context`` (8) context observations, the direct Δ=16 head, the
  autoregressive composition of the Δ=1 head and a static latent, all decoded
  to arena units through a ridge position probe fit on encoder latents; the static
  baseline is decoded through the same probe (``static16``; ``static16_true`` is the
  undecoded true-position one).
* Functional glide test: the model's own direct 16-step prediction on pure-glide
  windows against analytic references (true gamma, population-median gamma, static),
  every candidate carrying the same decoder residual so the comparison is in one space.
* Belief objective (``objective='belief'``): the probed state is the causal one, the trunk state
  conditioned on the prior's mean (what the heads predict with from the past alone; ``XJEPA.trunk``).
  ``probes_belief`` adds ridge probes of the prior mean itself (causal) and of the posterior mean on
  the probe window (which ends at the probed observation, so it sees the same history; it says whether
  the episode latent encodes a quantity at all from that evidence).
* Untrained bound: the same ridge probes on a randomly initialised model that shares
  only the trained model's input-normalisation statistics.

The pieces live by job in :mod:`.state` (latents, leak-free trunk states), :mod:`.probes` (targets,
ridge / MLP fits, the probe loop) and :mod:`.prediction` (decoded prediction errors, glide test), so
the real-robot metrics (:mod:`pokeworld.real.evaluate`) call the same code with other targets; this
module is the simulator's orchestrator and re-exports their public names.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..config import SEED, Limit, check_fields, from_preset, to_dict
from ..data import Dataset, load, read_manifest
from ..devices import pick_device
from ..errors import ConfigError, PokeworldError
from ..faults import crash_point
from ..io import check_outputs, check_writable_dir, read_json, write_json
from ..model_inputs import checked_model
from ..models.xjepa import XJEPA
from ..preflight import finished_run
from ..run_store import trained_store
from ..rundir import adopt_legacy_run, finished_marker, load_model, read_run_config
from .measure_record import MAX_MEASUREMENT_BYTES
from .prediction import (  # noqa: F401
    CONTEXT,
    HORIZON,
    glide_comparison,
    glide_reference,
    glide_test,
    position_decoder,
    prediction_quality,
)
from .probes import (  # noqa: F401
    KINDS,
    PARAM_TARGETS,
    STATE_TARGETS,
    fit_predict,
    fit_probes,
    probe_latents,
    probe_model,
    probe_targets,
    probe_windows,
)
from .state import (  # noqa: F401
    PROBE_DEVICES,
    EpisodeLatents,
    as_model_input,
    encode_episodes,
    model_device,
    neutral_last,
    padded_actions,
    probes_on_device,
    window_states,
)

READOUT = {
    "probes": "state at the window's last observation with the action after it replaced by the neutral "
              "(raw zero) action: leak-free, the primary readout",
    "probes_action_conditioned": "state conditioned on the real action after the last observation, which the "
                                 "scripted policy computed from the object state: an upper, leaky readout",
    "probes_belief": "belief objective only, ridge: 'prior_mean' reads μ_p(h_t) at the window's last observation "
                     "(causal, neutral last action); 'posterior_mean' reads μ_q of the probe window, which ends at "
                     "that observation: what the episode latent encodes from the same history",
}


@dataclass
class MeasureConfig:
    """Probe and evaluate one trained run."""

    run_dir: str = "runs/xjepa"
    """Run directory written by ``pokeworld train``."""
    data: str = ""
    """Dataset to measure on (default: the run's training dataset)."""
    window: int = 16
    """Probe window length (observations); the state at its last observation is probed."""
    stride: int = 4
    """Step between probe windows."""
    kinds: tuple[str, ...] = KINDS
    """Window kinds to probe."""
    action_conditioned_kinds: tuple[str, ...] = ("contact",)
    """Window kinds of the secondary, action-conditioned ridge readout (empty: skip it)."""
    max_windows: int = 6000
    """Cap on fit windows per kind (episode-preserving random subsample)."""
    mlp: bool = True
    """Also fit early-stopped MLP probes (slower)."""
    untrained: bool = True
    """Also probe a randomly initialised model of the same configuration (the untrained bound)."""
    batch_episodes: int = 64
    """Episodes encoded per forward pass."""
    seed: int = 0
    """Seed for subsampling and MLP probes."""
    context: int = CONTEXT
    """Context observations before the 16-step predictions and the glide test (paper: 8)."""
    overwrite: bool = False
    """Recompute even if measure.json is up to date. A measurement with settings other than the stored one's (another
    --preset, or any field changed) is written to measure.json and the earlier one kept as measure.previous.json
    (one line says so), with or without --overwrite."""
    device: str = "auto"
    """Where the model runs while its states are read: 'auto' (cuda when available, else cpu), 'cpu', 'cuda' or
    'cuda:N'. On CUDA the states are read with TF32 off (:func:`full_precision`), so GPU and CPU states differ by float
    rounding only (tests/test_cuda.py) and the device is not part of the measurement's key (a measurement made on
    either is up to date for both)."""
    probe_device: str = "auto"
    """Where the probes run: 'auto' — on the model's device when that is CUDA (the states never leave it; the probes
    run there in torch, ridge in float64, and only the R² numbers come back), else on the host in numpy / sklearn,
    the path every recorded measurement was made with; 'host' — always the latter; 'model' — always the former (on
    a CPU: torch on the CPU, equal to the numpy path to float rounding, tests/test_device_probes.py). Not part of
    the measurement's key."""

    LIMITS = {"window": Limit(2, 4096), "stride": Limit(1, 4096), "max_windows": Limit(1, 10**8),
              "batch_episodes": Limit(1, 10**5), "seed": SEED, "context": Limit(1, 4096)}

    def __post_init__(self) -> None:
        check_fields(self)
        bad = (set(self.kinds) | set(self.action_conditioned_kinds)) - set(KINDS)
        if bad:
            raise ConfigError(f"unknown window kinds {sorted(bad)}; choose from {list(KINDS)}")
        pick_device(self.device)  # a clear error now rather than inside torch later
        if self.probe_device not in PROBE_DEVICES:
            raise ConfigError(f"probe_device must be one of {list(PROBE_DEVICES)}, got {self.probe_device!r}")
        if self.context < 1 or self.window < 2:
            raise ConfigError(f"context must be ≥ 1 and window ≥ 2, got context={self.context}, window={self.window}")
        if not self.kinds:
            raise ConfigError(f"kinds is empty: name at least one window kind to probe, from {list(KINDS)}")
        counts = {"stride": self.stride, "max_windows": self.max_windows, "batch_episodes": self.batch_episodes}
        bad_counts = {k: v for k, v in counts.items() if v < 1}
        if bad_counts or self.seed < 0:
            raise ConfigError(f"stride, max_windows and batch_episodes must be ≥ 1 and seed ≥ 0, got "
                              f"{bad_counts or {'seed': self.seed}}")


PRESETS = {"tiny": {"max_windows": 400, "mlp": False}, "cpu": {}, "paper": {"max_windows": 100000}}
#: The training preset each measurement preset measures (``pokeworld probe`` without --preset measures a run with its
#: own: a tiny model measured at cpu sizes takes minutes for no better number); the demo's model is the cpu model.
MEASURE_PRESET_OF = {"tiny": "tiny", "cpu": "cpu", "demo": "cpu", "cpu_first": "cpu", "demo_first": "cpu", "paper": "paper"}
#: The fields a run's config.json records that tell the training presets apart (the model's sizes).
PRESET_FIELDS = ("image_size", "channels", "latent_dim", "width", "depth", "heads", "vec_dim")


# --------------------------------------------------------------------------- belief objective
@torch.no_grad()
def belief_states(model, lat: EpisodeLatents, w, acts: np.ndarray, which: str, batch: int = 512,
                  on_device: bool = False):
    """Belief readout per window: ``prior`` -> μ_p at the last observation (causal, neutral last action);
    ``posterior`` -> μ_q of the window, which ends at that observation (no future). (W, K): an array, or with
    ``on_device`` a tensor left on the model's device."""
    z, a = lat.gather(w), neutral_last(w.gather(acts))
    out = []
    for i in range(0, len(z), batch):
        zt, at = as_model_input(model, z[i:i + batch]), a[i:i + batch]
        mu = model.prior(zt, at)[0][:, -1] if which == "prior" else model.posterior(zt, at)[0]
        out.append(mu.float() if on_device else mu.float().cpu().numpy())
    return torch.cat(out) if on_device else np.concatenate(out)


def probe_belief(model, ds: Dataset, cfg: MeasureConfig, latents) -> dict:
    """Ridge probes of the belief objective's prior mean (causal) and posterior mean (same history)."""
    acts = padded_actions(ds)
    lat = dict(zip(("fit", "test"), latents))
    dev = probes_on_device(cfg.probe_device, model)
    return {f"{which}_mean": probe_windows(ds, lambda w, part, which=which: belief_states(model, lat[part], w, acts,
                                                                                         which, on_device=dev),
                                           cfg.kinds, cfg.window, cfg.stride, cfg.max_windows, cfg.seed, mlp=False)
            for which in ("prior", "posterior")}



def make_config(preset: str = "cpu", **overrides) -> MeasureConfig:
    return from_preset(MeasureConfig, PRESETS, preset, **overrides)


def training_preset(run_cfg: dict) -> str | None:
    """The training preset a run's config.json (a dict) was made with, from its model sizes (:data:`PRESET_FIELDS`):
    config.json records fields, not the preset's name. The preset matching most of them; None when even that one
    matches no more than half (a model whose sizes were set by hand)."""
    from ..train.config import PRESETS as TRAIN_PRESETS, field_defaults

    def as_json(v):
        return list(v) if isinstance(v, tuple) else v

    defaults = field_defaults()
    matches = {name: sum(as_json({**defaults, **over}[f]) == run_cfg.get(f) for f in PRESET_FIELDS)
               for name, over in TRAIN_PRESETS.items()}
    best = max(matches, key=matches.get)
    return best if 2 * matches[best] > len(PRESET_FIELDS) else None


def run_preset(cfg: MeasureConfig) -> str:
    """The measurement preset of ``cfg.run_dir``'s own training preset (:data:`MEASURE_PRESET_OF`): what
    ``pokeworld probe`` measures with when --preset is not given; ``cpu`` (the usual default) when the run has no
    readable config.json (:func:`run` then says why) or sizes of no preset."""
    try:
        run_cfg = read_run_config(cfg.run_dir)
    except PokeworldError:
        run_cfg = None
    trained = training_preset(run_cfg) if run_cfg else None
    return MEASURE_PRESET_OF.get(trained or "cpu", "cpu")


# --------------------------------------------------------------------------- entry
def measure(model, ds: Dataset, cfg: MeasureConfig, untrained_model=None) -> dict:
    """Probes (leak-free primary, action-conditioned secondary), prediction quality and the untrained bound."""
    torch.manual_seed(cfg.seed)
    probes, latents = probe_model(model, ds, cfg, cfg.mlp)
    res: dict = {"probes": probes}
    if cfg.action_conditioned_kinds:
        res["probes_action_conditioned"], _ = probe_model(model, ds, cfg, mlp=False, kinds=cfg.action_conditioned_kinds,
                                                          neutral_last_action=False, latents=latents)
    if getattr(model, "belief", None) is not None:
        res["probes_belief"] = probe_belief(model, ds, cfg, latents)
    res["prediction"] = prediction_quality(model, ds, *latents, cfg.seed, context=cfg.context)
    if untrained_model is not None:
        up, _ = probe_model(untrained_model, ds, cfg, mlp=False)
        res["untrained"] = up
    res["readout"] = {k: v for k, v in READOUT.items() if k in res}  # describe the readouts this run has
    return res


def untrained_copy(trained, seed: int = 12345):
    """A randomly initialised model of ``trained``'s architecture sharing only its input-normalisation buffers.

    Only the model's own top-level ``*_mean`` / ``*_std`` buffers (proprio, touch, action, param statistics,
    registered in ``XJEPA.__init__``) are copied: they describe the data, not learning. Nested buffers such
    as the encoder's BatchNorm running statistics are accumulated during training and stay fresh, or the
    bound would not be untrained.
    """
    stats = {k: v.detach().clone() for k, v in trained.named_buffers(recurse=False) if k.endswith(("_mean", "_std"))}
    with torch.random.fork_rng(devices=[]):  # a fixed initialisation without disturbing the caller's stream
        torch.manual_seed(seed)
        fresh = XJEPA(**trained.config)
    fresh.load_state_dict(stats, strict=False)
    return fresh.to(model_device(trained)).eval()  # initialised on the CPU, so a GPU measurement gets the same weights


def untrained_like(run_dir: Path, ds: Dataset | None = None, seed: int = 12345):
    """:func:`untrained_copy` of the model trained in ``run_dir``."""
    return untrained_copy(load_model(run_dir, map_location="cpu"), seed)


def measure_path(run_dir: str | Path, data: str = "") -> Path:
    """Where :func:`run` writes a run's measurement: ``measure.json`` on its training corpus, else
    ``measure-<corpus folder>.json``."""
    return Path(run_dir) / (f"measure-{Path(data).name}.json" if data else "measure.json")


def covers(stored: dict | None, wanted: dict) -> bool:
    """Whether a stored measurement's key answers a request's: the same key, or the same but for MLP probes the
    stored measurement fit and the request skips (the MLP probes add numbers; every ridge, prediction and bound
    number is computed identically without them), so a map without MLP probes keeps, and reports, the MLP
    readouts an earlier invocation fit for some of its runs."""
    if not stored:
        return False
    if stored == wanted:
        return True
    if wanted["config"].get("mlp") or not stored.get("config", {}).get("mlp"):
        return False
    return {**stored, "config": {**stored["config"], "mlp": False}} == wanted


def read_measurement(path: Path) -> dict:
    """A measure.json as :func:`run` wrote it (a JSON object whose ``key``, when present, is one); a ConfigError
    otherwise, since the file is then not one pokeworld wrote and replacing it would destroy someone's edit."""
    prev = read_json(path, "a measurement", None, MAX_MEASUREMENT_BYTES, error=ConfigError,
                     remedy="move it aside, or pass --overwrite to replace it")
    key = prev.get("key", {}) if isinstance(prev, dict) else None
    if not isinstance(key, dict) or not isinstance(key.get("config", {}), dict):
        raise ConfigError(f"{path} is not a measurement pokeworld wrote (not a JSON object with a 'key' object); "
                          "move it aside, or pass --overwrite to replace it")
    return prev


def run(cfg: MeasureConfig) -> Path:
    """Measure ``cfg.run_dir`` and write ``measure.json`` there (skipped when up to date).

    Refused with one line before anything is computed: a run that has not finished, a store whose content is not
    the one the run was trained on (:func:`pokeworld.run_store.trained_store`), a run folder that cannot be written
    and a measure.json pokeworld did not write (:func:`read_measurement`).
    """
    run_dir = Path(cfg.run_dir)
    run_cfg = finished_run(run_dir)
    # the run's own store is found by its recorded content hash, not by its path relative to the current folder
    data = cfg.data or trained_store(run_dir, "probe")
    out = measure_path(run_dir, cfg.data)
    check_writable_dir(run_dir)  # measure.json is written there
    adopt_legacy_run(run_dir)  # a run folder from before ownership records: its measure.json stays replaceable
    cfg_key = to_dict(cfg)
    if cfg.context == CONTEXT:  # added later: left out at its default so earlier measurements stay up to date
        del cfg_key["context"]
    del cfg_key["device"], cfg_key["probe_device"]  # where states and probes were computed, not what was measured
    key = {"config": cfg_key, "data_sha256": read_manifest(data).get("content_sha256"),
           "final_mtime": finished_marker(run_dir).stat().st_mtime_ns}
    prev = earlier_measurement(out, cfg.overwrite)
    if prev is not None and not cfg.overwrite and covers(prev.get("key"), key):
        print(f"[measure] {out} is up to date; skipping")
        return out
    changed = settings_changed(prev, key)
    kept = previous_path(out)
    # both outputs refused now, not after the measurement: an earlier measure.json pokeworld did not write (a copy
    # brought in with a downloaded model) is never replaced, and nothing is kept beside it first
    check_outputs(run_dir, out.name, *([kept.name] if changed else []))
    dev = pick_device(cfg.device)
    # the weights (finite, fitting their kwargs) and the store's streams and the windows against the model, before
    # the store is read
    model = checked_model(run_dir, data, max(cfg.window, cfg.context + HORIZON),
                          f"--window {cfg.window} and --context {cfg.context} (with its {HORIZON}-step future)",
                          device=dev)
    ds = load(data)
    torch.set_num_threads(max(1, torch.get_num_threads()))
    with full_precision(dev):
        res = measure(model, ds, cfg, untrained_copy(model) if cfg.untrained else None)
    res.update(key=key, run=run_cfg, data=data)
    crash_point("measure")
    if changed:
        write_json(kept, prev)
        print(f"[measure] settings differ from those of the earlier {out} ({changed}); it is kept as {kept}")
    write_json(out, res)
    print(f"[measure] {run_dir.name}: " + summary_line(res))
    return out


def earlier_measurement(out: Path, overwrite: bool) -> dict | None:
    """The measurement already at ``out`` (None: none). One pokeworld did not write is refused
    (:func:`read_measurement`), unless --overwrite asks to replace it."""
    if not out.exists():
        return None
    try:
        return read_measurement(out)
    except ConfigError:
        if overwrite:
            return None
        raise


def previous_path(out: Path) -> Path:
    """Where an earlier measurement made with other settings is kept: ``measure.previous.json`` beside
    ``measure.json`` (``measure-<corpus>.previous.json`` beside ``measure-<corpus>.json``)."""
    return out.with_name(out.name.removesuffix(".json") + ".previous.json")


def settings_changed(prev: dict | None, key: dict) -> str:
    """The settings (fields of the measurement's config) in which ``prev`` differs from a request's ``key``, as
    ``field old → new`` (empty: the same settings, or no earlier measurement). A new corpus content or a retrained
    model is not a change of settings: the earlier numbers are then out of date, not an alternative."""
    old = (prev or {}).get("key", {}).get("config")
    if not isinstance(old, dict):
        return ""
    new = key["config"]
    diff = [f"{k} {old.get(k, '(unset)')} → {new.get(k, '(unset)')}" for k in sorted(set(old) | set(new))
            if old.get(k) != new.get(k)]
    return ", ".join(diff[:4]) + (f" and {len(diff) - 4} more" if len(diff) > 4 else "")


@contextlib.contextmanager
def full_precision(dev: torch.device):
    """fp32 convolutions and matmuls on CUDA while states are read: cuDNN's default TF32 convolutions carry ~1e-3
    relative error, so a measurement made on the GPU would not match the CPU's (its key omits the device)."""
    if dev.type != "cuda":
        yield
        return
    saved = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False
    try:
        yield
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = saved


def summary_line(res: dict) -> str:
    c = res["probes"].get("ridge", {}).get("contact", {})
    parts = [f"{k}={c[k]:+.2f}" for k in ("log_k", "log_m", "gamma", "object_pos", "object_vel", "object_rel")
             if k in c]
    leaky = res.get("probes_action_conditioned", {}).get("ridge", {}).get("contact", {})
    if "object_pos" in leaky:
        parts.append(f"object_pos(action-conditioned)={leaky['object_pos']:+.2f}")
    p = res.get("prediction", {})
    parts += [f"{k}={p[k]:.3f}" for k in ("direct16", "rollout16", "static16") if k in p]
    return " ".join(parts)


__all__ = ["MeasureConfig", "PRESETS", "READOUT", "make_config", "measure", "run", "run_preset", "training_preset",
           "previous_path", "summary_line", "untrained_copy",
           "untrained_like", "CONTEXT", "HORIZON", "KINDS", "PARAM_TARGETS", "STATE_TARGETS", "EpisodeLatents",
           "encode_episodes", "fit_predict", "fit_probes", "glide_comparison", "glide_reference", "glide_test",
           "neutral_last", "padded_actions", "prediction_quality", "probe_latents", "probe_model", "probe_targets",
           "probe_windows", "window_states", "position_decoder"]
