"""The belief-state test: objective (latent vs. the episode-level-latent ELBO) × history length on the VFX trunk
(docs/model.md "The belief objective")."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..config import from_preset
from ..evaluate.tables import dagger, fmt, gate_failed, probe, run_gate_failed
from ..train.config import PRESETS as TRAIN_PRESETS, TrainConfig
from .runs import RunSpec, spec

if TYPE_CHECKING:
    from .config import MapConfig

NAME = "belief"


#: Whole-episode training window (64 control steps -> 65 observations) of the belief experiment's
#: long-history runs, and how they are measured: every probe / prediction window is an episode prefix
#: (stride past the episode end), the only windows whole-episode training ever shows the model, with 48
#: observations of history at the probed state and before the 16-step predictions.
LONG_WINDOW = 65

LONG_MEASURE = {"window": 48, "stride": 64, "context": 48}

def long_batch_size(preset: str, batch_size: int = 0) -> int:
    """Whole-episode batch size that keeps the frames per step of the standard runs (``batch_size``, 0 = the
    preset's; cpu: 32 × 24 -> 12 × 65): the long-history runs then differ from the standard ones in history
    length only, not in compute or in frames seen (docs/design.md, "The belief experiment")."""
    t = from_preset(TrainConfig, TRAIN_PRESETS, preset)
    return max(2, round((batch_size or t.batch_size) * t.window / LONG_WINDOW))


def specs(c: MapConfig) -> list[RunSpec]:
    """Objective × history length on the VFX trunk, every seed: latent (the factorial's VFX run) and belief
    objectives, each on the standard windows and on whole episodes at equal frames per step (docs/model.md
    "belief"), beside the system-ID head (the controls' run): what a supervised readout of the same trunk reaches."""
    lam, runs = c.sigreg_weight, []
    for s in c.seeds:
        if "window" in c.belief_histories:
            runs += [spec("belief", "VFX", s, lam), spec("belief", "VFX", s, lam, objective="belief")]
        if "episode" in c.belief_histories:
            long = dict(measure=LONG_MEASURE, window=LONG_WINDOW,
                        batch_size=long_batch_size(c.train_preset or c.preset, c.train_batch_size))
            runs += [spec("belief", "VFX", s, lam, **long), spec("belief", "VFX", s, lam, objective="belief", **long)]
    return runs + [spec("controls", "VFX", c.seeds[0], lam, sysid_weight=0.5)]


def belief_label(run: dict) -> str:
    """Row label of a belief-experiment run: variant, objective and training history."""
    t = run["train"]
    w = t.get("window")
    hist = "standard windows" if w is None else "whole episodes" if w >= 65 else f"{w}-observation windows"
    sysid = " + system-ID head (supervised)" if t.get("sysid_weight", 0) > 0 else ""
    return f"{t['variant']} {t.get('objective', 'latent')}{sysid}, {hist}, seed {t.get('seed', 0)}"

def belief_table(results: dict) -> list[str]:
    """Objective × history length: does an episode-level latent (ELBO) escape conditional-mean collapse?"""
    if "belief" not in results["experiments"]:
        return []
    names = results["experiments"]["belief"]
    g = dagger(gate_failed(results, "gamma"))
    lines = ["## Belief objective: an optimum that is not a conditional mean (VFX trunk)", "",
             "Same trunk, data, probes and optimizer; the objective (latent MSE vs. the belief ELBO: amortised "
             "posterior over the window, learned causal prior, KL) and the training history (standard windows vs. "
             "whole episodes) change. Every probe reads the causal state (for the belief objective the trunk state "
             "conditioned on the prior mean); whole-episode runs are probed on episode prefixes with 48 observations "
             "of history (the standard runs on 16-observation windows), so compare objectives within a history.", "",
             "| run | γ ridge contact | γ ridge glide | γ MLP contact | γ MLP glide | log k | log m | position | "
             "velocity | direct-16 | glide test: model / median-γ / static (uses γ) |",
             "|" + "---|" * 11]
    for n in names:
        r = results["runs"][n]
        gt = r["prediction"].get("glide_test", {})
        glide = (f"{fmt(gt.get('model'), 3)} / {fmt(gt.get('median_gamma'), 3)} / {fmt(gt.get('static'), 3)} "
                 f"({'yes' if gt.get('uses_gamma') else 'no'}){g}") if "model" in gt else "—"
        cells = [fmt(probe(r, "gamma", k, f)) + g for f in ("ridge", "mlp") for k in ("contact", "glide")]
        cells += [fmt(probe(r, q)) + dagger(run_gate_failed(results, r, q)) for q in ("log_k", "log_m")]
        cells += [fmt(probe(r, q)) for q in ("object_pos", "object_vel")]
        cells += [fmt(r["prediction"].get("direct16"), 3), glide]
        lines.append(f"| {belief_label(r)} | " + " | ".join(cells) + " |")
    std = results["certificates"].get("standard", {}).get("certificate", {})

    def cc(q: str, kind: str) -> str:  # the corpus's certificate cell: R² (best estimator)
        c = std.get(kind, {}).get(q, {})
        return f"{fmt(c['r2'])} ({c['estimator']})" if c.get("r2") is not None else "—"

    lines.append(f"| certificate (best estimator) | {cc('gamma', 'contact')} | {cc('gamma', 'glide')} | — | — | "
                 f"{cc('log_k', 'contact')} | {cc('log_m', 'contact')} | — | — | — | — |")
    rows = []
    for n in names:
        pb = results["runs"][n].get("probes_belief", {})
        if not pb:
            continue
        pr = lambda which, q, k: fmt(pb.get(f"{which}_mean", {}).get("ridge", {}).get(k, {}).get(q))  # noqa: E731
        rows.append(f"| {belief_label(results['runs'][n])} | {pr('prior', 'gamma', 'contact')}{g} | "
                    f"{pr('prior', 'gamma', 'glide')}{g} | {pr('prior', 'log_k', 'contact')} | "
                    f"{pr('posterior', 'gamma', 'contact')}{g} | {pr('posterior', 'gamma', 'glide')}{g} | "
                    f"{pr('posterior', 'log_k', 'contact')} |")
    if rows:
        lines += ["", "The episode-level latent itself (ridge R²). Both read the same evidence, the probe window, which "
                  "ends at the probed observation: the prior mean from the causal trunk state, the posterior mean "
                  "from the window's transitions (the encoder that, in training, also sees later steps). Posterior "
                  "high, prior low: the latent can encode the parameter from this history but the causal prior "
                  "does not extract it; both low: the latent never encodes it, so prediction never paid for it.", "",
                  "| run | γ prior contact | γ prior glide | log k prior | γ posterior contact | "
                  "γ posterior glide | log k posterior |", "|---|---|---|---|---|---|---|", *rows]
    return lines + [""]


section = belief_table


__all__ = ['NAME', 'LONG_WINDOW', 'LONG_MEASURE', 'long_batch_size', 'specs', 'section', 'belief_table', 'belief_label']
