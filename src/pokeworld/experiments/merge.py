"""Fold runs measured by a later `pokeworld map` invocation into an earlier map's results.json and re-render it.

A map's results.json is the record of one invocation. When a later invocation re-trains some of its runs (for
example with MLP probes switched on) or adds runs on the same corpora, this puts them into one report without
re-training the rest — but only if the re-trained runs reproduce: every ridge probe number of a run present in
both must agree to ``--tol``, otherwise nothing is written (training is deterministic in seed, data and config,
so a mismatch means the code or the data changed and the two records cannot share a table). With
``--replace-differing`` such a run replaces the record's wholesale (every number of the row then comes from the
re-trained run) and its largest ridge difference is recorded and named in the report. The earlier map's
certificates are kept; what was merged, from which command and commit, is appended to ``provenance["merged"]``.
A record that cannot be merged raises :class:`~pokeworld.errors.ConfigError`; ``main`` reports it as an error exit.

    python scripts/merge_map_results.py docs/results/frontier_cpu.json out/map/results.json \
        --experiments tokens controls attributes --out merged.json --markdown merged.md
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

from ..errors import ConfigError
from ..io import atomic_path, write_json
from . import report


def ridge_numbers(run: dict) -> dict[tuple[str, str], float]:
    return {(kind, q): v for kind, qs in run.get("probes", {}).get("ridge", {}).items() for q, v in qs.items()
            if isinstance(v, (int, float))}


def mismatches(old: dict, new: dict, tol: float) -> list[str]:
    a, b = ridge_numbers(old), ridge_numbers(new)
    out = [f"{k}: {a[k]:.6f} vs {b[k]:.6f}" for k in sorted(set(a) & set(b)) if abs(a[k] - b[k]) > tol]
    if not set(a) & set(b):
        out.append("no ridge probe in common")
    return out


def max_difference(old: dict, new: dict) -> float:
    a, b = ridge_numbers(old), ridge_numbers(new)
    return max((abs(a[k] - b[k]) for k in set(a) & set(b)), default=float("nan"))


def combine(old: dict, new: dict) -> dict:
    """A reproduced run: the new record's entry, keeping probe families only the old one measured (a re-run
    without MLP probes must not drop the MLP numbers of the run it reproduces)."""
    return {**old, **new, "probes": {**old.get("probes", {}), **new.get("probes", {})}}


def merge(base: dict, new: dict, experiments: list[str], tol: float,
          replace_differing: bool = False) -> tuple[dict, dict]:
    missing = [e for e in experiments if e not in new["experiments"]]
    if missing:
        raise ConfigError(f"{missing} not in the new results (it has {sorted(new['experiments'])})")
    merged = copy.deepcopy(base)
    added, replaced, bad, differing = [], [], {}, {}
    for exp in experiments:
        names = merged["experiments"].setdefault(exp, [])
        for name in new["experiments"][exp]:
            run = new["runs"][name]
            if name in merged["runs"]:
                diff = mismatches(merged["runs"][name], run, tol)
                if diff and not replace_differing:
                    bad[name] = diff
                    continue
                if diff:
                    differing[name] = max_difference(merged["runs"][name], run)
                else:
                    run = combine(merged["runs"][name], run)
                    if name not in replaced:
                        replaced.append(name)
            elif name not in added:
                added.append(name)
            merged["runs"][name] = run
            if name not in names:
                names.append(name)
        if exp not in merged["map_config"]["experiments"]:
            merged["map_config"]["experiments"].append(exp)
        if exp == "planning":  # its table reads the closed-loop results, not the runs' probes
            merged["planning"] = new["planning"]
    if bad:
        lines = [f"  {n}: " + "; ".join(d[:4]) + (" …" if len(d) > 4 else "") for n, d in bad.items()]
        raise ConfigError("re-trained runs do not reproduce the base record (ridge, tol "
                          f"{tol:g}); nothing written:\n" + "\n".join(lines))
    record = {"command": new["provenance"].get("command"), "git": new["provenance"].get("git"),
              "experiments": experiments, "runs_added": added, "runs_replaced_reproduced": replaced, "tol": tol,
              "runs_replaced_differing": differing}
    merged["provenance"].setdefault("merged", []).append(record)
    return merged, record


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("base", type=Path, help="results.json the runs are folded into (its certificates are kept)")
    ap.add_argument("new", type=Path, help="results.json of the later invocation")
    ap.add_argument("--experiments", nargs="+", required=True, help="experiments whose runs are taken from NEW")
    ap.add_argument("--out", type=Path, required=True, help="merged results.json")
    ap.add_argument("--markdown", type=Path, help="also write the report of the merged record here")
    ap.add_argument("--tol", type=float, default=1e-4, help="largest ridge R² difference a reproduced run may show")
    ap.add_argument("--replace-differing", action="store_true",
                    help="let a re-trained run that does not reproduce replace the record's anyway; its largest "
                         "ridge difference is recorded in provenance and named in the report")
    a = ap.parse_args(argv)
    for p in (a.base, a.new):
        if not p.is_file():
            print(f"error: {p} does not exist", file=sys.stderr)
            return 2
    try:
        merged, record = merge(json.loads(a.base.read_text()), json.loads(a.new.read_text()), a.experiments, a.tol,
                               a.replace_differing)
    except ConfigError as e:
        raise SystemExit(f"error: {e}") from None
    write_json(a.out, merged)
    if a.markdown:
        with atomic_path(a.markdown) as tmp:
            tmp.write_text(report.markdown(merged))
    print(f"[merge] {len(record['runs_replaced_reproduced'])} runs reproduced and replaced, "
          f"{len(record['runs_added'])} added, {len(record['runs_replaced_differing'])} differing and replaced "
          f"{ {k: round(v, 4) for k, v in record['runs_replaced_differing'].items()} } -> {a.out}")
    return 0
