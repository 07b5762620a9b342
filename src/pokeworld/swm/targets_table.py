"""Targets, not inputs, across environments: the ``swm-certify --variants V VF VX VFX`` records of several swm
environments side by side (``pokeworld swm-targets --records A/swm_certify.json B/swm_certify.json --out PREFIX``).

Per environment and factor: the certificate and its gate, each variant's predictor-state R² (ridge / MLP, the
untrained twin's ridge; mean over seeds), the three effects (ridge) — target without input VX − V, target with
input VFX − VF, input without target VF − V — with their per-seed values, and a verdict on which of the two carries
the factor. Writes ``PREFIX.json``, ``PREFIX.md`` and ``PREFIX.png`` (the effects per certified factor, seeds as
dots). Reads only records (JSON); trains nothing.

The verdict (a choice the paper leaves open, docs/design.md): an effect *carries* the factor when its mean over
seeds is at least :data:`MARGIN` and every seed's is positive. *target*: a target effect carries it and the input
effect does not; *input*: the input effect carries it and neither target effect does; *both*; where neither role
of the state matters, *vision alone* when V already holds the factor (its R² over its untrained twin's carries it
by the same rule: the latent's own forecasting target needs it), else *neither*. A factor
whose gate failed gets no verdict ("no claim"), and "(inert)" is added where the record's factor-effect check found
that the factor changes no observation at all.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError, DataError
from ..io import atomic_path, check_replaceable, read_json, save_text, write_json
from .factor_report import fmt
from .factorial import STATE_ROLE, SWM_VARIANTS

MARGIN = 0.10
"""Smallest mean ridge-R² effect (over seeds) that counts as carrying a factor."""

EFFECTS = {"target_without_input": ("VX", "V"), "target_with_input": ("VFX", "VF"),
           "input_without_target": ("VF", "V")}
"""Each effect as (variant with, variant without) the stream's role."""


@dataclass
class TargetsConfig:
    """Which factorial records to put side by side, and where."""

    records: tuple[str, ...] = ("out/swm/certify/swm_certify.json",)
    """``swm_certify.json`` records of ``pokeworld swm-certify ENV ... --variants V VF VX VFX`` (one per
    environment)."""
    out: str = "out/swm/targets"
    """Output prefix: writes PREFIX.json, PREFIX.md and PREFIX.png."""


def make_config(preset: str = "cpu") -> TargetsConfig:
    """Defaults (the command has no presets: it only reads records)."""
    return TargetsConfig()


def load_factorial(path: str | Path) -> dict:
    """One swm-certify record with its factorial, or one line saying what is missing."""
    rec = read_json(path, "an swm-certify record (swm_certify.json)",
                    remedy="pass the swm_certify.json that pokeworld swm-certify wrote")
    xj = rec.get("xjepa")
    if not isinstance(xj, dict) or not isinstance(xj.get("summary"), dict) or not isinstance(xj.get("variants"),
                                                                                                dict):
        raise DataError(f"{path} holds no X-JEPA factorial; run pokeworld swm-certify ENV --factors ... --variants "
                        f"{' '.join(SWM_VARIANTS)} and pass its swm_certify.json")
    missing = [v for v in SWM_VARIANTS if v not in xj["variants"]]
    if missing:
        raise DataError(f"{path}: the factorial lacks variants {missing}; rerun swm-certify with --variants "
                        f"{' '.join(SWM_VARIANTS)} (finished variants are reused)")
    return rec


def effect_per_seed(cells: dict[str, dict], a: str, b: str) -> dict[str, float]:
    """Ridge R² of variant ``a`` minus ``b`` for every seed both were run at."""
    sa, sb = cells[a].get("per_seed", {}), cells[b].get("per_seed", {})
    return {s: float(sa[s]["ridge"] - sb[s]["ridge"]) for s in sorted(set(sa) & set(sb))
            if sa[s].get("ridge") is not None and sb[s].get("ridge") is not None}


def carries(per_seed: dict[str, float], margin: float = MARGIN) -> bool:
    """The effect carries the factor: mean ≥ margin and positive at every seed."""
    vals = list(per_seed.values())
    return bool(vals) and float(np.mean(vals)) >= margin and min(vals) > 0


