"""Training throughput per preset: steps/s, frames/s, model FLOP/s and fraction of the measured matmul peak.

Usage:  python benchmarks/train_throughput.py [--presets tiny cpu] [--steps 20] [--out FILE.json]

Times full optimisation steps (window sampling from the in-memory dataset + forward + backward +
AdamW) on a synthetic dataset at the preset's image size, after warm-up. FLOPs per step are counted
with ``torch.utils.flop_counter.FlopCounterMode`` (matmul/conv FLOPs; elementwise ops excluded), and
the peak is a measured large square matmul (fp32 on CPU; bf16 on CUDA when autocast is used). On a
shared machine the numbers are pessimistic; the JSON records the load average.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import torch

from pokeworld.models import XJEPA
from pokeworld.train import PRESETS, WindowSampler, auto_threads, make_config, model_kwargs, synthetic_dataset


def matmul_peak(device: torch.device, dtype: torch.dtype, n: int = 2048, reps: int = 10) -> float:
    a = torch.randn(n, n, device=device, dtype=dtype)
    b = torch.randn(n, n, device=device, dtype=dtype)
    for _ in range(3):
        a @ b
    if device.type == "cuda":
        torch.cuda.synchronize()
    t = time.perf_counter()
    for _ in range(reps):
        a @ b
    if device.type == "cuda":
        torch.cuda.synchronize()
    return 2 * n ** 3 * reps / (time.perf_counter() - t)


def bench(preset: str, steps: int, device: torch.device) -> dict:
    cfg = make_config(preset, device=str(device))
    ds = synthetic_dataset(num_episodes=32, steps=64, size=64 if cfg.image_size <= 64 else cfg.image_size, seed=0)
    sampler = WindowSampler(ds, ds.episodes("train"), cfg.image_size, cfg.window, device, seed=0)
    torch.manual_seed(0)
    model = XJEPA(**model_kwargs(cfg, (4, 7, 2))).to(device).train()
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    amp = cfg.amp and device.type == "cuda" and torch.cuda.is_bf16_supported()
    kw = dict(sigreg_dirs=cfg.sigreg_dirs, sigreg_weight=cfg.sigreg_weight)

    def step(i):
        b = sampler.sample(cfg.batch_size)
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp):
            loss, _ = model.loss(b, sigreg_seed=i, **kw)
        opt.zero_grad()
        loss.backward()
        opt.step()

    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as fc:
        step(0)
    flops = fc.get_total_flops()
    for i in range(3):
        step(i)
    if device.type == "cuda":
        torch.cuda.synchronize()
    t = time.perf_counter()
    for i in range(steps):
        step(i)
    if device.type == "cuda":
        torch.cuda.synchronize()
    dt = (time.perf_counter() - t) / steps
    peak = matmul_peak(device, torch.bfloat16 if amp else torch.float32)
    return {"preset": preset, "device": str(device), "batch_size": cfg.batch_size, "window": cfg.window,
            "image_size": cfg.image_size, "params": sum(p.numel() for p in model.parameters()),
            "sec_per_step": dt, "steps_per_s": 1 / dt, "frames_per_s": cfg.batch_size * cfg.window / dt,
            "preset_steps": cfg.steps, "sec_per_model": cfg.steps * dt,
            "flops_per_step": flops, "achieved_flops": flops / dt, "matmul_peak_flops": peak,
            "fraction_of_peak": flops / dt / peak, "amp_bf16": amp}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=None, help="default: tiny cpu (+ paper on CUDA)")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--threads", type=int, default=0, help="CPU threads (0 = pokeworld.train.auto_threads())")
    ap.add_argument("--out", default="benchmarks/results/train_throughput.json")
    args = ap.parse_args()
    device = torch.device("cuda" if args.device == "auto" and torch.cuda.is_available() else
                          ("cpu" if args.device == "auto" else args.device))
    if device.type == "cpu":
        torch.set_num_threads(args.threads or auto_threads())
    presets = args.presets or (["tiny", "cpu", "paper"] if device.type == "cuda" else ["tiny", "cpu"])
    results = []
    for p in presets:
        if p not in PRESETS:
            raise SystemExit(f"unknown preset {p}; choose from {sorted(PRESETS)}")
        r = bench(p, args.steps, device)
        results.append(r)
        print(json.dumps(r))
    meta = {"torch": torch.__version__, "machine": platform.machine(), "cpu_count": os.cpu_count(),
            "threads": torch.get_num_threads(), "loadavg": os.getloadavg() if hasattr(os, "getloadavg") else None,
            "gpu": torch.cuda.get_device_name() if device.type == "cuda" else None}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"meta": meta, "results": results}, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
