"""The reproduction ledger: every quantitative result of the paper beside ours, with a verdict computed from the
committed records (``scripts/reproduction_ledger.py`` writes docs/results/reproduction.{json,md}).

Each row (:data:`ROWS`) is one result of the paper: its section, the quantity, and one :class:`Cell` per number in
it. A cell holds the paper's value (from :mod:`pokeworld.published.paper` or an experiment's module), the authors'
released value where their release has the run (:mod:`pokeworld.published.release`), a :class:`Tolerance`, and
*where* ours is read: a record under docs/results and a path into its JSON, once for the paper's budget and once
for the ``cpu`` budget. A path segment ``{seed}`` matches every seed the record holds (ours is their mean, compared
with the paper's mean over the same seeds), so a record that gains runs changes the ledger without an edit here.

The verdict is computed, never written by hand (:func:`row_verdict`):

* **reproduced** — every cell read at the paper's budget, on the default (reference) environment, within tolerance;
* **reproduced at cpu only** — not all cells at the paper's budget, but every cell within tolerance at the ``cpu``
  budget (a record of the retired calibrated environment is named as such in the row: it never counts as a
  default-environment reproduction, and a paper-budget record of that environment counts as no paper-budget value);
* **not reproduced** — a cell outside tolerance at the paper's budget, or, short of the paper's budget, at ``cpu``;
  the row's one-line measured cause is shown with it;
* **not run** — a cell no record holds and nothing outside tolerance; the row says what it needs.

A row is judged at one budget at a time (a comparison is never assembled from two budgets): at the paper's when
it measured every cell or missed one, else at ``cpu``, where a cell only the paper's budget measured counts with
the state it has there.

A record's budget and environment are its own: ``map_config.preset`` and ``map_config.environment`` (a record that
names no environment is the calibrated environment's, :func:`pokeworld.experiments.config.recorded_map_config`).
Records without a map config carry their context in the row (:class:`Context`, with the reason).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from pathlib import Path

from .experiments.attributes import ATTRIBUTES
from .experiments.config import recorded_map_config
from .experiments.controls import CONTROLS
from .experiments.coordinate import COORDINATE
from .experiments.coverage import COVERAGE
from .experiments.dose_glide import DOSE_GLIDE
from .experiments.dose_touch import DOSE_TOUCH
from .experiments.factorial import FACTORIAL, FACTORIAL_MLP
from .experiments.frame_averaged import FRAME_AVERAGED
from .experiments.lambda_factorial import RELEASED_VARIANTS, TARGETS_ORDER, ordering_holds, released_log_k
from .experiments.lambda_sweep import LAMBDA
from .experiments.lazy import LAZY
from .experiments.tokens import TOKENS
from .io import read_json
from .published import paper as P
from .published.release import DRIFT_LINEAR_CERTIFICATE as RELEASED_DRIFT_LINEAR, CONTACT_POOR_VFX, CONTROL_RUNS, DOSE_GLIDE_RUNS, DOSE_TOUCH_RUNS, FLOW_SENSOR_VFX as FLOW_RUNS, LAMBDA_0_1, LAMBDA_SWEEP_VFX, MULTI_HORIZON, MULTISCALE, SINGLE_HORIZON
from .sim.environments import DEFAULT as DEFAULT_ENVIRONMENT

REPRODUCED = "reproduced"
REPRODUCED_AT_CPU = "reproduced at cpu only"
NOT_REPRODUCED = "not reproduced"
NOT_RUN = "not run"
VERDICTS = (REPRODUCED, REPRODUCED_AT_CPU, NOT_REPRODUCED, NOT_RUN)

ENVIRONMENT_FREE = "independent of the environment"
"""The environment of a quantity no environment enters (a parameter count): it counts as the default's."""

# ----------------------------------------------------------------------------- tolerances and the paper's values


@dataclass(frozen=True)
class Tolerance:
    """How far ours may sit from the paper's value: the larger of ``absolute`` and ``relative`` × |value|."""

    label: str
    absolute: float = 0.0
    relative: float = 0.0
    style: str = "2"  # how a value prints: a number of digits, "percent", "rate", "millions" or "pass"

    def width(self, target: float) -> float:
        return max(self.absolute, self.relative * abs(target))

    def show(self, v) -> str:
        if v is None:
            return "—"
        if isinstance(v, bool):
            return "pass" if v else "fail"
        if self.style == "percent":
            return f"{100 * v:.0f} %"
        if self.style == "rate":
            return f"{100 * v:.2f} %"
        if self.style == "millions":
            return f"{v / 1e6:.2f} M"
        return f"{v:.{int(self.style) if self.style.isdigit() else 2}f}"


R2 = Tolerance("±0.1 R²", absolute=0.1)
"""R² readouts and certificates: 0.1 absolute (the project's GPU target for Table "targets")."""
ERROR = Tolerance("±20 % or ±0.01", absolute=0.01, relative=0.2, style="3")
"""Arena-unit errors: 0.1 absolute would be vacuous for values ≈ 0.1, so ±20 % or ±0.01, whichever is larger."""
POINTS = Tolerance("±10 points", absolute=0.10, style="percent")
"""Shares and rates (stored as fractions)."""
RATE = Tolerance("±10 points", absolute=0.10, style="rate")  # a rate of a few percent, printed to 0.01 %
SMALL_ERROR = Tolerance(ERROR.label, ERROR.absolute, ERROR.relative, style="4")  # errors as small as 0.0002
SIZE = Tolerance("±20 %", relative=0.2, style="millions")
CENTIMETRES = Tolerance("±20 %", relative=0.2, style="1")
COUNT = Tolerance("exact", style="0")
HOLDS = Tolerance("holds", style="pass")


@dataclass(frozen=True)
class AtMost:
    """A paper value that is a bound: "no gain" over ``value`` (ours within tolerance of it or below)."""

    value: float


@dataclass(frozen=True)
class Above:
    """A paper statement that ours exceeds ``value`` (strictly; no tolerance)."""

    value: float


def per_seed(pair) -> dict[int, float]:
    """A paper's (s0, s1) pair as {seed: value}."""
    return dict(enumerate(pair))


# ----------------------------------------------------------------------------- where ours is read


@dataclass(frozen=True)
class Context:
    """The budget and environment of a record that does not state them in a map config, and why they are that."""

    budget: str
    environment: str
    why: str


@dataclass(frozen=True)
class Read:
    """One number of ours: ``path`` into the JSON record ``record`` (a file under docs/results). Segments are
    separated by "/"; ``{seed}`` inside a segment matches every seed the record holds (the mean is ours);
    ``[key=value]`` selects the list element whose ``key`` is ``value``."""

    record: str
    path: str
    context: Context | None = None


@dataclass(frozen=True)
class Derived:
    """A number of ours computed from others: "difference" (a − b), "ratio" (a / b), "mean" (all needed), "max"
    (the best of those present), "ordering" (whether log k of the parts, Table "targets"' variants in
    ``TARGETS_ORDER``, keeps that table's ordering: a pass/fail), "first" (the first present, as it is) or
    "default_first" (the default
    environment's record, then a retired one's: as "first" alone, but a row reads its retired record for every such
    cell unless the default one holds them all, :func:`one_environment`)."""

    op: str
    parts: tuple


@dataclass(frozen=True)
class Cell:
    """One number of a row: the paper's ``paper`` value (a number, {seed: number}, a (low, high) range,
    :class:`AtMost`, :class:`Above`, True for "holds", or None for a cell shown beside the others, not judged),
    ours at the paper's budget and at ``cpu``, the released value ({seed: number} or a number)."""

    label: str
    paper: object
    tolerance: Tolerance
    paper_budget: Read | Derived | None = None
    cpu: Read | Derived | None = None
    released: object = None

    @property
    def counted(self) -> bool:
        return self.paper is not None


@dataclass(frozen=True)
class Row:
    """One quantitative result of the paper (the inventory's row ``id``)."""

    id: str
    part: str
    section: str
    quantity: str
    cells: tuple[Cell, ...]
    cause: str = ""  # the one-line measured cause, shown only when the verdict is "not reproduced"
    needs: str = ""  # what a "not run" row needs
    note: str = ""  # like-for-like remarks, always shown
    release: str = ""  # which of the release's runs the released column holds


# ----------------------------------------------------------------------------- reading the records


@dataclass(frozen=True)
class Measured:
    value: object
    seeds: tuple
    sources: tuple  # (record, path) pairs that gave a value
    budget: str
    environment: str
    context: str  # where the budget and environment come from: the record's map config, or a row's Context


class Records:
    """The committed records of one folder, each read once (a missing record reads as no value)."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self._cache: dict[str, dict | None] = {}

    def load(self, name: str) -> dict | None:
        if name not in self._cache:
            path = self.folder / name
            self._cache[name] = read_json(path, "a results record") if path.is_file() else None
        return self._cache[name]

    def context(self, name: str, declared: Context | None) -> tuple[str, str, str]:
        """(budget, environment, whence) of a record: its map config's, else the row's declared context, else
        (unknown, calibrated) — a record that names no environment is the calibrated environment's."""
        data = self.load(name) or {}
        config = data.get("map_config")
        if isinstance(config, dict):
            recorded = recorded_map_config(config)
            preset = recorded.get("preset", "unknown")
            train = str(recorded.get("train_preset") or "")
            budget = "paper" if preset == "paper" else "demo" if train.startswith("demo") else preset
            return budget, recorded["environment"], "the record's map_config"
        if declared is not None:
            return declared.budget, declared.environment, declared.why
        return "unknown", recorded_map_config({})["environment"], "the record names neither budget nor environment"


def resolve(data, path: str) -> dict:
    """{seed: value} at ``path`` in ``data`` (seed None for a path without ``{seed}``); {} when absent."""
    found = {None: data}
    for segment in path.split("/"):
        step = {}
        for seed, node in found.items():
            if isinstance(node, list) and segment.startswith("[") and segment.endswith("]"):
                key, _, want = segment[1:-1].partition("=")
                step.update({seed: x for x in node if isinstance(x, dict) and str(x.get(key)) == want})
            elif isinstance(node, dict) and "{seed}" in segment:
                pattern = re.compile(re.escape(segment).replace(re.escape("{seed}"), r"(\d+)"))
                for key, child in node.items():
                    m = pattern.fullmatch(key)
                    if m:
                        step[int(m.group(1))] = child
            elif isinstance(node, dict) and segment in node:
                step[seed] = node[segment]
        found = step
    return {s: v for s, v in found.items() if is_value(v)}


def cut_short(data: dict, path: str, seeds: tuple) -> list[str]:
    """The runs a value under ``runs/NAME/`` was read from whose training stopped before the schedule's end (a GPU
    allocation's ``steps_trained`` below its ``steps``), as "NAME (done of planned steps)"."""
    parts = path.split("/")
    if len(parts) < 2 or parts[0] != "runs":
        return []
    out = []
    for seed in seeds or (None,):
        name = parts[1] if seed is None else parts[1].replace("{seed}", str(seed))
        allocation = data.get("runs", {}).get(name, {}).get("allocation", {})
        done, planned = allocation.get("steps_trained"), allocation.get("steps")
        if isinstance(done, int) and isinstance(planned, int) and done < planned:
            out.append(f"{name} ({done:,} of {planned:,} steps)")
    return out


def is_value(v) -> bool:
    """A number of ours: a finite number or a pass/fail (a record's NaN or null is no value)."""
    return isinstance(v, bool) or (isinstance(v, (int, float)) and math.isfinite(v))


def combine_contexts(parts: list[Measured]) -> tuple[str, str, str]:
    """The weakest budget and environment of several values (a derived value is at the paper's budget on the default
    environment only if every part is), and where each came from."""
    budgets = {m.budget for m in parts}
    budget = "paper" if budgets == {"paper"} else sorted(budgets - {"paper"})[0]
    envs = {m.environment for m in parts} - {ENVIRONMENT_FREE}
    environment = ENVIRONMENT_FREE if not envs else DEFAULT_ENVIRONMENT if envs == {DEFAULT_ENVIRONMENT} else \
        sorted(envs - {DEFAULT_ENVIRONMENT})[0]
    return budget, environment, "; ".join(dict.fromkeys(m.context for m in parts))


