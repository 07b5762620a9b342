"""Learning proxy per behaviour-mix point: demo-size V / VX_p / VF / VFX trained on each point's corpus (run by hand).

The mix grid (scripts/mix_grid.py) scores a point on the corpus statistics and cheap certificates; this script adds
what a model learns there. For each chosen grid row it generates the point's corpus at the demo's size (2,400
episodes, split 40 / 40 / 20 %), trains V, VX_p, VF and VFX with train's ``demo`` preset (seed 0, one thread each,
``--parallel`` at a time) and reads ridge probes on contact windows as ``pokeworld demo`` does. The two learning
findings it scores: stiffness enters VFX but not VF (VFX − VF log k), mass enters V and VX_p (log m).
Each stage is a ``pokeworld`` command, so a re-run skips what is done. docs/design.md, "The learning proxy per
mix point".

    python scripts/mix_proxy.py --grid docs/results/mix_grid_tangent.json --rows 1 5 13 \
        --work out/mix_proxy --out docs/results/mix_proxy_tangent.json
"""

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from pokeworld.io import atomic_path, write_json
from pokeworld.sim import generate

VARIANTS = ("V", "VX_p", "VF", "VFX")
TARGETS = ("log_k", "log_m", "gamma")
POKEWORLD = str(Path(sys.executable).with_name("pokeworld"))


def run_parallel(commands: list[list[str]], parallel: int, log: Path) -> None:
    """Run commands ``parallel`` at a time (one thread each); stop on the first failure."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    pending = list(commands)
    with open(log, "a") as sink:
        while pending:
            batch, pending = pending[:parallel], pending[parallel:]
            procs = [subprocess.Popen(c, stdout=sink, stderr=subprocess.STDOUT, env=env) for c in batch]
            for cmd, proc in zip(batch, procs):
                if proc.wait() != 0:
                    raise SystemExit(f"mix_proxy: {' '.join(cmd)} failed (exit {proc.returncode}); see {log}")


def read_json(path: str | os.PathLike) -> dict:
    return json.loads(Path(path).read_text())


def probe_row(run: Path) -> dict:
    """Ridge R² on contact windows of one probed run."""
    ridge = read_json(run / "measure.json")["probes"]["ridge"]["contact"]
    return {t: ridge[t] for t in TARGETS}


def proxy_point(row: dict, work: Path, args) -> dict:
    t0 = time.time()
    work.mkdir(parents=True, exist_ok=True)
    log = work / "log.txt"
    data = work / "data"
    # the point's overrides through the generator's own preset layering, as the grid's corpora were built
    generate.run(generate.make_config("cpu", out=str(data), num_episodes=args.episodes,
                                      split_fractions=(0.4, 0.4, 0.2), **row["point"]))
    runs = {v: work / "runs" / v for v in VARIANTS}
    run_parallel([[POKEWORLD, "train", "--preset", "demo", "--variant", v, "--seed", "0", "--threads", "1",
                   "--data", str(data), "--out", str(r)] for v, r in runs.items()], args.parallel, log)
    run_parallel([[POKEWORLD, "probe", str(r), "--preset", "cpu", "--kinds", "contact", "--max-windows", "12000",
                   "--no-mlp", "--no-untrained"] for r in runs.values() if not (r / "measure.json").exists()],
                 args.parallel, log)
    probes = {v: probe_row(r) for v, r in runs.items()}
    return {"point": row["point"], "stats": row["stats"], "stats_loss": row["stats_loss"],
            "gru_contact": row.get("gru_contact"), "probes": probes,
            "vfx_minus_vf_log_k": probes["VFX"]["log_k"] - probes["VF"]["log_k"], "seconds": time.time() - t0}


def markdown(rows: list[dict]) -> str:
    lines = ["| mix (pursuit/strike/OU) | strike gain | launch | stats loss | GRU cert. log m / log k "
             "| log k V / VF / VFX | VFX − VF | log m V / VX_p / VFX |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        p, pr, g = r["point"]["policy"], r["probes"], r["gru_contact"] or {}
        lines.append(
            f"| {'/'.join(f'{w:.2f}' for w in p['mode_weights'])} | {p['strike_gain']} | {p['launch_fraction']} "
            f"({p['launch_speed'][0]}–{p['launch_speed'][1]}) | {r['stats_loss']:.2f} "
            f"| {g.get('log_m', float('nan')):.2f} / {g.get('log_k', float('nan')):.2f} "
            f"| {pr['V']['log_k']:+.2f} / {pr['VF']['log_k']:+.2f} / {pr['VFX']['log_k']:+.2f} "
            f"| {r['vfx_minus_vf_log_k']:+.2f} "
            f"| {pr['V']['log_m']:+.2f} / {pr['VX_p']['log_m']:+.2f} / {pr['VFX']['log_m']:+.2f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", default="docs/results/mix_grid_tangent.json", help="a scripts/mix_grid.py record")
    ap.add_argument("--rows", type=int, nargs="+", required=True, help="grid rows (0-based) to train on")
    ap.add_argument("--work", default="out/mix_proxy", help="corpora and runs, one folder per row")
    ap.add_argument("--out", default="docs/results/mix_proxy_tangent.json")
    ap.add_argument("--episodes", type=int, default=2400)
    ap.add_argument("--parallel", type=int, default=2, help="trainings at a time (one CPU thread each)")
    args = ap.parse_args()
    grid = read_json(args.grid)
    bad = [i for i in args.rows if not 0 <= i < len(grid["rows"])]
    if bad:
        raise SystemExit(f"mix_proxy: rows {bad} are not in {args.grid} ({len(grid['rows'])} rows); pick 0…"
                         f"{len(grid['rows']) - 1}")
    rows = []
    for i in args.rows:
        print(f"[mix_proxy] row {i}: {json.dumps(grid['rows'][i]['point']['policy'])}", flush=True)
        rows.append({"row": i, **proxy_point(grid["rows"][i], Path(args.work) / f"row{i}", args)})
        r = rows[-1]
        print(f"[mix_proxy] row {i}: VFX − VF log k {r['vfx_minus_vf_log_k']:+.2f}, log m V / VX_p "
              f"{r['probes']['V']['log_m']:+.2f} / {r['probes']['VX_p']['log_m']:+.2f} ({r['seconds'] / 60:.1f} min)",
              flush=True)
    cmd = (f"python scripts/mix_proxy.py --grid {args.grid} --rows {' '.join(map(str, args.rows))} "
           f"--work {args.work} --out {args.out} --episodes {args.episodes} --parallel {args.parallel}")
    write_json(args.out, {"command": cmd, "grid": grid["command"], "variants": VARIANTS, "rows": rows})
    with atomic_path(Path(args.out).with_suffix(".md")) as tmp:
        tmp.write_text(markdown(rows))
    print(f"[mix_proxy] wrote {len(rows)} points to {args.out} and {Path(args.out).with_suffix('.md')}")


if __name__ == "__main__":
    main()
