"""Gather finished ``pokeworld demo`` folders into one table of the objective's levers at the demo's budget
(docs/model.md, "The reference's objective at CPU budgets").

Each FOLDER is a demo output (``results.json`` + ``runs/*/config.json``). A row is one run: its variant, what its
training config changes against the ``demo_first`` preset (the first objective at the demo's size), and its ridge
readout on contact windows, so the table says exactly what each run varied.

    python scripts/demo_levers.py FOLDER [FOLDER ...] --out docs/results/demo_levers_cpu.json
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pokeworld.io import read_json, save_text, write_json
from pokeworld.train.config import changes_from

BASE_PRESET = "demo_first"


def changes(cfg: dict, preset: str = BASE_PRESET) -> dict:
    """Fields of a run's config that differ from ``preset`` (bookkeeping, seed and variant left out)."""
    return changes_from(cfg, preset, ignore={"seed", "variant"})


def rows_of(folder: Path) -> list[dict]:
    """One row per run of a demo folder (runs without a measurement are left out)."""
    res = read_json(folder / "results.json", "a demo results.json")
    out = []
    for name, run in sorted(res["runs"].items()):
        ridge = run.get("probes", {}).get("ridge", {}).get("contact")
        if not ridge:
            continue
        cfg = read_json(folder / "runs" / name / "config.json", "a run's config.json")
        pred = run.get("prediction", {})
        out.append({"folder": folder.name, "run": name, "variant": cfg["variant"], "seed": cfg["seed"],
                    "steps": cfg["steps"], "changes": changes(cfg),
                    "command": res.get("provenance", {}).get("command", ""),
                    "environment": res.get("map_config", {}).get("environment", ""),
                    **{k: ridge[k] for k in ("log_k", "log_m", "gamma", "object_pos")},
                    "direct16": pred.get("direct16"), "static16": pred.get("static16")})
    return out


def table(rows: list[dict]) -> str:
    lines = ["| folder | variant | changes against `demo_first` | log k | log m | γ | direct-16 / static-16 |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        ch = ", ".join(f"{k}={v}" for k, v in sorted(r["changes"].items())) or "none (the first objective)"
        pred = (f"{r['direct16']:.3f} / {r['static16']:.3f}" if r["direct16"] is not None else "—")
        lines.append(f"| {r['folder']} | {r['variant']} | {ch} | {r['log_k']:+.2f} | {r['log_m']:+.2f} | "
                     f"{r['gamma']:+.2f} | {pred} |")
    return "\n".join(lines) + "\n"


HEADER = """# The objective's levers at the demo's budget

Ridge R² on held-out contact windows of the demo's corpus (`pokeworld demo`'s 2,400 episodes, reference environment,
seed 0); each row one run, its changes read from its own `config.json` against the `demo_first` training preset
(the first objective at the demo's size); the command of each folder is in the JSON. A row whose changes are not a
named preset was trained with a preset made of them: `PRESETS[NAME] = {**PRESETS["demo_first"], **changes}` in
`pokeworld/train/config.py`, then `pokeworld demo --train-preset NAME --variants VFX --no-certify --out FOLDER`.
Regenerate the table with `python scripts/demo_levers.py FOLDER… --out docs/results/demo_levers_cpu.json`.

"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", type=Path, help="finished `pokeworld demo` output folders")
    ap.add_argument("--out", type=Path, required=True, help="JSON record to write (a .md table beside it)")
    args = ap.parse_args()
    rows = [r for f in args.folders for r in rows_of(f)]
    if not rows:
        raise SystemExit("no measured runs in the folders given: pass finished `pokeworld demo` outputs")
    write_json(args.out, {"base_preset": BASE_PRESET, "rows": rows})
    md = args.out.with_suffix(".md")
    save_text(md, HEADER + table(rows))
    print(f"wrote {args.out} and {md} ({len(rows)} runs)")


if __name__ == "__main__":
    main()