def measure(expr, records: Records) -> Measured | None:
    """Ours for one cell at one budget (None when a record lacks it)."""
    if expr is None:
        return None
    if isinstance(expr, Read):
        data = records.load(expr.record)
        values = resolve(data, expr.path) if data is not None else {}
        if not values:
            return None
        nums = list(values.values())
        value = nums[0] if len(nums) == 1 or isinstance(nums[0], bool) else sum(nums) / len(nums)
        seeds = tuple(sorted(s for s in values if s is not None))
        budget, environment, whence = records.context(expr.record, expr.context)
        short = cut_short(data, expr.path, seeds)
        if short:  # a run stopped before its schedule's end is not at the budget its record's preset names
            budget = f"{budget}, cut short: {'; '.join(short)}"
        return Measured(value, seeds, ((expr.record, expr.path),), budget, environment, whence)
    if expr.op in ("first", "default_first"):  # the first record that holds it
        return next((m for m in (measure(p, records) for p in expr.parts) if m is not None), None)
    parts = [measure(p, records) for p in expr.parts]
    present = [m for m in parts if m is not None]
    if not present or (expr.op != "max" and len(present) < len(parts)):
        return None
    vals = [m.value for m in present]
    if expr.op == "difference":
        value = vals[0] - vals[1]
    elif expr.op == "ratio":
        value = vals[0] / vals[1] if vals[1] else None
    elif expr.op == "mean":
        value = sum(vals) / len(vals)
    elif expr.op == "max":
        value = max(vals)
    elif expr.op == "ordering":  # log k of Table "targets"' variants, read in TARGETS_ORDER
        value = ordering_holds(dict(zip(TARGETS_ORDER, vals)))
    else:
        raise ValueError(f"unknown operation {expr.op!r}")
    if value is None:
        return None
    seeds = tuple(sorted({s for m in present for s in m.seeds}))
    return Measured(value, seeds, tuple(src for m in present for src in m.sources), *combine_contexts(present))


# ----------------------------------------------------------------------------- judging a cell and a row


def target(value, seeds: tuple):
    """The paper's (or the release's) value for the seeds ours covers: a per-seed table's mean over those seeds (all
    of its seeds when ours names none it has)."""
    if isinstance(value, dict):
        chosen = [value[s] for s in seeds if s in value] or list(value.values())
        return sum(chosen) / len(chosen)
    return value


def within(ours, paper, tolerance: Tolerance, seeds: tuple) -> bool:
    goal = target(paper, seeds)
    slack = 1e-9  # float rounding of the records' own numbers
    if isinstance(goal, bool):
        return bool(ours) is goal
    if isinstance(goal, tuple):
        low, high = goal
        return low - tolerance.width(low) - slack <= ours <= high + tolerance.width(high) + slack
    if isinstance(goal, AtMost):
        return ours <= goal.value + tolerance.width(goal.value) + slack
    if isinstance(goal, Above):
        return ours > goal.value
    return abs(ours - goal) <= tolerance.width(goal) + slack


def counts_at_paper_budget(m: Measured | None) -> bool:
    """A paper-budget value counts only from a paper-budget record of the default environment."""
    return m is not None and m.budget == "paper" and m.environment in (DEFAULT_ENVIRONMENT, ENVIRONMENT_FREE)


def state(m: Measured | None, goal, tolerance: Tolerance) -> str | None:
    """"ok" / "miss" against ``goal``; None without a value."""
    return None if m is None else "ok" if within(m.value, goal, tolerance, m.seeds) else "miss"


def row_verdict(paper: list, cpu: list) -> str:
    """A row's verdict from its judged cells' states at the paper's budget and at ``cpu`` (module docstring). A
    row is judged at one budget at a time, so a comparison is never assembled from two budgets: the paper's budget
    when it measured every cell (or missed one), else the ``cpu`` budget, where a cell the cpu records lack counts
    as measured if the paper's budget reproduced it."""
    if "miss" in paper:
        return NOT_REPRODUCED
    if paper and all(s == "ok" for s in paper):
        return REPRODUCED
    filled = [c if c is not None else "ok" if p == "ok" else None for p, c in zip(paper, cpu)]
    if "miss" in filled:
        return NOT_REPRODUCED
    if filled and all(s == "ok" for s in filled):
        return REPRODUCED_AT_CPU
    return NOT_RUN


def differs(paper, released, tolerance: Tolerance) -> bool:
    """Whether the paper's number and the release's disagree beyond the tolerance (the row is then judged against
    the release too)."""
    p, r = target(paper, ()), target(released, ())
    if not isinstance(p, (int, float)) or isinstance(p, bool) or not isinstance(r, (int, float)):
        return False
    return abs(p - r) > tolerance.width(p) + 1e-9


def rounded(v):
    return round(v, 6) if isinstance(v, float) else v


def json_paper(v):
    """A paper or released value as JSON."""
    if isinstance(v, dict):
        return {f"s{k}": rounded(x) for k, x in v.items()}
    if isinstance(v, tuple):
        return {"range": [rounded(x) for x in v]}
    if isinstance(v, AtMost):
        return {"at_most": v.value}
    if isinstance(v, Above):
        return {"above": v.value}
    return rounded(v)


def json_measured(m: Measured | None) -> dict | None:
    if m is None:
        return None
    return {"value": rounded(m.value), "seeds": list(m.seeds), "budget": m.budget, "environment": m.environment,
            "context": m.context, "read": [{"record": r, "path": p} for r, p in m.sources]}


def miss_line(cell: Cell, m: Measured, at_paper: bool) -> str:
    where = "paper budget" if at_paper else f"{m.budget}, {m.environment} environment"
    return (f"{cell.label}: {cell.tolerance.show(m.value)} vs {show_paper(cell.paper, cell.tolerance)} "
            f"(tolerance {cell.tolerance.label}; {where})")


def one_environment(row: Row, records: Records) -> Row:
    """``row`` with every "default_first" cell at ``cpu`` reading one record: the default environment's when it holds
    all of them, else the retired one's for all — so no row sets a run of one environment beside a run of another (a
    dose–response's default weight from one, its other weights from the other)."""
    mixed = [c for c in row.cells if isinstance(c.cpu, Derived) and c.cpu.op == "default_first"]
    if not mixed or all(measure(c.cpu.parts[0], records) is not None for c in mixed):
        return row
    return replace(row, cells=tuple(replace(c, cpu=c.cpu.parts[1]) if c in mixed else c for c in row.cells))


def judge_row(row: Row, records: Records) -> dict:
    """A row's cells with ours and their states, and the row's verdict (and, where the paper and the release
    disagree beyond the tolerance, its verdict against the release, judged the same way)."""
    row = one_environment(row, records)
    cells, paper, cpu, rel_paper, rel_cpu, misses = [], [], [], [], [], {True: [], False: []}
    calibrated, hold_release = False, False
    for cell in row.cells:
        paper_m, cpu_m = measure(cell.paper_budget, records), measure(cell.cpu, records)
        counted = paper_m if counts_at_paper_budget(paper_m) else None
        entry = {"quantity": cell.label, "paper": json_paper(cell.paper), "released": json_paper(cell.released),
                 "tolerance": cell.tolerance.label, "format": cell.tolerance.style, "judged": cell.counted,
                 "paper_budget": json_measured(paper_m),
                 "cpu": json_measured(cpu_m)}
        if cell.counted:
            p, c = state(counted, cell.paper, cell.tolerance), state(cpu_m, cell.paper, cell.tolerance)
            entry["state"] = {"paper_budget": p, "cpu": c}
            paper.append(p)
            cpu.append(c)
            if p == "miss":
                misses[True].append(miss_line(cell, counted, True))
            if c == "miss":
                misses[False].append(miss_line(cell, cpu_m, False))
            calibrated = calibrated or (c == "ok" and cpu_m.environment not in (DEFAULT_ENVIRONMENT, ENVIRONMENT_FREE))
            if cell.released is not None:
                rel_paper.append(state(counted, cell.released, cell.tolerance))
                rel_cpu.append(state(cpu_m, cell.released, cell.tolerance))
                hold_release = hold_release or differs(cell.paper, cell.released, cell.tolerance)
        cells.append(entry)
    verdict = row_verdict(paper, cpu)
    out = {"id": row.id, "part": row.part, "section": row.section, "quantity": row.quantity, "cells": cells,
           "verdict": verdict, "note": row.note, "release": row.release}
    if verdict == REPRODUCED_AT_CPU:
        out["environment"] = "calibrated (retired)" if calibrated else DEFAULT_ENVIRONMENT
    if verdict == NOT_REPRODUCED:
        at_paper = "miss" in paper
        out.update(cause=row.cause, measured_at="paper budget" if at_paper else "cpu budget", outside=misses[at_paper])
    if verdict == NOT_RUN:
        out["needs"] = row.needs
    if hold_release:
        out["against_release"] = row_verdict(rel_paper, rel_cpu)
    return out


def show_paper(v, tolerance: Tolerance) -> str:
    """A paper or released value as the tables print it."""
    if v is None:
        return "—"
    if isinstance(v, dict):
        return "/".join(tolerance.show(x) for x in v.values())
    if isinstance(v, tuple):
        return f"{tolerance.show(v[0])}–{tolerance.show(v[1])}"
    if isinstance(v, AtMost):
        return f"≤ {tolerance.show(v.value)} (no gain)"
    if isinstance(v, Above):
        return f"> {tolerance.show(v.value)}"
    if v is True:
        return "holds"
    return tolerance.show(v)


# ----------------------------------------------------------------------------- the rows: where each number is read

MPR = "map_paper_reference.json"  # the paper's budget on the reference environment (V, VF, VFX so far)
MCR = "map_cpu_reference.json"  # the cpu factorial on the reference environment
FC = "frontier_cpu.json"  # the frontier at cpu (calibrated environment)
LC = "ledger_cpu.json"  # the γ ledger and the coordinate test at cpu (calibrated environment)
LZ = "lazy_cpu.json"  # single- vs multi-horizon heads at cpu (calibrated environment)
FR = "findings_cpu_reference.json"  # every experiment's runs at cpu on the reference environment (when recorded)


def at_cpu(record: str, path: str) -> Derived:
    """Ours at ``cpu``: the reference environment's record of every experiment (:data:`FR`) when it holds the run,
    else ``record``, an earlier record of the retired calibrated environment (named so in the row)."""
    return Derived("default_first", (Read(FR, path), Read(record, path)))
DRIFT = "drift_certificates_cpu.json"  # the rejected drift constructions' certificates (scripts/drift_certificates.py)
CCR = "certificates_cpu_reference.json"  # the cpu corpus's further certificates (windowed MLP, pixels, glide windows)


def cert_at_cpu(estimator: str, q: str, kind: str = "contact") -> Derived:
    """A certificate at ``cpu`` on the reference environment: the factorial's record when it fit that estimator,
    else the further certificates of the same corpus (:data:`CCR`)."""
    return Derived("first", (Read(MCR, cert(estimator, q, kind=kind)), Read(CCR, cert(estimator, q, kind=kind))))


PPR = "planning_paper_reference.json"
RFM = "reference_fidelity_model.json"

VARIANTS = ("V", "VF", "VX_p", "VX_t", "VX", "VFX")
TABLE_VARIANTS = ("V", "VX_p", "VX_t", "VX", "VFX")  # Tables "mlp" and "planning", the position column
LABEL = {"log_k": "log k", "log_m": "log m", "gamma": "γ", "object_pos": "position", "object_vel": "velocity",
         "finger_pos": "finger position", "object_rel": "object − finger"}

PARTS = {
    "certificates": "§3 and App. A: recoverability certificates and the gate",
    "targets": "§4.1 and App. C: targets, not inputs (Tables \"targets\" and \"mlp\")",
    "lazy": "§4.2 and App. C: the lazy equilibrium, multi-horizon heads, direct prediction",
    "lambda": "§4.3 and App. C: the regularizer (Table \"lambda\")",
    "levers": "§4.4 and App. C: information, computation, data coverage",
    "frontier": "§4.5 and App. C: the frontier (matrix, controls, dose–responses, γ ledger, coordinate test)",
    "planning": "§4.6 and App. C: closed-loop planning (Table \"planning\")",
    "model": "§3 and App. B: the model",
    "real": "§5 and App. C: real-robot data (RH20T)",
}