def verdict(effects: dict[str, dict[str, float]], gate_passed: bool, vision_gain: dict[str, float] | None = None,
            margin: float = MARGIN) -> str:
    """``target``, ``input``, ``both``, ``vision alone``, ``neither`` or ``no claim`` (see the module);
    ``vision_gain``: V's ridge R² over its untrained twin's, per seed."""
    if not gate_passed:
        return "no claim"
    target = any(carries(effects.get(k, {}), margin) for k in ("target_without_input", "target_with_input"))
    inp = carries(effects.get("input_without_target", {}), margin)
    word = {(True, False): "target", (False, True): "input", (True, True): "both"}.get((target, inp), "neither")
    return "vision alone" if word == "neither" and carries(vision_gain or {}, margin) else word


def factor_row(env: str, factor: str, row: dict, inert: bool | None = None) -> dict:
    """One (environment, factor) row of the table from a record's factorial summary row; ``inert``: the record's
    factor-effect check found the factor changes no observation (:mod:`pokeworld.swm.factor_effect`)."""
    cells = row["variants"]
    per_seed = {name: effect_per_seed(cells, a, b) for name, (a, b) in EFFECTS.items()}
    vision_gain = {s: float(c["ridge"] - c["untrained"]) for s, c in cells["V"].get("per_seed", {}).items()
                   if c.get("ridge") is not None and c.get("untrained") is not None}
    return {"env": env, "factor": factor, "certificate": row["certificate"], "threshold": row["threshold"],
            "gate_passed": bool(row["gate_passed"]),
            "variants": {v: {k: cells[v].get(k) for k in ("ridge", "mlp", "untrained")} for v in SWM_VARIANTS},
            "effects_ridge": {k: (float(np.mean(list(v.values()))) if v else None) for k, v in per_seed.items()},
            "effects_per_seed": per_seed, "inert": inert,
            "vision_gain_per_seed": vision_gain,
            "verdict": verdict(per_seed, bool(row["gate_passed"]), vision_gain) + (" (inert)" if inert else "")}


def summarise(records: dict[str, dict]) -> dict:
    """``{path: record}`` → the side-by-side table (rows), each environment's command and training, the verdicts."""
    rows, envs = [], []
    for path, rec in records.items():
        env = rec.get("env") or rec.get("source") or path
        xj = rec["xjepa"]
        runs = [r for per in xj["variants"].values() for r in per.values()]
        envs.append({"env": env, "record": path, "command": rec.get("command"), "preset": xj.get("preset"),
                     "seeds": xj.get("seeds"), "steps": runs[0].get("steps") if runs else None,
                     "episodes": rec.get("corpus", {}).get("episodes"), "policy": rec.get("config", {}).get("policy")})
        effects = rec.get("factor_effects") or {}
        rows += [factor_row(env, q, r, (effects.get(q) or {}).get("inert")) for q, r in xj["summary"].items()]
    certified = [r for r in rows if r["gate_passed"]]
    return {"margin": MARGIN, "environments": envs, "rows": rows,
            "certified": {"factors": len(certified), "environments": len({r["env"] for r in certified})},
            "verdicts": {r["env"] + " " + r["factor"]: r["verdict"] for r in rows}}


