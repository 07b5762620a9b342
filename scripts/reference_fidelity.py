"""PokeWorld's environments against the authors' released reference, statistic by statistic (run by hand).

Generates each environment's corpus at a preset render-free (the statistics read states, touch and actions only),
measures the statistics of the side-by-side table on it (pokeworld.sim.fidelity) and writes JSON + Markdown:

    python scripts/reference_fidelity.py --preset paper --out docs/results/reference_fidelity

The reference's numbers were measured outside the project by running the authors' released simulator
(exp/e001_xmodal_jepa/pokeworld.py of tantansir/latent-world-model-identifiability, the later ``glide_ep`` draw
removed), side by side with the same statistics of the calibrated environment's paper corpus (the outside
measurement's calibrated column, ``fidelity.CALIBRATED_ISSUE``); the calibrated environment's numbers measured here
are checked against that column first, which proves the measurement. The JSON keeps a ``model`` section for the
model half (parameter counts, per-variant numbers: scripts/reference_model_table.py); this script leaves what is
there untouched.
"""

import argparse
import time
from pathlib import Path

from pokeworld.io import read_json, read_json_if_present, save_text, write_json
from pokeworld.sim import fidelity
from pokeworld.sim.generate import content_config, make_config, simulate

REFERENCE_SOURCE = ("the authors' released simulator (exp/e001_xmodal_jepa/pokeworld.py, "
                    "tantansir/latent-world-model-identifiability, with the later glide_ep draw removed), run outside "
                    "the project side by side with the calibrated environment's paper corpus; its probe-test split reproduces static-16 0.2048 "
                    "(exp/e003_motion/results/VFX_s0_l0.02.json static_baseline_err) and the window counts 3,228 / 3,319")
LABELS = {"restitution_k500": "head-on restitution, k 500 (m 1.22, v 1.3)", "restitution_k1732": "… k 1732",
          "restitution_k6000": "… k 6000", "static16": "static-16 ‖p(31) − p(15)‖",
          "contact_step_fraction": "steps in contact", "contact_window_fraction": "windows with ≥ 2 contact frames",
          "glide_window_fraction": "glide windows", "impact_speed_median": "impact speed median",
          "object_speed_p99": "object speed p99", "first_frame_moving": "first frame moving",
          "ridge_log_m": "raw-state ridge, contact windows: log m", "ridge_gamma": "… γ", "ridge_log_k": "… log k"}


def measure(env: str, preset: str, seed: int) -> dict:
    t0 = time.time()
    cfg = make_config(preset, environment=env, seed=seed)
    ds = simulate(cfg, progress=False, render=False)
    stats = {**fidelity.restitutions(cfg.physics), **fidelity.corpus_statistics(ds)}
    return {"environment": env, "episodes": cfg.num_episodes, "split_counts": {k: int((ds.split == v).sum())
            for k, v in (("train", 0), ("probe_fit", 1), ("probe_test", 2))}, "config": content_config(cfg),
            "statistics": stats, "verdicts": fidelity.verdicts(stats), "seconds": round(time.time() - t0, 1)}