PLANNING_CPU = Context("cpu", DEFAULT_ENVIRONMENT, "the released planner on map_cpu_reference.json's seed-0 runs "
                       "(the invocation's --runs are that map's)")
MODEL_SIZE = Context("paper", ENVIRONMENT_FREE, "parameter counts of the paper preset's model, built without "
                     "training; no environment enters them")
NEEDS_GPU = "a GPU lease: this variant's paper-budget run (seed 0 first)"


def run(variant: str, tail: str = "", seed: str = "{seed}", corpus: str = "standard", lam: str = "0.02",
        horizons: str = "1-4-16") -> str:
    """The path of a map run (its name as the map writes it)."""
    return f"runs/{variant}-h{horizons}-lam{lam}-{corpus}{'-' + tail if tail else ''}-s{seed}"


def ridge(q: str, kind: str = "contact") -> str:
    return f"probes/ridge/{kind}/{q}"


def mlp(q: str, kind: str = "contact") -> str:
    return f"probes/mlp/{kind}/{q}"


def cert(estimator: str, q: str, corpus: str = "standard", kind: str = "contact") -> str:
    return f"certificates/{corpus}/estimators/{estimator}/{kind}/{q}"


def both(path: str, cpu_record: str = MCR) -> dict:
    """Ours at the paper's budget (map_paper_reference.json) and at cpu (``cpu_record``), the same path in each (a
    calibrated environment's record after the reference environment's, :func:`at_cpu`)."""
    return {"paper_budget": Read(MPR, path),
            "cpu": at_cpu(cpu_record, path) if cpu_record in (FC, LC, LZ) else Read(cpu_record, path)}


def released_value(r: dict, q: str, family: str = "ridge") -> float | None:
    """A released run's reading of ``q`` as the paper tabulates it: ridge / MLP on contact windows, the frame-position
    readout, the moving-window velocity (the paper's velocity columns), the direct-16 error."""
    if q == "object_pos":
        return r["object_pos_frame"]
    if q == "object_vel":
        return r["object_vel_moving"]
    if q == "direct16":
        return r["direct16"]
    return r[family][q]


def released(variant: str, pick, table: dict = MULTI_HORIZON) -> dict | None:
    """{seed: value} of the release's runs of ``variant`` (``pick`` reads a run; None when none has it)."""
    out = {}
    for (v, seed), r in table.items():
        try:
            value = pick(r)
        except KeyError:
            continue
        if v == variant and value is not None:
            out[seed] = value
    return out or None


def ridge_of(q: str):
    return lambda r: r["ridge"][q]


def mlp_of(q: str):
    return lambda r: r["mlp"][q]


PIXEL_CAUSE = ("on the cpu corpus's 32-px frames the pixel GRU reads log m 0.77 and log k 0.86 (paper 0.72 / 0.78) but "
               "γ 0.66 (paper 0.43): pixel centroids cost the GRU 0.07 / 0.03 / 0.15 of its true-state reading (0.84 "
               "/ 0.89 / 0.81), the paper's 0.14 / 0.09 / 0.27, so drag stays more recoverable from this corpus's "
               "glides, as the drag estimator's 1.00 on glide windows says; the centroid analytic drag estimator "
               "reads γ −0.34 (paper 0.05 at 64 px): it fails here as in the paper, further below 0 (an estimator "
               "without a fit is not pulled to the mean); the paper's 64-px frames are not certified")


def certificate_rows() -> tuple[Row, ...]:
    params = (("log_m", "log m"), ("gamma", "γ"), ("log_k", "log k"))
    fit = ("ours: certificates fit on the paper corpus's probe-fit split (12,000 windows at the paper budget), not "
           "on the paper preset's separate 3,840-episode certificate corpus")
    return (
        Row("A1", "certificates", "§3; App. A \"instrument hierarchy\"", "GRU-oracle certificates, contact windows",
            tuple(Cell(label, P.CERTIFICATES["gru"][q], R2, **both(cert("gru", q))) for q, label in params),
            note=fit),
        Row("A2", "certificates", "abstract; §3; §4.5", "physics-informed drag-estimator certificate of γ",
            (Cell("drag estimator γ", P.CERTIFICATES["drag"]["gamma"], R2, **both(cert("drag", "gamma"))),),
            cause="the drag estimator reads 0.78 on the reference environment's corpus at both budgets (12,000- and "
                  "17,535-window fits agree to 0.001; 0.83–0.85 on the calibrated environment); it is exact where a "
                  "window glides (R² 1.00 on the 77 % of cpu contact windows with a usable glide pair and on every "
                  "glide window) and the other 23 % take the fit median, which costs the whole 0.22 "
                  "(certificates_cpu_reference.json, drag_coverage): the share of contact windows that glide sets the "
                  "number; the release computes no drag certificate (its 0.89 is a constant in its figure script), "
                  "so the paper's windows cannot be matched", note=fit),
        Row("A3", "certificates", "App. A \"The oracle estimator\"",
            "the gate: GRU oracle ≥ 0.4 / 0.4 / 0.25 (m / γ / k) on contact windows",
            tuple(Cell(f"{label} passes", True, HOLDS, **both(f"certificates/standard/gate/{q}/paper_rule_passed"))
                  for q, label in params), note="the paper's rule (the GRU oracle alone), as each record applies it"),
        Row("A4", "certificates", "App. A \"Instrument hierarchy\"", "linear probe on raw windows scores ≈ 0",
            tuple(Cell(label, P.CERTIFICATES["linear"][q], R2, **both(cert("linear", q))) for q, label in params),
            cause="the linear certificate of log k reads 0.16 (paper budget) and 0.19 (cpu): full-force impacts make "
                  "peak touch force partly linear in log k (findings_cpu.md)"),
        Row("A5", "certificates", "App. A \"Instrument hierarchy\"", "windowed-MLP estimator on raw windows",
            tuple(Cell(label, P.CERTIFICATES["mlp"][q], R2, Read(MPR, cert("mlp", q)), cert_at_cpu("mlp", q))
                  for q, label in params if q in P.CERTIFICATES["mlp"]),
            cause="the windowed MLP reads log m 0.63 / γ 0.27 fit on the cpu certificate corpus (17,535 contact "
                  "windows, as the map's other certificates), 0.40 / 0.09 fit on the probe-fit split (5,560): its "
                  "reading grows with its fit set, which the paper does not state (certificates_cpu_reference.json)",
            needs="a certificate fit with the windowed-MLP estimator (`pokeworld certify --estimators mlp`; CPU "
                  "only)"),
        Row("A6", "certificates", "App. C \"Pixel-derived certificates\"",
            "pixel-derived certificates (GRU m / γ / k; centroid analytic γ)",
            tuple(Cell(f"GRU {label}", P.CERTIFICATES["gru_pixel"][q], R2, Read(MPR, cert("gru_pixel", q)),
                       cert_at_cpu("gru_pixel", q)) for q, label in params)
            + (Cell("analytic γ", P.CERTIFICATES["drag_pixel"]["gamma"], R2, Read(MPR, cert("drag_pixel", "gamma")),
                    cert_at_cpu("drag_pixel", "gamma")),),
            cause=PIXEL_CAUSE,
            needs="pixel-derived certificates on the reference environment (`pokeworld certify --estimators "
                  "gru_pixel drag_pixel`; CPU only; the paper corpus's 64-px frames for the paper's resolution)",
            note="ours at cpu: the cpu corpus's 32-px frames (the paper's are 64 px), so a centroid is read from a "
                 "quarter of the pixels"),
    )


def factorial_rows() -> tuple[Row, ...]:
    section = "§4.1; App. C Table \"targets\""
    mass = ("at the cpu budget mass reads 0.05–0.14 in every variant while the paper-budget V / VF / VFX reach "
            "0.15 / 0.20 / 0.31 (within 0.1 of the paper): the budget, not the objective; this variant has no "
            "paper-budget run yet")
    causes = {("VX_t", "log_k"): "VX_t reads 0.32 / 0.29 at cpu (s0 / s1; mean 0.11 below the paper); at 64 px and "
                                 "12,000 steps it reads 0.49 (budget_curve_cpu_reference.json): the budget",
              ("VX_p", "log_m"): mass, ("VX_t", "log_m"): mass, ("VX", "log_m"): mass}
    rows, n = [], 0
    for variant in VARIANTS:
        for q in ("log_k", "log_m"):
            n += 1
            cell = Cell(f"{variant} {LABEL[q]}", per_seed(P.TARGETS_PER_SEED[variant][q]), R2,
                        **both(f"{run(variant)}/{ridge(q)}"), released=released(variant, ridge_of(q)))
            rows.append(Row(f"B{n}", "targets", section, f"{variant} {LABEL[q]} (ridge, contact windows)", (cell,),
                            cause=causes.get((variant, q), ""), needs=NEEDS_GPU,
                            release="e003 runs, λ 0.02, per seed"))
    contrast = {s: a - b for s, (a, b) in enumerate(zip(P.TARGETS_PER_SEED["VFX"]["log_k"],
                                                         P.TARGETS_PER_SEED["VF"]["log_k"]))}
    pair = lambda record: Derived("difference", (Read(record, f"{run('VFX')}/{ridge('log_k')}"),  # noqa: E731
                                                 Read(record, f"{run('VF')}/{ridge('log_k')}")))
    rel_vfx, rel_vf = released("VFX", ridge_of("log_k")), released("VF", ridge_of("log_k"))
    rows.append(Row("B13", "targets", "§4.1 (i); abstract", "the central contrast VFX − VF, log k",
                    (Cell("VFX − VF log k", contrast, R2, pair(MPR), pair(MCR),
                          released={s: rel_vfx[s] - rel_vf[s] for s in rel_vfx if s in rel_vf}),),
                    release="e003 runs, per seed"))
    return tuple(rows)


def mlp_rows() -> tuple[Row, ...]:
    section = "§4.1 (ii); App. C Table \"mlp\""

    def cells(q, variants):
        return tuple(Cell(f"{v} {LABEL[q]} MLP", FACTORIAL_MLP[v][q], R2, **both(f"{run(v)}/{mlp(q)}"),
                          released=released(v, mlp_of(q))) for v in variants)
    mlp_probe = ("the released MLP protocol (one network for the three parameters, kept at its best mean validation "
                 "step, on the released windows) run on our paper-budget states reads VX_t 0.17 / 0.09 / 0.46 and VX "
                 "0.18 / 0.11 / 0.49 (log m / γ / log k; paper 0.20 / 0.06 / 0.40 and 0.21 / 0.05 / 0.44) but VX_p "
                 "0.12 / 0.10, not the paper's −0.01 / −0.01: it keeps the network at step 200 of 4,001, below ridge; "
                 "on VX_p no draw of the rule reaches chance (10 probe seeds: log m 0.10–0.15; 6 validation blocks: "
                 "0.12–0.17; step 200 above step 0 by 0.02–0.10 mean validation R²), so the release's at-chance "
                 "VX_p is its states', not the rule's or a draw's (mlp_probe_protocols.md); our own MLP reads what "
                 "ridge reads")
    return (
        Row("B14", "targets", section, "MLP log k, V and VFX", cells("log_k", ("V", "VFX")),
            release="e003 runs, per seed"),
        Row("B15", "targets", section, "MLP log k, VX_p / VX_t / VX", cells("log_k", ("VX_p", "VX_t", "VX")),
            needs=NEEDS_GPU, release="e003 runs, per seed"),
        Row("B16", "targets", section, "MLP log m, every variant of the table", cells("log_m", TABLE_VARIANTS),
            cause=f"at the paper budget V's MLP reads log m 0.13, as its ridge does (0.15); the paper's and the "
                  f"release's V MLP read 0.00 beside a ridge of 0.15; {mlp_probe}", release="e003 runs, per seed"),
        Row("B17", "targets", section, "MLP γ (\"at chance\"), every variant of the table",
            cells("gamma", TABLE_VARIANTS),
            cause=f"at the paper budget our MLP reads γ 0.11 (V) and 0.15 (VFX), beside ridge 0.14 / 0.15, where "
                  f"the paper's and the release's MLP sit at chance; {mlp_probe}", release="e003 runs, per seed"),
    )


def ordering_at(lam: str, record: str) -> Derived:
    """Whether a record's factorial at SIGReg weight ``lam`` (seed 0) keeps Table "targets"' log k ordering."""
    return Derived("ordering", tuple(Read(record, f"{run(v, seed='0', lam=lam)}/{ridge('log_k')}")
                                     for v in TARGETS_ORDER))


