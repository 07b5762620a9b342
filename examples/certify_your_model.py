"""Certify your own model: the worked example of docs/protocol.md, end to end on a small generated corpus.

    python examples/certify_your_model.py [--out out/certify_example] [--episodes 96]

The model below is defined here, outside the package, the way your own world model would be: a small
CNN per frame, fused with proprioception, touch and the action, and a GRU over time. It is left at its
random initialisation so the script runs in minutes on a CPU; load your trained weights in its place.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from torch import nn

from pokeworld.data import is_complete, save
from pokeworld.protocol import certify_model
from pokeworld.sim.generate import make_config, simulate


class TinyWorldModel(nn.Module):
    """frames (B, L, H, W) uint8, proprio (B, L, 4), touch (B, L, 7), actions (B, L, 2) -> states (B, L, 64)."""

    def __init__(self, seed: int = 0, width: int = 64):
        super().__init__()
        torch.manual_seed(seed)
        self.cnn = nn.Sequential(nn.Conv2d(1, 8, 4, 2, 1), nn.GELU(), nn.Conv2d(8, 16, 4, 2, 1), nn.GELU(),
                                 nn.AdaptiveAvgPool2d(4), nn.Flatten(), nn.Linear(16 * 4 * 4, 32))
        self.gru = nn.GRU(32 + 4 + 7 + 2, width, batch_first=True)

    def forward(self, frames, proprio, touch, actions):
        B, L, H, W = frames.shape
        x = self.cnn(frames.reshape(B * L, 1, H, W).float() / 255.0).reshape(B, L, -1)
        states, _ = self.gru(torch.cat([x, proprio, touch, actions], -1))
        return states


def verdict(claim: dict) -> str:
    """What a row says: a gate that passed licenses a claim either way, so the line says which way it goes (the
    model holds the parameter when its R² is above the untrained bound, or 0 without one)."""
    if claim["status"] != "claim":
        return claim["status"]  # "no claim (gate failed)" or "not gated"
    bound = claim.get("untrained", 0.0)
    if claim["ridge"] > max(bound, 0.0):
        return "gate passed: claim — the model holds it (R² above the untrained bound)"
    return "gate passed: claim — the model does not hold it (R² at or below the untrained bound)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/certify_example", help="where the corpus and the report go")
    ap.add_argument("--episodes", type=int, default=96, help="episodes in the generated corpus")
    args = ap.parse_args()
    out = Path(args.out)

    # 1. a small PokeWorld corpus (train / probe-fit / probe-test episode split included)
    store = out / "data"
    if not is_complete(store):
        save(simulate(make_config("tiny", num_episodes=args.episodes, batch_envs=args.episodes)), store)

    # 2. your model, and the same architecture at initialisation for the untrained bound
    model, untrained = TinyWorldModel(seed=0), TinyWorldModel(seed=1)

    # 3. certificates (computed here: the store has none), probes, report
    report = certify_model(model, data=store, out=out / "report", untrained=untrained, name="TinyWorldModel",
                           preset="tiny", certify_estimators=("gru", "linear", "drag"))

    for q, c in report["claims"].items():
        print(f"{q:12s} ridge R² {c['ridge']:+.2f}  untrained {c.get('untrained', float('nan')):+.2f}  {verdict(c)}")
    print(f"report: {out / 'report' / 'protocol.md'}")


if __name__ == "__main__":
    main()
