"""CPU training throughput study for the `cpu` preset (issue: the demo on 2 cores).

Usage:  python benchmarks/train_cpu.py [--preset cpu] [--batch-size N] [--image-size N] [--steps 30] [--out benchmarks/results/train_cpu.json]

Measures, on synthetic data at the preset's sizes, full optimisation steps as ``pokeworld.train.run`` takes them:

* one model with 1 thread, one model with 2 threads, and two models side by side with 1 thread each
  (two processes; aggregate steps/s), which is how ``pokeworld map``/``demo`` use a 2-core machine;
* ``channels_last`` and ``torch.compile`` (inductor, CPU) on one thread;
* the cost split of one eager step on one thread: encoder forward+backward, SIGReg forward+backward,
  AdamW step and the rest (predictor, heads, losses, window gathering), each by timing it in isolation
  with the same tensors.

This CPU has AVX2 only (no AVX-512, no AMX), so bf16 autocast is not measured: it is slower than fp32 here.
Run it on an idle machine; the JSON records the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from train_throughput import write_results  # noqa: E402

from pokeworld.losses import sigreg  # noqa: E402
from pokeworld.models import XJEPA  # noqa: E402
from pokeworld.train import (  # noqa: E402
    WindowSampler,
    compiled,
    loss_kwargs,
    make_config,
    make_optimizer,
    model_kwargs,
    sigreg_directions,
    synthetic_dataset,
    train_step,
)


def setup(preset: str, channels_last: bool = False, **over):
    cfg = make_config(preset, device="cpu", fast="off", channels_last=channels_last, **over)
    ds = synthetic_dataset(num_episodes=32, steps=64, size=64, seed=0)
    sampler = WindowSampler(ds, ds.episodes("train"), cfg.image_size, cfg.window, torch.device("cpu"), seed=0)
    torch.manual_seed(0)
    model = XJEPA(**model_kwargs(cfg, (4, 7, 2))).train()
    if channels_last:
        model.to(memory_format=torch.channels_last)
    return cfg, sampler, model, make_optimizer(model, cfg)


def time_steps(preset: str, steps: int, threads: int, compile: bool = False, channels_last: bool = False,
               **over) -> float:
    """Seconds per full optimisation step after 3 warm-up steps."""
    torch.set_num_threads(threads)
    cfg, sampler, model, opt = setup(preset, channels_last, **over)
    kw = loss_kwargs(cfg)
    fn = compiled(model) if compile else model

    def step(i):
        train_step(model, opt, cfg, sampler.sample(cfg.batch_size), i, torch.device("cpu"), kw, loss_fn=fn)

    for i in range(3):
        step(i)
    t = time.perf_counter()
    for i in range(steps):
        step(i)
    return (time.perf_counter() - t) / steps


def _worker(args, over, q):
    q.put(time_steps(*args, **over))


def side_by_side(preset: str, steps: int, n: int = 2, **over) -> list[float]:
    """Seconds per step of each of ``n`` concurrent single-threaded models (separate processes)."""
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    procs = [ctx.Process(target=_worker, args=((preset, steps, 1), over, q)) for _ in range(n)]
    for p in procs:
        p.start()
    out = [q.get() for _ in procs]
    for p in procs:
        p.join()
    return out


def cost_split(preset: str, reps: int, **over) -> dict:
    """Seconds per step spent in each part of an eager single-threaded step."""
    torch.set_num_threads(1)
    cfg, sampler, model, opt = setup(preset, **over)
    kw = loss_kwargs(cfg)
    b = sampler.sample(cfg.batch_size)
    dirs = sigreg_directions(cfg, 0, "cpu")

    def timed(fn) -> float:
        fn()
        t = time.perf_counter()
        for _ in range(reps):
            fn()
        return (time.perf_counter() - t) / reps

    def full():
        loss, _ = model(b, sigreg_seed=0, sigreg_directions=dirs, **kw)
        opt.zero_grad(set_to_none=True)
        loss.backward()

    def sample():
        sampler.sample(cfg.batch_size)

    def encoder():
        z = model.encode(b["frames"], b["proprio"], b["touch"])
        z.square().mean().backward()

    z0 = model.encode(b["frames"], b["proprio"], b["touch"]).detach()

    def sig():
        z = z0.clone().requires_grad_()
        sigreg(z.transpose(0, 1), cfg.sigreg_dirs, 0, cfg.sigreg_knots, directions=dirs).backward()

    full()

    def adamw():
        opt.step()

    t_full, t_sample, t_enc, t_sig, t_opt = timed(full), timed(sample), timed(encoder), timed(sig), timed(adamw)
    return {"step_without_optimizer_s": t_full, "window_sampling_s": t_sample, "encoder_fwd_bwd_s": t_enc,
            "sigreg_fwd_bwd_s": t_sig, "adamw_s": t_opt,
            "predictor_heads_losses_s": max(0.0, t_full - t_enc - t_sig),
            "note": "predictor_heads_losses = full forward+backward minus encoder and SIGReg; sampling and "
                    "AdamW come on top of the full forward+backward"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="cpu")
    ap.add_argument("--batch-size", type=int, default=0, help="windows per step (0: the preset's)")
    ap.add_argument("--image-size", type=int, default=0, help="encoder input side (0: the preset's; 64 = the paper's)")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--out", default="benchmarks/results/train_cpu.json")
    args = ap.parse_args()
    load_before = os.getloadavg()
    over = ({"batch_size": args.batch_size} if args.batch_size else {}) | (
        {"image_size": args.image_size} if args.image_size else {})
    rows = []
    one1 = time_steps(args.preset, args.steps, 1, **over)
    rows.append({"setting": "one model, 1 thread", "sec_per_step": one1, "model_steps_per_s": 1 / one1})
    one2 = time_steps(args.preset, args.steps, 2, **over)
    rows.append({"setting": "one model, 2 threads", "sec_per_step": one2, "model_steps_per_s": 1 / one2})
    pair = side_by_side(args.preset, args.steps, **over)
    rows.append({"setting": "two models, 1 thread each (2 processes)", "sec_per_step": pair,
                 "model_steps_per_s": sum(1 / s for s in pair)})
    cl = time_steps(args.preset, args.steps, 1, channels_last=True, **over)
    rows.append({"setting": "one model, 1 thread, channels_last", "sec_per_step": cl, "model_steps_per_s": 1 / cl})
    try:
        comp = time_steps(args.preset, args.steps, 1, compile=True, **over)
        rows.append({"setting": "one model, 1 thread, torch.compile", "sec_per_step": comp,
                     "model_steps_per_s": 1 / comp})
    except Exception as e:  # inductor needs a C++ compiler; record why it could not be timed
        rows.append({"setting": "one model, 1 thread, torch.compile", "error": f"{type(e).__name__}: {e}"[:300]})
    for r in rows:
        print(json.dumps(r))
    split = cost_split(args.preset, max(5, args.steps // 3), **over)
    print(json.dumps(split))
    res = {"preset": args.preset, "batch_size": args.batch_size or make_config(args.preset).batch_size,
           "image_size": args.image_size or make_config(args.preset).image_size, "rows": rows, "cost_split_1_thread": split,
           "loadavg_before": load_before, "loadavg_after": os.getloadavg()}
    write_results(args.out, torch.device("cpu"), [res])


if __name__ == "__main__":
    main()
