"""The paper's central comparison on an swm environment: does a state *target* put a factor in the latent where the
state *input* does not? (``pokeworld swm-certify ENV --factors ... --variants V VF VX VFX``)

PokeWorld's X-JEPA factorial varies where proprio and touch enter the model. On an swm corpus
(:mod:`pokeworld.swm.factors`) the environment's low-dimensional observation (Cartpole's 5-d state, Finger's 12-d)
takes the proprio role and touch is absent (a stream of width 0 is neither read nor forecast, :class:`XJEPA`), so

=======  ==========================  =============================================
variant  the state is                inputs -> targets
=======  ==========================  =============================================
V        absent                      vision -> latent
VF       an input only               vision + state -> latent
VX       a forecasting target only   vision -> latent + state (Δ-step forecasts)
VFX      both                        vision + state -> latent + state
=======  ==========================  =============================================

Everything else is the PokeWorld recipe (:mod:`pokeworld.train` at the chosen preset: SIGReg, the Δ = 1, 4, 16
heads where the episode is long enough, vision always in). Each variant is trained on the corpus's train episodes,
written once as a pokeworld store beside the corpus (``xjepa/data``, checked by content hash), and probed through
:func:`pokeworld.protocol.certify_model` with the factor certificates the LeWM is gated by, its untrained twin
(:func:`pokeworld.evaluate.measure.untrained_copy`) as the bound. Every claim stays gated per factor.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .. import data as data_mod, protocol as P
from ..config import config_error
from ..data import Dataset
from ..errors import ConfigError
from ..evaluate.measure import untrained_copy
from ..rundir import load_model, read_metrics
from ..train import config as TC
from ..train.single import run as train_run
from .factor_report import factor_rows, fmt

SWM_VARIANTS = ("V", "VF", "VX", "VFX")
STATE_ROLE = {"V": "absent", "VF": "input only", "VX": "target only", "VFX": "input and target"}
SUBDIR = "xjepa"
STATUS_EVERY = 30.0
"""Seconds between a training's status lines (its progress bar is off inside this command)."""


def check_variants(variants: tuple[str, ...]) -> None:
    bad = [v for v in variants if v not in SWM_VARIANTS]
    if bad or len(set(variants)) != len(variants):
        raise config_error(f"--variants takes distinct names from {list(SWM_VARIANTS)} (the state absent, input, "
                          f"target, both), got {list(variants)}")


def train_config(ds: Dataset, store: Path, out: Path, variant: str, seed: int, preset: str,
                 steps: int) -> TC.TrainConfig:
    """The preset's TrainConfig fitted to the corpus: window ≤ the episode, horizons below it, frames not upsampled."""
    base = TC.make_config(preset)
    side, T1 = int(ds.frames.shape[-1]), ds.num_steps + 1
    if side < 16:
        raise ConfigError(f"X-JEPA reads frames of at least 16 px; this corpus's are {side} px (collect with "
                          "--image-size 16 or more)")
    window = min(base.window, T1)
    horizons = tuple(h for h in base.horizons if h < window)
    return TC.make_config(preset, variant=variant, seed=seed, data=str(store), out=str(out), window=window,
                          horizons=horizons, image_size=min(base.image_size, side), progress=False,
                          **({"steps": steps} if steps else {}))


def ensure_store(ds: Dataset, folder: Path, digest: str) -> Path:
    """The corpus as a pokeworld store at ``folder``, written unless one with the same content is there."""
    if data_mod.is_complete(folder) and data_mod.read_manifest(folder).get("content_sha256") == digest:
        return folder
    return data_mod.save(ds, folder)


def run_variant(ds: Dataset, certs: dict, pcfg: P.ProtocolConfig, cfg: TC.TrainConfig, out: Path) -> dict:
    """Train (or resume, or reuse) one variant and probe it with the factor certificates; its record."""
    t0 = time.time()
    run_dir = train_run(cfg, status_every=STATUS_EVERY)
    train_s = time.time() - t0
    model = load_model(run_dir).eval()
    t0 = time.time()
    report = P.certify_model(model.features, ds, out, untrained=untrained_copy(model).features,
                             certificates=certs, name=f"X-JEPA {cfg.variant}", config=pcfg)
    last = read_metrics(run_dir)[-1:]
    return {"run": str(run_dir), "factors": factor_rows(report, certs), "train_s": round(train_s, 1),
            "protocol_s": round(time.time() - t0, 1), "steps": cfg.steps, "last_training_row": last}


def run_factorial(ds: Dataset, certs: dict, pcfg: P.ProtocolConfig, out: Path, digest: str,
                  variants: tuple[str, ...], seeds: tuple[int, ...], preset: str, steps: int) -> dict:
    """Every variant at every seed: ``{"variants": {V: {seed: record}}, "summary": per factor and variant}``."""
    check_variants(variants)
    root = Path(out) / SUBDIR
    store = ensure_store(ds, root / "data", digest)
    runs: dict[str, dict[str, dict]] = {v: {} for v in variants}
    total = len(variants) * len(seeds)
    for i, (seed, v) in enumerate((s, v) for s in seeds for v in variants):
        cfg = train_config(ds, store, root / "runs" / f"{v}-s{seed}", v, seed, preset, steps)
        print(f"[swm-certify] X-JEPA {v} (state {STATE_ROLE[v]}), seed {seed}: run {i + 1} of {total}, "
              f"{cfg.steps} steps at {preset}", flush=True)
        runs[v][str(seed)] = run_variant(ds, certs, pcfg, cfg, root / "protocol" / f"{v}-s{seed}")
    first = next(iter(next(iter(runs.values())).values()))["factors"]
    return {"variants": runs, "summary": summary(runs, first), "state_role": {v: STATE_ROLE[v] for v in variants},
            "preset": preset, "seeds": list(seeds)}