def token_ordering(record: str) -> Derived:
    """Whether a record's factorial under spatial tokens (seed 0) keeps Table "targets"' log k ordering."""
    return Derived("ordering", tuple(Read(record, f"{run(v, 'tokensTrue', seed='0')}/{ridge('log_k')}")
                                     for v in TARGETS_ORDER))


def composition_rows() -> tuple[Row, ...]:
    tokens = run("VFX", "tokensTrue")
    return (
        Row("B20", "targets", "§4.1 (iii); App. C", "token encoder: the factorial's ordering, VFX log k and position",
            (Cell("VFX tokens log k", TOKENS["VFX"]["log_k"], R2, Read(MPR, f"{tokens}/{ridge('log_k')}"),
                  at_cpu(FC, f"{tokens}/{ridge('log_k')}")),
             Cell("VFX tokens position", TOKENS["VFX"]["object_pos"], R2, Read(MPR, f"{tokens}/{ridge('object_pos')}"),
                  at_cpu(FC, f"{tokens}/{ridge('object_pos')}")),
             Cell("the factorial's ordering under tokens", True, HOLDS, token_ordering(MPR), token_ordering(FR))),
            cause="on the reference environment the token factorial at cpu reads log k -0.01 / -0.00 / -0.00 / 0.24 / 0.28 / 0.40 for V / VF / VX_p "
                  "/ VX_t / VX / VFX (the global embedding's seed 0: 0.00 / −0.00 / −0.00 / 0.32 / 0.34 / 0.54, "
                  "map_cpu_reference.json): the ordering holds, as the paper says, but VFX with tokens stays below the "
                  "global embedding where the paper's "
                  "rises to 0.62: 32-px frames give a 2 × 2 token map (the paper's 64 px give 16); position "
                  "0.94 (paper 0.98)"),
        Row("B21", "targets", "App. C (after Table \"targets\")", "the factorial's ordering is unchanged at λ = 0.1",
            (Cell("ordering at λ 0.1", True, HOLDS, ordering_at("0.1", MPR), ordering_at("0.1", FR),
                  released=ordering_holds(released_log_k(), RELEASED_VARIANTS)),)
            + tuple(Cell(f"{v} log k at λ 0.1", None, R2, Read(MPR, f"{run(v, seed='0', lam='0.1')}/{ridge('log_k')}"),
                         Read(FR, f"{run(v, seed='0', lam='0.1')}/{ridge('log_k')}"),
                         released=released(v, ridge_of("log_k"), LAMBDA_0_1)) for v in TARGETS_ORDER),
            needs="the six-variant factorial at λ = 0.1 (`pokeworld map --experiments lambda_factorial`, cpu or a GPU "
                  "lease)",
            note="ordering: every variant with touch more than 0.1 above every variant without, and no pair of Table "
                 "\"targets\"' order (VFX, VX, VX_t, VX_p, VF, V) reversed by more than 0.1; the release ran V, VX_t, "
                 "VX and VFX at λ 0.1 (its released column is their seed means' ordering)",
            release="exp/e003_motion runs at λ 0.1, per seed"),
        Row("B22", "targets", "App. C \"Composition probes\"",
            "finger, object and relative position saturate for every variant (multi-horizon)",
            tuple(Cell(f"{v} {LABEL[q]}", P.COMPOSITION, R2, **both(f"{run(v)}/{ridge(q)}"))
                  for v in VARIANTS for q in ("finger_pos", "object_pos", "object_rel")),
            cause="at the cpu budget the relative (object − finger) position reads 0.70–0.95 (V, VX_t lowest); the "
                  "paper-budget V / VF / VFX read 0.96–1.00; VX_p, VX_t, VX have no paper-budget run yet"),
    )


LAZY_NOTE = ("position = the frame embedding's R² on every test frame (the release's probe_r2_pos_frame), of the "
             "lazy experiment's runs, trained as the release's e001 (single horizon) and e002 (multi-horizon) runs: "
             "the frame alone as input, SIGReg weight 0.1")


def lazy_rows() -> tuple[Row, ...]:
    def frame_position(variant: str, horizons: str) -> dict:  # the lazy experiment's run, trained as the release's
        path = f"{run(variant, 'motion_channelFalse', lam='0.1', horizons=horizons)}/prediction/frame_position_r2"
        return {"paper_budget": Read(MPR, path), "cpu": at_cpu(LZ, path)}
    single = tuple(Cell(f"{v} single-horizon position", FACTORIAL[v]["object_pos_h1"], R2, **frame_position(v, "1"),
                        released=released(v, lambda r: r["object_pos_frame"], SINGLE_HORIZON))
                   for v in TABLE_VARIANTS)
    v_single, v_multi = frame_position("V", "1"), frame_position("V", "1-4-16")
    rel_single = released("V", lambda r: r["object_pos_frame"], SINGLE_HORIZON) or {}
    rel_multi = released("V", lambda r: r["object_pos_frame"], MULTISCALE) or {}
    # the row's claim is a restoration: what the heads add to V's single-horizon position, judged beside the levels
    restored = Cell("V position restored by the heads (multi − single horizon)",
                    round(LAZY["V-h3"] - FACTORIAL["V"]["object_pos_h1"], 2), R2,
                    **{b: Derived("difference", (v_multi[b], v_single[b])) for b in ("paper_budget", "cpu")},
                    released={s: round(rel_multi[s] - rel_single[s], 4) for s in rel_multi if s in rel_single} or None)
    multi = (Cell("V multi-horizon position", LAZY["V-h3"], R2, **v_multi,
                  released=rel_multi or None),
             Cell("VFX multi-horizon position", LAZY["VFX-h3"], R2, **frame_position("VFX", "1-4-16"),
                  released=released("VFX", lambda r: r["object_pos_frame"], MULTISCALE)), restored)
    open_loop = (tuple(Cell(f"{v} position", P.OPEN_LOOP["object_pos"], R2, **both(f"{run(v)}/{ridge('object_pos')}"))
                       for v in VARIANTS)
                 + tuple(Cell(f"{v} rollout-8", P.OPEN_LOOP["rollout8"], ERROR, **both(f"{run(v)}/prediction/rollout8"))
                         for v in VARIANTS)
                 + (Cell("static-8 (true positions)", P.CORPUS_STATS["static8"][0], ERROR,
                         **both(f"{run('VFX')}/prediction/static8_true")),))
    pred = {"direct16": "direct Δ16 head", "rollout16": "autoregressive rollout", "static16": "static baseline"}
    direct = tuple(Cell(f"VFX {label}", P.PREDICTION[q], ERROR,
                        **both(f"{run('VFX')}/prediction/{'static16_true' if q == 'static16' else q}"),
                        released=released("VFX", lambda r, q=q: r[q])) for q, label in pred.items())
    return (
        Row("B18", "lazy", "§4.2; App. C Table \"targets\" (position column)",
            "single-horizon object position (the lazy equilibrium)", single, note=LAZY_NOTE,
            cause="trained and read as the release's e001 runs (the frame alone, SIGReg 0.1, the frame embedding), "
                  "single-horizon V / VX_p / VX_t / VX / VFX read position 0.99 / 0.98 / 0.93 / 0.92 / 0.95 at cpu on the reference "
                  "environment (paper 0.04 / 0.09 / 0.17 / 0.58 / 0.98): no lazy equilibrium forms at this budget "
                  "(32 px, 4,000 steps, the cpu model, whose untrained encoder already reads 0.81; the release's runs "
                  "are 64 px, 20,000 steps); the paper-budget runs are queued",
            needs="the lazy experiment as the release trains it (`pokeworld map --preset cpu --experiments lazy`; "
                  "a GPU lease for the paper budget); the earlier cpu record (the factorial's trunk and λ, "
                  "predictor-state readout, the retired calibrated environment) read V 1.00",
            release="e001 single-horizon runs, seed 0"),
        Row("B19", "lazy", "§4.2; abstract", "multi-horizon heads restore V's position to 0.89; with targets 0.98",
            multi, note=LAZY_NOTE,
            cause="trained and read as the release's e002 runs, multi-horizon V / VX / VFX read position "
                  "0.99 / 0.99 / 0.99 at cpu on the reference environment (paper V 0.89, VFX 0.98): the levels agree, "
                  "but the heads restore nothing (V −0.01 beside its single-horizon run; paper +0.85), because the "
                  "single-horizon runs never lost position at this budget (row B18)",
            needs="the lazy experiment as the release trains it (as row B18); the factorial's V (the release's e003 "
                  "trunk, λ 0.02) reads 0.99 at the paper budget",
            release="e002 multiscale runs, seed 0"),
        Row("B23", "lazy", "App. C (after Table \"targets\")",
            "multi-horizon position 0.95–0.98 and open-loop 8-step error 0.062–0.082 (static 0.109), every variant",
            open_loop,
            cause="at the cpu budget 8-step rollouts err 0.10–0.15 (32 px, 4,000 steps); the paper-budget V / VF / "
                  "VFX read 0.051–0.065 with positions 0.99; VX_p, VX_t, VX have no paper-budget run yet"),
        Row("B24", "lazy", "§4.2; abstract; design rule 3", "direct Δ16 vs autoregressive vs static, 16 steps (VFX)",
            direct,
            cause="at the paper budget the autoregressive rollout is as good as the direct head (VFX 0.105 vs 0.097; "
                  "V 0.097 vs 0.099); the release's e003 runs read 0.11–0.14, not the paper's 0.19",
            note="static in true positions (the corpus's own baseline, as the release's); direct and rollout decoded",
            release="e003 VFX runs, per seed"),
    )


def lambda_rows() -> tuple[Row, ...]:
    section = "§4.3; App. C Table \"lambda\" (VFX)"
    flat = ("at cpu on the reference environment (released objective) log k falls with λ as in the paper but less "
            "(0.53 / 0.46 / 0.36 at λ 0.02 / 0.1 / 0.3, the first two the mean of seeds 0 and 1 as the release has "
            "them: 0.54 / 0.51 and 0.48 / 0.45; paper 0.50 / 0.24 / 0.12) and is flat below 0.02 (0.53–0.55); "
            "mass stays at the cpu budget's level (0.11–0.13), velocity rises slightly with λ (0.66 → 0.71; the "
            "paper's falls 0.79 → 0.54) and direct-16 does not halve (0.104–0.120); the paper-budget sweep is not "
            "run (the calibrated environment's per-step SIGReg was flat: frontier_cpu.md)")
    quantities = (("C1", "log_k", ridge("log_k"), R2, ridge_of("log_k")),
                  ("C2", "log_m", ridge("log_m"), R2, ridge_of("log_m")),
                  ("C3", "object_vel", ridge("object_vel"), R2, lambda r: r["object_vel_moving"]),
                  ("C4", "direct16", "prediction/direct16", ERROR, lambda r: r["direct16"]))
    rows = []
    for rid, q, path, tol, pick in quantities:
        cells = tuple(Cell(f"λ {lam:g}", LAMBDA[lam][q], tol, **both(f"{run('VFX', lam=f'{lam:g}')}/{path}", FC),
                           released={s: pick(r) for (w, s), r in LAMBDA_SWEEP_VFX.items() if w == lam} or None)
                      for lam in LAMBDA)
        label = "direct-16 error (\"halves\")" if q == "direct16" else LABEL[q]
        note = ("the paper's velocity column equals the release's moving-window readout (``velocity_r2.moving``; "
                "0.79 at λ 0.02 is its two seeds' 0.786 / 0.784), though the caption says contact windows; ours "
                "reads contact windows" if q == "object_vel" else "")
        rows.append(Row(rid, "lambda", section, f"{label} at λ = 0.3 / 0.1 / 0.02 / 0.01 / 0.005", cells, cause=flat,
                        note=note, release="exp/e003_motion VFX runs, per seed (λ 0.3 / 0.01 / 0.005: seed 0 only)"))
    return tuple(rows)


