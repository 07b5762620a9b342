"""Closed-loop push-to-goal planning with frozen X-JEPA models (paper App. C "Closed-loop planning").

CEM over smooth two-knot action programs (16 actions linearly interpolated
between two 2-d knots), scored by the direct Δ=4 and Δ=16 heads: each
candidate's predicted latent is decoded to an object position by a ridge
probe fit on the model's encoder latents (probe-fit episodes), and the score
is the decoded distance to the goal (Δ=16, plus half the Δ=4 distance).
Replanning every 4 steps; the same planner, budget and environment for every
representation, plus a random controller.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .config import from_preset, to_dict
from .data import load
from .errors import ConfigError
from .io import atomic_path, write_json
from .paper_values import PLANNING
from .sim import PhysicsConfig, PokeWorldSim

PROGRAM = 16


@dataclass
class PlanConfig:
    """Push-to-goal with CEM on trained runs."""

    out: str = "out/plan"
    """Output directory for plan.json and plan.md."""
    runs: tuple[str, ...] = ()
    """Run directories (multi-horizon models with Δ=4 and Δ=16 heads) to plan with."""
    data: str = ""
    """Dataset for fitting each model's position decoder (default: each run's training data)."""
    episodes: int = 50
    """Planning episodes (identical starts and goals for every controller)."""
    steps: int = 48
    """Control steps per episode."""
    replan: int = 4
    """Steps executed between replans."""
    population: int = 64
    """CEM candidates per iteration."""
    elites: int = 8
    """CEM elites."""
    iterations: int = 3
    """CEM iterations per replan."""
    context: int = 8
    """Observations of history fed to the model."""
    goal_radius: float = 0.1
    """A success is the object's centre entering this radius around the goal."""
    seed: int = 0
    """Seed of starts, goals and CEM noise."""

    def __post_init__(self) -> None:
        if self.elites > self.population or self.elites < 1:
            raise ConfigError("need 1 <= elites <= population")
        if self.replan < 1 or self.replan > PROGRAM:
            raise ConfigError(f"replan must be in [1, {PROGRAM}]")


PRESETS = {"tiny": {"episodes": 3, "steps": 8, "population": 8, "elites": 2, "iterations": 1},
           "cpu": {}, "paper": {"episodes": 100, "population": 128, "iterations": 4}}


def make_config(preset: str = "cpu", **overrides) -> PlanConfig:
    return from_preset(PlanConfig, PRESETS, preset, **overrides)


def programs(knots: np.ndarray) -> np.ndarray:
    """(..., 4) knots -> (..., 16, 2) actions interpolated from knot 1 to knot 2, clipped to [-1, 1]."""
    w = np.linspace(0.0, 1.0, PROGRAM)[:, None]
    a = knots[..., None, 0:2] * (1 - w) + knots[..., None, 2:4] * w
    return np.clip(a, -1.0, 1.0)


