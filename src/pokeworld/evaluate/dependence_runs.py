"""Forecast dependence of trained runs, beside their readout: ``forecast_dependence.{json,md,png}``.

For each run: S, its episode-bootstrap interval and the forecast error per parameter
(:func:`pokeworld.evaluate.dependence.forecast_dependence` through :class:`~.forecasters.XJEPAForecaster`), on a
fresh corpus from the generator of the run's training store, and the run's own ridge readout of the same parameter
(``measure.json``, contact and glide windows) beside it. Per training store, the planted reference rows on the same
windows — the simulator itself, and the simulator ignoring or reversing each parameter — show the measurement
coming out at 1, ≈ 0 and < 0 there before any model is read.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__
from ..config import SEED, Limit, check_fields, from_preset
from ..data import load, read_manifest
from ..errors import ConfigError
from ..io import check_outputs, check_writable_dir, save_text, write_json
from ..model_inputs import checked_model
from ..rundir import read_run_config
from ..run_store import trained_store
from ..sim.generate_config import generator_config
from ..sim.replay import physics_of
from . import tables as R
from .dependence import PARAMETERS, REGRESSOR, RESPONSE, DependenceConfig, forecast_dependence, fresh_corpus
from .dependence_record import read_record
from .forecasters import PLANTS, SimulatorForecaster, XJEPAForecaster
from .measure_record import read_readout

REVISION = {
    "VFX": {"gamma": {"S": 1.04, "readout_contact": 0.12, "readout_glide": 0.50}},
    "coordinate-target": {"gamma": {"readout": 0.95, "S_sign": "negative (forecast displacement rises with drag)"}},
}
"""What the authors' revised paper reports (tantansir/latent-world-model-identifiability, docs/index.html and
README): VFX's 16-step glide displacement falls with drag at S = 1.04 although its linear drag readout is 0.12 on
contact windows (0.50 on glides); a coordinate-target model reads drag at 0.95 but forecasts displacement that rises
with drag. Paper values, shown beside ours, never used as ours."""
PARAM_READOUT = {"gamma": "gamma", "mass": "log_m", "stiffness": "log_k"}


@dataclass
class DependenceRunsConfig:
    """Measure forecast dependence (slope ratio S) of trained runs, beside their probe readout."""

    runs: tuple[str, ...] = ("runs/xjepa",)
    """Run directories written by ``pokeworld train`` (a map's or demo's ``runs/<name>``; default: where ``pokeworld
    train`` writes)."""
    out: str = "out/forecast_dependence"
    """Folder of the record (``<name>.json``, ``.md``, ``.png``)."""
    name: str = "forecast_dependence"
    """File stem of the record."""
    store: str = ""
    """A store to fit the decoders on and draw the fresh episodes from, for every run (default: each run's own
    training store, checked by content). For runs whose training store is not at hand (weights returned from a GPU):
    a store of the same generator (physics, policy, parameter ranges, episode length), which the caller vouches for;
    the record names it."""
    environment: str = ""
    """What the record calls the environment the runs were trained on (e.g. the corpus and simulator); default: the
    environment each store's manifest names."""
    eval_episodes: int = 2400
    """Fresh evaluation episodes simulated from each training store's generator."""
    eval_seed: int = 1000
    """Seed of the evaluation episodes (the store's own seed would repeat its episodes)."""
    bootstrap: int = 1000
    """Episode-bootstrap resamples of S."""
    max_windows: int = 3000
    """Cap on windows per response."""
    seed: int = 0
    """Seed of the decoders' subsample, the window subsample and the bootstrap."""
    merge: tuple[str, ...] = ()
    """Earlier records (``<name>.json`` of this command, same settings and store) whose runs join this
    record's, so runs measured at different times make one table; a run measured here replaces its earlier row."""

    LIMITS = {"eval_episodes": Limit(20, 10**6), "eval_seed": SEED, "bootstrap": Limit(10, 10**5),
              "max_windows": Limit(10, 10**7), "seed": SEED}

    def __post_init__(self) -> None:
        check_fields(self)


PRESETS = {"tiny": {"eval_episodes": 200, "bootstrap": 50, "max_windows": 300}, "cpu": {}, "paper": {}}


def make_config(preset: str = "cpu", **overrides) -> DependenceRunsConfig:
    return from_preset(DependenceRunsConfig, PRESETS, preset, **overrides)