def lever_rows() -> tuple[Row, ...]:
    std, flow, poor = (run("VFX", seed="0"), run("VFX", corpus="flow_velocity", seed="0"),
                       run("VFX", corpus="contact_poor"))
    best_k = lambda record, corpus: Read(record, f"certificates/{corpus}/certificate/contact/log_k/r2")  # noqa: E731
    coverage = tuple(Cell(f"standard {LABEL[q]}", COVERAGE["standard"][q], R2, **both(f"{run('VFX')}/{ridge(q)}", FC),
                          released=released("VFX", lambda r, q=q: released_value(r, q)))
                     for q in ("log_k", "log_m", "object_pos", "object_vel"))
    coverage += tuple(Cell(f"contact-poor {LABEL[q]}", COVERAGE["contact_poor"][q], R2,
                           Read(MPR, f"{poor}/{ridge(q)}"), at_cpu(FC, f"{poor}/{ridge(q)}"),
                           released={0: released_value(CONTACT_POOR_VFX, q)})
                      for q in ("log_k", "log_m", "object_pos", "object_vel"))
    return (
        Row("A8", "levers", "§4.4 \"Information bandwidth\"",
            "stiffness certificate: sub-step touch 0.87, frame-averaged touch unrecoverable",
            (Cell("log k certificate, sub-step touch", FRAME_AVERAGED["certificate_log_k_substep"], R2,
                  best_k(MPR, "standard"),
                  Derived("default_first", (Derived("first", (best_k(FR, "standard"), best_k(MCR, "standard"))),
                                            best_k(FC, "standard")))),
             Cell("log k certificate, frame-averaged touch", P.FRAME_AVERAGED_LOG_K_CERTIFICATE, R2,
                  best_k(MPR, "frame_averaged"),
                  Derived("default_first", (Derived("first", (best_k(FR, "frame_averaged"),
                                                              best_k(CCR, "frame_averaged"))),
                                            best_k(FC, "frame_averaged")))),
             Cell("GRU oracle, frame-averaged touch", None, R2,
                  cpu=Read(CCR, cert("gru", "log_k", "frame_averaged"))),
             Cell("GRU with contact geometry, sub-step touch", None, R2, cpu=Read(CCR, cert("gru_geom", "log_k")))),
            cause="on the reference environment at cpu frame-averaged touch leaves stiffness recoverable: the GRU "
                  "with contact geometry reads log k 0.96 (0.97 with sub-step touch), the GRU oracle 0.82 (0.89), "
                  "the linear fit 0.08 (0.19): a push holds the overlap at (F/k)^(2/3), visible in the kinematics; "
                  "the VFX model falls 0.54 → 0.27 (the retired calibrated environment: GRU 0.78 → 0.57, geometry "
                  "GRU 0.95, model 0.35 → 0.04)",
            note="certificate = the best estimator each corpus's records ran: the GRU oracle among GRU, linear "
                 "and drag on the standard corpus (the paper's 0.87 is its GRU oracle), any of linear, GRU and GRU "
                 "with contact geometry on the frame-averaged one (\"unrecoverable\" is a claim about every "
                 "estimator); the geometry GRU on the standard corpus is shown beside it, like for like"),
        Row("D1", "levers", "§4.4 \"Computation\"; App. C γ ledger",
            "a frozen flow sensor raises velocity readout 0.79 → 0.88",
            (Cell("velocity, VFX", COORDINATE["object_vel"][0], R2, Read(MPR, f"{std}/{ridge('object_vel')}"),
                  at_cpu(LC, f"{std}/{ridge('object_vel')}"),
                  released=released("VFX", lambda r: r["object_vel_moving"])),
             Cell("velocity, VFX with the flow sensor", COORDINATE["object_vel"][1], R2,
                  Read(MPR, f"{flow}/{ridge('object_vel')}"), at_cpu(LC, f"{flow}/{ridge('object_vel')}"),
                  released={0: FLOW_RUNS["fl"]["object_vel_moving"]})),
            cause="at cpu on the reference environment VFX reads velocity 0.66 without the sensor (the paper's "
                  "0.79; the paper-budget VFX reads 0.82) and 0.93 with the frozen flow velocity sensor (paper "
                  "0.88): the endpoint reproduces, the baseline is the cpu budget's (the retired calibrated "
                  "environment: 0.58 → 0.87)",
            note="the paper's pair equals the release's moving-window velocity readouts (standard VFX 0.786, the "
                 "velocity-only flow-input VFX 0.880); ours reads contact windows, the sensor's velocity as proprio "
                 "channels (the flow_velocity corpus; the release feeds dense flow image channels)",
            release="exp/e003_motion VFX_s0/s1_l0.02 and VFX_s0_l0.02_fl, moving windows"),
        Row("D2", "levers", "§4.4 \"Data coverage\"; App. C",
            "VFX on contact-poor data: log k 0.50 → 0.05, log m 0.29 → 0.11, position 0.98 → 0.87, velocity "
            "0.79 → 0.58", coverage,
            cause="at cpu on the reference environment the contact-poor cells reproduce (log k 0.11, log m 0.06, "
                  "position 0.79, velocity 0.53; paper 0.05 / 0.11 / 0.87 / 0.58; seed 0) and stiffness falls from "
                  "its standard twin's 0.53 (seeds 0 and 1) as in the paper; the twin's mass and velocity are the "
                  "cpu budget's (0.11, 0.67; the paper-budget VFX reads 0.31 and 0.82)"),
    )


def readout_rows() -> tuple[Row, ...]:
    vfx = run("VFX")
    def ratio(q: str, est: str) -> dict:  # the VFX readout over the certificate, each budget's own pair
        return {"paper_budget": Derived("ratio", (Read(MPR, f"{vfx}/{ridge(q)}"), Read(MPR, cert(est, q)))),
                "cpu": Derived("ratio", (Read(MCR, f"{vfx}/{ridge(q)}"), cert_at_cpu(est, q)))}
    glide = f"{vfx}/prediction/glide_test"
    refs = (("true_gamma", "true-γ reference"), ("median_gamma", "median-γ reference"), ("static", "static predictor"))
    return (
        Row("A7", "frontier", "§4.5; App. C \"Pixel-derived certificates\"",
            "model readout over the pixel certificate (VFX): stiffness, mass, drag",
            (Cell("log k / pixel certificate", P.PIXEL_READOUT_RATIO["log_k"], R2, **ratio("log_k", "gru_pixel")),
             Cell("log m / pixel certificate", P.PIXEL_READOUT_RATIO["log_m"], R2, **ratio("log_m", "gru_pixel")),
             Cell("γ / pixel certificate", P.PIXEL_READOUT_RATIO["gamma"], R2, **ratio("gamma", "gru_pixel"))),
            cause="at cpu the VFX readout over the pixel certificate is 0.61 for log k (in the paper's range), but "
                  "0.14 for log m and 0.01 for γ: the readouts are the cpu budget's (log m 0.11, γ 0.00; the "
                  "paper-budget VFX reads 0.31 and 0.15, which over these certificates would give 0.40 and 0.23), "
                  "and the paper corpus's 64-px frames have no pixel certificate yet",
            needs="row A6's pixel-derived certificates (the paper-budget VFX readouts exist)"),
        Row("E1", "frontier", "abstract; §4.5", "γ plateaus near 0.13 in every model (ridge, contact windows)",
            tuple(Cell(f"{v} γ", P.GAMMA_PLATEAU, R2, **both(f"{run(v)}/{ridge('gamma')}"),
                       released=released(v, ridge_of("gamma"))) for v in VARIANTS),
            cause="at the cpu budget γ reads −0.02 to 0.05 in every variant (the paper-budget V / VF / VFX read 0.14 "
                  "/ 0.18 / 0.15: the plateau is the budget's); VX_p, VX_t, VX have no paper-budget run yet",
            note="the paper tabulates no per-variant ridge γ; its MLP counterpart (0.06) is row B17",
            release="e003 runs, per seed"),
        Row("E2", "frontier", "App. C γ ledger (the functional glide test)",
            "glide-test references in true positions: true-γ 0.0002, median-γ 0.049, static 0.144",
            tuple(Cell(label, P.GLIDE_TEST[q], SMALL_ERROR, **both(f"{glide}/undecoded/{q}")) for q, label in refs)
            + tuple(Cell(f"{label}, decoded (not the paper's coordinates)", None, SMALL_ERROR, **both(f"{glide}/{q}"))
                    for q, label in refs[1:]),
            cause="on the reference environment's pure-glide windows (490 at the paper budget) the true-position "
                  "median-γ reference errs 0.028 and the static one 0.113: the corpus's glides, not a model; the "
                  "decoded 0.054 the map report sets beside 0.049 carries the position decoder's residual",
            note="judged in true positions, as the paper's; the decoded references are shown, not judged"),
        Row("E3", "frontier", "§4.5; App. C γ ledger",
            "the model's own glide predictions are beaten by the median-γ reference (VFX)",
            (Cell("glide test: model − median-γ (decoded)", Above(0.0), ERROR,
                  Derived("difference", (Read(MPR, f"{glide}/model"), Read(MPR, f"{glide}/median_gamma"))),
                  Derived("difference", (Read(MCR, f"{glide}/model"), Read(MCR, f"{glide}/median_gamma")))),),
            note="both errors decoded through the same latent position probe"),
    )


def control_row(rid: str, key: str, path: str, cause: str) -> Row:
    """A row of Table "controls": ridge and MLP readouts, position, velocity, direct-16 where the paper has it."""
    def at(tail):
        return {"paper_budget": Read(MPR, f"{path}/{tail}"), "cpu": at_cpu(FC, f"{path}/{tail}")}
    rel = CONTROL_RUNS[key]

    def released_of(q, family="ridge"):
        value = released_value(rel, q, family)
        return None if value is None else {0: value}
    cells = tuple(Cell(f"{LABEL[q]} ridge", CONTROLS[key][q], R2, **at(ridge(q)), released=released_of(q))
                  for q in ("log_m", "gamma", "log_k"))
    cells += tuple(Cell(f"{LABEL[q]} MLP", P.CONTROLS_MLP[key][q], R2, **at(mlp(q)), released=released_of(q, "mlp"))
                   for q in ("log_m", "gamma", "log_k"))
    cells += tuple(Cell(LABEL[q], CONTROLS[key][q], R2, **at(ridge(q)), released=released_of(q))
                   for q in ("object_pos", "object_vel"))
    if key in P.CONTROLS_DIRECT16:
        cells += (Cell("direct-16", P.CONTROLS_DIRECT16[key], ERROR, **at("prediction/direct16"),
                       released=released_of("direct16")),)
    return Row(rid, "frontier", "§4.5; App. C Table \"controls\"", f"objective-attribution control: {key}", cells,
               cause=cause, needs=NEEDS_GPU, release=f"exp/e003_motion {rel['source'].rsplit('/', 1)[-1]}",
               note="velocity: the release's moving-window readout (the paper's column), ours contact windows")


def control_rows() -> tuple[Row, ...]:
    return (
        control_row("E4", "VFX+sysid", run("VFX", "sysid_weight0.5"),
                    "at cpu on the reference environment the supervised head lifts log k 0.54 → 0.80, log m "
                    "0.11 → 0.33 and γ 0.00 → 0.13 beside the same seed's VFX (paper 0.50 → 0.91, 0.29 → 0.72, "
                    "0.12 → 0.45): every parameter moves as in the paper, log k to within 0.11, mass and drag at the "
                    "cpu budget's levels; velocity 0.66 (paper 0.78)"),
        control_row("E5", "VFX-gnll", run("VFX", "objectivegnll"),
                    "at cpu the Gaussian NLL leaves log k at 0.51 beside the same seed's VFX 0.54, γ at 0.01 beside "
                    "0.00 and mass at 0.11 beside 0.11 (\"moves nothing\" holds; log k, γ and direct-16 are within "
                    "tolerance of the paper) but mass and velocity (0.67) sit at the cpu budget's levels (paper 0.31, "
                    "0.88)"),
        control_row("E6", "V-recon", run("V", "objectiverecon"),
                    "V with pixel reconstruction keeps position at 0.95 at cpu (paper 0.75; V without it 0.98) and "
                    "its mass falls to 0.03 (paper 0.16; V 0.14): at this budget reconstruction removes the mass the "
                    "paper's V-recon keeps (the paper's MLP log k −0.10 reads −0.0003 in the release's run)"),
        control_row("E7", "VFX-recon", run("VFX", "objectiverecon"),
                    "VFX-recon reads log k 0.41 at cpu (paper 0.61), below the same seed's VFX 0.54 where the "
                    "paper's sits above its VFX (0.61 vs 0.50): on the reference environment at cpu reconstruction "
                    "lowers stiffness; mass 0.08 (paper 0.19)"),
    )


