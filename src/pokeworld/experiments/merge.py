"""Fold runs measured by a later `pokeworld map` invocation into an earlier map's results.json and re-render it.

A map's results.json is the record of one invocation. When a later invocation re-trains some of its runs (for
example with MLP probes switched on) or adds runs on the same corpora, this puts them into one report without
re-training the rest — but only if the re-trained runs reproduce: every ridge probe number of a run present in
both must agree to ``--tol``, otherwise nothing is written (training is deterministic in seed, data and config,
so a mismatch means the code or the data changed and the two records cannot share a table). With
``--replace-differing`` such a run replaces the record's wholesale (every number of the row then comes from the
re-trained run) and its largest ridge difference is recorded and named in the report. A ridge number the base
holds that the new record lacks or holds as NaN is a mismatch (difference inf), never "reproduced"; a reproduced
run keeps every number the base held that the new record lacks (or holds as null / NaN), so a merge drops a base
number only where ``--replace-differing`` replaces the run. Both inputs are checked first
(:func:`.record.read_record`): a file that is not a results record is one error line. The earlier map's
certificates are kept; what was merged, from which command and commit, is appended to ``provenance["merged"]``.
A record that cannot be merged raises :class:`~pokeworld.errors.ConfigError`; ``main`` reports it as an error exit.

    python scripts/merge_map_results.py docs/results/frontier_cpu.json out/map/results.json \
        --experiments tokens controls attributes --out merged.json --markdown merged.md
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
from pathlib import Path

from ..errors import ConfigError, PokeworldError
from ..io import save_text, write_json
from . import report
from .record import MEASURED, read_record


def ridge_numbers(run: dict) -> dict[tuple[str, str], float]:
    """(kind, quantity) -> value of a run record's ridge probes; null and other non-numbers left out."""
    return {(kind, q): v for kind, qs in run.get("probes", {}).get("ridge", {}).items() for q, v in qs.items()
            if isinstance(v, (int, float))}


def differences(old: dict, new: dict) -> dict[tuple[str, str], float]:
    """|old − new| for every ridge number the base record ``old`` holds: 0 when both are NaN, inf when the new
    record lacks it or holds NaN (or holds a number where the base held NaN), so that a missing or NaN number is a
    mismatch and never counts as reproduced."""
    a, b = ridge_numbers(old), ridge_numbers(new)
    out = {}
    for k, x in a.items():
        y = b.get(k, math.nan)
        finite = math.isfinite(x), math.isfinite(y)
        out[k] = abs(x - y) if all(finite) else 0.0 if not any(finite) else math.inf
    return out


def mismatches(old: dict, new: dict, tol: float) -> list[str]:
    """One line per base ridge number the new record does not reproduce to ``tol`` (missing or NaN included)."""
    a, b = ridge_numbers(old), ridge_numbers(new)
    out = [f"{k}: {a[k]:.6f} vs {b[k]:.6f}" if k in b else f"{k}: {a[k]:.6f} vs missing"
           for k, d in sorted(differences(old, new).items()) if d > tol]
    if not set(a) & set(b):
        out.append("no ridge probe in common")
    return out


def max_difference(old: dict, new: dict) -> float:
    """The largest of :func:`differences` (inf when a base number is missing or NaN in the new record)."""
    return max(differences(old, new).values(), default=float("nan"))


def is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def keep_numbers(old, new):
    """``new`` with every number ``old`` held that ``new`` lacks or holds as null / NaN put back, at any depth."""
    if isinstance(old, dict) and isinstance(new, dict):
        return {**old, **{k: keep_numbers(old[k], v) if k in old else v for k, v in new.items()}}
    if is_number(old) and not is_number(new):
        return old
    return new


def combine(old: dict, new: dict) -> dict:
    """A reproduced run: the new record's entry, keeping in its measured sections (:data:`.record.MEASURED`) what
    only the old one measured (probe families, kinds, quantities: a re-run without MLP probes must not drop the MLP
    numbers of the run it reproduces) and every number of the old one the new holds as null or NaN."""
    return {**old, **new, **{s: keep_numbers(old[s], new[s]) for s in MEASURED if s in old and s in new}}


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
            if name not in new["runs"]:
                raise ConfigError(f"the new results list run {name} under {exp} but hold no record of it")
            run = new["runs"][name]
            if name in merged["runs"]:
                diff = mismatches(merged["runs"][name], run, tol)
                if diff and not replace_differing:
                    bad[name] = diff
                    continue
                if diff:  # JSON has no infinity: a number the new record lost is recorded as such, in words
                    largest = max_difference(merged["runs"][name], run)
                    differing[name] = largest if math.isfinite(largest) else "a base number is missing or NaN"
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
            if "planning" not in new:
                raise ConfigError("planning is among --experiments but the new results hold no planning section")
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
        # NaN may stand in the records: merge() judges it (a mismatch against a number the base holds)
        base, new = (read_record(p, "give the results.json a `pokeworld map` wrote", finite=False)
                     for p in (a.base, a.new))
        merged, record = merge(base, new, a.experiments, a.tol, a.replace_differing)
    except PokeworldError as e:  # a record that cannot be read or merged: one line, nothing written
        raise SystemExit(f"error: {e}") from None
    write_json(a.out, merged)
    if a.markdown:
        save_text(a.markdown, report.markdown(merged))
    print(f"[merge] {len(record['runs_replaced_reproduced'])} runs reproduced and replaced, "
          f"{len(record['runs_added'])} added, {len(record['runs_replaced_differing'])} differing and replaced "
          f"{ {k: round(v, 4) if isinstance(v, float) else v for k, v in record['runs_replaced_differing'].items()} }"
          f" -> {a.out}")
    return 0