def markdown(summary: dict) -> str:
    """The table, the effects and the verdicts, each environment's command."""
    head = " | ".join(f"{v} ({STATE_ROLE[v]})" for v in SWM_VARIANTS)
    lines = ["# Targets, not inputs, across stable-worldmodel environments", "",
             (f"Predictor-state R² ridge / MLP (untrained twin's ridge), mean over seeds; effects are ridge "
              f"differences, mean [per seed]; an effect carries the factor when its mean is ≥ {summary['margin']:.2f} "
              "and every seed's is positive. † and \"no claim\": the factor's certificate failed its gate."), "",
             f"| environment | factor | certificate | {head} | VX − V | VFX − VF | VF − V | verdict |",
             "|---|---|---|" + "---|" * len(SWM_VARIANTS) + "---|---|---|---|"]
    for r in summary["rows"]:
        mark = "" if r["gate_passed"] else "†"
        cells = [f"{fmt(c['ridge'])}{mark} / {fmt(c['mlp'])}{mark} ({fmt(c['untrained'])})"
                 for c in r["variants"].values()]
        effects = [(f"{fmt(r['effects_ridge'][k])} [{', '.join(fmt(x) for x in r['effects_per_seed'][k].values())}]"
                    if r["gate_passed"] else "—") for k in EFFECTS]
        lines.append(f"| {r['env']} | {r['factor']} | {fmt(r['certificate'])} ({'PASS' if r['gate_passed'] else 'FAIL'}) | "
                     + " | ".join(cells + effects) + f" | {r['verdict']} |")
    c = summary["certified"]
    lines += ["", f"Certified: {c['factors']} factors in {c['environments']} environments.", "", "Records:", ""]
    lines += [(f"- {e['env']}: `{e['command']}` ({e['episodes']} episodes, {e['policy']} policy; X-JEPA "
               f"`{e['preset']}` {e['steps']} steps, seeds {e['seeds']}) — "
               f"`{e['record']}`") for e in summary["environments"]]
    return "\n".join(lines) + "\n"


def figure(summary: dict, path: Path) -> Path:
    """The three effects per certified factor and V's gain over its untrained twin (bars: mean; dots: seeds), the
    margin dashed, the verdict under each factor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in summary["rows"] if r["gate_passed"]]
    colors = {"target_without_input": "tab:orange", "target_with_input": "tab:blue",
              "input_without_target": "tab:green"}
    names = {"target_without_input": "target, no input (VX − V)", "target_with_input": "target, with input "
             "(VFX − VF)", "input_without_target": "input, no target (VF − V)"}
    colors["vision"], names["vision"] = "tab:gray", "vision alone (V − its untrained twin)"
    fig, ax = plt.subplots(figsize=(2.2 * max(len(rows), 1) + 3.5, 3.6))
    width, x = 0.2, np.arange(len(rows))
    for i, k in enumerate([*EFFECTS, "vision"]):
        for j, r in enumerate(rows):
            pos = x[j] + (i - 1.5) * width
            seeds = list((r["vision_gain_per_seed"] if k == "vision" else r["effects_per_seed"][k]).values())
            ax.bar(pos, float(np.mean(seeds)) if seeds else 0.0, width, color=colors[k],
                   label=names[k] if j == 0 else None)
            ax.plot([pos] * len(seeds), seeds, "k.", ms=4, label="seeds" if i == 0 and j == 0 else None)
    ax.axhline(summary["margin"], color="red", lw=0.8, ls="--", label=f"margin {summary['margin']:.2f}")
    ax.axhline(0, color="black", lw=0.5)
    ax.set_xticks(x, [f"{r['env'].removeprefix('swm/')}\n{r['factor']}\n→ {r['verdict']}" for r in rows],
                  fontsize=7)
    ax.set_ylabel("ridge R² difference (predictor state)", fontsize=8)
    ax.set_title("Which role of the state puts a certified factor in the latent?", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=150, format="png")
    plt.close(fig)
    return path


def run(cfg: TargetsConfig) -> Path:
    """Read the records, write PREFIX.{json,md,png} (:func:`summarise`'s summary in the JSON); return the table's
    path."""
    if not cfg.records:
        raise ConfigError("--records is empty: pass one swm_certify.json per environment")
    summary = summarise({str(p): load_factorial(p) for p in cfg.records})
    paths = {ext: Path(f"{cfg.out}.{ext}") for ext in ("json", "md", "png")}
    for p in paths.values():  # all three refused before any is written (never a half-replaced set)
        check_replaceable(p)
    write_json(paths["json"], summary)
    save_text(paths["md"], markdown(summary))
    figure(summary, paths["png"])
    for r in summary["rows"]:
        print(f"[swm-targets] {r['env']} {r['factor']}: {r['verdict']}")
    print(f"[swm-targets] wrote {paths['json']}, {paths['md']}, {paths['png']}")
    return paths["md"]


__all__ = ["EFFECTS", "MARGIN", "TargetsConfig", "carries", "effect_per_seed", "factor_row", "figure",
           "load_factorial", "make_config", "markdown", "run", "summarise", "verdict"]