def matrix_rows() -> tuple[Row, ...]:
    section = "§4.5 Table \"matrix\"; App. C Table \"matrixfull\""
    recurrent = ("gru", "gru_geom")

    def cert_of(record, estimators, qs, corpus="standard"):
        per = [Derived("mean", tuple(Read(record, cert(e, q, corpus)) for q in qs)) for e in estimators]
        return per[0] if len(per) == 1 else Derived("max", tuple(per))

    def model_of(record, qs, corpus="standard", family=ridge):
        return Derived("mean", tuple(Read(record, f"{run('VFX', corpus=corpus)}/{family(q)}") for q in qs))

    def at(build):
        # at cpu the reference environment: the factorial's map (MCR) first, which holds the standard corpus's runs
        # and certificates together, so a row's model, certificate and their ratio read one record; then the findings
        # map (FR: the attribute corpora's runs) and the further certificates of each corpus (CCR); else the retired
        # record for the whole row (one_environment)
        default = Derived("first", (build(MCR), build(FR), build(CCR)))
        return {"paper_budget": build(MPR), "cpu": Derived("default_first", (default, build(FC)))}
    k = ATTRIBUTES["stiffness"]
    stiffness = (Cell("linear certificate", k["linear"], R2, **at(lambda r: cert_of(r, ("linear",), ("log_k",)))),
                 Cell("recurrent certificate", k["recurrent"], R2, **at(lambda r: cert_of(r, recurrent, ("log_k",)))),
                 Cell("model (VFX ridge)", k["model"], R2, **at(lambda r: model_of(r, ("log_k",)))),
                 Cell("model / recurrent certificate", k["ratio"], R2, **at(lambda r: Derived(
                     "ratio", (model_of(r, ("log_k",)), cert_of(r, recurrent, ("log_k",)))))))
    bias = ("bias_x", "bias_y")
    levels = ("bias0.5", "bias1.5", "bias2.5")
    drag = ATTRIBUTES["drag"]
    g = P.GAIN_CELL
    gain_run = run("VFX", corpus="gain")
    return (
        Row("E8", "frontier", section, "stiffness (fast × ratio): linear ≈ 0, recurrent 0.87, model 0.50–0.62",
            stiffness, cause="the linear certificate of log k reads 0.16 at the paper budget and 0.19 at cpu (row A4); "
                             "the recurrent certificate (0.86 / 0.89), the model (0.55 / 0.53) and their ratio (0.64 "
                             "/ 0.59) reproduce at both budgets"),
        Row("E9", "frontier", section, "force bias ±0.5 / ±1.5 / ±2.5: linear certificate",
            tuple(Cell(f"b ∈ ±{c[4:]}", ATTRIBUTES[c]["linear"], R2,
                       **at(lambda r, c=c: cert_of(r, ("linear",), bias, c))) for c in levels)),
        Row("E10", "frontier", section, "force bias: recurrent certificate",
            tuple(Cell(f"b ∈ ±{c[4:]}", ATTRIBUTES[c]["recurrent"], R2,
                       **at(lambda r, c=c: cert_of(r, recurrent, bias, c))) for c in levels),
            cause="the ±0.5 bias's GRU certificate read 0.81 at cpu on the retired calibrated environment (paper 0.92; "
                  "0.97 at ±1.5 and ±2.5); 0.98 / 0.99 / 0.99 on the reference environment"),
        Row("E11", "frontier", section, "force bias: model readout (VFX ridge)",
            tuple(Cell(f"b ∈ ±{c[4:]}", ATTRIBUTES[c]["model"], R2, **at(lambda r, c=c: model_of(r, bias, c)))
                  for c in levels),
            cause="on the reference environment at cpu the model reads 0.02 / 0.22 / 0.50 (MLP 0.00 / 0.22 / 0.54) "
                  "beside linear certificates of 0.14 / 0.50 / 0.69 on the same corpora (row E9, reproduced): the "
                  "paper's model tracks its linear certificate (0.13 / 0.39 / 0.65 against 0.13 / 0.51 / 0.65), ours "
                  "stays 0.12–0.28 below it at this budget (the retired calibrated environment read 0.08 / 0.27 / "
                  "0.57)"),
        Row("E12", "frontier", section, "drag (slow × ratio, gated): linear ≈ 0, drag estimator 0.89, model 0.13",
            (Cell("linear certificate", drag["linear"], R2, **at(lambda r: cert_of(r, ("linear",), ("gamma",)))),
             Cell("drag-estimator certificate", drag["recurrent"], R2,
                  **at(lambda r: cert_of(r, ("drag",), ("gamma",)))),
             Cell("model (VFX ridge)", drag["model"], R2, **at(lambda r: model_of(r, ("gamma",))))),
            cause="the drag certificate reads 0.78 on the reference environment at both budgets (row A2: exact on the "
                  "77 % of contact windows that glide, the fit median on the rest); the linear "
                  "≈ 0 and the model's 0.15 reproduce at the paper budget"),
        Row("E13", "frontier", "App. C \"Constructing the cells\"; Table \"matrixfull\"",
            "actuation gain (slow × ratio, ungated): certificates, readout, and that run's k / m / position",
            (Cell("linear certificate", g["linear"], R2, **at(lambda r: cert_of(r, ("linear",), ("gain",), "gain"))),
             Cell("GRU certificate", g["recurrent"], R2, **at(lambda r: cert_of(r, recurrent, ("gain",), "gain"))),
             Cell("model ridge", g["ridge"], R2, **at(lambda r: model_of(r, ("gain",), "gain"))),
             Cell("model MLP", g["mlp"], R2, **at(lambda r: model_of(r, ("gain",), "gain", mlp))))
            + tuple(Cell(f"gain run {LABEL[q]}", g[q], R2, paper_budget=Read(MPR, f"{gain_run}/{ridge(q)}"),
                         cpu=at_cpu(FC, f"{gain_run}/{ridge(q)}")) for q in ("log_k", "log_m", "object_pos")),
            cause="on the reference environment at cpu the gain's GRU certificate reads 0.93 (paper 0.69; the retired "
                  "calibrated environment 0.45): the gain is more recoverable from raw windows here, and the model "
                  "still reads none of it (ridge 0.02, MLP −0.02; paper −0.01), as in the paper; the gain run's log m "
                  "0.09 (paper 0.20) is the cpu budget's mass level"),
        Row("E14", "frontier", "App. C \"Constructing the cells\" (i), (ii)",
            "rejected constructions: drift certificate 0.03; fixed-γ drift fails a linear certificate",
            (Cell("(i) linear certificate, all windows", P.DRIFT_CERTIFICATE, R2,
                  cpu=Read(DRIFT, "summary/drift/linear_all")),
             Cell("(ii) fixed γ fails the linear certificate", True, HOLDS,
                  cpu=Read(DRIFT, "summary/drift_fixed_gamma/linear_fails")),
             Cell("(ii) linear certificate, all windows", None, R2,
                  cpu=Read(DRIFT, "summary/drift_fixed_gamma/linear_all"),
                  released=sum(RELEASED_DRIFT_LINEAR.values()) / len(RELEASED_DRIFT_LINEAR)),
             Cell("(i) GRU certificate, all windows", None, R2, cpu=Read(DRIFT, "summary/drift/gru_all")),
             Cell("(ii) GRU certificate, all windows", None, R2, cpu=Read(DRIFT, "summary/drift_fixed_gamma/gru_all")),
             Cell("(i) linear certificate, glide windows", None, R2, cpu=Read(DRIFT, "summary/drift/linear_glide")),
             Cell("(ii) linear certificate, glide windows", None, R2,
                  cpu=Read(DRIFT, "summary/drift_fixed_gamma/linear_glide"))),
            needs="the drift corpora's certificates (`python scripts/drift_certificates.py`, CPU only)",
            note="the paper quotes 0.03 for (i); the release's one drift certificate (linear, all windows, "
                 "0.038 / 0.019 by component) is of its generator's fixed-drag corpus, i.e. (ii); \"fails\" is read "
                 "as below 0.1 (the accepted force bias passed at 0.13); a GRU reads both drifts (0.51, 0.86), so "
                 "\"unrecoverable\" holds for the linear certificate only",
            release="exp/e003_motion/results/drift_probe.json (construction (ii))"),
    )


DOSE1_NOTE = ("the paper's dose 1 is the release's flow-input VFX on its glide-enriched split, zero-contact episodes "
              "drawn W times as often; ours is the standard VFX on the standard split, glide frames weighted W in the "
              "loss (the same share formula; docs/design.md)")
DOSE1_RELEASE = "exp/e003_motion VFX_s0_l0.02_fl_g and _fl_g_gw4 / 16 / 64"


def dose_rows() -> tuple[Row, ...]:
    """Dose–responses 1 and 2 (one seed, as the paper): weight 1 (glide) and 4 (touch) are the default VFX run."""
    def dose(tail):
        return run("VFX", tail, seed="0")
    glide = {w: dose("" if w == 1.0 else f"glide_loss_weight{w}") for w in DOSE_GLIDE}
    touch = {w: dose("" if w == 4.0 else f"touch_contact_weight{w}") for w in DOSE_TOUCH}

    def released_dose(table, w):  # the release's run of a dose (weight 4 of dose 2 is the factorial's VFX)
        if table is DOSE_GLIDE:
            return FLOW_RUNS[DOSE_GLIDE_RUNS[w]]
        return DOSE_TOUCH_RUNS.get(w) or MULTI_HORIZON[("VFX", 0)]

    def cells(weights, runs, table, q, path, tol, label, pick=None):
        """``pick`` reads the release's run of a weight (:func:`released_dose`) for the released column."""
        return tuple(Cell(f"{label} {w:g}", table[w][q], tol, Read(MPR, f"{runs[w]}/{path}"),
                          at_cpu(FC, f"{runs[w]}/{path}"),
                          released={0: pick(released_dose(table, w))} if pick else None) for w in weights)
    share = tuple(Cell(f"glide loss share at weight {w:g}", DOSE_GLIDE[w]["share"], POINTS,
                       cpu=at_cpu(FC, f"{glide[w]}/trained/glide_loss_share")) for w in DOSE_GLIDE)
    d1, d2 = "App. C Table \"dose1\"", "App. C Table \"dose2\""
    return (
        Row("E15", "frontier", d1, "dose 1: glide loss share and γ on glide windows",
            share + cells(DOSE_GLIDE, glide, DOSE_GLIDE, "gamma_glide", ridge("gamma", "glide"), R2, "γ glide, weight",
                          lambda r: r["gamma_glide"]),
            cause="at cpu on the reference environment the realised glide loss share follows the paper's (38 / 71 "
                  "/ 90 / 97 %) but γ on glide windows reads −0.01 at every weight, on 306 glide test windows (the "
                  "paper's 351): the creep does not appear at this budget",
            note="the realised share is the mean over the run's logged steps (metrics.jsonl, the record's "
                 "trained/glide_loss_share); " + DOSE1_NOTE, release=DOSE1_RELEASE),
        Row("E16", "frontier", d1, "dose 1: functional glide error (decoded)",
            cells(DOSE_GLIDE, glide, DOSE_GLIDE, "glide_model", "prediction/glide_test/model", ERROR, "weight"),
            cause="at cpu on the reference environment the functional glide error worsens with the glide share as "
                  "in the paper (0.110 → 0.125; paper 0.098 → 0.136)"),
        Row("E17", "frontier", d1, "dose 1: log k",
            cells(DOSE_GLIDE, glide, DOSE_GLIDE, "log_k", ridge("log_k"), R2, "weight", lambda r: r["ridge"]["log_k"]),
            cause="the dose table's weight 1 is not Table \"targets\"' VFX but the release's flow-input VFX on its "
                  "glide-enriched split (0.42; the standard VFX 0.50): our paper-budget default VFX reads 0.55 there; "
                  "at cpu on the reference environment (the standard VFX and split, glide frames weighted in the "
                  "loss) log k falls 0.54 / 0.54 / 0.40 / 0.06 over weights 1 / 4 / 16 / 64 (paper 0.42 / 0.34 / "
                  "0.20 / 0.10): the cost reproduces, starting later",
            note=DOSE1_NOTE, release=DOSE1_RELEASE),
        Row("E18", "frontier", d1, "dose 1: velocity",
            cells(DOSE_GLIDE, glide, DOSE_GLIDE, "object_vel", ridge("object_vel"), R2, "weight",
                  lambda r: r["object_vel_moving"]),
            cause="velocity reads 0.66–0.69 at every glide share at cpu on the reference environment (paper 0.85 → "
                  "0.65, the flow-input runs' moving-window readouts); the paper-budget default VFX reads 0.82",
            note=DOSE1_NOTE + "; the paper's velocity is the release's moving-window readout, ours contact windows",
            release=DOSE1_RELEASE),
        Row("E19", "frontier", d2, "dose 2: log k against the contact-frame touch weight",
            cells(DOSE_TOUCH, touch, DOSE_TOUCH, "log_k", ridge("log_k"), R2, "touch weight",
                  lambda r: r["ridge"]["log_k"]),
            cause="at cpu on the reference environment starving touch starves stiffness, as in the paper (0.54 / "
                  "0.52 / 0.20 / −0.01 at weights 4 / 1 / 0.25 / 0; paper 0.50 / 0.37 / 0.12 / −0.005), but weight 1 "
                  "keeps nearly all of it (0.52 against the paper's 0.37): the fall comes at a lower dose here"),
        Row("E20", "frontier", d2, "dose 2: log m and γ",
            cells(DOSE_TOUCH, touch, DOSE_TOUCH, "log_m", ridge("log_m"), R2, "log m, touch weight",
                  lambda r: r["ridge"]["log_m"])
            + cells(DOSE_TOUCH, touch, DOSE_TOUCH, "gamma", ridge("gamma"), R2, "γ, touch weight",
                    lambda r: r["ridge"]["gamma"]),
            cause="at cpu on the reference environment mass reads 0.07–0.13 and γ 0.00–0.04 at every dose: the cpu "
                  "budget's levels (the paper-budget VFX reads 0.31 / 0.15), so the paper's flat mass and γ columns "
                  "cannot be told from a floor here"),
    )


