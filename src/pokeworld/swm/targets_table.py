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
from ..io import check_apart, check_replaceable, read_json, save_bytes, save_text, write_json
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
    check_record_fields(rec, path)
    return rec


def malformed(path: str | Path, where: str, what: str) -> DataError:
    return DataError(f"{path}: {where} is not {what}; the record is damaged or was edited: pass the swm_certify.json "
                     "that pokeworld swm-certify wrote")


def check_mapping(value: object, path: str | Path, where: str) -> dict:
    if not isinstance(value, dict):
        raise malformed(path, where, f"a mapping (it is a JSON {type(value).__name__})")
    return value


def check_number(value: object, path: str | Path, where: str, optional: bool = True) -> None:
    """A JSON number (None allowed when ``optional``: an R² that was not computed); never a string or bool."""
    if (value is None and optional) or (isinstance(value, float) or (isinstance(value, int) and not
                                                                     isinstance(value, bool) and abs(value) < 2**63)):
        return  # a float (NaN prints as nan) or an integer a float holds: never a 400-digit one
    raise malformed(path, where, f"a number ({str(value)[:40]!r})")


def check_record_fields(rec: dict, path: str | Path) -> None:
    """Every field :func:`summarise` reads, of the type swm-certify writes (mappings, numbers or null, a bool
    gate, a string environment), each summary row with its variants and their per-seed R²; one DataError line
    naming the record and the field otherwise."""
    if not isinstance(rec.get("env", ""), (str, type(None))):
        raise malformed(path, "'env'", "a string")
    for key in ("corpus", "config", "factor_effects"):
        if rec.get(key) is not None:
            check_mapping(rec[key], path, repr(key))
    for q, effect in (rec.get("factor_effects") or {}).items():
        if effect is not None:
            check_mapping(effect, path, f"factor_effects[{q!r}]")
    for v, seeds in rec["xjepa"]["variants"].items():
        for seed, run in check_mapping(seeds, path, f"xjepa.variants.{str(v)[:20]}").items():
            check_mapping(run, path, f"xjepa.variants.{str(v)[:20]}[{str(seed)[:20]!r}]")
    for q, row in check_mapping(rec["xjepa"]["summary"], path, "xjepa.summary").items():
        where = f"xjepa.summary[{str(q)[:40]!r}]"
        row = check_mapping(row, path, where)
        check_number(row.get("certificate"), path, f"{where}.certificate")
        check_number(row.get("threshold"), path, f"{where}.threshold")
        if not isinstance(row.get("gate_passed"), bool):
            raise malformed(path, f"{where}.gate_passed", "true or false")
        variants = check_mapping(row.get("variants"), path, f"{where}.variants")
        for v in SWM_VARIANTS:
            cell = check_mapping(variants.get(v), path, f"{where}.variants.{v}")
            for k in ("ridge", "mlp", "untrained"):
                check_number(cell.get(k), path, f"{where}.variants.{v}.{k}")
            for seed, r in check_mapping(cell.get("per_seed", {}), path, f"{where}.variants.{v}.per_seed").items():
                r = check_mapping(r, path, f"{where}.variants.{v}.per_seed[{str(seed)[:20]!r}]")
                for k in ("ridge", "untrained"):
                    check_number(r.get(k), path, f"{where}.variants.{v}.per_seed[{str(seed)[:20]!r}].{k}")


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
                     "episodes": (rec.get("corpus") or {}).get("episodes"),
                     "policy": (rec.get("config") or {}).get("policy")})
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


MAX_FIGURE_FACTORS = 24
"""Most certified factors the figure draws (its width grows with them; a record of 1,500 factors would ask for a
figure of gigabytes): the first ones in table order, the rest named as left out. The JSON and markdown hold all."""
LABEL_CHARS = 28
"""Longest environment or factor name in a figure label (a longer one is cut, marked with …)."""


def short(text: str, n: int = LABEL_CHARS) -> str:
    return text if len(text) <= n else text[:n - 1] + "…"


def figure_png(summary: dict) -> tuple[bytes, int]:
    """The three effects per certified factor and V's gain over its untrained twin (bars: mean; dots: seeds), the
    margin dashed, the verdict under each factor, as PNG bytes (nothing written), and how many certified factors
    were left out (beyond :data:`MAX_FIGURE_FACTORS`; the title says so)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    certified = [r for r in summary["rows"] if r["gate_passed"]]
    rows, left_out = certified[:MAX_FIGURE_FACTORS], max(len(certified) - MAX_FIGURE_FACTORS, 0)
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
    ax.set_xticks(x, [f"{short(str(r['env']).removeprefix('swm/'))}\n{short(str(r['factor']))}\n→ {r['verdict']}"
                      for r in rows], fontsize=7)
    ax.set_ylabel("ridge R² difference (predictor state)", fontsize=8)
    ax.set_title("Which role of the state puts a certified factor in the latent?"
                 + (f"\n(the first {len(rows)} of {len(certified)} certified factors; the rest are in the table)"
                    if left_out else ""), fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    buf = io.BytesIO()
    try:
        fig.savefig(buf, dpi=150, format="png")  # into memory; the caller writes it through io
    finally:
        plt.close(fig)
    return buf.getvalue(), left_out


def figure(summary: dict, path: Path) -> Path:
    """:func:`figure_png` written to ``path``."""
    save_bytes(path, figure_png(summary)[0])
    return path


def run(cfg: TargetsConfig) -> Path:
    """Read the records, write PREFIX.{json,md,png} (:func:`summarise`'s summary in the JSON); return the table's
    path. No output may be one of the records (:func:`pokeworld.io.check_apart`), and all three are made (the
    figure rendered in memory) and checked before the first is written: all or none."""
    if not cfg.records:
        raise ConfigError("--records is empty: pass one swm_certify.json per environment")
    paths = {ext: Path(f"{cfg.out}.{ext}") for ext in ("json", "md", "png")}
    check_apart(cfg.records, paths.values())
    summary = summarise({str(p): load_factorial(p) for p in cfg.records})
    for p in paths.values():  # all three refused before any is written (never a half-replaced set)
        check_replaceable(p)
    png, left_out = figure_png(summary)
    table = markdown(summary)
    if left_out:
        summary["figure_left_out"] = left_out
        table += (f"\nThe figure shows the first {MAX_FIGURE_FACTORS} certified factors; {left_out} more are in "
                  "the table only.\n")
    write_json(paths["json"], summary)
    save_text(paths["md"], table)
    save_bytes(paths["png"], png)
    for r in summary["rows"]:
        print(f"[swm-targets] {r['env']} {r['factor']}: {r['verdict']}")
    print(f"[swm-targets] wrote {paths['json']}, {paths['md']}, {paths['png']}"
          + (f" (the figure leaves out {left_out} certified factors beyond the first {MAX_FIGURE_FACTORS})"
             if left_out else ""))
    return paths["md"]


__all__ = ["EFFECTS", "MARGIN", "MAX_FIGURE_FACTORS", "TargetsConfig", "carries", "check_record_fields",
           "effect_per_seed", "factor_row", "figure", "figure_png",
           "load_factorial", "make_config", "markdown", "run", "summarise", "verdict"]