class LatentScorer:
    """Scores action programs with one model's direct heads and its position decoder."""

    def __init__(self, run_dir: str, data: str):
        from .evaluate.measure import EpisodeLatents, position_decoder
        from .train import load_model

        self.model = load_model(run_dir, map_location="cpu")
        if not {4, 16} <= set(self.model.horizons):
            raise ConfigError(f"{run_dir}: planning needs Δ=4 and Δ=16 heads, model has {self.model.horizons}")
        if not data:
            data = json.loads((Path(run_dir) / "config.json").read_text())["data"]
        ds = load(data)
        fit = ds.episodes("probe_fit")
        lat = EpisodeLatents(self.model, ds, fit, 64)
        self.decoder = position_decoder(ds, lat, fit, np.random.default_rng(0))
        self._encoded: tuple[dict, torch.Tensor] | None = None  # (history, its latents): one encode per replan

    @torch.no_grad()
    def score(self, hist: dict, cand: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """hist: frames (E, C, H, W), proprio, touch (E, C, .), actions (E, C-1, 2); cand (E, P, 16, 2) -> (E, P)."""
        E, P = cand.shape[:2]
        m = self.model
        # the history is the same for every CEM iteration of a replan (control() builds it once), so its
        # frames are encoded once, not once per iteration
        if self._encoded is None or self._encoded[0] is not hist:
            self._encoded = (hist, m.encode(hist["frames"], hist["proprio"], hist["touch"]))  # (E, C, D)
        z = self._encoded[1]
        C = z.shape[1]
        zc = z[:, None].expand(E, P, *z.shape[1:]).reshape(E * P, C, -1)
        past = np.repeat(hist["actions"][:, None], P, 1).reshape(E * P, C - 1, 2)
        first = cand[:, :, 0].reshape(E * P, 1, 2)
        h = m.trunk(zc, np.concatenate([past, first], 1).astype(np.float32))[:, -1:]
        h16 = torch.cat([h, h.new_zeros(E * P, PROGRAM - 1, h.shape[-1])], 1)
        acts = cand.reshape(E * P, PROGRAM, 2).astype(np.float32)
        out = 0.0
        for delta, weight in ((16, 1.0), (4, 0.5)):
            zh = m.predict(h16, acts, delta)[:, 0].float().numpy()
            pos = self.decoder.predict(zh).reshape(E, P, 2)
            out = out + weight * np.linalg.norm(pos - goal[:, None], axis=-1)
        return out


def episode_setup(cfg: PlanConfig) -> dict:
    rng = np.random.default_rng(cfg.seed)
    n = cfg.episodes
    fp = rng.uniform(0.15, 0.85, (n, 2))
    op = rng.uniform(0.25, 0.75, (n, 2))
    for _ in range(100):
        bad = np.linalg.norm(op - fp, axis=1) < 0.25
        if not bad.any():
            break
        op[bad] = rng.uniform(0.25, 0.75, (int(bad.sum()), 2))
    ang = rng.uniform(0, 2 * np.pi, n)
    goal = np.clip(op + 0.4 * np.stack([np.cos(ang), np.sin(ang)], 1), 0.15, 0.85)
    return {"finger_pos": fp, "object_pos": op, "goal": goal, "sim_seed": int(rng.integers(2**31))}


def control(cfg: PlanConfig, setup: dict, scorer: LatentScorer | None) -> dict:
    """Run every episode with CEM on ``scorer`` (random actions when None); returns distances over time."""
    n = cfg.episodes
    sim = PokeWorldSim(n, PhysicsConfig(), seed=setup["sim_seed"])
    obs = sim.reset(finger_pos=setup["finger_pos"], object_pos=setup["object_pos"])
    rng = np.random.default_rng(cfg.seed + 1)
    goal = setup["goal"]
    hist = {"frames": [obs["vision"]], "proprio": [obs["proprio"]], "touch": [obs["touch"]], "actions": []}
    dist = [np.linalg.norm(sim.state[:, 4:6] - goal, axis=1)]
    obj_path, finger_path = [sim.state[:, 4:6].copy()], [sim.state[:, 0:2].copy()]
    plan = np.zeros((n, PROGRAM, 2))
    for t in range(cfg.steps):
        k = t % cfg.replan
        if k == 0:
            if scorer is None:
                plan = rng.uniform(-1, 1, (n, PROGRAM, 2))
            else:
                c = cfg.context
                h = {key: np.stack(v[-c:], 1) for key, v in hist.items() if key != "actions"}
                past = hist["actions"][-(h["frames"].shape[1] - 1):] if h["frames"].shape[1] > 1 else []
                h["actions"] = np.stack(past, 1) if len(past) else np.zeros((n, 0, 2), np.float32)
                mu, sd = np.zeros((n, 4)), np.full((n, 4), 0.8)
                for _ in range(cfg.iterations):
                    knots = mu[:, None] + sd[:, None] * rng.normal(size=(n, cfg.population, 4))
                    cand = programs(knots)
                    scores = scorer.score(h, cand, goal)
                    elite = np.argsort(scores, 1)[:, :cfg.elites]
                    ek = np.take_along_axis(knots, elite[..., None], 1)
                    mu, sd = ek.mean(1), ek.std(1) + 0.05
                plan = programs(mu)
        a = plan[:, k]
        obs = sim.step(a)
        hist["frames"].append(obs["vision"])
        hist["proprio"].append(obs["proprio"])
        hist["touch"].append(obs["touch"])
        hist["actions"].append(a.astype(np.float32))
        dist.append(np.linalg.norm(sim.state[:, 4:6] - goal, axis=1))
        obj_path.append(sim.state[:, 4:6].copy())
        finger_path.append(sim.state[:, 0:2].copy())
    d = np.stack(dist, 1)
    paths = np.stack(obj_path, 1)
    # the median improvement is exactly 0 whenever most episodes never touch the object; the mean and the
    # share of episodes whose object moved say whether that is what happened
    moved = np.linalg.norm(paths - paths[:, :1], axis=-1).max(1) > 0.01
    return {"reach": float((d.min(1) < cfg.goal_radius).mean()),
            "median_improvement": float(np.median(d[:, 0] - d[:, -1])),
            "mean_improvement": float(np.mean(d[:, 0] - d[:, -1])), "object_moved": float(moved.mean()), "distance": d,
            "finger_final": sim.state[:, 0:2].copy(), "object_path": paths,
            "finger_path": np.stack(finger_path, 1)}


METRICS = ("reach", "median_improvement", "mean_improvement", "object_moved")
"""Per-controller planning metrics (:func:`control`); the paper reports the first two."""

PAPER = PLANNING
"""Paper Table "planning": controller -> (goal-region reach, median distance improvement)."""


def plan_runs(cfg: PlanConfig, runs: dict[str, list[str]], data: str = "") -> dict:
    """Plan with every run and with the random controller on one shared start/goal set.

    ``runs`` maps a controller label (e.g. a variant) to its run directories (seeds); a label's reach and
    median improvement are the means over its runs (per-run values under ``per_run``). Returns
    ``{"summary": {label: {"reach", "median_improvement", "per_run"}}, "episodes": {label: control output of
    its first run}, "setup": episode_setup(cfg)}``; ``data`` overrides each run's decoder-fit corpus.
    """
    setup = episode_setup(cfg)
    episodes = {"random": control(cfg, setup, None)}
    summary = {"random": {k: episodes["random"][k] for k in METRICS} | {"per_run": {}}}
    for label, dirs in runs.items():
        per = {}
        for r in dirs:
            res = control(cfg, setup, LatentScorer(r, data or cfg.data))
            episodes.setdefault(label, res)
            per[Path(r).name] = {k: res[k] for k in METRICS}
            print(f"[plan] {label} ({Path(r).name}): reach {res['reach']:.0%}, "
                  f"median improvement {res['median_improvement']:+.3f}")
        summary[label] = {k: float(np.mean([v[k] for v in per.values()])) for k in METRICS}
        summary[label]["per_run"] = per
    return {"summary": summary, "episodes": episodes, "setup": setup}


def showcase_episode(episodes: dict, left: str, right: str) -> int:
    """The held-out episode the figure shows: the one where ``right`` beats ``left`` by the largest final
    object-goal distance (a fixed rule, so the figure is not hand-picked)."""
    gain = episodes[left]["distance"][:, -1] - episodes[right]["distance"][:, -1]
    return int(np.argmax(gain))


def figure(planned: dict, out: Path, goal_radius: float, left: str | None = None, right: str | None = None) -> list[Path]:
    """The paper's plan figure: one held-out episode under two representations, plus both distance curves.

    ``left`` / ``right`` default to the first and last planned representation (e.g. V and VFX).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    eps = planned["episodes"]
    labels = [k for k in eps if k != "random"] or ["random"]
    left, right = left or labels[0], right or labels[-1]
    i = showcase_episode(eps, left, right)
    goal = planned["setup"]["goal"][i]
    fig, axes = plt.subplots(1, 3, figsize=(12, 4))
    for ax, label in zip(axes[:2], (left, right)):
        res = eps[label]
        op, fp = res["object_path"][i], res["finger_path"][i]
        ax.add_patch(plt.Circle(goal, goal_radius, color="tab:green", alpha=0.25, lw=0))
        ax.scatter(op[:, 0], op[:, 1], c=np.arange(len(op)), cmap="Blues", s=12, vmin=-len(op) / 3)
        ax.plot(fp[:, 0], fp[:, 1], ":", color="goldenrod", lw=1.5)
        ax.scatter(*op[0], s=120, facecolors="none", edgecolors="tab:blue", lw=1.5)
        reached = res["distance"][i].min() < goal_radius
        ax.set_title(f"{label} {'✓' if reached else '×'} (final distance {res['distance'][i, -1]:.2f})", fontsize=10)
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    for label, style in ((left, "--"), (right, "-")):
        axes[2].plot(eps[label]["distance"][i], style, label=label)
    axes[2].axhline(goal_radius, color="tab:green", lw=1, alpha=0.6, label="goal region")
    axes[2].set_xlabel("control step")
    axes[2].set_ylabel("object-goal distance")
    axes[2].legend(fontsize=8)
    fig.suptitle(f"Held-out episode {i}: same planner and budget, two frozen latents", fontsize=10)
    fig.tight_layout()
    from .io import save_figure

    return save_figure(fig, out, "plan_episode")


def write_outputs(planned: dict, out: Path, goal_radius: float) -> list[Path]:
    """``distances.npz`` (object-goal distance over time per controller, atomically) and the episode figure."""
    with atomic_path(Path(out) / "distances.npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **{k: v["distance"] for k, v in planned["episodes"].items()})
    return figure(planned, Path(out), goal_radius)


def table_lines(summary: dict) -> list[str]:
    """Markdown rows: controller, reach and median improvement, ours beside the paper's."""
    lines = ["| controller | goal-region reach (ours / paper) | median distance improvement (ours / paper) | "
             "mean improvement | object moved |", "|---|---|---|---|---|"]
    for k, v in summary.items():
        p = PAPER.get(k)
        extra = " | ".join("—" if v.get(m) is None else (f"{v[m]:+.3f}" if m == "mean_improvement" else f"{v[m]:.0%}")
                           for m in ("mean_improvement", "object_moved"))
        lines.append(f"| {k} | {v['reach']:.0%} / {f'{p[0]:.0%}' if p else '—'} | "
                     f"{v['median_improvement']:+.3f} / {f'{p[1]:.2f}' if p else '—'} | {extra} |")
    return lines


def run(cfg: PlanConfig) -> Path:
    if not cfg.runs:
        raise ConfigError("give at least one trained run directory with --runs")
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    planned = plan_runs(cfg, {Path(r).name: [r] for r in cfg.runs})
    summary = planned["summary"]
    write_json(out / "plan.json", {"config": to_dict(cfg), "results": summary,
                                   "paper": {k: list(v) for k, v in PAPER.items()}})
    write_outputs(planned, out, cfg.goal_radius)
    lines = table_lines(summary)
    with atomic_path(out / "plan.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return out