def ledger_rows() -> tuple[Row, ...]:
    """The γ intervention ledger and the coordinate test (LC: ledger_cpu.json; one seed)."""
    def best(path):
        return lambda record: Derived("max", tuple(Read(record, f"{path}/probes/{fam}/{kind}/gamma")
                                                   for fam in ("ridge", "mlp") for kind in ("contact", "glide")))
    def released_best_gamma(flow_stage: bool) -> dict | None:  # the release's flow-sensor run, ``fl``
        r = FLOW_RUNS["fl"]
        return {0: max(r["ridge"]["gamma"], r["gamma_glide"], r["mlp"]["gamma"], r["mlp_gamma_glide"])} \
            if flow_stage else None
    plateau = AtMost(P.GAMMA_LEDGER["motion_channel"])
    L = P.GAMMA_LEDGER
    flow, sensor = run("VFX", corpus="flow", seed="0"), run("VFX", corpus="flow_velocity", seed="0")
    stages = (("single-horizon head", L["single_horizon"], run("VFX", horizons="1", seed="0")),
              ("multi-horizon heads without the motion channel", L["multi_horizon"],
               run("VFX", "motion_channelFalse", seed="0")),
              ("multi-horizon heads with the motion channel (the default)", L["motion_channel"], run("VFX", seed="0")),
              ("spatial tokens (no gain)", plateau, run("VFX", "tokensTrue", seed="0")),
              ("magnitude-weighted motion targets (no gain)", plateau, run("VFX", "motion_loss_weight4.0", seed="0")),
              ("frozen flow velocity sensor (no gain)", plateau, sensor),
              ("glide-enriched loss (no gain)", plateau, run("VFX", "glide_loss_weight16.0", seed="0")))
    std = run("VFX", seed="0")
    glide_cert = lambda est, corpus, kind="glide": Read(LC, cert(est, "gamma", corpus, kind))  # noqa: E731
    standard_glide = Derived("first", (Read(CCR, cert("linear", "gamma", kind="glide")), glide_cert("linear", "standard")))
    section = "App. C \"The coordinate test\""
    return (
        Row("E21", "frontier", "App. C Fig. \"ledger\"", "best γ readout under every prediction-side mechanism (VFX)",
            tuple(Cell(label, paper, R2, best(path)(MPR), Derived("default_first", (best(path)(FR), best(path)(LC))),
                       released=released_best_gamma(path == sensor))
                  for label, paper, path in stages),
            cause="at cpu on the reference environment every prediction-side mechanism's best γ is −0.01 to 0.02, "
                  "flat as in the paper but at the cpu budget's level (the default VFX 0.00; paper 0.12; the "
                  "paper-budget VFX reads 0.15); the frozen flow velocity sensor reads 0.05 (the release's 0.11), "
                  "and only the coordinate test's log-speed channel lifts γ (0.25 on glide windows, row E23)",
            note="best γ = the largest ridge / MLP readout on contact and glide windows; our default trunk has the "
                 "motion channel, so the paper's stages map as labelled; the flow stage's released run is the "
                 "velocity-only sensor (its γ 0.11 on contact, 0.01 on glide windows)",
            release="the flow stage: exp/e003_motion VFX_s0_l0.02_fl (dense flow input channels, standard split)"),
        Row("E22", "frontier", section, "linear γ certificate on glide windows: ≈ 0, and 0.52 under log speed",
            (Cell("standard coordinates", COORDINATE["gamma_linear_certificate_standard"], R2, cpu=standard_glide),
             Cell("log-speed coordinates", COORDINATE["gamma_linear_certificate_logspeed"], R2, cpu=Derived("first", (
                 Read(CCR, cert("linear_logspeed", "gamma", "flow", "glide")), glide_cert("linear_logspeed", "flow")))),
             Cell("log-speed coordinates, contact windows (not the paper's glide windows)", None, R2,
                  cpu=Derived("first", (Read(CCR, cert("linear_logspeed", "gamma", "flow", "contact")),
                                        glide_cert("linear_logspeed", "flow", "contact"))))),
            needs="the coordinate test's certificates on glide windows (`--certify-kinds contact glide`; CPU only): "
                  "the record holds them on contact windows",
            cause="on the reference environment at cpu the log-speed coordinate linearizes glide decay further than "
                  "the paper's: the linear γ certificate on glide windows reads 0.85 (paper 0.52; standard "
                  "coordinates −0.06, paper ≈ 0), fit on the flow store's 575 probe-fit glide windows (paper 696) "
                  "and scored on 306 (paper 351)"),
        Row("E23", "frontier", section, "model γ readout on glide windows: 0.08 → 0.33 with the log-speed channel",
            (Cell("before", COORDINATE["gamma_glide_readout"][0], R2, Read(MPR, f"{std}/{ridge('gamma', 'glide')}"),
                  at_cpu(LC, f"{std}/{ridge('gamma', 'glide')}"), released={0: FLOW_RUNS["fl_g"]["gamma_glide"]}),
             Cell("with the log-speed channel", COORDINATE["gamma_glide_readout"][1], R2,
                  Read(MPR, f"{flow}/{ridge('gamma', 'glide')}"), at_cpu(LC, f"{flow}/{ridge('gamma', 'glide')}"),
                  released={0: FLOW_RUNS["fl_g_ls"]["gamma_glide"]})),
            cause="on the retired calibrated environment γ on glide windows read −0.02 → −0.05 at cpu (152 test "
                  "windows); the reference environment's 185 read −0.01 → 0.25 (paper 0.08 → 0.33)",
            note="the paper's pair is the release's flow-input VFX on its glide-enriched training split without and "
                 "with a log-speed image channel; ours is the standard VFX and the flow corpus's VFX (the sensor's "
                 "velocity and log speed as proprio channels) on the standard split (docs/design.md, \"The "
                 "coordinate test\")",
            release="exp/e003_motion VFX_s0_l0.02_fl_g and _fl_g_ls, seed 0"),
        Row("E24", "frontier", section, "functional glide test with the log-speed channel: 0.114 vs median-γ 0.054",
            (Cell("model", COORDINATE["glide_test_model_after"], ERROR,
                  Read(MPR, f"{flow}/prediction/glide_test/model"), at_cpu(LC, f"{flow}/prediction/glide_test/model")),
             Cell("median-γ reference", COORDINATE["glide_test_median_gamma"], ERROR,
                  Read(MPR, f"{flow}/prediction/glide_test/median_gamma"),
                  at_cpu(LC, f"{flow}/prediction/glide_test/median_gamma"))),
            cause="at cpu on the reference environment the flow-channel VFX errs 0.083 on pure-glide windows "
                  "(paper 0.114; the standard VFX 0.110), still above its median-γ reference (0.046; paper 0.054): "
                  "the paper's conclusion holds (no run uses drag functionally), its model error is 27 % lower here "
                  "(the retired calibrated environment read 0.104 / 0.044)",
            note="both decoded"),
    )


def planning_rows() -> tuple[Row, ...]:
    section = "§4.6; App. C Table \"planning\""
    cpu = "invocations/released_planner_cpu_budget/results"

    def cells(i, tol, q):
        return tuple(Cell(v, P.PLANNING[v][i], tol, Read(MPR, f"planning/summary/{v}/{q}"),
                          Read(PPR, f"{cpu}/{v}/{q}", PLANNING_CPU)) for v in P.PLANNING)
    return (
        Row("F1", "planning", section, "goal-region reach: random / V / VX_t / VX_p / VFX",
            cells(0, POINTS, "reach"),
            cause="at the cpu budget the released planner reaches 0–7 % with every model (its Δ16 heads predict "
                  "phantom pushes, deviations_cpu.md §3); the paper-budget random / V / VFX reach 0 / 20 / 60 %; "
                  "VX_t and VX_p have no paper-budget run yet"),
        Row("F2", "planning", section, "median distance improvement (start − closest): random / V / VX_t / VX_p / VFX",
            cells(1, ERROR, "median_closest_improvement"),
            cause="the paper-budget V improves the distance by 0.048 (paper 0.02) and moves the object in 84 % of "
                  "episodes, where the paper's V never reaches it; VFX's 0.276 reproduces"),
    )


def model_rows() -> tuple[Row, ...]:
    return (
        Row("G1", "model", "§3; App. B; Limitations", "model size ≈ 5 M parameters, every variant",
            tuple(Cell(v, P.MODEL_PARAMETERS, SIZE, Read(RFM, f"parameters/[variant={v}]/ours_paper", MODEL_SIZE),
                       released=released(v, lambda r: r["params"])) for v in VARIANTS),
            release="e003 runs (parameter counts)"),
    )


def real_cells(table: dict, prefix: str = "", tol: Tolerance = R2, pair: tuple = ("IID", "OOD")) -> tuple[Cell, ...]:
    """One cell per number of a real-robot table (a pair, by default (IID, OOD), gives two); errors in cm (or m)
    keep ±20 %."""
    cells = []
    for key, value in table.items():
        label = f"{prefix} {key}".strip()
        if isinstance(value, dict):
            cells += real_cells(value, label, tol, pair)
        elif isinstance(value, tuple):
            cells += [Cell(f"{label} {split}", v, tol) for split, v in zip(pair, value)]
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            is_error = any(w in label for w in ("pred16", "static16", "rollout16"))
            cells.append(Cell(label, value, CENTIMETRES if is_error else tol))
    return tuple(cells)