def markdown(rec: dict) -> str:
    cal, ref = rec["environments"]["calibrated"], rec["environments"]["reference"]
    lines = ["# PokeWorld against the authors' released reference\n",
             "## Environment\n", f"Ours: `{rec['command']}` (render-free corpora at the `{rec['preset']}` preset, "
             f"seed {rec['seed']}; statistics on the probe-test split, the ridge fit on probe-fit). Reference: "
             f"{REFERENCE_SOURCE}. Definitions: `pokeworld.sim.fidelity`. Pass: within the tolerance column.\n",
             "| statistic | reference | tolerance | reference env (ours, default) | pass | calibrated env (ours) | "
             "calibrated env, measured outside |", "|---|---|---|---|---|---|---|"]
    for name, (value, tol) in fidelity.REFERENCE.items():
        v = ref["verdicts"][name]
        lines.append(f"| {LABELS[name]} | {value:g} | ±{tol:g} | {v['ours']:.3f} | {'pass' if v['pass'] else 'FAIL'} "
                     f"| {cal['statistics'][name]:.3f} | {fidelity.CALIBRATED_ISSUE[name]:g} |")
    passed = sum(v["pass"] for v in ref["verdicts"].values())
    ours = {t: ref["statistics"][f"ridge_{t}"] - cal["statistics"][f"ridge_{t}"] for t in fidelity.TARGETS}
    outside = {t: fidelity.REFERENCE[f"ridge_{t}"][0] - fidelity.CALIBRATED_ISSUE[f"ridge_{t}"]
               for t in fidelity.TARGETS}
    same = [n for n, (_, tol) in fidelity.REFERENCE.items() if not n.startswith("ridge")
            and abs(cal["statistics"][n] - fidelity.CALIBRATED_ISSUE[n]) <= tol]
    differ = [n for n in fidelity.REFERENCE if not n.startswith("ridge") and n not in same]
    lines += ["", "The check of the measurement: on the calibrated environment's corpus it reproduces the outside "
              "measurement's calibrated column within the same tolerances for "
              f"{len(same)} of {len(same) + len(differ)} non-ridge rows"
              + (f"; not for {', '.join(differ)}" if differ else "") + ". (Static-16 reads 0.181 here, the number the "
              "outside measurement itself gives for the same corpus's paper-budget runs, \"static-16 0.181 (0.205)\"; "
              "its table's 0.168 we could not reproduce by any reading of its definition we tried.)", "",
              "The ridge rows are a measurement of our own: the outside measurement names its 19 hand features "
              "but does not publish them, and the reference's code has no such set. Ours (`fidelity.HAND_FEATURES`: "
              "peak force, contact time, impulse, force over acceleration, glide decay rate, overlap, …) does not "
              "reproduce the outside measurement's calibrated column (the check the other rows pass), so its pass / "
              "fail against the reference's levels is not evidence either way. What it can compare is the shift from the calibrated to the "
              "reference environment: ours " + " / ".join(f"{ours[t]:+.2f}" for t in fidelity.TARGETS)
              + ", the outside measurement's " + " / ".join(f"{outside[t]:+.2f}" for t in fidelity.TARGETS)
              + " (log m / γ / log k): the same signs. The reference's own raw-window control (`raw_lin+obj` of "
              "probe_controls.py, ridge on the flattened 16-frame window) reads "
              + " / ".join(f"{ref['statistics'][f'raw_ridge_{t}']:.2f}" for t in fidelity.TARGETS)
              + " (reference environment) and " + " / ".join(f"{cal['statistics'][f'raw_ridge_{t}']:.2f}"
                                                                for t in fidelity.TARGETS) + " (calibrated).", "",
              f"Reference environment: {passed} of {len(ref['verdicts'])} statistics within tolerance. Contact "
              f"/ moving windows on the probe-test split: {ref['statistics']['contact_windows']} / "
              f"{ref['statistics']['moving_windows']} of {6 * ref['split_counts']['probe_test']} (the reference's "
              "3,228 / 3,319 of 4,800).\n",
              "## Model\n", "Parameter counts and per-variant numbers beside the paper's and the reference's JSONs: "
              "[reference_fidelity_model.md](reference_fidelity_model.md) (`scripts/reference_model_table.py`).\n"]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/results/reference_fidelity", help="output stem (.json and .md)")
    ap.add_argument("--preset", default="paper", help="generator preset of both corpora")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--markdown-only", action="store_true", help="rewrite the .md from the existing .json")
    args = ap.parse_args()
    if args.markdown_only:
        save_text(Path(args.out + ".md"), markdown(read_json(Path(args.out + ".json"), "a fidelity record")))
        return
    envs = {env: measure(env, args.preset, args.seed) for env in ("calibrated", "reference")}
    previous = read_json_if_present(Path(args.out + ".json"), "a fidelity record") or {}
    rec = {"command": f"python scripts/reference_fidelity.py --preset {args.preset} --seed {args.seed} --out {args.out}",
           "preset": args.preset, "seed": args.seed, "reference_source": REFERENCE_SOURCE,
           "reference": {k: {"value": v, "tolerance": t} for k, (v, t) in fidelity.REFERENCE.items()},
           "calibrated_issue_column": fidelity.CALIBRATED_ISSUE, "environments": envs,
           "model": previous.get("model", {"note": "parameter counts and per-variant numbers: "
                                                   "reference_fidelity_model.json (scripts/reference_model_table.py)"})}
    write_json(Path(args.out + ".json"), rec)
    save_text(Path(args.out + ".md"), markdown(rec))
    print(markdown(rec))


if __name__ == "__main__":
    main()