def _readout(run_dir: Path) -> dict:
    """The run's ridge R² per parameter on contact and glide windows (None where not measured), its measure.json
    checked (:func:`~pokeworld.evaluate.measure_record.read_readout`)."""
    ridge = (read_readout(Path(run_dir) / "measure.json") or {}).get("ridge", {})
    return {p: {kind: ridge.get(kind, {}).get(q) for kind in ("contact", "glide")} for p, q in PARAM_READOUT.items()}


def planted_rows(ds, cfg: DependenceConfig) -> dict:
    """S of the simulator and of its planted corruptions, per parameter, on ``ds``'s windows."""
    physics, eps = physics_of(ds.manifest), np.arange(ds.num_episodes)
    return {plant: {p: forecast_dependence(SimulatorForecaster(physics, p, plant), ds, eps, cfg, (p,))[p]
                    for p in PARAMETERS} for plant in PLANTS}


def checked_forecaster_model(run_dir: str | Path, store: str, cfg: DependenceConfig):
    """The run's model, read and held against what the measurement feeds it before any work
    (:func:`pokeworld.model_inputs.checked_model`: finite weights, the store's streams, the context and its
    ``horizon``-step future within its max_len, its Δ=horizon head) and a latent objective (a reconstruction model
    has no latent forecast)."""
    model = checked_model(run_dir, store, cfg.context + cfg.horizon,
                          f"the context ({cfg.context}) and its {cfg.horizon}-step future", horizons=(cfg.horizon,),
                          remedy="its forecasts cannot be measured on these windows")
    if model.objective == "recon":
        raise ConfigError(f"{run_dir}: a reconstruction-objective model has no latent forecast heads to measure")
    return model


def measure_run(run_dir: Path, fresh, store, cfg: DependenceConfig, seed: int, model=None,
                readout: dict | None = None) -> dict:
    """One run's forecast dependence on ``fresh`` (decoders fit on its training ``store``) and its readout
    (``model`` and ``readout`` as already read; default: read here)."""
    model = model if model is not None else checked_model(run_dir, store)
    rc = read_run_config(run_dir) or {}
    forecaster = XJEPAForecaster(model, store, seed=seed)
    return {"run": str(run_dir), "variant": rc.get("variant", model.variant), "seed": rc.get("seed"),
            "steps": rc.get("steps"), "dependence": forecast_dependence(forecaster, fresh, np.arange(fresh.num_episodes),
                                                                       cfg),
            "readout": readout if readout is not None else _readout(run_dir)}


def stores_environment(stores: dict, earlier: list[dict]) -> str:
    """What a record calls its environment when ``--environment`` names none: the one each store's manifest names
    (``reference PokeWorld (the store's manifest)``), each store's when they differ; else the ``earlier`` merged
    records' own, when they agree; "" when nothing says."""
    named = {path: generator_config(store.manifest, f"{path}'s manifest").environment
             for path, store in stores.items()}
    if len(set(named.values())) == 1:
        where = "the store's manifest" if len(named) == 1 else f"the manifests of its {len(named)} stores"
        return f"{next(iter(named.values()))} PokeWorld ({where})"
    if named:
        return "; ".join(f"{env} PokeWorld ({path})" for path, env in named.items())
    merged = {rec.get("environment", "") for rec in earlier}
    return merged.pop() if len(merged) == 1 else ""


SETTINGS = ("store", "eval_episodes", "eval_seed", "bootstrap", "max_windows", "seed")
"""The config fields a record's numbers depend on (besides its runs): records merge only when these agree."""


def store_sha256(cfg: DependenceRunsConfig) -> str | None:
    """The content hash of ``cfg.store`` (its manifest's), which names the store in the record; None without one."""
    return read_manifest(cfg.store).get("content_sha256") if cfg.store else None


def merged_records(cfg: DependenceRunsConfig) -> list[dict]:
    """The ``merge`` records, every field read and checked (:func:`~.dependence_record.read_record`, same settings
    as ``cfg``, the same store by content hash) before anything is measured."""
    sha = store_sha256(cfg)
    return [read_record(path, {k: getattr(cfg, k) for k in SETTINGS}, sha) for path in cfg.merge]


def same_store_named(rec: dict, store: str) -> dict:
    """A merged record (of this measurement's store: :func:`merged_records`) with that store named as this
    measurement names it, in its rows and its planted rows: a committed record names it by a placeholder (or by the
    path of the machine it was made on), and one store must not read as two. A record of one store (its config
    names it) holds only that store's rows and planted rows, so every one of them is renamed."""
    if not store or rec["config"].get("store") == store:
        return rec
    planted = {store: v for v in (rec.get("planted") or {}).values()}
    rows = [{**row, "store": store} for row in rec["runs"]]
    return {**rec, "planted": planted, "runs": rows, "config": {**rec["config"], "store": store}}


