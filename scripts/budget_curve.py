"""Learning curves over the training budget: every kept checkpoint of a run measured like a finished run.

A run's kept checkpoints (``RUN/kept/ckpt-<step>.pt``, copies of ``ckpt.pt`` taken during training — ``pokeworld
train --keep-every N`` makes them, or a driver that trains with ``--stop-at`` and copies) are each turned into a
finished snapshot run (``WORK/<run>/step-<step>``: the run's config, the checkpoint's weights as ``final.pt``,
``DONE``), measured by ``pokeworld probe`` (ridge and MLP probes of log k, log m and γ on contact windows) and
``pokeworld plan`` (the Δ = 16 heads' phantom push — the predicted object displacement for programs that miss the
object — and the rank test's top-8 overlap with the simulator), then gathered into one record, a table and a
figure with the paper's values as lines. Re-running skips what is measured (each command skips up-to-date work).
Works the same on GPU-trained runs.

    python scripts/budget_curve.py RUN [RUN ...] --work out/budget_curve --preset cpu \\
        --out docs/results/budget_curve_cpu.json
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from pokeworld import checkpoint, plan
from pokeworld.data import read_manifest
from pokeworld.errors import PokeworldError
from pokeworld.evaluate import measure
from pokeworld.experiments.factorial import FACTORIAL, FACTORIAL_MLP
from pokeworld.io import atomic_path, check_outputs, read_json, save_figure, write_json
from pokeworld.rundir import read_run_config, write_final
from pokeworld.run_store import trained_store
from pokeworld.sim.environments import LEGACY
from pokeworld.train.config import REFERENCE_OBJECTIVE

QUANTITIES = ("log_k", "log_m", "gamma")
PAPER_STEPS = 20_000


def kept_checkpoints(run: Path) -> dict[int, Path]:
    """step -> kept checkpoint file of ``run`` (``kept/ckpt-<step>.pt``)."""
    kept = {}
    for p in sorted((run / "kept").glob("ckpt-*.pt")):
        m = re.fullmatch(r"ckpt-(\d+)\.pt", p.name)
        if m:
            kept[int(m[1])] = p
    return kept


def snapshot(run: Path, step: int, ckpt: Path, work: Path) -> Path:
    """A finished run folder holding ``ckpt``'s weights (made once; kept when it is there)."""
    snap = work / run.name / f"step-{step}"
    if (snap / "DONE").exists():
        return snap
    cfg = read_run_config(run)
    ck = checkpoint.load(ckpt)
    if int(ck["step"]) != step:
        raise PokeworldError(f"{ckpt} holds step {ck['step']}, not {step}; rename it after the step it holds")
    snap.mkdir(parents=True, exist_ok=True)
    write_json(snap / "config.json", cfg)
    write_final(snap, ck["model"], ck["model_kwargs"], cfg, step, f" (kept checkpoint of {run})")
    return snap


def measure_point(snap: Path, data: str, preset: str, plan_episodes: int) -> dict:
    """Probe and plan one snapshot; the numbers the curve needs."""
    m = read_json(measure.run(measure.make_config(preset, run_dir=str(snap), data=data)), "a run's measurement")
    out = {f"{kind}_{q}": m["probes"][kind]["contact"].get(q) for kind in ("ridge", "mlp") for q in QUANTITIES
           if kind in m["probes"]}
    plan_dir = snap / "plan"
    if not (plan_dir / "plan.json").exists():
        plan.run(plan.make_config(preset, runs=(str(snap),), out=str(plan_dir), data=data, episodes=plan_episodes))
    results = read_json(plan_dir / "plan.json", "a plan record")["results"]
    # `pokeworld plan` keys a lone run by its variant (records written before that: by the run folder's name)
    summary = results.get(snap.name) or next(v for k, v in results.items() if k != "random")
    # the phantom push against its control: the same decoder on the true end frames of the missing programs
    out.update(phantom_push=summary.get("miss_displacement"),
               decoded_true_miss_push=summary.get("decoded_truth_miss_displacement"),
               topk_overlap=summary.get("topk_overlap"), topk_chance=summary.get("topk_chance"),
               reach=summary.get("reach"))
    return out


def objective_of(cfg: dict) -> str:
    """Which loss weighting a run's config.json trained with: the reference's (the ``cpu`` preset) or the first."""
    stored = {k: list(v) if isinstance(v, tuple) else v for k, v in REFERENCE_OBJECTIVE.items()}
    return "reference weighting" if all(cfg.get(k) == v for k, v in stored.items()) else "first objective"


def curve(run: Path, work: Path, preset: str, plan_episodes: int) -> dict:
    cfg = read_run_config(run)
    data = trained_store(run, "budget-curve")
    points = {}
    for step, ckpt in kept_checkpoints(run).items():
        print(f"[budget-curve] {run.name} step {step}", flush=True)
        points[str(step)] = measure_point(snapshot(run, step, ckpt, work), data, preset, plan_episodes)
    # a store written before environments were named is the calibrated one (its manifest has no environment key)
    environment = read_manifest(data).get("environment", LEGACY)
    return {"run": str(run), "variant": cfg.get("variant"), "image_size": cfg.get("image_size"),
            "steps": cfg.get("steps"), "environment": environment, "objective": objective_of(cfg),
            "points": points,
            "paper": {"ridge": FACTORIAL.get(cfg.get("variant"), {}), "mlp": FACTORIAL_MLP.get(cfg.get("variant"), {}),
                      "steps": PAPER_STEPS}}


