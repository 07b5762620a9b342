"""Can a direct Δ = 16 head of a given depth represent where an action program sends the object?

The planner asks a model's Δ = 16 head, for every candidate two-knot program, where the object ends up. Most
candidates never touch the object (the true answer is then "nowhere"); a head that cannot tell them apart
predicts *phantom pushes* (docs/results/deviations_cpu.md §3). This separates capacity from representation: the
model's own :class:`~pokeworld.models.xjepa.DeltaHead` is trained on the **true** simulator state (finger and
object position and velocity) plus the flattened program, on programs drawn like the planner's and the
open-loop slots' (half aimed at the object, knots spread ``KNOT_SD``), with as many hidden layers as asked. If
a head cannot fit the contact gate even from the true state, no representation will let it plan.

With ``--run RUN`` the same heads are fit on that trained model's **frozen** trunk state at the start
observation (what its own Δ = 16 head reads when the planner asks; the trunk sees the program's first action, as
in planning) instead of the true state: if a fresh head on the frozen state fits the gate where the model's own
head predicts phantom pushes, the state holds the geometry and the head's training signal is what is missing.

Scored on held-out starts and programs (:func:`pokeworld.evaluate.counterfactual.counterfactual_fit`'s
terms): the mean predicted displacement on programs that truly miss (truth 0), on those that hit (against the
true mean), and R² of the end displacement.

    python scripts/head_capacity.py --out docs/results/head_capacity.json
    python scripts/head_capacity.py --run RUN --out docs/results/head_capacity_frozen.json
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict, dataclass

import numpy as np
import torch

from ..evaluate.counterfactual import counterfactual_fit
from ..evaluate.state import encode_observations
from ..io import write_json
from ..models.xjepa import DeltaHead
from ..plan import FINGER_BOX, OBJECT_BOX
from ..rundir import load_model
from ..sim import PhysicsConfig, PokeWorldSim
from ..sim.policy import PROGRAM, PolicyConfig, aimed_knots, programs


@dataclass
class HeadCapacityConfig:
    """What to fit and how long."""

    layers: tuple[int, ...] = (1, 2, 3)
    """Hidden-layer counts to compare (``TrainConfig.head_layers``)."""
    hidden: int = 128
    """Hidden width of each head (the ``cpu`` preset's predictor width, which a head's hidden layers share)."""
    fit_samples: int = 20000
    """(start, program) pairs to fit on."""
    test_samples: int = 10000
    """Held-out pairs (independent starts, parameters and programs)."""
    steps: int = 8000
    """Adam steps at batch 256."""
    seed: int = 0
    """Seed of the fit set (the test set uses seed + 1) and of each head's initialisation."""
    run: str = ""
    """A trained run directory: fit on its frozen trunk state at the start observation instead of the true state."""


def sample(n: int, seed: int, observe: bool = False) -> tuple[np.ndarray, ...]:
    """n starts (finger and object at rest, anywhere in the planner's boxes, random hidden parameters) with one
    program each -> (state (n, 8), program (n, 16, 2), the object's true displacement after it (n, 2)); with
    ``observe`` also the start observation (rendered frames, proprio, touch)."""
    rng = np.random.default_rng(seed)
    sim = PokeWorldSim(n, PhysicsConfig() if observe else PhysicsConfig(image_size=8), seed=seed)
    fp, op = rng.uniform(*FINGER_BOX, (n, 2)), rng.uniform(*OBJECT_BOX, (n, 2))
    obs = sim.reset(finger_pos=fp, object_pos=op)
    start = sim.state[:, :8].copy()
    u = (op - fp) / np.maximum(np.linalg.norm(op - fp, axis=1, keepdims=True), 1e-9)
    aimed = rng.random(n) < 0.5  # half like the open-loop slots, half like the CEM's first proposal (aim 0)
    acts = programs(aimed_knots(u, PolicyConfig().open_loop_aim * aimed[:, None], rng))
    for t in range(PROGRAM):
        sim.step(acts[:, t], render=False)
    out = (start, acts, sim.state[:, 4:6] - start[:, 4:6])
    return (*out, obs) if observe else out


@torch.no_grad()
def frozen_states(run_dir: str, obs: dict, acts: np.ndarray) -> np.ndarray:
    """A trained model's trunk state (n, width) at each start observation, given the program's first action."""
    model = load_model(run_dir, map_location="cpu").eval()
    z = torch.as_tensor(encode_observations(model, obs, keep_tokens=True))[:, None]
    return model.trunk(z, acts[:, :1].astype(np.float32))[:, 0].float().numpy()