def _mean(values: list) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def summary(runs: dict[str, dict[str, dict]], gate_rows: dict[str, dict]) -> dict[str, dict]:
    """Per factor: the gate, and per variant the ridge / MLP / untrained R² (mean and per seed); with VX, V, VFX and
    VF present, the target effects VX − V and VFX − VF and the input effect VF − V (ridge means)."""
    out = {}
    for q, g in gate_rows.items():
        per = {}
        for v, seeds in runs.items():
            rows = [r["factors"][q] for r in seeds.values()]
            per[v] = {k: _mean([r[k] for r in rows]) for k in ("ridge", "mlp", "untrained")}
            per[v]["per_seed"] = {s: {k: r["factors"][q][k] for k in ("ridge", "mlp", "untrained")}
                                  for s, r in seeds.items()}
        ridge = {v: per[v]["ridge"] for v in per}
        effects = {}
        for name, (a, b) in {"target_without_input": ("VX", "V"), "target_with_input": ("VFX", "VF"),
                             "input_without_target": ("VF", "V")}.items():
            if ridge.get(a) is not None and ridge.get(b) is not None:
                effects[name] = ridge[a] - ridge[b]
        out[q] = {"certificate": g["certificate"], "threshold": g["threshold"], "gate_passed": g["gate_passed"],
                  "variants": per, "effects_ridge": effects}
    return out


def table_markdown(summary_rows: dict[str, dict], variants: tuple[str, ...]) -> list[str]:
    """factor | certificate | gate | per variant ridge / MLP (untrained) | target effects."""
    head = " | ".join(f"{v} ({STATE_ROLE[v]})" for v in variants)
    lines = [f"| factor | certificate | gate | {head} | VX − V / VFX − VF (ridge) |",
             "|---|---|---|" + "---|" * len(variants) + "---|"]
    for q, r in summary_rows.items():
        mark = "" if r["gate_passed"] else "†"
        cells = [f"{fmt(r['variants'][v]['ridge'])}{mark} / {fmt(r['variants'][v]['mlp'])}{mark} "
                 f"({fmt(r['variants'][v]['untrained'])})" for v in variants]
        e = r["effects_ridge"]
        effects = (f"{fmt(e.get('target_without_input'))} / {fmt(e.get('target_with_input'))}"
                   if r["gate_passed"] else "no claim")
        verdict = "PASS" if r["gate_passed"] else "FAIL"
        lines.append(f"| {q} | {fmt(r['certificate'])} | {verdict} (≥ {r['threshold']:.2f}) | "
                     + " | ".join(cells) + f" | {effects} |")
    return lines


def figure(summary_rows: dict[str, dict], variants: tuple[str, ...], title: str, path: Path) -> Path:
    """Bars per factor and variant (ridge solid, MLP open), untrained twins as ticks, the certificate dashed; a
    factor whose gate failed is hatched and marked "no claim"."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io import save_figure_as

    colors = {"V": "tab:gray", "VF": "tab:green", "VX": "tab:orange", "VFX": "tab:blue"}
    qs = list(summary_rows)
    fig, ax = plt.subplots(figsize=(2.2 * len(qs) + 3.0, 3.8))
    width, x = 0.8 / len(variants), np.arange(len(qs))
    for i, v in enumerate(variants):
        for j, q in enumerate(qs):
            r = summary_rows[q]
            cell, pos = r["variants"][v], x[j] + (i - (len(variants) - 1) / 2) * width
            hatch = "" if r["gate_passed"] else "//"
            if cell["ridge"] is not None:
                ax.bar(pos, np.clip(cell["ridge"], -0.1, 1.0), width, color=colors[v], hatch=hatch,
                       edgecolor="black" if hatch else colors[v],
                       label=f"{v} ({STATE_ROLE[v]}) ridge" if j == 0 else None)
            if cell["mlp"] is not None:
                ax.plot(pos, np.clip(cell["mlp"], -0.1, 1.0), marker="o", mfc="white", mec=colors[v], ls="",
                        label="MLP (open circle)" if i == 0 and j == 0 else None)
            if cell["untrained"] is not None:
                ax.plot([pos - width / 2, pos + width / 2], [np.clip(cell["untrained"], -0.1, 1.0)] * 2,
                        color="black", lw=1.5, label="untrained twin (tick)" if i == 0 and j == 0 else None)
    for j, q in enumerate(qs):
        r = summary_rows[q]
        if r["certificate"] is not None:
            ax.plot([x[j] - 0.45, x[j] + 0.45], [np.clip(r["certificate"], -0.1, 1.0)] * 2, color="red", lw=1,
                    ls="--", label="certificate (raw state)" if j == 0 else None)
        if not r["gate_passed"]:
            ax.text(x[j], 1.03, "gate ✗: no claim", ha="center", fontsize=8, color="red")
    ax.axhline(0, color="black", lw=0.5)
    ax.set_xticks(x, qs, fontsize=8)
    ax.set_ylim(-0.1, 1.12)
    ax.set_ylabel("held-out R² of the predictor state")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    save_figure_as(fig, [path])  # atomically, then closed
    return path


__all__ = ["STATE_ROLE", "SWM_VARIANTS", "check_variants", "ensure_store", "figure", "run_factorial", "run_variant",
           "summary", "table_markdown", "train_config"]
