"""Which swm variations reach the physics, and what collecting on two cores buys (run by hand, in the swm environment
with dm-control).

1. For each (environment, factor): the compiled MuJoCo ``body_mass`` after a reset with the factor at its range's
   low and high end, beside :func:`pokeworld.swm.factor_effect.factor_effects`'s verdict (inert or not) — the
   numbers behind docs/design.md, "Does a factor act at all?".
2. With ``--collect-episodes N``: the wall time of ``swm-certify``'s collection of N Pendulum episodes with one and
   with two workers (docs/design.md, "Collecting on several cores").

    python scripts/swm_factor_physics.py --out benchmarks/results/swm_factor_physics.json --collect-episodes 120
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from pokeworld.io import write_json

FACTORS = {
    "swm/PendulumDMControl-v0": ("agent.mass_density", "agent.pole_density", "gravity.z"),
    "swm/CartpoleDMControl-v0": ("agent.cart_mass", "agent.pole_density", "gravity.z"),
    "swm/AcrobotDMControl-v0": ("agent.upper_arm_density", "agent.lower_arm_density"),
    "swm/FingerDMControl-v0": ("spinner.density",),
    "swm/BallInCupDMControl-v0": ("ball.density",),
}


def body_masses(env_id: str, key: str) -> dict[str, list[float]]:
    """The compiled body masses with ``key`` at the low and at the high end of its range."""
    import gymnasium as gym

    from pokeworld.swm.factor_effect import subspace

    env = gym.make(env_id)
    try:
        sub = subspace(env.unwrapped.variation_space, key)
        out = {}
        for end, value in (("low", sub.low), ("high", sub.high)):
            env.reset(seed=0, options={"variation": [key], "variation_values": {key: np.asarray(value, sub.dtype)}})
            out[end] = np.round(env.unwrapped.env.physics.model.body_mass, 4).tolist()
        return out
    finally:
        env.close()


def collection_times(episodes: int, work: Path) -> dict[str, float]:
    from pokeworld.swm.certify_env import collect, make_config

    times = {}
    for workers in (1, 2):
        cfg = make_config("cpu", env="swm/PendulumDMControl-v0", factors=("gravity.z",), episodes=episodes, steps=48,
                          workers=workers, out=str(work))
        path = work / f"corpus-w{workers}.h5"
        t0 = time.time()
        collect(cfg, path)
        times[f"workers_{workers}_s"] = round(time.time() - t0, 1)
        print(f"[swm-factor-physics] {episodes} Pendulum episodes, {workers} worker(s): {times[f'workers_{workers}_s']} s")
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="out/swm_factor_physics.json")
    ap.add_argument("--collect-episodes", type=int, default=0, help="0: skip the collection timing")
    ap.add_argument("--work", default="out/swm_factor_physics", help="where the timed collections are written")
    args = ap.parse_args()
    from pokeworld.swm.certify_env import headless_gl, variation_names
    from pokeworld.swm.factor_effect import factor_effects

    headless_gl()
    rows = []
    for env_id, keys in FACTORS.items():
        variation_names(env_id)  # registers the environments
        effects = factor_effects(env_id, keys)
        for key in keys:
            row = {"env": env_id, "factor": key, "body_mass": body_masses(env_id, key), "inert": effects[key]["inert"],
                   "effect": effects[key]["effect"]}
            rows.append(row)
            print(f"[swm-factor-physics] {env_id} {key}: body_mass {row['body_mass']['low']} -> "
                  f"{row['body_mass']['high']}, inert {row['inert']}")
    result = {"factors": rows, "cpu_count": os.cpu_count()}
    if args.collect_episodes:
        work = Path(args.work)
        work.mkdir(parents=True, exist_ok=True)
        result["collection"] = {"episodes": args.collect_episodes, **collection_times(args.collect_episodes, work)}
    write_json(args.out, result)
    print(f"[swm-factor-physics] wrote {args.out}")


if __name__ == "__main__":
    main()
