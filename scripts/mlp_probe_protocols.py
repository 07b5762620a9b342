"""Our MLP probe beside the released one, on model folders: does the paper's "MLP at chance" come from the probe?

For each model (an exported folder or a finished run) and one store, the contact-window predictor states of the
main probe are read once and four readouts of log m, γ and log k fitted on them
(:mod:`pokeworld.evaluate.mlp_protocols`): ridge, our per-parameter early-stopped MLP, and the released joint MLP
under its own selection rule (best validation R² averaged over the three) and under a per-parameter rule (the
same network and trajectory). The record puts the paper's Table "mlp" and the released run's numbers beside them.

    python scripts/mlp_probe_protocols.py models/xjepa-VX_p-paper-s0 models/xjepa-VX_t-paper-s0 \\
        --data DIR --preset paper --out docs/results/mlp_probe_protocols.json

``--probe-seeds K`` also refits the released rule with probe seeds 0 … K − 1 on the released windows' states
(:func:`~pokeworld.evaluate.mlp_protocols.selection_stability`): the step each seed keeps and what it then reads.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from pokeworld import __version__
from pokeworld.data import load, read_manifest
from pokeworld.errors import DataError, PokeworldError
from pokeworld.evaluate.measure import HORIZON, make_config
from pokeworld.evaluate.tables import git_commit
from pokeworld.evaluate.mlp_protocols import (JOINT_TARGETS, PROTOCOLS, compare, release_states,
                                              selection_stability)
from pokeworld.experiments.factorial import FACTORIAL_MLP
from pokeworld.io import check_outputs, read_json, save_text, write_json
from pokeworld.model_inputs import checked_model
from pokeworld.published.release import RUNS as RELEASED
from pokeworld.rundir import read_run_config

LABELS = {"ridge": "ridge", "mlp_per_parameter": "our MLP (one per parameter, own early stop)",
          "mlp_joint_mean": "released MLP (joint; best mean validation R²)",
          "mlp_joint_each": "released MLP's run, each parameter at its own best step"}
WINDOW_SETS = {"ours": "ours: every 4th start, ≥ 1 contact frame", "release": "released: starts 8 apart, ≥ 2 contact frames"}


HEADER = """# MLP probe protocols: ours beside the released one

R² on held-out contact windows of log m, γ and log k from each model's predictor state (the leak-free readout of
`pokeworld probe`), four readouts on the same states (`pokeworld.evaluate.mlp_protocols`): ridge; our MLP, one
network per parameter early-stopped on its own validation loss; the released MLP probe (exp/e003_motion/train.py of
the authors' release), one 256-128 network for the three parameters, kept at the evaluation step (every 200 of
4,001) whose validation R² averaged over the three is best; and that same run with each parameter kept at its own
best step. Two window sets: ours, and the released probe's (starts 8 apart, ≥ 2 contact frames). Preset `{preset}`
window counts, store `{data}` (content hash {sha}…). Command: `{command} --out docs/results/mlp_probe_protocols.json`.
The paper's and the released run's values are theirs, shown for comparison.

