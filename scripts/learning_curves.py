"""Gather ``scripts/probe_curve.py`` runs into one table and figure (docs/model.md, "Learning speed").

Each RUN is a probe-curve output directory (``config.json`` + ``curve.jsonl``). The settings column is what the
run's config changes against the training preset's defaults, so the table says exactly what each curve varied.

    python scripts/learning_curves.py RUN [RUN ...] --preset cpu --out docs/results/learning_speed_demo.json
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

from pokeworld import train
from pokeworld.config import to_dict
from pokeworld.io import write_json
from pokeworld.train.config import changes_from


def changes(cfg: dict, preset: str) -> dict:
    """Fields of a run's config that differ from ``preset`` (bookkeeping fields left out)."""
    return changes_from(cfg, preset)


def gather(runs: list[Path], preset: str) -> list[dict]:
    rows = []
    for run in runs:
        cfg = json.loads((run / "config.json").read_text())
        curve = [json.loads(x) for x in (run / "curve.jsonl").read_text().splitlines() if x.strip()]
        if not curve:
            continue
        rows.append({"run": run.name, "changes": changes(cfg, preset),
                     "curve": [{k: r[k] for k in ("step", "log_k", "log_m", "gamma", "object_pos", "object_vel",
                                                  "train_s") if k in r} for r in sorted(curve, key=lambda r: r["step"])]})
    return rows


def shared_changes(rows: list[dict]) -> dict:
    """Settings most runs share (each field's most common value, when over half the runs set it): the base the
    figure's labels are read against."""
    counts = Counter((k, json.dumps(v)) for r in rows for k, v in r["changes"].items())
    return {k: json.loads(v) for (k, v), n in counts.most_common() if n > len(rows) / 2}


def plot(rows: list[dict], path: Path, preset: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    common = shared_changes(rows)
    preset_values = to_dict(train.make_config(preset))
    fig, ax = plt.subplots(figsize=(10, 4.8))
    ax.set_prop_cycle(color=[plt.get_cmap("tab20")(i % 20) for i in range(len(rows))],
                      marker=[["o", "s", "^", "D", "v"][i % 5] for i in range(len(rows))])
    for r in rows:
        values = {**{k: preset_values[k] for k in common}, **r["changes"]}  # a shared key the run left at the preset's
        label = ", ".join(f"{k}={v}" for k, v in values.items() if common.get(k, object()) != v) or "base"
        ax.plot([p["step"] for p in r["curve"]], [p["log_k"] for p in r["curve"]], ms=4, lw=1.2, label=label)
    base = ", ".join(f"{k}={v}" for k, v in common.items())
    ax.set_xlabel("training step (the cosine schedule spans each run's own length)")
    ax.set_ylabel("log k ridge R² (held-out contact windows)")
    ax.set_title(f"VFX, base: the preset with {base}" if base else "VFX", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=130)
    plt.close(fig)
    tmp.replace(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--preset", default="cpu", help="training preset the settings are read against")
    ap.add_argument("--out", required=True, type=Path, help="JSON path; the figure goes beside it (.png)")
    args = ap.parse_args()
    rows = gather(args.runs, args.preset)
    write_json(args.out, {"preset": args.preset, "runs": rows})
    plot(rows, args.out.with_suffix(".png"), args.preset)
    for r in rows:
        print(r["run"], r["changes"], " ".join(f"{p['step']}:{p['log_k']:.3f}" for p in r["curve"]))


if __name__ == "__main__":
    main()
