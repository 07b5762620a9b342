"""PokeWorld env-steps/s with rendering at several batch sizes (and gym-pusht for scale, if installed).

Run by hand:  python benchmarks/sim_throughput.py [--seconds 3] [--out benchmarks/results/sim_throughput.json]
Writes JSON: machine facts, steps/s per N, and the PushT ratio when gym-pusht imports.
Target (issue 2): >= 300,000 env-steps/s with rendering at N >= 1024 on a 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np


def bench_pokeworld(n: int, seconds: float) -> dict:
    from pokeworld.sim import PokeWorldSim

    sim = PokeWorldSim(n, seed=0)
    sim.reset()
    acts = np.random.default_rng(0).uniform(-1, 1, (64, n, 2))
    sim.step(acts[0])  # compile / warm up
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for k in range(64):
            sim.step(acts[k])
        sim.reset()
        steps += 64
    dt = time.perf_counter() - t0
    return {"num_envs": n, "env_steps_per_s": n * steps / dt, "seconds": dt}


def bench_pusht(seconds: float) -> dict | None:
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    try:
        import gym_pusht  # noqa: F401
        import gymnasium as gym
    except Exception as e:  # noqa: BLE001 - optional comparison only
        return {"available": False, "reason": repr(e)}
    env = gym.make("gym_pusht/PushT-v0", obs_type="pixels", render_mode="rgb_array")
    env.reset(seed=0)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        n += 1
        if term or trunc:
            env.reset()
    return {"available": True, "env_steps_per_s": n / (time.perf_counter() - t0), "obs": "pixels 96x96 RGB",
            "note": "single env, pymunk physics + pygame rendering"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 1024, 4096])
    ap.add_argument("--out", default="")
    args = ap.parse_args()
    import numba

    res = {"benchmark": "sim_throughput", "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                                                      "numba_threads": numba.get_num_threads()},
           "pokeworld": [bench_pokeworld(n, args.seconds) for n in args.sizes],
           "pusht": bench_pusht(args.seconds)}
    best = max(r["env_steps_per_s"] for r in res["pokeworld"] if r["num_envs"] >= 1024)
    res["target_300k_at_N>=1024"] = {"best": best, "met": best >= 300_000}
    if res["pusht"] and res["pusht"].get("available"):
        one = next(r for r in res["pokeworld"] if r["num_envs"] == 1)["env_steps_per_s"]
        res["pusht"]["ratio_pokeworld_N1"] = one / res["pusht"]["env_steps_per_s"]
        res["pusht"]["ratio_pokeworld_best"] = best / res["pusht"]["env_steps_per_s"]
    text = json.dumps(res, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text + "\n")


if __name__ == "__main__":
    main()