def markdown(record: dict) -> str:
    lines = ["# Probe R² and planning diagnostics against training steps", "",
             "Each kept checkpoint measured as a finished run (contact windows, held-out episodes); the paper's "
             "value is at its own budget (20,000 steps, 64 px). Commands: " + " ; ".join(record["commands"]), "",
             "Environment and objective per run: " + "; ".join(
                 f"{Path(r['run']).name}: {r.get('environment', LEGACY)}, {r.get('objective', 'first objective')}"
                 for r in record["runs"]), "",
             "| run | step | log k ridge / MLP (paper) | log m ridge / MLP (paper) | γ ridge / MLP | phantom push "
             "(true end frames decoded) | top-8 overlap (chance) |", "|---|---|---|---|---|---|---|"]

    def f(v):
        return "—" if v is None else f"{v:+.2f}"

    for r in record["runs"]:
        for step, p in sorted(r["points"].items(), key=lambda kv: int(kv[0])):
            paper = r["paper"]["ridge"]
            push = "—" if p.get("phantom_push") is None else f"{p['phantom_push']:.3f}"
            if p.get("decoded_true_miss_push") is not None:
                push += f" ({p['decoded_true_miss_push']:.3f})"
            top = "—" if p.get("topk_overlap") is None else f"{p['topk_overlap']:.2f} ({p['topk_chance']:.2f})"
            lines.append(f"| {Path(r['run']).name} | {step} | {f(p.get('ridge_log_k'))} / {f(p.get('mlp_log_k'))} "
                         f"({f(paper.get('log_k'))}) | {f(p.get('ridge_log_m'))} / {f(p.get('mlp_log_m'))} "
                         f"({f(paper.get('log_m'))}) | {f(p.get('ridge_gamma'))} / {f(p.get('mlp_gamma'))} | {push} "
                         f"| {top} |")
    return "\n".join(lines) + "\n"


def figure(record: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(17, 4.2))
    for i, r in enumerate(record["runs"]):
        steps = sorted(int(s) for s in r["points"])
        name, color = f"{r['variant']} ({r['image_size']} px)", f"C{i}"
        for ax, q in zip(axes[:3], QUANTITIES):
            for kind, style in (("ridge", "-o"), ("mlp", "--s")):
                ys = [r["points"][str(s)].get(f"{kind}_{q}") for s in steps]
                ax.plot(steps, [float("nan") if y is None else y for y in ys], style, color=color, ms=4,
                        label=f"{name}, {kind}")
            paper = r["paper"]["ridge"].get(q)
            if paper is not None:  # the paper's value at its own budget, and as a line to read the gap against
                ax.axhline(paper, color=color, ls=":", lw=1.0)
                ax.plot([r["paper"]["steps"]], [paper], "*", color=color, ms=10,
                        label=f"{r['variant']}, paper (ridge, {r['paper']['steps']:,} steps)")
        axes[3].plot(steps, [r["points"][str(s)].get("phantom_push") for s in steps], "-o", color=color, ms=4,
                     label=f"{name}: phantom push")
        axes[3].plot(steps, [r["points"][str(s)].get("topk_overlap") for s in steps], "--s", color=color, ms=4,
                     label=f"{name}: top-8 overlap")
    for ax in axes:
        ax.set_xlim(0, PAPER_STEPS * 1.05)
    for ax, q in zip(axes[:3], ("log k (stiffness)", "log m (mass)", "γ (drag)")):
        ax.set_ylim(min(-0.05, ax.get_ylim()[0]), max(0.6, ax.get_ylim()[1]))
        ax.set_title(q)
        ax.set_xlabel("training steps")
        ax.set_ylabel("held-out R² (contact windows)")
        ax.legend(fontsize=6)
    axes[3].set_title("planning diagnostics (Δ = 16 heads)")
    axes[3].set_xlabel("training steps")
    axes[3].set_ylabel("arena units / overlap fraction")
    axes[3].legend(fontsize=6)
    settings = sorted({f"{r.get('environment', LEGACY)} environment, {r.get('objective', 'first objective')}"
                       for r in record["runs"]})
    fig.suptitle("Budget curve: each kept checkpoint measured as a finished run (★ and dotted: the paper's value at "
                 f"its budget); {'; '.join(settings)}")
    fig.tight_layout()
    save_figure(fig, out.parent, out.stem)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path, help="run folders with kept/ckpt-<step>.pt checkpoints")
    ap.add_argument("--work", type=Path, default=Path("out/budget_curve"), help="where the snapshot runs go")
    ap.add_argument("--preset", default="cpu", help="measurement and planning preset")
    ap.add_argument("--plan-episodes", type=int, default=50)
    ap.add_argument("--out", type=Path, default=Path("docs/results/budget_curve_cpu.json"))
    a = ap.parse_args(argv)
    try:
        check_outputs(a.out.parent, a.out.name, a.out.with_suffix(".md").name, a.out.with_suffix(".png").name,
                      a.out.with_suffix(".pdf").name)
        for run in a.runs:
            if not kept_checkpoints(run):
                raise PokeworldError(f"{run} has no kept/ckpt-<step>.pt checkpoints; train it with --keep-every")
        record = {"runs": [curve(r, a.work, a.preset, a.plan_episodes) for r in a.runs],
                  "commands": ["python scripts/budget_curve.py " + " ".join(str(r) for r in a.runs)
                               + f" --work {a.work} --preset {a.preset} --out {a.out}"]}
    except PokeworldError as e:
        print(f"budget_curve: error: {e}", file=sys.stderr)
        return 2
    write_json(a.out, record)
    with atomic_path(a.out.with_suffix(".md")) as tmp:
        tmp.write_text(markdown(record))
    figure(record, a.out.with_suffix(".png"))
    print(f"[budget-curve] wrote {a.out}, {a.out.with_suffix('.md')} and {a.out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