def run(cfg: DependenceRunsConfig) -> Path:
    if not cfg.runs and not cfg.merge:
        raise ConfigError("give at least one trained run directory with --runs (or records to join with --merge)")
    # every input first: the earlier records, each run's store, model and readout; then the outputs
    earlier = [same_store_named(rec, cfg.store) for rec in merged_records(cfg)]
    stores = {str(r): cfg.store or trained_store(r, "[forecast-dependence]") for r in cfg.runs}
    dep = DependenceConfig(bootstrap=cfg.bootstrap, max_windows=cfg.max_windows, seed=cfg.seed)
    models = {str(r): checked_forecaster_model(r, stores[str(r)], dep) for r in cfg.runs}
    measured = {str(Path(r)) for r in cfg.runs}
    joined = []
    for rec in earlier:  # in the order given, then this invocation's runs
        joined += [row for row in rec["runs"] if row["run"] not in measured and row not in joined]
    # a run probed after its dependence was measured gets its readout now
    readouts = {row["run"]: _readout(Path(row["run"])) for row in joined if Path(row["run"], "measure.json").is_file()}
    readouts |= {str(Path(r)): _readout(Path(r)) for r in cfg.runs}
    out = Path(cfg.out)
    check_writable_dir(out.parent)
    check_outputs(out, *(f"{cfg.name}.{ext}" for ext in ("json", "md", "png", "pdf")))
    # the first result line comes only after a store's fresh episodes and planted rows: say what is coming
    print(f"[forecast-dependence] plan: {len(set(stores.values()))} store(s) x {cfg.eval_episodes} fresh episodes "
          f"and the planted rows, then {len(cfg.runs)} run(s) ({cfg.bootstrap} bootstrap resamples each); a line "
          "as each finishes", flush=True)
    loaded, rows, refs = {}, [], {}
    for r in cfg.runs:
        path = stores[str(r)]
        if path not in loaded:
            store = load(path)
            loaded[path] = (store, fresh_corpus(store, cfg.eval_episodes, cfg.eval_seed))
            refs[path] = planted_rows(loaded[path][1], dep)
            print(f"[forecast-dependence] {path}: {cfg.eval_episodes} fresh episodes; planted rows done")
        store, fresh = loaded[path]
        rows.append({**measure_run(Path(r), fresh, store, dep, cfg.seed, models.pop(str(r)),
                                   readouts[str(Path(r))]), "store": path})
        print(f"[forecast-dependence] {r}: " + ", ".join(
            f"{p} S {v['S']:+.2f}" for p, v in rows[-1]["dependence"].items() if "S" in v))
    for rec in earlier:
        refs = {**(rec.get("planted") or {}), **refs}
    rows = [{**row, "readout": readouts.get(row["run"], row["readout"])} for row in joined] + rows
    environment = cfg.environment or stores_environment({path: store for path, (store, _) in loaded.items()},
                                                        earlier)
    config = {k: getattr(cfg, k) for k in SETTINGS} | {"store_sha256": store_sha256(cfg)}
    result = {"environment": environment, "config": config, "responses": RESPONSE,
              "regressors": REGRESSOR, "runs": rows, "planted": refs, "revision": REVISION,
              "provenance": {"pokeworld": __version__, "git": R.git_commit()}}
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / f"{cfg.name}.json", result)
    save_text(out / f"{cfg.name}.md", markdown(result))
    figure(result, out / f"{cfg.name}.png")
    print(f"[forecast-dependence] wrote {out / cfg.name}.json, .md, .png")
    return out


def _cell(v: dict) -> str:
    if "S" not in v:
        return f"— ({v.get('note', 'not measured')})"
    lo, hi = v["S_interval"]
    return f"{v['S']:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def _label(row: dict) -> str:
    return f"{row['variant']} s{row['seed']} ({row['steps']} steps)"


def _r2(x) -> str:
    return "—" if x is None else f"{x:+.2f}"


