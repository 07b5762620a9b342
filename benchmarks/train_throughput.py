"""Training throughput per preset: steps/s, frames/s, model FLOP/s and fraction of the measured matmul peak.

Usage:  python benchmarks/train_throughput.py [--presets tiny cpu] [--steps 20] [--fast] [--compile]
                                             [--channels-last] [--out FILE.json]

Times full optimisation steps (window sampling from the in-memory dataset + forward + backward +
gradient clipping + AdamW) on a synthetic dataset at the preset's image size, after warm-up, the way
``pokeworld.train.run`` takes them: the plain path, or with ``--fast`` the fast path (non-blocking
uploads of indices and SIGReg directions, fused AdamW); ``--compile`` / ``--channels-last`` as the
TrainConfig fields. benchmarks/train_fast_path.py compares the paths side by side. FLOPs per step are counted
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

from pokeworld.devices import pick_device
from pokeworld.models import XJEPA
from pokeworld.train import (
    PRESETS,
    WindowSampler,
    auto_threads,
    compiled,
    loss_kwargs,
    make_config,
    make_optimizer,
    model_kwargs,
    synthetic_dataset,
    train_step,
)


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


def bench(preset: str, steps: int, device: torch.device, fast: bool = False, compile: bool = False,
          channels_last: bool = False, compile_mode: str = "default") -> dict:
    """Time ``steps`` training steps of ``preset`` on ``device`` (after 3 warm-up steps, which hold any
    compilation); ``compile_mode`` is torch.compile's mode when ``compile``."""
    cfg = make_config(preset, device=str(device), fast="on" if fast else "off", compile=compile,
                      channels_last=channels_last)
    ds = synthetic_dataset(num_episodes=32, steps=64, size=64 if cfg.image_size <= 64 else cfg.image_size, seed=0)
    sampler = WindowSampler(ds, ds.episodes("train"), cfg.image_size, cfg.window, device, seed=0, non_blocking=fast)
    torch.manual_seed(0)
    model = XJEPA(**model_kwargs(cfg, (4, 7, 2))).to(device).train()
    if channels_last:
        model.to(memory_format=torch.channels_last)
    opt = make_optimizer(model, cfg, fused=fast)
    amp = cfg.amp and device.type == "cuda" and torch.cuda.is_bf16_supported()
    kw = loss_kwargs(cfg)
    loss_fn = compiled(model, mode=compile_mode) if compile else model
    acc = torch.zeros((), device=device)

    def step(i, fn=loss_fn):
        nonlocal acc
        loss, _ = train_step(model, opt, cfg, sampler.sample(cfg.batch_size), i, device, kw, amp=amp, fast=fast,
                             loss_fn=fn)
        acc = acc + loss  # as the trainer: summed on the device, read at log steps only

    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as fc:
        step(0, fn=model)  # count on the eager model: compiled kernels hide their matmuls from the counter
    flops = fc.get_total_flops()
    t_warm = time.perf_counter()
    for i in range(3):  # includes compilation with --compile
        step(i)
    if device.type == "cuda":
        torch.cuda.synchronize()
    warmup_s = time.perf_counter() - t_warm
    t = time.perf_counter()
    for i in range(steps):
        step(i)
    if device.type == "cuda":
        torch.cuda.synchronize()
    dt = (time.perf_counter() - t) / steps
    peak = matmul_peak(device, torch.bfloat16 if amp else torch.float32)
    return {"preset": preset, "device": str(device), "fast": fast, "compile": compile,
            "compile_mode": compile_mode if compile else None, "channels_last": channels_last,
            "warmup_s": warmup_s, "batch_size": cfg.batch_size, "window": cfg.window,
            "image_size": cfg.image_size, "params": sum(p.numel() for p in model.parameters()),
            "sec_per_step": dt, "steps_per_s": 1 / dt, "frames_per_s": cfg.batch_size * cfg.window / dt,
            "preset_steps": cfg.steps, "sec_per_model": cfg.steps * dt,
            "flops_per_step": flops, "achieved_flops": flops / dt, "matmul_peak_flops": peak,
            "fraction_of_peak": flops / dt / peak, "amp_bf16": amp}


def write_results(path: str, device: torch.device, results: list[dict]) -> None:
    """The benchmark's JSON record: machine metadata and one row per timed configuration."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    m = meta(device)
    name = m["gpu"] or f"cpu ({m['cpu_count']} cores)"
    rows = [{"device_name": name, **r} for r in results]  # each row says where it was measured
    out.write_text(json.dumps({"meta": m, "results": rows}, indent=2) + "\n")
    print(f"wrote {out}")


def meta(device: torch.device) -> dict:
    """Where the numbers were taken (a shared machine's load average makes CPU numbers pessimistic)."""
    return {"torch": torch.__version__, "machine": platform.machine(), "cpu_count": os.cpu_count(),
            "threads": torch.get_num_threads(), "loadavg": os.getloadavg() if hasattr(os, "getloadavg") else None,
            "gpu": torch.cuda.get_device_name() if device.type == "cuda" else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=None, help="default: tiny cpu (+ paper on CUDA)")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--threads", type=int, default=0, help="CPU threads (0 = pokeworld.train.auto_threads())")
    ap.add_argument("--fast", action="store_true", help="the fast path (TrainConfig fast='on')")
    ap.add_argument("--compile", action="store_true", help="torch.compile the loss (TrainConfig compile)")
    ap.add_argument("--channels-last", action="store_true", help="channels-last convolutions")
    ap.add_argument("--out", default="benchmarks/results/train_throughput.json")
    args = ap.parse_args()
    device = pick_device(args.device)
    if device.type == "cpu":
        torch.set_num_threads(args.threads or auto_threads())
    presets = args.presets or (["tiny", "cpu", "paper"] if device.type == "cuda" else ["tiny", "cpu"])
    results = []
    for p in presets:
        if p not in PRESETS:
            raise SystemExit(f"unknown preset {p}; choose from {sorted(PRESETS)}")
        r = bench(p, args.steps, device, args.fast, args.compile, args.channels_last)
        results.append(r)
        print(json.dumps(r))
    write_results(args.out, device, results)


if __name__ == "__main__":
    main()