"""


def variant_of(model_dir: Path) -> str:
    cfg = read_run_config(model_dir)
    return str(cfg.get("variant", model_dir.name))


def measure_one(model_dir: Path, data: str, preset: str) -> dict:
    cfg = make_config(preset, data=data)
    model = checked_model(model_dir, data, max(cfg.window, cfg.context + HORIZON), "the probe windows")
    t0 = time.time()
    res = compare(model, load(data), cfg)
    res.update(model=model_dir.name, variant=variant_of(model_dir), seconds=round(time.time() - t0, 1))
    return res


def add_selection(rec: dict, model_dir: Path, data: str, preset: str, seeds: int, blocks: int) -> None:
    """``rec["selection"]``: the released rule under ``seeds`` probe seeds and ``blocks`` validation blocks; a part
    an earlier run measured with as many is kept, and the states are read once for what is missing."""
    have = rec.get("selection", {})
    need_seeds = seeds and have.get("seeds") != seeds
    need_blocks = blocks and have.get("validation", {}).get("seeds") != blocks
    if not (need_seeds or need_blocks):
        return
    cfg = make_config(preset, data=data)
    model = checked_model(model_dir, data, max(cfg.window, cfg.context + HORIZON), "the probe windows")
    t0 = time.time()
    new = selection_stability(release_states(model, load(data), cfg), seeds if need_seeds else 0,
                              blocks if need_blocks else 0, cfg.seed)
    rec["selection"] = {**have, **new, "seconds": round(have.get("seconds", 0) + time.time() - t0, 1)}


DRAWS = {"seed": "probe seed 0 … K − 1 (release's validation episodes)",
         "validation": "the last K blocks of 15 % of the episodes validating in turn, the first the release's (probe "
                       "seed 0)"}


def selection_table(records: list[dict]) -> str:
    parts = [(r["model"], part, r["selection"]["ridge"]) for r in records if "selection" in r
             for part in (r["selection"], r["selection"].get("validation")) if part and "runs" in part]
    if not parts:
        return ""
    lines = ["", "", "## The released rule under other draws", "",
             "The released probe fixes `torch.manual_seed(0)` and validates on the last 15 % of the probe-fit "
             "episodes. Here the same rule (joint network, best mean validation R²) is refit on the same states of the "
             "released windows, once per draw: other probe seeds, or another block of episodes validating. Per model: "
             "how many draws keep step 0 (every output near the training mean, the release's \"at chance\"), the "
             "range of what the rule then reports, how far the kept step's mean validation R² stood above step 0's, "
             "and ridge on the same states.", "",
             "| model | draws | kept at step 0 | log m | γ | log k | validation margin over step 0 | ridge log m / γ / "
             "log k |",
             "|---|---|---|---|---|---|---|---|"]
    for model, s, ridge in parts:
        rng = " | ".join(f"{s['r2_range'][t][0]:.2f} … {s['r2_range'][t][1]:.2f}" for t in JOINT_TARGETS)
        margins = [x["val_margin_over_step0"] for x in s["runs"]]
        lines.append(f"| {model} | {s['seeds']} × {DRAWS[s.get('vary', 'seed')]} | {s['kept_step_0']} | {rng} | "
                     f"{min(margins):.3f} … {max(margins):.3f} | "
                     + " / ".join(f"{ridge[t]:.2f}" for t in JOINT_TARGETS) + " |")
    return "\n".join(lines)


def table(records: list[dict]) -> str:
    lines = ["| model | windows (fit / test) | readout | log m | γ | log k | kept at step |",
             "|---|---|---|---|---|---|---|"]
    for r in records:
        for name in WINDOW_SETS:
            res = r[name]
            where = f"{WINDOW_SETS[name]} ({res['counts']['fit']:,} / {res['counts']['test']:,})"
            for p in PROTOCOLS:
                cells = " | ".join(f"{res['r2'][p].get(t, float('nan')):.2f}" for t in JOINT_TARGETS)
                step = {"mlp_joint_mean": str(res["joint_steps"]["mean"]),
                        "mlp_joint_each": " / ".join(str(res["joint_steps"]["each"].get(t, "—")) for t in JOINT_TARGETS)
                        }.get(p, "")
                lines.append(f"| {r['model']} | {where} | {LABELS[p]} | {cells} | {step} |")
        v = r["variant"]
        paper, rel = FACTORIAL_MLP.get(v), RELEASED.get(v, {}).get("mlp")
        if paper:
            lines.append("| | | *paper, Table \"mlp\"* | " + " | ".join(f"{paper[t]:.2f}" for t in JOINT_TARGETS) + " | |")
        if rel:
            lines.append(f"| | | *released {v} seed 0, MLP* | " + " | ".join(f"{rel[t]:.2f}" for t in JOINT_TARGETS)
                         + " | |")
    return "\n".join(lines)


def record(done: dict, args, sha: str) -> dict:
    """The record: every model measured so far, and the one command that reproduces all of it (the most probe
    seeds and validation blocks any model holds)."""
    models = list(done.values())
    seeds = max((r.get("selection", {}).get("seeds", 0) for r in models), default=0)
    blocks = max((r.get("selection", {}).get("validation", {}).get("seeds", 0) for r in models), default=0)
    command = f"python scripts/mlp_probe_protocols.py MODEL ... --data DIR --preset {args.preset}" \
        + (f" --probe-seeds {seeds}" if seeds else "") + (f" --validation-blocks {blocks}" if blocks else "")
    return {"data": {"name": Path(args.data).name, "content_sha256": sha}, "preset": args.preset,
            "command": command, "models": models,
            "provenance": {"pokeworld": __version__, "git": git_commit(),
                           "wall": "seconds per model (and per refit part, under selection) in each model's record"}}


def report_one(rec: dict) -> None:
    for name in WINDOW_SETS:
        r = rec[name]["r2"]
        print(f"[protocols] {rec['model']}, {name} windows: log m ridge {r['ridge']['log_m']:.2f} · our MLP "
              f"{r['mlp_per_parameter']['log_m']:.2f} · released rule {r['mlp_joint_mean']['log_m']:.2f} "
              f"(kept at step {rec[name]['joint_steps']['mean']})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("models", nargs="+", type=Path, help="model folders or finished runs")
    ap.add_argument("--data", required=True, help="the PokeWorld store the models are probed on")
    ap.add_argument("--preset", default="paper", help="measurement preset (window counts): tiny, cpu or paper")
    ap.add_argument("--out", type=Path, default=Path("out/mlp_probe_protocols.json"),
                    help="the record (JSON; a Markdown table beside it)")
    ap.add_argument("--probe-seeds", type=int, default=0,
                    help="also refit the released rule with this many probe seeds on the released windows (0: no)")
    ap.add_argument("--validation-blocks", type=int, default=0,
                    help="also refit it (probe seed 0) validating on each of this many blocks of episodes (0: no)")
    args = ap.parse_args(argv)
    if args.probe_seeds < 0 or args.validation_blocks < 0:
        print(f"error: --probe-seeds and --validation-blocks must be 0 or more, got {args.probe_seeds} and "
              f"{args.validation_blocks}", file=sys.stderr)
        return 2
    try:
        md = args.out.with_suffix(".md")
        check_outputs(args.out.parent, args.out.name, md.name)
        # a re-run keeps what an earlier one measured (one model at a time is minutes at the paper's window counts)
        earlier = read_json(args.out, "an mlp_probe_protocols record") if args.out.exists() else {}
        sha = read_manifest(args.data).get("content_sha256")
        if earlier and earlier.get("data", {}).get("content_sha256") != sha:
            raise DataError(f"{args.out} was measured on another store (content hash "
                            f"{str(earlier.get('data', {}).get('content_sha256'))[:12]}…, this one {str(sha)[:12]}…); "
                            "give --out a new record or --data that store")
        done = {r["model"]: r for r in earlier.get("models", [])}
        for i, m in enumerate(args.models, 1):
            if m.name in done:
                print(f"[protocols] {m.name}: in {args.out} already; kept")
            else:
                print(f"[protocols] {i}/{len(args.models)} {m.name}: reading states, fitting four readouts ...",
                      flush=True)
                done[m.name] = measure_one(m, args.data, args.preset)
                report_one(done[m.name])
            if args.probe_seeds or args.validation_blocks:
                print(f"[protocols] {m.name}: the released rule under {args.probe_seeds} probe seeds and "
                      f"{args.validation_blocks} validation blocks ...", flush=True)
                add_selection(done[m.name], m, args.data, args.preset, args.probe_seeds, args.validation_blocks)
                sel = done[m.name]["selection"]
                for part in (sel, sel.get("validation")):
                    if part and "runs" in part:
                        print(f"[protocols] {m.name}: {part['kept_step_0']} of {part['seeds']} "
                              f"{part.get('vary', 'seed')} draws keep step 0; log m "
                              f"{part['r2_range']['log_m'][0]:.2f} … {part['r2_range']['log_m'][1]:.2f}")
            write_json(args.out, record(done, args, sha))
        save_text(md, HEADER.format(preset=args.preset, data=Path(args.data).name, sha=str(sha)[:12],
                                    command=record(done, args, sha)["command"])
                      + table(list(done.values())) + selection_table(list(done.values())) + "\n")
    except PokeworldError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"[protocols] wrote {args.out} and {md}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
