"""Wall time of the ``paper`` preset's stages on one machine, on a small corpus, to plan a paper-scale map.

Usage:  python benchmarks/paper_stage_costs.py [--episodes 800] [--train-steps 300] [--out FILE.json]

Generates ``--episodes`` episodes with the paper preset's generator, trains a paper-preset VFX model for
``--train-steps`` steps (fast path on CUDA), measures it with the paper preset's measurement (every window,
MLP probes, untrained bound) and certifies the corpus with the gate's instruments (GRU oracle, linear floor,
drag; contact windows; paper epochs) on its probe-fit split. Each stage's seconds go into the JSON with the
corpus size, so a full corpus's cost can be extrapolated (generation is linear in episodes; measurement and
certification roughly linear in windows). Run by hand.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # a sibling script, not a package
from train_throughput import write_results  # noqa: E402

from pokeworld import certify, train  # noqa: E402
from pokeworld.devices import pick_device  # noqa: E402
from pokeworld.evaluate import measure  # noqa: E402
from pokeworld.sim import generate  # noqa: E402


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=800)
    ap.add_argument("--train-steps", type=int, default=300)
    ap.add_argument("--out", default="benchmarks/results/paper_stage_costs.json")
    args = ap.parse_args()
    device = pick_device("auto")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data"
        _, s = timed(lambda: generate.run(generate.make_config("paper", out=str(data), num_episodes=args.episodes)))
        rows.append({"stage": "generate", "episodes": args.episodes, "seconds": s})
        print(json.dumps(rows[-1]), flush=True)
        cfg = train.make_config("paper", data=str(data), out=str(Path(tmp) / "run"), steps=args.train_steps,
                                progress=False, tensorboard=False, warmup=min(500, args.train_steps // 2))
        _, s = timed(lambda: train.run(cfg))
        rows.append({"stage": "train", "steps": args.train_steps, "seconds": s, "device": str(device),
                     "sec_per_step_incl_setup": s / args.train_steps})
        print(json.dumps(rows[-1]), flush=True)
        mcfg = measure.make_config("paper", run_dir=cfg.out)
        res, s = timed(lambda: json.loads(measure.run(mcfg).read_text()))
        rows.append({"stage": "measure", "episodes": args.episodes, "seconds": s, "torch_threads": torch.get_num_threads(),
                     "mlp": mcfg.mlp, "untrained": mcfg.untrained, "max_windows": mcfg.max_windows})
        print(json.dumps(rows[-1]), flush=True)
        ccfg = certify.make_config("paper", data=str(data), estimators=("gru", "linear", "drag"), kinds=("contact",),
                                   fit_episodes=0)
        _, s = timed(lambda: certify.run(ccfg))
        rows.append({"stage": "certify (gru, linear, drag; contact; probe-fit split)", "episodes": args.episodes,
                     "seconds": s, "epochs": ccfg.epochs})
        print(json.dumps(rows[-1]), flush=True)
    write_results(args.out, device, rows)


if __name__ == "__main__":
    main()