def markdown(result: dict) -> str:
    """Readout and S side by side per run and parameter; the planted rows; the revision's values."""
    lines = ["# Forecast dependence (slope ratio S) beside readout", "",
             f"Environment: {result['environment'] or 'not named'}. pokeworld {result['provenance']['pokeworld']}, "
             f"git {result['provenance']['git']}. S = the model's partial slope of its forecast response on the "
             "parameter / the simulator's, context state and the other parameters controlled (docs/design.md, "
             "\"Forecast dependence\"); [95 % episode-bootstrap interval]. Readout: the run's ridge R² of the "
             "parameter (contact / glide windows, measure.json). Error: the forecast's mean error on the same "
             "windows (arena units; the store's touch units for stiffness).", ""]
    for p in PARAMETERS:
        lines += [f"## {p}: {result['responses'][p]}; regressed on {result['regressors'][p]}", "",
                  "| run | readout contact / glide | S [95 %] | slope model / simulator | error | windows (episodes) |",
                  "|---|---|---|---|---|---|"]
        for row in result["runs"]:
            v, rd = row["dependence"][p], row["readout"][p]
            slopes = f"{v['slope_model']:+.4f} / {v['slope_simulator']:+.4f}" if "S" in v else "—"
            err = f"{v['forecast_error']:.3f}" if "forecast_error" in v else "—"
            lines.append(f"| {_label(row)} | {_r2(rd['contact'])} / {_r2(rd['glide'])} | {_cell(v)} "
                         f"| {slopes} | {err} | {v.get('windows', 0)} ({v.get('episodes', '—')}) |")
        for store, ref in result["planted"].items():
            lines.append(f"| *planted, {Path(store).name}:* simulator / ignores {p} / reverses {p} | — | "
                         f"{_cell(ref['true'][p])} / {_cell(ref['ignore'][p])} / {_cell(ref['reverse'][p])} | | | |")
        lines.append("")
    lines += ["## The revision's reported values (paper, not ours)", "",
              "| model | parameter | S | readout |", "|---|---|---|---|",
              "| VFX | drag (γ), pure glides | +1.04 | 0.12 contact / 0.50 glides |",
              "| coordinate-target model | drag (γ) | negative: displacement rises with drag | 0.95 |", ""]
    return "\n".join(lines)


def figure(result: dict, path: Path) -> Path:
    """S with its interval per run and parameter (left axis per parameter), the readout beside it; one legend for
    the three panels, below them, where it hides no point."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io import save_figure

    fig, axes = plt.subplots(1, len(PARAMETERS), figsize=(4.2 * len(PARAMETERS), 4.3), sharey=False)
    legend: dict[str, object] = {}  # label -> the first artist drawn with it, in any panel
    for ax, p in zip(np.atleast_1d(axes), PARAMETERS):
        names = [_label(r) for r in result["runs"]]
        for i, r in enumerate(result["runs"]):
            v = r["dependence"][p]
            if "S" in v:
                # the interval drawn as it is, not as error bars around S: a ratio's percentile bootstrap need not
                # contain its full-sample value (few windows, a slope near zero), and error bars cannot be negative
                lo, hi = v["S_interval"]
                ax.vlines(i - 0.12, lo, hi, color="C0", lw=1.5)
                legend.setdefault("S [95 % episode bootstrap]", ax.plot(i - 0.12, v["S"], "o", color="C0")[0])
            reported = REVISION.get(r["variant"], {}).get(p, {}).get("S")
            if reported is not None:
                legend.setdefault(f"revision's {r['variant']} S (paper, not ours)",
                                  ax.plot(i - 0.12, reported, "*", color="grey", ms=10)[0])
            rd = r["readout"][p]["contact"]
            if rd is not None:
                legend.setdefault("readout R² (contact)", ax.plot(i + 0.12, rd, "s", color="C1")[0])
        ax.axhline(1.0, color="grey", lw=0.8, ls="--")
        ax.axhline(0.0, color="grey", lw=0.8)
        ax.set_xticks(range(len(names)), names, rotation=30, fontsize=8)
        ax.set_title(f"{p}: S and readout", fontsize=9)
        ax.set_ylabel("S (1 = the simulator's dependence) / R²")
    title = f"Forecast dependence beside readout ({result['environment'] or 'environment not named'})"
    fig.suptitle("\n".join(textwrap.wrap(title, 200)), fontsize=8)
    fig.tight_layout(rect=(0, 0.07, 1, 1))  # the bottom strip holds the legend
    if legend:  # a record whose runs have no S and no readout draws no legend rather than an empty one
        fig.legend(list(legend.values()), list(legend), loc="lower center", ncol=len(legend), fontsize=7,
                   frameon=False)
    save_figure(fig, path.parent, path.stem, dpi=130)
    return path


__all__ = ["DependenceRunsConfig", "PRESETS", "REVISION", "SETTINGS", "make_config", "markdown", "measure_run",
           "merged_records", "same_store_named", "store_sha256", "planted_rows", "run", "stores_environment", "figure"]
