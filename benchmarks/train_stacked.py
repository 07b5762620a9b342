"""Stacked ensembles vs sequential models: s/step, frames/s and speed-up for M members in one process.

Usage:  python benchmarks/train_stacked.py [--presets paper] [--members 1 2 4 6] [--mix seeds|factorial]
                                          [--steps 20] [--out benchmarks/results/train_stacked.json]

For each preset and member count M, times full optimisation steps of

* ``stacked``: one ``pokeworld.train.stacked`` group of M members (window sampling of an (M, B) index
  block, one vmapped forward/backward, per-member clipping, one AdamW), and
* ``sequential``: the M members as separate models, one plain ``train.run``-style step each (the
  cost of training them one after another, or interleaved, in one process),

on a synthetic dataset at the preset's image size, after warm-up, on the default path of the device
(fast path on CUDA). ``--mix seeds``: M VFX members with different seeds; ``--mix factorial``: the
first M variants of V, VF, VX_p, VX_t, VX, VFX (zero-embedded into the smallest variant containing
them; M = 6 is the full factorial). ``--compile`` is the members' TrainConfig ``compile`` (default 'off', the eager
path the recorded numbers measured; 'auto' compiles both sides with CUDA graphs on CUDA, as training now does by
default). ``speedup`` = sequential s/step ÷ stacked s/step; ``frames_per_s``
counts all members' frames. On CUDA the JSON also records the peak memory of each configuration. On a
shared CPU the numbers are only indicative (the JSON records the load average).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # a sibling script, not a package
from train_throughput import write_results  # noqa: E402

from pokeworld.devices import pick_device  # noqa: E402
from pokeworld.models import XJEPA  # noqa: E402
from pokeworld.models.xjepa import VARIANTS  # noqa: E402
from pokeworld.train import (  # noqa: E402
    PRESETS,
    WindowSampler,
    auto_threads,
    compile_mode_for,
    compiled,
    data_stats,
    loss_kwargs,
    make_config,
    make_optimizer,
    model_kwargs,
    synthetic_dataset,
    train_step,
    use_fast_path,
)
from pokeworld.train.stacked import StackedGroup, superset_variant  # noqa: E402


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def _timed(step, steps: int, device: torch.device) -> float:
    for i in range(3):
        step(i)
    _sync(device)
    t = time.perf_counter()
    for i in range(steps):
        step(3 + i)
    _sync(device)
    return (time.perf_counter() - t) / steps


def member_configs(preset: str, m: int, mix: str, device: torch.device, compile: str = "off") -> list:
    names = list(VARIANTS)
    if mix == "factorial" and m > len(names):
        raise SystemExit(f"--mix factorial has {len(names)} variants; asked for {m}")
    return [make_config(preset, variant=names[i] if mix == "factorial" else "VFX", seed=i, device=str(device),
                        out=f"/nonexistent/m{i}", progress=False, tensorboard=False, compile=compile)
            for i in range(m)]


def bench_stacked(cfgs, ds, device: torch.device, steps: int) -> dict:
    fast = use_fast_path(cfgs[0], device)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats()
    g = StackedGroup(cfgs, device, fast, ds=ds)
    acc = torch.zeros(g.M, device=device)

    def step(i):
        nonlocal acc
        loss, _ = g.step(i)
        acc = acc + loss  # summed on the device, read at log steps only, as the trainer

    dt = _timed(step, steps, device)
    mem = torch.cuda.max_memory_allocated() if device.type == "cuda" else None
    return {"sec_per_step": dt, "peak_mem_bytes": mem, "superset_variant": g.super_variant}


def bench_sequential(cfgs, ds, device: torch.device, steps: int) -> dict:
    fast = use_fast_path(cfgs[0], device)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats()
    ep = ds.episodes("train")
    c0 = cfgs[0]
    sampler = WindowSampler(ds, ep, c0.image_size, c0.window, device, c0.contact_channel, seed=1, non_blocking=fast)
    stats = data_stats(ds, ep)
    dims = (ds.proprio.shape[-1], ds.touch.shape[-1], ds.actions.shape[-1])
    amp = c0.amp and device.type == "cuda" and torch.cuda.is_bf16_supported()
    runs = []
    for c in cfgs:
        torch.manual_seed(c.seed)
        m = XJEPA(**model_kwargs(c, dims))
        m.set_stats(stats)
        m = m.to(device).train()
        mode = compile_mode_for(c, device)  # as train.run compiles a separate run
        fn = compiled(m, mode=mode) if mode else m
        runs.append((c, m, fn, make_optimizer(m, c, fused=fast), loss_kwargs(c)))
    acc = torch.zeros((), device=device)

    def step(i):
        nonlocal acc
        for c, m, fn, opt, kw in runs:
            loss, _ = train_step(m, opt, c, sampler.sample(c.batch_size), i, device, kw, amp=amp, fast=fast,
                                 loss_fn=fn)
            acc = acc + loss

    dt = _timed(step, steps, device)
    mem = torch.cuda.max_memory_allocated() if device.type == "cuda" else None
    return {"sec_per_step": dt, "peak_mem_bytes": mem}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=None, help="default: paper on CUDA, cpu on CPU")
    ap.add_argument("--members", nargs="+", type=int, default=[1, 2, 4, 6])
    ap.add_argument("--mix", choices=("seeds", "factorial"), default="seeds")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--threads", type=int, default=0, help="CPU threads (0 = pokeworld.train.auto_threads())")
    ap.add_argument("--no-sequential", action="store_true", help="time the stacked groups only")
    ap.add_argument("--compile", choices=("auto", "on", "off"), default="off",
                    help="the members' TrainConfig compile (stacked and sequential alike)")
    ap.add_argument("--out", default="benchmarks/results/train_stacked.json")
    args = ap.parse_args()
    device = pick_device(args.device)
    if device.type == "cpu":
        torch.set_num_threads(args.threads or auto_threads())
    presets = args.presets or (["paper"] if device.type == "cuda" else ["cpu"])
    results = []
    for preset in presets:
        if preset not in PRESETS:
            raise SystemExit(f"unknown preset {preset}; choose from {sorted(PRESETS)}")
        c = make_config(preset)
        ds = synthetic_dataset(num_episodes=32, steps=64, size=max(64, c.image_size), seed=0)
        for m in args.members:
            cfgs = member_configs(preset, m, args.mix, device, args.compile)
            r = {"preset": preset, "mix": args.mix, "members": m, "variants": [x.variant for x in cfgs],
                 "superset_variant": superset_variant([x.variant for x in cfgs]), "device": str(device),
                 "compile": args.compile,
                 "batch_size": c.batch_size, "window": c.window, "image_size": c.image_size}
            st = bench_stacked(cfgs, ds, device, args.steps)
            r.update({"stacked_sec_per_step": st["sec_per_step"], "stacked_peak_mem_bytes": st["peak_mem_bytes"],
                      "frames_per_s": m * c.batch_size * c.window / st["sec_per_step"],
                      "stacked_sec_per_model": c.steps * st["sec_per_step"] / m})
            if not args.no_sequential:
                sq = bench_sequential(cfgs, ds, device, args.steps)
                r.update({"sequential_sec_per_step": sq["sec_per_step"],
                          "sequential_peak_mem_bytes": sq["peak_mem_bytes"],
                          "sequential_frames_per_s": m * c.batch_size * c.window / sq["sec_per_step"],
                          "speedup": sq["sec_per_step"] / st["sec_per_step"]})
            results.append(r)
            print(json.dumps(r), flush=True)
            if device.type == "cuda":
                torch.cuda.empty_cache()
    write_results(args.out, device, results)


if __name__ == "__main__":
    main()
