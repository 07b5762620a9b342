"""Probe R² against training step for one configuration (docs/model.md, "Learning speed").

Trains one model with checkpoints every ``--every`` steps (the cosine schedule spans ``steps``, so the
curve is that of the full run) and, after each segment, fits the leak-free ridge probes of the map on
contact windows (``measure.probe_model``, same windows and split as ``pokeworld probe``). Appends one
JSON line per checkpoint to ``<out>/curve.jsonl``; re-running resumes the training and skips probed steps.
``--probe-data DIR`` fits and tests the probes on another corpus's probe splits instead (rows go to
``curve-probe-<DIR name>.jsonl``): re-run on a finished run it probes the final checkpoint only, which is how
docs/model.md separates probe-set size from training-corpus size.

    python scripts/probe_curve.py DATA OUT --every 250 -- variant=VFX steps=1000 lr=2e-3
    python scripts/probe_curve.py DATA OUT --every 250 --probe-data OTHER -- variant=VFX steps=1000 lr=2e-3
"""

from __future__ import annotations

import argparse
import ast
import json
import time
from pathlib import Path

import torch

from pokeworld import checkpoint, train
from pokeworld.data import load
from pokeworld.evaluate import measure

QUANTITIES = ("log_k", "log_m", "gamma", "object_pos", "object_vel")


def parse_value(text: str):
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def checkpoint_step(run_dir: Path) -> int:
    return int(checkpoint.load(run_dir / "ckpt.pt")["step"])


def probe_at(run_dir: Path, ds, mcfg) -> dict:
    model = train.load_model(run_dir, final=False)
    res, _ = measure.probe_model(model, ds, mcfg, mlp=False, kinds=("contact",))
    ridge = res.get("ridge", {}).get("contact", {})
    return {q: round(float(ridge[q]), 4) for q in QUANTITIES if q in ridge}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data")
    ap.add_argument("out")
    ap.add_argument("--every", type=int, default=250)
    ap.add_argument("--preset", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--probe-data", default="", help="probe on this corpus's probe splits (default: DATA)")
    ap.add_argument("overrides", nargs="*", help="TrainConfig field=value")
    args = ap.parse_intermixed_args()
    torch.set_num_threads(args.threads)
    over = dict(kv.split("=", 1) for kv in args.overrides)
    over = {k: parse_value(v) for k, v in over.items()}
    out = Path(args.out)
    cfg = train.make_config(args.preset, data=args.data, out=str(out), progress=False, tensorboard=False,
                            threads=args.threads, ckpt_every=args.every, **over)
    ds = load(args.probe_data or args.data)
    mcfg = measure.make_config(args.preset, run_dir=str(out), mlp=False, untrained=False)
    curve = out / (f"curve-probe-{Path(args.probe_data).name}.jsonl" if args.probe_data else "curve.jsonl")
    done = set()
    if curve.exists():
        done = {json.loads(line)["step"] for line in curve.read_text().splitlines()}
    for stop in range(args.every, cfg.steps + 1, args.every):
        t0 = time.time()
        train.run(train.make_config(args.preset, **{**train.to_dict(cfg), "stop_at": stop}))
        dt = time.time() - t0
        if stop in done:
            continue
        if checkpoint_step(out) != stop:  # a finished run keeps only its last checkpoint
            continue
        row = {"step": stop, "train_s": round(dt, 1), **probe_at(out, ds, mcfg)}
        with curve.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
