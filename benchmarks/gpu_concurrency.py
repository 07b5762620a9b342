"""Several runs on one GPU: 1, 2 and 3 concurrent training processes, and one stacked group, per-model step time.

Usage:  python benchmarks/gpu_concurrency.py [--preset paper] [--processes 1 2 3] [--members 2 4 6] [--steps 30]
                                            [--compile auto] [--max-s 115] [--out OUT.json]

Each configuration runs in fresh processes (no compilation is shared with another configuration):

* ``processes k``: k separate training processes at once, each one model (``VFX``, seeds 0..k-1) stepping as
  ``train.run`` does (:func:`train_stacked.bench_sequential` with one member); each times ``--steps`` steps after 3
  warm-up steps (which hold any compilation). Per-model step time = the slowest process's s/step ÷ k: the wall time
  the GPU needs per model-step when k runs share it.
* ``stacked M`` (each M of ``--members``): one process training an M-member stacked group (``pokeworld.train.stacked``; the factorial's
  variants, zero-embedded), per-model step time = its s/step ÷ M.

``--compile auto`` (default) is training's own default: CUDA graphs on CUDA (the warm-up compiles), eager on a CPU.
The whole benchmark stops at ``--max-s`` (default 115 s, so it fits a 2-minute slot): a configuration that would start
past it, or is still running then, is killed and reported as not measured. Rows are printed and written to ``--out``
as each configuration ends, with the device, torch and the load average. On a CPU (``--preset tiny``) it is a dry run
of the script, not a measurement.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # sibling scripts, not a package
from train_stacked import bench_sequential, bench_stacked, member_configs  # noqa: E402

from pokeworld.devices import pick_device  # noqa: E402
from pokeworld.train import synthetic_dataset  # noqa: E402


def worker(a: argparse.Namespace) -> None:
    """One process of one configuration: time its steps and print one JSON line."""
    device = pick_device("auto")
    mix = "factorial" if a.worker == "stacked" else "seeds"
    cfgs = member_configs(a.preset, a.members[0] if a.worker == "stacked" else 1, mix, device, a.compile)
    if a.worker == "single":
        cfgs = [dataclasses.replace(cfgs[0], seed=a.seed)]
    ds = synthetic_dataset(num_episodes=24, steps=40, size=cfgs[0].image_size, seed=0)
    t0 = time.perf_counter()
    row = (bench_stacked if a.worker == "stacked" else bench_sequential)(cfgs, ds, device, a.steps)
    print(json.dumps({"sec_per_step": row["sec_per_step"], "peak_mem_bytes": row.get("peak_mem_bytes"),
                      "wall_s": time.perf_counter() - t0}), flush=True)


class Utilisation:
    """nvidia-smi's GPU utilisation sampled every half second while a configuration runs (read only; None without
    nvidia-smi): the share of time a kernel ran, not how full the GPU was."""

    def __enter__(self) -> "Utilisation":
        import shutil

        self.proc = None
        if shutil.which("nvidia-smi"):
            self.proc = subprocess.Popen(["nvidia-smi", "--query-gpu=utilization.gpu", "--format=csv,noheader,nounits",
                                          "-lms", "500"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        return self

    def __exit__(self, *exc) -> None:
        self.mean = None
        if self.proc is not None:
            self.proc.terminate()
            values = [float(x) for x in self.proc.communicate()[0].split() if x.replace(".", "", 1).isdigit()]
            self.mean = round(sum(values) / len(values), 1) if values else None


def launch(a: argparse.Namespace, kind: str, n: int, deadline: float) -> dict:
    """Run one configuration (n processes of ``single``, or one ``stacked`` of n members) until ``deadline``."""
    with Utilisation() as util:
        row = run_configuration(a, kind, n, deadline)
    return {**row, "gpu_utilisation_percent": util.mean}


def run_configuration(a: argparse.Namespace, kind: str, n: int, deadline: float) -> dict:
    base = [sys.executable, __file__, "--worker", kind, "--preset", a.preset, "--steps", str(a.steps),
            "--compile", a.compile, "--members", str(n)]
    procs = [subprocess.Popen(base + ["--seed", str(i)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in range(n if kind == "single" else 1)]
    rows, failed = [], []
    for p in procs:
        try:
            out, err = p.communicate(timeout=max(1.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            for q in procs:
                q.kill()
            return {"measured": False, "why": "still running at --max-s"}
        lines = [x for x in out.splitlines() if x.startswith("{")]
        if p.returncode != 0 or not lines:
            failed.append(err.strip().splitlines()[-1] if err.strip() else f"exit status {p.returncode}")
        else:
            rows.append(json.loads(lines[-1]))
    if failed:
        return {"measured": False, "why": "; ".join(failed)}
    slowest = max(r["sec_per_step"] for r in rows)
    return {"measured": True, "sec_per_step_each": [r["sec_per_step"] for r in rows],
            "sec_per_model_step": slowest / n, "peak_mem_bytes": [r["peak_mem_bytes"] for r in rows],
            "wall_s": max(r["wall_s"] for r in rows)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="paper")
    ap.add_argument("--processes", nargs="+", type=int, default=[1, 2, 3])
    ap.add_argument("--members", type=int, nargs="*", default=[6],
                    help="members of each stacked group to time (none: no stacked group)")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--compile", choices=("auto", "on", "off"), default="auto")
    ap.add_argument("--max-s", type=float, default=115.0)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--worker", choices=("single", "stacked"), help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        worker(a)
        return
    if any(k < 1 for k in a.processes) or any(m < 1 for m in a.members) or a.steps < 1:
        raise SystemExit("--processes and --members must be ≥ 1 and --steps ≥ 1")
    deadline = time.monotonic() + a.max_s
    device = pick_device("auto")
    meta = {"device": torch.cuda.get_device_name() if device.type == "cuda" else f"cpu ({os.cpu_count()} cores)",
            "torch": torch.__version__, "preset": a.preset, "compile": a.compile, "steps": a.steps,
            "loadavg": list(os.getloadavg())}
    rows = []
    configs = [("single", k) for k in a.processes] + [("stacked", m) for m in a.members]
    for kind, n in configs:
        label = f"{n} process{'es' if n > 1 else ''}" if kind == "single" else f"stacked group of {n}"
        row = {"configuration": label, **(launch(a, kind, n, deadline) if time.monotonic() < deadline else
                                         {"measured": False, "why": "not started: --max-s reached"})}
        rows.append(row)
        each = ", ".join(f"{s:.4f}" for s in row.get("sec_per_step_each", []))
        print(f"[gpu_concurrency] {label}: " + (f"{row['sec_per_model_step']:.4f} s per model-step (each process "
                                                f"{each} s/step)" if row["measured"] else
                                                f"not measured ({row['why']})"), flush=True)
        if a.out:
            a.out.parent.mkdir(parents=True, exist_ok=True)
            a.out.write_text(json.dumps({"meta": meta, "results": rows}, indent=1))


if __name__ == "__main__":
    main()
