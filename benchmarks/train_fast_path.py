"""Plain vs fast training path, side by side: s/step, frames/s, FLOP/s and fraction of the matmul peak.

Usage:  python benchmarks/train_fast_path.py [--presets cpu paper] [--steps 30] [--no-compile]
                                            [--configs plain fast ...]
                                            [--out benchmarks/results/train_fast_path.json]

Runs benchmarks/train_throughput.py's ``bench`` for each preset in the configurations of ``--configs`` (default
the first four) — ``plain`` (TrainConfig fast='off'), ``fast`` (fast='on': non-blocking uploads, fused AdamW, no
per-step host sync), ``fast+channels_last``, ``fast+compile`` (torch.compile of the loss in its default mode) and
``fast+reduce-overhead`` (compiled with CUDA graphs, the default on CUDA); a compile time is the ``warmup_s``
field, not in s/step — on whatever device is present, prints one JSON line per configuration and writes them with
each configuration's speed-up over the first. Run it by hand; the numbers on a shared CPU are pessimistic and say
little about a GPU (docs/model.md, "Fast path").
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # a sibling script, not a package
from train_throughput import bench, write_results  # noqa: E402

from pokeworld.devices import pick_device  # noqa: E402
from pokeworld.train import PRESETS, auto_threads  # noqa: E402

CONFIGS = {  # name -> bench() keyword arguments
    "plain": {},
    "fast": {"fast": True},
    "fast+channels_last": {"fast": True, "channels_last": True},
    "fast+compile": {"fast": True, "compile": True},
    "fast+reduce-overhead": {"fast": True, "compile": True, "compile_mode": "reduce-overhead"},
}
DEFAULT_CONFIGS = ("plain", "fast", "fast+channels_last", "fast+compile")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=None, help="default: cpu (+ paper on CUDA)")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--threads", type=int, default=0, help="CPU threads (0 = pokeworld.train.auto_threads())")
    ap.add_argument("--no-compile", action="store_true", help="skip fast+compile (minutes of compilation on CPU)")
    ap.add_argument("--configs", nargs="+", choices=list(CONFIGS), default=list(DEFAULT_CONFIGS),
                    help="configurations to time, in order; speed-ups are against the first")
    ap.add_argument("--out", default="benchmarks/results/train_fast_path.json")
    args = ap.parse_args()
    device = pick_device(args.device)
    if device.type == "cpu":
        torch.set_num_threads(args.threads or auto_threads())
    presets = args.presets or (["cpu", "paper"] if device.type == "cuda" else ["cpu"])
    configs = {k: CONFIGS[k] for k in args.configs if not (args.no_compile and CONFIGS[k].get("compile"))}
    results = []
    for preset in presets:
        if preset not in PRESETS:
            raise SystemExit(f"unknown preset {preset}; choose from {sorted(PRESETS)}")
        base = None
        for name, kw in configs.items():
            r = {"config": name, **bench(preset, args.steps, device, **kw)}
            base = base or r["sec_per_step"]
            r[f"speedup_vs_{next(iter(configs))}"] = base / r["sec_per_step"]
            results.append(r)
            print(json.dumps(r), flush=True)
    write_results(args.out, device, results)


if __name__ == "__main__":
    main()
