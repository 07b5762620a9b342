"""Where does a spatial-token model keep stiffness? Probe its predictor state three ways.

The measurement reads a token model through the mean of its S token states at the probed step (what
``XJEPA.trunk`` returns, so the token runs share every table with the global-embedding runs). A parameter that
lives in a few tokens — the ones over the contact — can be diluted by that mean. This probes the same
contact windows, with the same leak-free readout, split and ridge probe (``probes.probe_windows``), from
(a) the mean over tokens (must equal the run's measure.json), (b) every token state concatenated (S × width)
and (c) the element-wise max over tokens, for the trained model and for its untrained copy (the bound that
says how much a wider feature vector reads by itself). It also scores every run's own training loss terms
on held-out (probe-test) windows in eval mode — for the token runs and for ``--reference`` runs (the
global-embedding runs they are compared with) — to ask whether a token model that reads less stiffness
forecasts touch worse or better.

    python scripts/token_state_probe.py out/map/data/standard out/map/runs/VF-…-tokensTrue-s0 \
        out/map/runs/VFX-…-tokensTrue-s0 --reference out/map/runs/VFX-…-standard-s0 \
        --out docs/results/token_state_probe_cpu.json
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from ..data import load
from ..evaluate import measure
from ..evaluate.probes import probe_latents, probe_windows
from ..evaluate.state import padded_actions, window_states
from ..io import read_json, write_json
from ..run_store import RECORDED
from ..rundir import finished_run_config, load_model
from ..train.config import TrainConfig
from ..train.sampler import WindowSampler
from ..train.step import loss_kwargs

TARGETS = ("log_k", "log_m", "gamma", "object_pos")
POOLS = ("mean", "concat", "max")


def pooled(h: np.ndarray, pool: str) -> np.ndarray:
    if pool == "mean":
        return h.mean(1)
    if pool == "max":
        return h.max(1)
    return h.reshape(len(h), -1)


def probe_pools(model, ds, cfg) -> dict:
    lat = dict(zip(("fit", "test"), probe_latents(model, ds, cfg)))
    acts = padded_actions(ds)
    cache: dict = {}

    def states(pool):
        def read(w, part):
            key = (part, w.episode.tobytes(), w.start.tobytes())
            if key not in cache:  # one trunk pass per window set, three pools
                cache[key] = window_states(model, ds, lat[part], w, acts, per_token=True)
            return pooled(cache[key], pool)
        return read

    res = {}
    for pool in POOLS:
        r = probe_windows(ds, states(pool), ("contact",), cfg.window, cfg.stride, cfg.max_windows, cfg.seed,
                          mlp=False, targets=TARGETS)
        res[pool] = {"ridge": r["ridge"]["contact"], "counts": r["counts"]["contact"]}
    return res


@torch.no_grad()
def heldout_terms(run: Path, ds, batches: int = 10, batch_size: int = 64, seed: int = 0) -> dict:
    """Mean loss terms (``XJEPA.loss``, eval mode, the run's loss settings) on windows of probe-test episodes."""
    model = load_model(run, map_location="cpu").eval()
    # config.json also records the store's identity (run_store.RECORDED), which is no TrainConfig field
    cfg = TrainConfig(**{k: v for k, v in finished_run_config(run).items() if k not in RECORDED})
    smp = WindowSampler(ds, ds.episodes("probe_test"), model.image_size, cfg.window, torch.device("cpu"), seed=seed)
    acc: dict = {}
    for _ in range(batches):
        _, terms = model.loss(smp.sample(batch_size), **loss_kwargs(cfg))
        for k, v in terms.items():
            acc.setdefault(k, []).append(float(v))
    return {k: float(np.mean(v)) for k, v in acc.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="corpus the runs were measured on")
    ap.add_argument("runs", type=Path, nargs="+", help="token-model run directories")
    ap.add_argument("--reference", type=Path, nargs="*", default=[],
                    help="global-embedding runs whose held-out loss terms are scored beside the token runs'")
    ap.add_argument("--preset", default="cpu", help="measurement preset (windows, caps, seed)")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    for p in (a.data, *a.runs, *a.reference):
        if not p.exists():
            print(f"error: {p} does not exist", file=sys.stderr)
            return 2
    ds, cfg = load(a.data), measure.make_config(a.preset)
    out = {"data": str(a.data), "preset": a.preset, "targets": list(TARGETS), "runs": {}}
    for run in a.runs:
        model = load_model(run, map_location="cpu").eval()
        if not getattr(model, "tokens", False):
            print(f"error: {run} is not a token model", file=sys.stderr)
            return 2
        torch.manual_seed(cfg.seed)
        row = {"tokens_per_step": model.num_tokens, "width": model.width, "image_size": model.image_size,
               "trained": probe_pools(model, ds, cfg),
               "untrained": probe_pools(measure.untrained_like(run).eval(), ds, cfg)}
        measured = Path(run) / "measure.json"
        if measured.exists():  # the mean pool must reproduce the run's own measurement
            stored = read_json(measured, "a run's measure.json")["probes"]["ridge"]["contact"]
            row["measure_json_mean"] = {q: stored.get(q) for q in TARGETS}
        row["heldout_loss_terms"] = heldout_terms(run, ds)
        out["runs"][run.name] = row
        print(run.name, {p: {q: round(row["trained"][p]["ridge"][q], 3) for q in TARGETS} for p in POOLS},
              "untrained", {p: round(row["untrained"][p]["ridge"]["log_k"], 3) for p in POOLS})
    out["reference"] = {r.name: {"heldout_loss_terms": heldout_terms(r, ds)} for r in a.reference}
    for name, row in {**out["runs"], **out["reference"]}.items():
        print(name, "held-out loss terms", {k: round(v, 4) for k, v in row["heldout_loss_terms"].items()})
    write_json(a.out, out)
    return 0
