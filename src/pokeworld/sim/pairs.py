"""The matched-pairs figure (paper Fig. "pairs"): same start frame and actions, one hidden parameter differs."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import SEED, Limit, check_fields, from_preset
from ..errors import ConfigError
from ..io import check_outputs, save_figure, save_npz
from .core import PhysicsConfig, PokeWorldSim

PAIRS = {  # parameter -> (low value, high value, base params, finger start, object start, action program)
    "gamma": ((0.5, 4.0), "strike"),
    "mass": ((0.5, 3.0), "strike"),
    "stiffness": ((500.0, 6000.0), "strike"),
}
BASE = {"mass": 1.0, "gamma": 1.0, "stiffness": 2000.0}


@dataclass
class PairsConfig:
    """Render the matched-pairs figure."""

    out: str = "out/pairs"
    """Output directory for pairs.png / pairs.pdf and pairs.npz (the trajectories)."""
    steps: int = 40
    """Control steps per episode."""
    seed: int = 0
    """Seed of the touch noise (trajectories are noise-free)."""
    contact_damping: str = PhysicsConfig.contact_damping
    """The contact-damping law (PhysicsConfig.contact_damping): "tangent" (the default) or "constant"."""

    LIMITS = {"steps": Limit(1, 10**4), "seed": SEED}

    def __post_init__(self) -> None:
        check_fields(self)


PRESETS = {"tiny": {"steps": 12}, "cpu": {}, "paper": {}}


def make_config(preset: str = "cpu", **overrides) -> PairsConfig:
    return from_preset(PairsConfig, PRESETS, preset, **overrides)


def strike_actions(steps: int) -> np.ndarray:
    """Full-force strike to the right for 6 steps, then retreat and hold: one clean impact and a glide."""
    a = np.zeros((steps, 2))
    a[:6, 0] = 1.0
    a[6:12, 0] = -0.6
    return a


def rollout_pair(param: str, steps: int, seed: int = 0, contact_damping: str = PhysicsConfig.contact_damping) -> dict:
    """Two episodes from the identical start and actions, differing only in ``param``."""
    if param not in PAIRS:
        raise ConfigError(f"unknown pair parameter {param!r}; choose one of {list(PAIRS)}")
    (lo, hi), _ = PAIRS[param]
    sim = PokeWorldSim(2, PhysicsConfig(touch_noise=0.0, contact_damping=contact_damping), seed=seed)
    values = {k: np.array([v, v]) for k, v in BASE.items()}
    values[param] = np.array([lo, hi])
    sim.reset(params=values, finger_pos=[0.2, 0.45], object_pos=[0.38, 0.47])
    acts = strike_actions(steps)
    frames, obj, fin, touch = [sim.frames.copy()], [sim.state[:, 4:6].copy()], [sim.state[:, 0:2].copy()], []
    for t in range(steps):
        sim.step(np.repeat(acts[t][None], 2, 0))
        frames.append(sim.frames.copy())
        obj.append(sim.state[:, 4:6].copy())
        fin.append(sim.state[:, 0:2].copy())
        touch.append(sim.touch_clean.copy())
    return {"param": param, "values": (lo, hi), "frames": np.stack(frames, 1), "object": np.stack(obj, 1),
            "finger": np.stack(fin, 1), "touch": np.stack(touch, 1), "actions": acts}


def final_gap(pair: dict) -> float:
    """Distance between the two episodes' objects at the last step: how far the hidden parameter moved the
    post-contact trajectory (arena units)."""
    return float(np.linalg.norm(pair["object"][0, -1] - pair["object"][1, -1]))


def _draw_pair(ax, pr: dict, plt) -> None:
    """One panel: both episodes' object paths (solid / dashed, end position circled), the finger's paths (dotted) and
    the shared start positions, with axis labels and a legend that names every mark."""
    for k, (style, alpha) in enumerate((("-", 1.0), ("--", 0.8))):
        ob, fi = pr["object"][k], pr["finger"][k]
        ax.plot(ob[:, 0], ob[:, 1], style, color=f"C{k}", alpha=alpha,
                label=f"object path, {pr['param']} = {pr['values'][k]:g}")
        ax.plot(fi[:, 0], fi[:, 1], ":", color="goldenrod", alpha=0.6, label="finger path" if k == 0 else None)
        ax.add_patch(plt.Circle(ob[-1], 0.09, fill=False, color=f"C{k}", label=f"object at the end, {pr['param']} = "
                                f"{pr['values'][k]:g}"))
    ax.add_patch(plt.Circle(pr["object"][0, 0], 0.09, color="tab:blue", alpha=0.4, label="object at start"))
    ax.add_patch(plt.Circle(pr["finger"][0, 0], 0.06, color="gold", alpha=0.6, label="finger at start"))
    same0 = np.array_equal(pr["frames"][0, 0], pr["frames"][1, 0])
    peak = pr["touch"][:, :, 2].max(1)
    ax.set_title(f"{pr['param']}: first frames {'identical' if same0 else 'DIFFER'}\npeak touch {peak[0]:.2f} vs "
                 f"{peak[1]:.2f} (× max finger force)\nfinal object gap {final_gap(pr):.3f} arena units", fontsize=8)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_aspect("equal")
    ax.set_xlabel("x (arena units)")
    ax.set_ylabel("y (arena units)")
    ax.legend(fontsize=7, loc="upper left")


def run(cfg: PairsConfig) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(cfg.out)
    check_outputs(out, "pairs.png", "pairs.pdf", "pairs.npz")  # a user's file of those names is refused first
    pairs = [rollout_pair(p, cfg.steps, cfg.seed, cfg.contact_damping) for p in PAIRS]
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.8))
    for ax, pr in zip(axes, pairs):
        _draw_pair(ax, pr, plt)
    fig.suptitle("Matched pairs: identical start frame and actions, one hidden parameter differs "
                 f"({cfg.contact_damping} contact damping)")
    fig.tight_layout()
    save_figure(fig, out, "pairs", dpi=130)
    save_npz(out / "pairs.npz", {f"{p['param']}_{k}": p[k] for p in pairs for k in ("object", "finger", "touch")},
             compressed=True)
    print(f"[pairs] wrote {out / 'pairs.png'}, pairs.pdf and pairs.npz")
    return out