def fit_head(layers: int, x: np.ndarray, a: np.ndarray, y: np.ndarray, cfg: HeadCapacityConfig) -> DeltaHead:
    """Fit a DeltaHead(state, program) -> displacement (inputs standardised, targets ×10) by MSE."""
    torch.manual_seed(cfg.seed)
    head = DeltaHead(x.shape[1], a.shape[1], y.shape[1], hidden=cfg.hidden, layers=layers)
    opt = torch.optim.Adam(head.parameters(), 1e-3)
    X, A, Y = (torch.tensor(v, dtype=torch.float32) for v in (x, a, y * 10))
    g = torch.Generator().manual_seed(cfg.seed)
    for _ in range(cfg.steps):
        i = torch.randint(0, len(X), (256,), generator=g)
        loss = ((head(X[i], A[i]) - Y[i]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return head


def score(pred: np.ndarray, true: np.ndarray) -> dict:
    """Predicted vs true displacements (n, 2) -> the rank test's miss / hit displacements (every pair its own
    start, at the origin) and R² of the displacement."""
    fit = counterfactual_fit(pred[None], true[None], np.zeros((1, 2)))
    r2 = 1 - ((pred - true) ** 2).sum() / ((true - true.mean(0)) ** 2).sum()
    return {k: fit[k] for k in ("miss_displacement", "hit_displacement", "hit_true_displacement", "hit_share")} | {
        "r2": float(r2)}


def fit_and_score(layers: int, fit: tuple, test: tuple, cfg: HeadCapacityConfig) -> dict:
    """Fit one head on ``fit`` = (features (n, F), programs (n, 16, 2), displacements (n, 2)), both inputs
    standardised with the fit set's statistics, and :func:`score` it on ``test`` (same layout)."""
    (xs, acts, ys), (xt, actt, yt) = fit, test
    flat, flatt = acts.reshape(len(acts), -1), actt.reshape(len(actt), -1)
    mu, sd, amu, asd = xs.mean(0), xs.std(0) + 1e-6, flat.mean(0), flat.std(0) + 1e-6
    head = fit_head(layers, (xs - mu) / sd, (flat - amu) / asd, ys, cfg)
    with torch.no_grad():
        pred = head(torch.tensor((xt - mu) / sd, dtype=torch.float32),
                    torch.tensor((flatt - amu) / asd, dtype=torch.float32)).numpy() / 10
    return score(pred, yt)


def run(cfg: HeadCapacityConfig) -> dict:
    fit, test = sample(cfg.fit_samples, cfg.seed, bool(cfg.run)), sample(cfg.test_samples, cfg.seed + 1, bool(cfg.run))
    if cfg.run:  # the frozen model state replaces the true one
        fit, test = ((frozen_states(cfg.run, d[3], d[1]), *d[1:3]) for d in (fit, test))
    out = {"config": asdict(cfg), "input": f"frozen trunk state of {cfg.run}" if cfg.run else "true state",
           "heads": {}}
    for layers in cfg.layers:
        t0 = time.time()
        res = fit_and_score(layers, fit[:3], test[:3], cfg) | {"seconds": round(time.time() - t0, 1)}
        out["heads"][str(layers)] = res
        print(f"[head_capacity] {out['input']}, {layers} hidden layer(s): predicted displacement on misses "
              f"{res['miss_displacement']:.3f}, on hits {res['hit_displacement']:.3f} (true "
              f"{res['hit_true_displacement']:.3f}), R² {res['r2']:+.2f}")
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", required=True, help="JSON file to write")
    p.add_argument("--steps", type=int, default=HeadCapacityConfig.steps)
    p.add_argument("--fit-samples", type=int, default=HeadCapacityConfig.fit_samples)
    p.add_argument("--layers", type=int, nargs="+", default=list(HeadCapacityConfig.layers))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--run", default="", help="fit on this trained run's frozen trunk state instead of the true state")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (small heads run fastest on one)")
    a = p.parse_args(argv if argv is not None else sys.argv[1:])
    torch.set_num_threads(a.threads)
    cfg = HeadCapacityConfig(layers=tuple(a.layers), fit_samples=a.fit_samples, steps=a.steps, seed=a.seed,
                             run=a.run)
    write_json(a.out, run(cfg))


__all__ = ["HeadCapacityConfig", "sample", "frozen_states", "fit_head", "fit_and_score", "score", "run", "main"]