def real_rows() -> tuple[Row, ...]:
    needs = ("RH20T data (not downloadable here) and a GPU lease; real_synthetic.json runs the same pipeline on "
             "synthetic RH20T-layout corpora only, which test the code, not the paper's numbers")
    corpus = P.REAL_CORPUS
    rows = (
        ("H1", "§5; App. C protocol notes", "the RH20T corpora: episodes, tasks, onset base rates, static baselines",
         (Cell("KUKA episodes", corpus["kuka_episodes"], COUNT), Cell("KUKA tasks", corpus["kuka_tasks"], COUNT),
          Cell("Flexiv episodes", corpus["flexiv_episodes"], COUNT),
          Cell("onset base rate cfg7", corpus["onset_base_rate"]["cfg7"], RATE),
          Cell("onset base rate cfg1", corpus["onset_base_rate"]["cfg1"], RATE),
          Cell("static-16 cfg7 (cm)", P.REAL_KUKA_STATIC16, CENTIMETRES),
          Cell("static-16 cfg1 (cm)", P.REAL_CFG1_STATIC16, CENTIMETRES))),
        ("H2", "§5; App. C Table \"kuka\"", "KUKA (cfg7): force, position, 16-step error, AUC for V / VX / VX_t / VFX",
         real_cells(P.REAL_KUKA)),
        ("H3", "§5; App. C Table \"viewpoint\"", "viewpoint selects observables (cfg7), and VFX across viewpoints",
         real_cells(P.REAL_VIEWPOINT) + real_cells(P.REAL_VIEWPOINT_VFX, "VFX", pair=("low", "high"))),
        ("H4", "§5; App. C Table \"cfg1\"", "the four-arm factorial across scale (Flexiv, cfg1), and its compute "
         "control", real_cells(P.REAL_CFG1) + real_cells(P.REAL_CFG1_NOTES)),
        ("H5", "App. C Table \"crossemb\"", "cross-embodiment comparison, V and VFX, cfg7 vs cfg1",
         real_cells(P.REAL_CROSS)),
        ("H6", "§5; App. C Table \"rand\"", "untrained-encoder bounds", real_cells(P.REAL_UNTRAINED)),
        ("H7", "App. C Table \"futforce\"", "future-force forecasting against persistence",
         real_cells(P.REAL_FORECAST)),
        ("H8", "§5; App. C", "held-out Δ4 force forecast across scale and its bootstrap CIs",
         real_cells(P.REAL_FORECAST_SCALING) + real_cells(P.REAL_FORECAST_CI, "CI of model − persistence",
                                                           pair=("low", "high"))),
        ("H9", "§5 \"One model, two robots\"", "configuration-blind joint VFX: KUKA held-out force retention",
         real_cells(P.REAL_JOINT)),
        ("H10", "§5; App. C Fig. \"forceread\"",
         "VF force retention vs the untrained bound; direct-16 12.0 → 2.3 cm; camera-only AUC 0.62 → 0.77",
         real_cells(P.REAL_FORCE_RETENTION, "force retention")
         + (Cell("V direct-16 at 4,258 episodes (cm)", P.REAL_CFG1["V"][4258]["pred16"], CENTIMETRES),
            Cell("VFX direct-16 at 4,258 episodes (cm)", P.REAL_CFG1["VFX"][4258]["pred16"], CENTIMETRES),
            Cell("V AUC OOD at 4,258 episodes", P.REAL_CFG1["V"][4258]["auc_ood"], R2),
            Cell("VX AUC OOD at 4,258 episodes", P.REAL_CFG1["VX"][4258]["auc_ood"], R2))),
    )
    return tuple(Row(rid, "real", section, quantity, cells, needs=needs) for rid, section, quantity, cells in rows)


ROWS: tuple[Row, ...] = (certificate_rows() + factorial_rows() + mlp_rows() + composition_rows() + lazy_rows()
                         + lambda_rows() + lever_rows() + readout_rows() + control_rows() + matrix_rows() + dose_rows()
                         + ledger_rows() + planning_rows() + model_rows() + real_rows())
"""Every quantitative result of the paper, one row each (ids of the hand-made inventory)."""

# ----------------------------------------------------------------------------- the ledger and its report

TOLERANCES = {t.label: desc for t, desc in (
    (R2, "R² readouts and certificates, ratios of R²"), (ERROR, "errors in arena units"),
    (POINTS, "shares and rates"), (SIZE, "parameter counts"), (CENTIMETRES, "real-robot errors in cm"),
    (COUNT, "corpus counts"), (HOLDS, "a stated property: a gate passes, an ordering holds"))}


def ledger(records: str | Path, rows: tuple[Row, ...] = ROWS) -> dict:
    """The reproduction ledger computed from the records in ``records`` (docs/results): every row judged, and the
    count of rows per verdict."""
    found = Records(records)
    judged = [judge_row(row, found) for row in rows]
    counts = {v: sum(r["verdict"] == v for r in judged) for v in VERDICTS}
    return {"about": "every quantitative result of the paper beside ours, verdicts computed from the committed "
                     "records (pokeworld.reproduction)",
            "verdicts": list(VERDICTS), "tolerances": [[k, v] for k, v in TOLERANCES.items()],
            "parts": [[k, v] for k, v in PARTS.items()], "counts": counts,
            "counts_detail": {
                "not reproduced at the paper budget": sum(r.get("measured_at") == "paper budget" for r in judged),
                "reproduced at cpu only, with calibrated-environment cells": sum(
                    r.get("environment") == "calibrated (retired)" for r in judged)},
            "rows": judged}


def show_json(v, style: str) -> str:
    """A value of the ledger's JSON (ours, the paper's or the release's) as the report prints it."""
    tol = Tolerance("", style=style)
    if isinstance(v, dict):
        if "range" in v:
            return f"{tol.show(v['range'][0])}–{tol.show(v['range'][1])}"
        if "at_most" in v:
            return f"≤ {tol.show(v['at_most'])} (no gain)"
        if "above" in v:
            return f"> {tol.show(v['above'])}"
        return "/".join(tol.show(x) for x in v.values()) + f" ({'/'.join(v)})"
    if v is True:
        return "holds"
    return tol.show(v)


def numbers(values) -> list[float]:
    """Every number inside ledger values (a per-seed table or a range gives each of its numbers)."""
    out = []
    for v in values:
        if isinstance(v, dict):
            out += numbers(x for k, x in v.items() if k not in ("at_most", "above")) + numbers(v.get("range", []))
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out.append(v)
    return out


def column(cells: list[dict], pick) -> str:
    """One report cell for a row's values: each in order (· between cells) for a few cells, else their span per
    tolerance (so R² and errors are never one span)."""
    values = [pick(c) for c in cells]
    if all(v is None for v in values):
        return "—"
    if len(cells) <= 6:
        return " · ".join("—" if v is None else show_json(v, c["format"]) for v, c in zip(values, cells))
    spans = []
    for tolerance in dict.fromkeys(c["tolerance"] for c in cells):
        group = [(v, c) for v, c in zip(values, cells) if c["tolerance"] == tolerance]
        nums = numbers(v for v, _ in group if v is not None)
        if nums:
            style = group[0][1]["format"]
            spans.append(f"{sum(v is not None for v, _ in group)} of {len(group)}: {show_json(min(nums), style)} to "
                         f"{show_json(max(nums), style)}")
    return " · ".join(spans) or "—"


ENVIRONMENT_WORDS = {DEFAULT_ENVIRONMENT: f"{DEFAULT_ENVIRONMENT} environment", ENVIRONMENT_FREE: ENVIRONMENT_FREE,
                     "calibrated": "calibrated environment (retired)"}


def where(cells: list[dict], budget: str) -> str:
    """The records (linked), seeds, budget and environment behind a row's values at one budget."""
    found = [c[budget] for c in cells if c[budget] is not None]
    if not found:
        return ""
    records = sorted({r["record"] for m in found for r in m["read"]})
    seeds = sorted({s for m in found for s in m["seeds"]})
    envs = sorted({m["environment"] for m in found})
    budgets = sorted({m["budget"] for m in found})
    parts = [", ".join(f"[{r}]({r})" for r in records)]
    if seeds:
        parts.append(f"seed{'s' if len(seeds) > 1 else ''} {', '.join(map(str, seeds))}")
    if budget == "cpu" or envs != [DEFAULT_ENVIRONMENT]:
        parts.append("; ".join(ENVIRONMENT_WORDS.get(e, f"{e} environment") for e in envs))
    if budget == "paper_budget" and (budgets != ["paper"] or not set(envs) <= {DEFAULT_ENVIRONMENT, ENVIRONMENT_FREE}):
        parts.append("not counted at the paper budget")
    if budget == "cpu" and budgets != ["cpu"]:
        parts.append(f"budget {', '.join(budgets)}")
    return " (" + "; ".join(parts) + ")"


def verdict_cell(row: dict) -> str:
    verdict = row["verdict"]
    if verdict == REPRODUCED:
        text = "**reproduced**"
    elif verdict == REPRODUCED_AT_CPU:
        text = "reproduced at cpu only" + (" (cells from the retired calibrated environment)"
                                           if row["environment"] != DEFAULT_ENVIRONMENT else "")
    elif verdict == NOT_REPRODUCED:
        text = (f"**not reproduced** ({row['measured_at']}): {row['cause'] or 'no cause recorded yet'}. Outside: "
                + "; ".join(row["outside"]))
    else:
        text = f"not run; needs {row['needs'] or 'a record of it'}"
    if "against_release" in row:
        text += f". Against the release (the paper and the release differ here): {row['against_release']}"
    return text


def row_line(row: dict) -> str:
    cells = row["cells"]
    labels = "" if len(cells) == 1 else ": " + " · ".join(
        c["quantity"] + ("" if c["judged"] else " [shown, not judged]") for c in cells) if len(cells) <= 6 \
        else f": {len(cells)} cells"
    quantity = f"{row['quantity']}{labels} ({row['section']})" + (f". {row['note']}" if row["note"] else "")
    released_text = column(cells, lambda c: c["released"])
    if row["release"] and released_text.strip("—· "):
        released_text += f" ({row['release']})"
    tolerance = " · ".join(sorted({c["tolerance"] for c in cells}))
    return (f"| {row['id']} | {quantity} | {column(cells, lambda c: c['paper'])} | {released_text} | "
            f"{column(cells, lambda c: (c['paper_budget'] or {}).get('value'))}{where(cells, 'paper_budget')} | "
            f"{column(cells, lambda c: (c['cpu'] or {}).get('value'))}{where(cells, 'cpu')} | {tolerance} | "
            f"{verdict_cell(row)} |")


def summary_line(result: dict) -> str:
    c, d = result["counts"], result["counts_detail"]
    return (f"**{len(result['rows'])} rows: {c[REPRODUCED]} reproduced · {c[REPRODUCED_AT_CPU]} reproduced at cpu "
            f"only ({d['reproduced at cpu only, with calibrated-environment cells']} of them with cells from the "
            f"retired calibrated environment) · {c[NOT_REPRODUCED]} not reproduced "
            f"({d['not reproduced at the paper budget']} of them measured at the paper budget) · {c[NOT_RUN]} not "
            f"run.**")


def ledger_markdown(result: dict) -> str:
    """docs/results/reproduction.md: the summary line, then one table per part of the paper."""
    lines = ["# Reproduction ledger", "", summary_line(result), "",
             "Every quantitative result of the paper (one row each, the ids of the hand-made inventory) beside ours, "
             "written by `python scripts/reproduction_ledger.py` from the committed records in this folder; "
             "`tests/test_reproduction.py` fails when this file and the records disagree. Ours is read from a record "
             "and a path into its JSON (both in [reproduction.json](reproduction.json)), at the paper's budget "
             "(20,000 steps, seed 0 so far, the reference environment) and at the `cpu` budget (4,000 steps, 32 px), "
             "each with the environment its record was made on. Verdicts are computed from the numbers "
             "(`pokeworld.reproduction`): **reproduced** — every cell within tolerance at the paper's budget on the "
             "default (reference) environment; **reproduced at cpu only** — every cell within tolerance at `cpu` "
             "(a row with cells from the retired calibrated environment says so; such a record never counts as a "
             "default-environment reproduction); **not reproduced** — a cell outside tolerance where measured (the "
             "paper's budget first), with the measured cause; **not run** — a cell no record holds. A row is judged "
             "at one budget at a time. Seeds: a paper value given per seed (s0/s1) is compared with ours over the "
             "seeds we have. Released: the authors' per-run numbers (`pokeworld.published.release`); where they differ "
             "from the paper's beyond the tolerance the row is judged against them too.", "",
             "Tolerances: " + "; ".join(f"{k} ({v})" for k, v in result["tolerances"]) + ".", ""]
    for part, title in result["parts"]:
        rows = [r for r in result["rows"] if r["part"] == part]
        if not rows:
            continue
        lines += [f"## {title}", "", "| id | quantity | paper | released | ours, paper budget | ours, cpu | "
                  "tolerance | verdict |", "|---|---|---|---|---|---|---|---|", *(row_line(r) for r in rows), ""]
    return "\n".join(lines)
