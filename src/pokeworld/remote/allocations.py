"""The paper-budget map from short GPU allocations: where an allocation ran, and the merge of any number of them.

A GPU comes in short allocations (a fresh machine for minutes at a time), so the paper-budget factorial is trained
in pieces: ``bash scripts/gpu_allocation.sh OUT`` spends one allocation on as many ``paper``-preset runs as fit
(:mod:`.run`) and brings back ``device.json`` (:func:`device_record`: which GPU, driver, torch, the date,
the commit passed in as ALLOC_COMMIT), the records (each run's config, metrics and measurement, the corpus manifest,
progress.json and device.json again) and the finished runs' weights and the unfinished run's checkpoint
(:mod:`.pack`). ``scripts/merge_allocations.py`` assembles any number of them into one record
(:func:`merge_allocations`), and ``--plan`` prints the next allocation's queue (:func:`plan`):

* every allocation must have trained on the same corpus (the seeded paper corpus: its manifest's content hash) with
  the same map-wide settings (:data:`AGREE`) and the same objective and model (:func:`model_form`: the first paper
  model and the one aligned with the released reference share run names); otherwise the merge is refused with one
  line, and ``--plan`` refuses allocations whose runs are not of the model the preset trains now;
* an allocation contributes its finished runs only (progress.json): a run its time budget cut short is named, not
  counted;
* each returned weight file and checkpoint is checked (its sha256, a weights-only load, its tensors against the
  model its kwargs declare) and restored in float32 beside the run's records (:func:`restore_returned`), so probes
  can be computed from it on the CPU; a finished run whose weights did not come back says so;
* each run record is the map's own (:func:`pokeworld.experiments.report.collect`) plus where it was trained
  (``run["allocation"]``: device, date, torch, steps and s/step);
* a run present in two allocations is kept once, the later allocation's (device.json dates), and the largest
  difference of the two ridge readouts is recorded (:func:`pokeworld.experiments.merge.merge`,
  :func:`pokeworld.experiments.merge.max_difference`);
* certificates come from a certify JSON computed elsewhere (``--certificates``; the allocations compute none),
  refused when it certifies another corpus.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import re
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from .. import __version__, certify, checkpoint
from ..bounded_tar import TarBounds, extract
from ..config import from_dict
from ..errors import ConfigError, PokeworldError
from ..evaluate.tables import fmt, git_commit, probe
from ..io import (
    check_apart,
    check_regular_file,
    check_replaceable,
    read_json as io_read_json,
    read_jsonl,
    read_regular_bytes,
    save_bytes,
    save_text,
    write_json,
)
from ..model_folder import folder_config, read_weights
from ..record_paths import without_machine_paths
from ..published import paper as P
from ..rundir import model_from_checkpoint
from ..train.optimizer_state import check_optimizer_fits
from ..experiments import merge, report, stages
from ..experiments.config import VARIANT_ORDER, MapConfig, recorded_map_config
from ..experiments.factorial import FACTORIAL
from ..experiments.runs import spec_measure_path
from . import plan as lease_plan
from .cpu_side import attach_cpu_side, record_lines
from .pack import COMPACT_MIN_ELEMENTS, INDEX, RECORDS, ReturnLimits, load_member, part_path, read_stream
from .plan import Returned, configuration_key, plan_lines
from .queue import catalog, factorial_key, word_of

DEVICE_FILE = "device.json"
"""Where an allocation records its machine (:func:`device_record`), in its output folder and inside its pack."""

#: Map settings every merged allocation must share: they decide the corpus, the runs' training and what is measured.
AGREE = ("preset", "train_preset", "train_steps", "train_batch_size", "num_episodes", "data_seed", "split_fractions",
         "environment", "contact_damping", "sigreg_weight", "sigreg_pool", "sigreg_reference_rows", "gnll_variance",
         "measure_max_windows", "measure_kinds")
MAX_PACK_BYTES = 64 << 20
"""Largest pack read (a device machine returns files of at most 16 MiB)."""
PACK_BOUNDS = TarBounds(members=4096, member_bytes=64 << 20, total_bytes=128 << 20)
"""What a map pack may unpack to (an allocation's records are a few dozen files, a few MiB): checked on its
headers before anything is read or written (:mod:`pokeworld.bounded_tar`)."""
RUN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,199}")
"""A run's name as a record may give it (a folder under runs/)."""


def device_record() -> dict:
    """Where this process runs: the GPU as nvidia-smi names it (torch's name without nvidia-smi; the processor
    without a GPU), the driver, torch and CUDA versions, the UTC date and time, the git commit and the CPU count."""
    import torch

    name, driver = gpu_name()
    return {"device": name, "driver": driver, "torch": torch.__version__, "cuda": torch.version.cuda,
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "git": commit(),
            "cpu_count": os.cpu_count(), "python": platform.python_version(), "pokeworld": __version__}


def commit() -> str:
    """The commit an allocation runs: ALLOC_COMMIT as the script was given it (a device machine's copy of the
    repository has no .git), else this checkout's."""
    return os.environ.get("ALLOC_COMMIT") or git_commit()


def gpu_name() -> tuple[str, str | None]:
    """(name, driver version) of the first GPU; ("cpu (<processor>)", None) on a machine without one."""
    smi = shutil.which("nvidia-smi")
    if smi:
        try:
            lines = subprocess.run([smi, "--query-gpu=name,driver_version", "--format=csv,noheader"],
                                   capture_output=True, text=True, timeout=30).stdout.strip().splitlines()
        except (OSError, subprocess.SubprocessError):
            lines = []
        if lines:
            name, _, driver = lines[0].partition(",")
            return name.strip(), driver.strip() or None
    import torch

    if torch.cuda.is_available():
        return torch.cuda.get_device_name(), None
    return f"cpu ({platform.processor() or platform.machine()})", None


def write_device(path: str | os.PathLike) -> dict:
    """Write :func:`device_record` to ``path`` (parents created); returns it."""
    rec = device_record()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    write_json(path, rec)
    return rec


# ---------------------------------------------------------------------- one allocation


@dataclass
class Allocation:
    """One allocation's records, unpacked."""

    source: str
    """The path it was read from, as given."""
    root: Path
    """Its map folder (map_config.json, progress.json, data/*/manifest.json, runs/*)."""
    device: dict
    map_config: dict
    corpus_sha256: str
    progress: dict
    weights: dict[str, str] = field(default_factory=dict)
    """Finished run -> 'returned' (its final weights restored as runs/NAME/final.pt), else why not."""
    checkpoints: dict[str, int] = field(default_factory=dict)
    """Unfinished run -> the step of its returned checkpoint (restored as runs/NAME/ckpt.pt)."""
    configuration: str = ""
    """The configuration key of its corpus (:func:`.plan.configuration_key` of the manifest's config)."""


def read_json(path: Path, what: str) -> dict:
    """A JSON object from a regular file (:func:`pokeworld.io.read_json`); one ConfigError line otherwise."""
    return io_read_json(path, what, dict, error=ConfigError)  # io's bound: parsing costs ~25x a file's size


def unpack(pack: Path, scratch: Path) -> Path:
    """A map pack unpacked into a new folder under ``scratch``: its headers checked first against
    :data:`PACK_BOUNDS` (sizes, entry count, types; nothing read beyond them), then regular files and folders only,
    nothing outside the folder, no name twice (:func:`pokeworld.bounded_tar.extract`)."""
    try:
        check_regular_file(pack, "a map pack", MAX_PACK_BYTES)
    except PokeworldError as e:
        raise ConfigError(str(e)) from None
    dest = Path(tempfile.mkdtemp(prefix="allocation-", dir=scratch))
    extract(pack, dest, PACK_BOUNDS, what="a map pack")
    return dest


def open_allocation(path: str | os.PathLike, scratch: Path, weights: Path | None = None) -> Allocation:
    """The allocation at ``path``: a folder as a device machine returns it (device.json beside the records pack and
    the parts of the weights, or beside one map pack), a pack (.tar.gz), or a map folder; packs are unpacked under
    ``scratch``, and returned weights and checkpoints restored there (:func:`restore_returned`) from ``weights``
    when given (the parts of a lease joined from its returns, :func:`open_lease`), else from ``path``."""
    path = Path(path)
    outer_device, returned = None, None
    if path.is_dir() and not (path / "map_config.json").exists():
        packs = [path / RECORDS] if (path / RECORDS).exists() else sorted(
            p for p in path.iterdir() if p.name.endswith((".tar.gz", ".tgz")))
        if len(packs) != 1:
            raise ConfigError(f"{path}: an allocation folder holds one map pack (*.tar.gz); found {len(packs)}")
        root, outer_device, returned = unpack(packs[0], scratch), path / DEVICE_FILE, path
    elif path.is_dir():
        root = path
    elif path.name.endswith((".tar.gz", ".tgz")):
        root = unpack(path, scratch)
    else:
        raise ConfigError(f"{path} is neither an allocation folder, a map pack (.tar.gz) nor a map folder")
    device_path = root / DEVICE_FILE
    if not device_path.exists() and outer_device is not None:
        device_path = outer_device
    if not device_path.exists():
        raise ConfigError(f"{path} has no {DEVICE_FILE}: which device trained its runs is unknown "
                          "(scripts/gpu_allocation.sh writes it)")
    manifest = read_json(root / "data" / "standard" / "manifest.json", "a corpus manifest")
    if not isinstance(manifest.get("content_sha256"), str):
        raise ConfigError(f"{path}: its corpus manifest records no content hash")
    a = Allocation(str(path), root, read_json(device_path, "a device record"),
                   read_json(root / "map_config.json", "a map config"), manifest["content_sha256"],
                   check_progress(read_json(root / "progress.json", "a map's progress record"),
                                  root / "progress.json"),
                   configuration=configuration_key(manifest.get("config") if isinstance(manifest.get("config"), dict)
                                                   else {}))
    if returned is not None:
        restore_returned(a, weights or returned, scratch)
    return a


MAX_LEASE_PARTS = 64
"""Most parts of a lease's weights tar an index may name (a 15-minute lease returns at most a dozen)."""
SHA256 = re.compile(r"[0-9a-f]{64}")


def lease_groups(paths: list[Path]) -> list[list[Path]]:
    """``paths`` grouped by allocation: return folders of one allocation (several commands of one lease) hold the
    same device.json, written once when the allocation started; each group in the order the allocation wrote them
    (its allocation.log only grows), every other path a group of its own, in the order given."""
    groups: dict[object, list[Path]] = {}
    for p in paths:
        key: object = p
        if p.is_dir() and (p / RECORDS).is_file() and (p / DEVICE_FILE).is_file():
            try:
                key = ("device", read_regular_bytes(p / DEVICE_FILE, "an allocation's device.json", 1 << 20))
            except PokeworldError as e:
                raise ConfigError(str(e)) from None
        groups.setdefault(key, []).append(p)

    def log_size(p: Path) -> int:
        log = p / "allocation.log"
        return log.stat().st_size if log.is_file() and not log.is_symlink() else 0

    return [sorted(g, key=log_size) for g in groups.values()]


def join_lease_parts(folders: list[Path], index: dict, dest: Path) -> int:
    """Into the new folder ``dest``, the parts of the weights tar the latest index names (``part_sha256``), each
    taken from whichever of ``folders`` holds it with those bytes (a lease's commands each return the parts no
    earlier one returned); returns how many were found, in order (the tar is read up to the first missing one)."""
    shas = index.get("part_sha256", [])
    if not isinstance(shas, list) or len(shas) > MAX_LEASE_PARTS or not all(
            isinstance(x, str) and SHA256.fullmatch(x) for x in shas):
        raise ConfigError(f"{folders[-1]}: its index's part_sha256 is not a list of at most {MAX_LEASE_PARTS} "
                          "sha256 digests; the record is damaged or was edited")
    dest.mkdir()
    for i, sha in enumerate(shas):
        for folder in reversed(folders):
            part = part_path(folder, i)
            if not part.is_file() or part.is_symlink():
                continue
            try:
                data = read_regular_bytes(part, "a part of an allocation's pack", ReturnLimits().file_bytes)
            except PokeworldError as e:
                raise ConfigError(str(e)) from None
            if hashlib.sha256(data).hexdigest() == sha:
                save_bytes(part_path(dest, i), data)
                break
        else:
            return i
    return len(shas)


def open_lease(folders: list[Path], scratch: Path) -> Allocation:
    """One allocation from the folders its lease's commands returned (:func:`lease_groups` order): the records of
    the latest, the weights of all (:func:`join_lease_parts`)."""
    if len(folders) == 1:
        return open_allocation(folders[0], scratch)
    latest = open_allocation(folders[-1], scratch, weights=Path(tempfile.mkdtemp(prefix="none-", dir=scratch)))
    index = read_json(latest.root / INDEX, "an allocation's index of returned weights")
    joined = Path(tempfile.mkdtemp(prefix="lease-", dir=scratch)) / "parts"
    found = join_lease_parts(folders, index, joined)
    a = open_allocation(folders[-1], scratch, weights=joined)
    a.source = " + ".join(str(f) for f in folders)
    if found < len(index.get("part_sha256", [])):
        print(f"[allocations] {a.source}: {found} of {len(index['part_sha256'])} parts of the weights came back; "
              "the runs in the rest are named 'not returned'")
    return a


LEASE_INDEX = "lease.json"
"""A landed lease's index of the model folders that hold its runs' weights (:mod:`.land`)."""
MODELS = Path("models")
"""Where a landed lease's model folders are looked for by default: the repository's models/."""


def open_landed(folder: Path, scratch: Path, models: Path = MODELS) -> Allocation:
    """A lease landed in the repository (:mod:`.land`): its records, the parts it kept, and each run's
    final weights from the model folder its :data:`LEASE_INDEX` names under ``models`` (the weights file checked
    against the digest landed, read weights-only, its tensors against the model its kwargs declare), restored as
    runs/NAME/final.pt in float32 beside the run's records."""
    index = read_json(folder / LEASE_INDEX, "a landed lease's index")
    a = open_allocation(folder, scratch)
    rows = index.get("runs")
    if not isinstance(rows, dict):
        raise ConfigError(f"{folder / LEASE_INDEX}: 'runs' is not a table of runs; the record is damaged")
    for name, row in rows.items():
        where = f"{folder / LEASE_INDEX}: run {str(name)[:60]!r}"
        if not (isinstance(name, str) and RUN_NAME.fullmatch(name) and name in a.progress.get("finished", [])
                and isinstance(row, dict) and isinstance(row.get("model"), str) and RUN_NAME.fullmatch(row["model"])
                and isinstance(row.get("model_sha256"), str) and SHA256.fullmatch(row["model_sha256"])):
            raise ConfigError(f"{where} is not a finished run with a model folder and its digest; the record is "
                              "damaged or was edited")
        restore_model(a, name, models / row["model"], row["model_sha256"])
    return a


def restore_model(a: Allocation, name: str, folder: Path, sha256: str) -> None:
    """Run ``name`` of ``a``'s final weights from the released model ``folder`` (see :func:`open_landed`)."""
    import torch

    try:
        cfg = folder_config(folder)
        if cfg is None:
            raise ConfigError(f"{folder} is not an exported model folder (pokeworld export)")
        state = {k: v.float() if v.dtype == torch.bfloat16 else v for k, v in read_weights(folder, sha256).items()}
        run = a.root / "runs" / name
        ck = {"model": state, "model_kwargs": cfg["model_kwargs"], "step": cfg["step"],
              "config": read_json(run / "config.json", "a run config")}
        model_from_checkpoint(ck, folder / "model.safetensors")
    except PokeworldError as e:
        raise ConfigError(f"the released model of {name}: {e}") from None
    checkpoint.save(ck, run / "final.pt")
    a.weights[name] = "returned"


def open_allocations(paths: list[Path], scratch: Path, models: Path = MODELS) -> list[Allocation]:
    """Every allocation among ``paths``: a lease's return folders joined into one (:func:`open_lease`), a landed
    lease read with its model folders under ``models`` (:func:`open_landed`)."""
    return [open_landed(g[0], scratch, models) if len(g) == 1 and (g[0] / LEASE_INDEX).is_file()
            else open_lease(g, scratch) for g in lease_groups(list(paths))]


def check_progress(prog: dict, path: Path) -> dict:
    """``prog`` when its fields are what the map writes: ``finished`` and ``pending`` lists of run names,
    ``partial`` a mapping of run name to a step (an integer ≥ 0), ``elapsed_min`` a finite number or absent;
    ConfigError naming ``path`` and the field otherwise."""
    def names(value: object, field: str) -> None:
        if not isinstance(value, list) or not all(isinstance(n, str) and RUN_NAME.fullmatch(n) for n in value):
            raise ConfigError(f"{path}: {field!r} is not a list of run names ({str(value)[:60]}); the record is "
                              "damaged or was edited")

    names(prog.get("finished", []), "finished")
    names(prog.get("pending", []), "pending")
    partial = prog.get("partial", {})
    if not isinstance(partial, dict):
        raise ConfigError(f"{path}: 'partial' is not a mapping of run names to steps; the record is damaged")
    names(list(partial), "partial")
    for name, step in partial.items():
        check_step(step, f"{path}: the step of partial run {name}")
    elapsed = prog.get("elapsed_min")
    if elapsed is not None and (isinstance(elapsed, bool) or not isinstance(elapsed, (int, float))
                                or not math.isfinite(elapsed)):
        raise ConfigError(f"{path}: 'elapsed_min' is {str(elapsed)[:40]!r}, not a number; the record is damaged")
    return prog


def check_step(step: object, where: str) -> int:
    """``step`` when it is an integer ≥ 0 (not a string, float or bool); ConfigError naming ``where`` otherwise."""
    if isinstance(step, bool) or not isinstance(step, int) or step < 0:
        raise ConfigError(f"{where} is {str(step)[:40]!r}, not an integer step ≥ 0; the record is damaged or was "
                          "edited")
    return step


def restore_returned(a: Allocation, folder: Path, scratch: Path) -> None:
    """The weights and checkpoints in ``folder``'s parts (:func:`.pack.read_stream`: each member's bytes
    checked against the sha256 its name carries), each loaded weights-only, checked against the model its kwargs
    declare and restored in float32 into ``a``'s run folders (final.pt, ckpt.pt); ``a.weights`` then says for each
    finished run whether its weights came back, ``a.checkpoints`` which unfinished runs can resume. A member that
    matches its checksum but does not load is refused (ConfigError): the device wrote something else than it says."""
    index = read_json(a.root / INDEX, "an allocation's index of returned weights") if (a.root / INDEX).exists() else {}
    finished = set(a.progress.get("finished", []))
    for m in read_stream(folder):
        run = a.root / "runs" / m.run
        if (m.kind == "final") != (m.run in finished) or (m.kind == "final" and not (run / "config.json").exists()):
            continue  # records of another state of the map than the parts (a kill between the two writes)
        ck = load_member(m, scratch)
        what = Path(f"{folder}: the returned {m.kind} of {m.run}")
        try:
            model = model_from_checkpoint(ck, what)
            if m.kind == "ckpt":  # resumed by the next allocation: its optimizer is checked like its model
                check_optimizer_fits(model, ck.get("optimizer"), what)
        except PokeworldError as e:
            raise ConfigError(str(e)) from None
        step = check_step(ck.get("step", 0), f"{what}: its step")
        if not (run / "config.json").exists():
            # the parts are written before the records: a kill between the two returns a checkpoint whose run the
            # records do not list yet, and the checkpoint carries the run's config itself
            if not isinstance(ck.get("config"), dict):
                continue
            run.mkdir(parents=True, exist_ok=True)
            write_json(run / "config.json", ck["config"])
        checkpoint.save(ck, run / f"{m.kind}.pt")
        if m.kind == "final":
            a.weights[m.run] = "returned"
        else:
            a.checkpoints[m.run] = step
    for name in sorted(finished - set(a.weights)):
        a.weights[name] = index.get("left_out", {}).get(name, "not returned")


def training_facts(a: Allocation, name: str) -> dict:
    """Where and how run ``name`` of ``a`` was trained: device, date, torch, the steps it was configured for and
    reached, the median s/step over its logged rows (the first row holds any compilation), its compile setting,
    whether its weights came back and, for a run resumed from an earlier allocation's checkpoint, from where."""
    run = a.root / "runs" / name
    cfg = read_json(run / "config.json", "a run config")
    rows = []
    metrics = run / "metrics.jsonl"
    if metrics.exists():
        try:
            rows = read_jsonl(metrics, "a metrics log")
        except PokeworldError as e:
            raise ConfigError(f"{metrics} is not a metrics log pokeworld wrote ({e})") from None
    for i, r in enumerate(rows):
        check_step(r.get("step", 0), f"{metrics} line {i + 1}: 'step'")
    rates = [r["steps_per_s"] for r in rows if isinstance(r.get("steps_per_s"), (int, float))
             and not isinstance(r["steps_per_s"], bool) and math.isfinite(r["steps_per_s"]) and r["steps_per_s"] > 0]
    return {"source": a.source, "device": a.device.get("device"), "date": a.device.get("date"),
            "torch": a.device.get("torch"), "steps": cfg.get("steps"),
            "steps_trained": max((r.get("step", 0) for r in rows), default=0),
            "sec_per_step": statistics.median(1 / r for r in rates) if rates else None,
            "compile": cfg.get("compile"), "compile_mode": cfg.get("compile_mode"),
            "weights": a.weights.get(name, "not returned"),
            **({"resumed": read_json(run / "resumed.json", "a resumed run's record")}
               if (run / "resumed.json").exists() else {})}


def allocation_record(a: Allocation, certificates: dict) -> dict:
    """The finished runs of ``a`` as a map record (:func:`pokeworld.experiments.report.collect`), each naming where
    it was trained."""
    c = from_dict(MapConfig, {**recorded_map_config(a.map_config), "out": str(a.root)})
    finished = set(a.progress.get("finished", []))
    specs = [s for s in stages.all_specs(c) if s.name in finished]
    for s in specs:
        if not spec_measure_path(c, s).exists():
            raise ConfigError(f"{a.source}: run {s.name} is listed as finished but its measurement is missing")
    rec = report.collect(c, specs, certificates)
    # the experiments' finished runs only; planning's runs are the factorial's, its table reads rec["planning"]
    rec["experiments"] = {e: [n for n in names if n in rec["runs"]] for e, names in rec["experiments"].items()
                          if e != "planning"}
    rec["experiments"] = {e: names for e, names in rec["experiments"].items() if names}
    rec["map_config"] = dict(a.map_config)
    for name, run in rec["runs"].items():
        run["allocation"] = training_facts(a, name)
    rec["provenance"].update(command=f"allocation {a.source} ({a.device.get('device')}, {a.device.get('date')})",
                             git=a.device.get("git", "?"))
    results = a.root / "results.json"
    if results.exists():
        planning = read_json(results, "a results record").get("planning")
        if isinstance(planning, dict):
            rec["planning"] = planning
    return rec


# ---------------------------------------------------------------------- the merge


def model_form(a: Allocation) -> dict:
    """The objective-and-model fields (those of ``train.config.REFERENCE_MODEL``) the allocation's runs trained with,
    from its first run config (one preset per allocation; a field a config predates reads its default, the value it
    had then); {} when no run config came back."""
    from ..train.config import REFERENCE_MODEL, field_defaults

    for path in sorted((a.root / "runs").glob("*/config.json")):
        cfg, defaults = read_json(path, "a run config"), field_defaults()
        return {k: json_value(cfg.get(k, defaults[k])) for k in REFERENCE_MODEL}
    return {}


def json_value(v):
    """A config value as config.json holds it (tuples as lists)."""
    return [json_value(x) for x in v] if isinstance(v, (list, tuple)) else v


def check_model_form(allocs: list[Allocation]) -> None:
    """ConfigError (one line) unless the allocations' runs trained the objective and model the map's training preset
    trains now (:func:`model_form`): a plan built on runs of another model would skip runs the preset has not
    trained."""
    from ..train.config import PRESETS as TRAIN_PRESETS, REFERENCE_MODEL, field_defaults

    mc = allocs[0].map_config
    preset = mc.get("train_preset") or mc.get("preset")
    if preset not in TRAIN_PRESETS:  # a record that names no training preset has nothing to compare with
        return
    now = {k: json_value({**field_defaults(), **TRAIN_PRESETS[preset]}[k]) for k in REFERENCE_MODEL}
    for a in allocs:
        form = model_form(a)
        diff = {k: (v, now[k]) for k, v in form.items() if v != now[k]}
        if diff:
            raise ConfigError(f"{a.source} trained another objective or model than the {preset!r} preset trains now "
                              f"(then, now): {diff}; start the next allocation afresh (no ALLOC_RESUME), docs/model.md "
                              "\"GPU allocations\"")


def check_agreement(allocs: list[Allocation]) -> None:
    """ConfigError (one line) unless every allocation trained on the first one's corpus with its map settings and
    its objective and model."""
    first = allocs[0]
    for a in allocs[1:]:
        forms = model_form(first), model_form(a)
        if all(forms) and forms[0] != forms[1]:
            diff = {k: (forms[0][k], forms[1][k]) for k in forms[0] if forms[0][k] != forms[1][k]}
            raise ConfigError(f"{a.source} trained another objective or model than {first.source} (first, this): "
                              f"{diff}; allocations merge only when their runs are the same model")
        if a.corpus_sha256 != first.corpus_sha256:
            raise ConfigError(f"{a.source} trained on corpus {a.corpus_sha256[:12]}, {first.source} on "
                              f"{first.corpus_sha256[:12]}: allocations merge only when they share the seeded corpus")
        diff = {k: (first.map_config.get(k), a.map_config.get(k)) for k in AGREE
                if first.map_config.get(k) != a.map_config.get(k)}
        if diff:
            raise ConfigError(f"{a.source} ran the map with other settings than {first.source} (first, this): {diff}")


def read_certificates(path: Path, corpus_sha256: str) -> dict:
    """A certify JSON (``pokeworld certify``'s certificates.json) of the allocations' corpus; ConfigError when it
    certifies another corpus or is not one."""
    cert = read_json(path, "a certify JSON")
    if not (isinstance(cert.get("estimators"), dict) and isinstance(cert.get("certificate"), dict)):
        raise ConfigError(f"{path} is not a certify JSON (no 'estimators' and 'certificate' objects)")
    sha = (cert.get("dataset") or {}).get("content_sha256")
    if sha != corpus_sha256:
        raise ConfigError(f"{path} certifies corpus {str(sha)[:12]}, the allocations trained on {corpus_sha256[:12]}: "
                          "certificates must come from the same seeded corpus")
    return cert


def ridge_difference(old: dict, new: dict) -> float | str:
    """The largest ridge difference of a run trained twice, in JSON (no infinity: a lost number is said in words)."""
    d = merge.max_difference(old, new)
    return d if math.isfinite(d) else "a number of the earlier run is missing or NaN in the later"


def merge_allocations(allocs: list[Allocation], certificates: dict | None = None, tol: float = 1e-4,
                      command: str = "") -> dict:
    """One record from ``allocs`` (later allocations win a run trained twice; see the module docstring)."""
    if not allocs:
        raise ConfigError("no allocation to merge")
    check_agreement(allocs)
    order = sorted(allocs, key=lambda a: str(a.device.get("date", "")))  # stable: equal dates keep the given order
    certs = {"standard": certificates} if certificates else {}
    merged, duplicates, planning = None, [], None
    for a in order:
        rec = allocation_record(a, certs)
        planning = rec.pop("planning", planning)
        if merged is None:
            merged = rec
            continue
        for name, run in rec["runs"].items():
            if name in merged["runs"]:
                old = merged["runs"][name]
                duplicates.append({"run": name, "kept": a.source, "dropped": old["allocation"]["source"],
                                   "largest_ridge_difference": ridge_difference(old, run)})
        if rec["experiments"]:
            merged, _ = merge.merge(merged, rec, list(rec["experiments"]), tol, replace_differing=True)
    if planning is not None:
        merged["planning"] = planning
    names = {r["train"]["variant"] for r in merged["runs"].values()}
    merged["map_config"]["variants"] = [v for v in VARIANT_ORDER if v in names] + sorted(names - set(VARIANT_ORDER))
    merged["map_config"]["seeds"] = sorted({r["train"]["seed"] for r in merged["runs"].values()})
    merged["provenance"] = {**merged["provenance"], "command": command or "merge_allocations", "git": git_commit(),
                            "pokeworld": __version__, "python": platform.python_version(),
                            "corpus_sha256": allocs[0].corpus_sha256, "duplicates": duplicates,
                            "allocations": [allocation_summary(a) for a in order]}
    return merged


def allocation_summary(a: Allocation) -> dict:
    """What the record says of one allocation: its device and what it finished or left unfinished."""
    return {"source": a.source, **{k: a.device.get(k) for k in ("device", "driver", "date", "torch", "cuda", "git")},
            "finished": list(a.progress.get("finished", [])), "partial": dict(a.progress.get("partial", {})),
            "pending": list(a.progress.get("pending", [])), "elapsed_min": a.progress.get("elapsed_min"),
            "weights_missing": {n: w for n, w in a.weights.items() if w != "returned"},
            "checkpoints": dict(a.checkpoints)}


# ---------------------------------------------------------------------- the report


def allocation_lines(merged: dict) -> list[str]:
    """Every allocation: device, date, torch, what it finished and what its budget cut short."""
    lines = ["## Allocations", "", "| allocation | device | date (UTC) | torch | finished | not finished |",
             "|---|---|---|---|---|---|"]
    for a in merged["provenance"]["allocations"]:
        cut = [f"{n} (step {s})" for n, s in a["partial"].items()] + [f"{n} (not started)" for n in a["pending"]]
        lines.append(f"| {a['source']} | {a['device']} | {a['date']} | {a['torch']} | "
                     f"{', '.join(a['finished']) or '—'} | {', '.join(cut) or '—'} |")
    for a in merged["provenance"]["allocations"]:
        for name, why in a.get("weights_missing", {}).items():
            lines.append(f"\nThe final weights of `{name}` did not come back from {a['source']}: {why}.")
    carried = merged["provenance"].get("carried")
    if isinstance(carried, dict) and carried.get("runs"):
        lines.append(f"\nCarried from the earlier record of this corpus (their allocations' folders were not given to "
                     f"this merge; each record as it was): {', '.join(carried['runs'])}.")
    for d in merged["provenance"].get("duplicates", []):
        diff = d["largest_ridge_difference"]
        lines.append(f"\n`{d['run']}` was trained in two allocations: the later ({d['kept']}) is kept; the largest "
                     f"ridge difference to the earlier ({d['dropped']}) is "
                     + (f"{diff:.4f}." if isinstance(diff, float) else f"unknown: {diff}."))
    return lines + [""]


def run_lines(merged: dict) -> list[str]:
    """Every run with its device and date, our numbers beside the paper's (ridge R², contact windows)."""
    lines = ["## Runs (ridge R², contact windows; paper values beside ours)", "",
             "| run | device | date (UTC) | steps | s/step | log k (ours / paper) | log m (ours / paper) | γ | "
             "obj. position | direct-16 |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name, r in sorted(merged["runs"].items()):
        al, pv = r.get("allocation", {}), FACTORIAL.get(r["train"]["variant"], {})
        s = al.get("sec_per_step")
        lines.append(f"| {name} | {al.get('device', '—')} | {al.get('date', '—')} | {al.get('steps_trained', '—')} | "
                     f"{'—' if s is None else f'{s:.4f}'} | {fmt(probe(r, 'log_k'))} / {fmt(pv.get('log_k'))} | "
                     f"{fmt(probe(r, 'log_m'))} / {fmt(pv.get('log_m'))} | {fmt(probe(r, 'gamma'))} | "
                     f"{fmt(probe(r, 'object_pos'))} | {fmt(r['prediction'].get('direct16'), 3)} |")
    # the paper gives its decoded 16-step error once (§4.2), not per variant
    return lines + ["", f"Paper values: log k and log m from Table \"targets\" (mean of two seeds, 20k steps); "
                        f"direct-16 {P.PREDICTION['direct16']} arena units (§4.2, one number, not per variant).", ""]


def smaller_than_paper(certs: dict) -> str:
    """Words for certificates fit with less than the paper preset's budget (empty when they were not)."""
    paper = certify.PRESETS["paper"]
    used = certs.get("settings", {})
    less = {k: (used.get(k), v) for k, v in paper.items() if k in used and used.get(k) != v}
    return ("" if not less else " — less than the paper preset's " + ", ".join(f"{k} {v}" for k, (_, v) in
                                                                              less.items())
            + " (0 fit episodes: the corpus's own probe-fit split)")


def corpus_lines(merged: dict, level: str = "#") -> list[str]:
    """One corpus's record: its allocations, the per-run table and, where computed, the CPU side's numbers."""
    cpu = merged["provenance"].get("cpu_side")
    certs = merged["certificates"].get("standard", {})
    head = [f"{level} Corpus {merged['provenance']['corpus_sha256'][:12]}", "",
            "Content hash of the seeded corpus every allocation below trained on (a record of one environment: a "
            "corpus of another environment gets its own section). Paper values are the paper's own numbers, shown "
            "beside ours; they are never used as ours. Certificates: "
            + (f"computed on {certs.get('device')}, {str(certs.get('date'))[:10]}, settings "
               f"`{json.dumps(certs.get('settings', {}), sort_keys=True)}`{smaller_than_paper(certs)}."
               if certs.get("device") else
               "from a CPU-side certify JSON." if certs else "none given.")
            + (f" CPU side ({cpu['device']}): MLP probes and the untrained bound of "
               f"{', '.join(cpu['measured']) or 'no run yet'}; "
               f"certificates {'computed' if cpu['certificates'] else 'not yet'}; "
               f"planning {'computed' if cpu['planning'] else 'not yet'}." if cpu else ""), ""]
    return head + allocation_lines(merged) + run_lines(merged) + (record_lines(merged) if cpu else [])


def markdown(merged: dict) -> str:
    """The merged record's report: allocations and runs with their devices, then the map's own report, then the
    records of other corpora kept in the same file (:func:`carry_other_corpora`)."""
    body = report.markdown(merged).split("\n", 1)[1]  # its sections, under this report's title
    lines = ["# Identifiability map at the paper's budget, from GPU allocations", ""] + corpus_lines(merged, "##")
    text = "\n".join(lines) + body
    for rec in merged.get("other_corpora", {}).values():
        text += "\n" + "\n".join(corpus_lines(rec, "##"))
    return text


def carry_other_corpora(merged: dict, previous: dict | None) -> dict:
    """``merged`` with the records of other corpora that ``previous`` (the file at --out) held, by corpus hash, so
    a merge of another environment's allocations adds its own record instead of replacing the earlier one's."""
    if not isinstance(previous, dict) or not isinstance(previous.get("provenance"), dict):
        return merged
    sha = merged["provenance"]["corpus_sha256"]
    others = {k: v for k, v in (previous.get("other_corpora") or {}).items() if k != sha and isinstance(v, dict)}
    prev_sha = previous["provenance"].get("corpus_sha256")
    if isinstance(prev_sha, str) and prev_sha != sha:
        others[prev_sha] = {k: v for k, v in previous.items() if k != "other_corpora"}
    if others:
        merged["other_corpora"] = others
    return merged


def carried_from(prev: dict, runs: list[str]) -> dict:
    """Which merge measured the carried ``runs``: the earlier record's own ``carried`` when it carried them too
    (a record re-merged keeps the command that first measured its runs), else the earlier record's command."""
    before = prev.get("carried")
    if isinstance(before, dict) and set(runs) <= set(before.get("runs") or []):
        return {**before, "runs": runs}
    return {"runs": runs, "command": prev.get("command", "?"), "git": prev.get("git", "?")}


def carry_earlier_runs(merged: dict, previous: dict | None) -> dict:
    """``merged`` with the runs of the same corpus that ``previous`` (the file at --out) holds and this merge does
    not: an earlier lease's runs, whose folders are not given again, keep their records (each unchanged, its
    ``allocation`` naming where it was trained), as do their allocations in the provenance, the certificates when
    this merge has none, and the planning rows of variants this merge did not plan. ``provenance.carried`` names
    what was carried, so a record never presents a carried run as measured by this merge."""
    if not isinstance(previous, dict) or not isinstance(previous.get("provenance"), dict) \
            or previous["provenance"].get("corpus_sha256") != merged["provenance"]["corpus_sha256"]:
        return merged
    runs = {n: r for n, r in (previous.get("runs") or {}).items() if n not in merged["runs"] and isinstance(r, dict)}
    if not runs:
        return merged
    out = {**merged, "runs": {**merged["runs"], **runs},
           "experiments": {k: list(v) for k, v in merged["experiments"].items()}}
    for exp, names in (previous.get("experiments") or {}).items():
        if isinstance(names, list):
            out["experiments"].setdefault(exp, []).extend(n for n in names if n in runs)
    if not out.get("certificates") and previous.get("certificates"):
        out["certificates"] = previous["certificates"]
    planned = previous.get("planning")
    if isinstance(planned, dict) and isinstance(planned.get("summary"), dict):
        if not isinstance(out.get("planning"), dict):
            out["planning"] = planned
        else:
            summary = dict(out["planning"].get("summary", {}))
            extra = {v: row for v, row in planned["summary"].items() if v not in summary}
            out["planning"] = {**out["planning"], "summary": {**summary, **extra},
                               "carried_variants": sorted(extra)}
    names = {r["train"]["variant"] for r in out["runs"].values()}
    out["map_config"] = {**out["map_config"],
                         "variants": [v for v in VARIANT_ORDER if v in names] + sorted(names - set(VARIANT_ORDER)),
                         "seeds": sorted({r["train"]["seed"] for r in out["runs"].values()})}
    prev = previous["provenance"]
    # an earlier allocation named by a path of the machine that merged it: its folder name alone (records name no
    # machine's paths), marked as not given to this merge
    now = {(a.get("device"), a.get("date")) for a in merged["provenance"].get("allocations", [])}
    suffix = " (not given to this merge)"
    earlier = [{**a, "source": (str(a.get("source", "?")) if str(a.get("source", "")).endswith(suffix)
                                else f"{Path(str(a.get('source', '?'))).name}{suffix}")}
               for a in prev.get("allocations", [])
               if isinstance(a, dict) and (a.get("device"), a.get("date")) not in now]  # this merge's own: not twice
    out["provenance"] = {**merged["provenance"],
                         "allocations": earlier + list(merged["provenance"].get("allocations", [])),
                         "carried": carried_from(prev, sorted(runs))}
    return out


# ---------------------------------------------------------------------- the next allocation


def run_key(a: Allocation, name: str, other_names: set[str]) -> str:
    """The queue token of run ``name`` of ``a`` (:func:`.queue.word_of`: its name for a run of another
    experiment than the factorial, else ``VARIANT@SEED``), from its config.json: a known variant and an integer seed,
    else one ConfigError line naming the file (the words go into a printed command)."""
    path = a.root / "runs" / name / "config.json"
    cfg = read_json(path, "a run config")
    return word_of(name, cfg.get("variant"), cfg.get("seed", 0), other_names, str(path))


def returned_of(a: Allocation) -> Returned:
    """What ``a`` returned, as the plan needs it: every run's words checked (:func:`run_key`)."""
    seeds = {0, 1, 2}  # the paper queue's seeds: another experiment's run at another seed is named by its config
    preset = str(a.map_config.get("preset", "paper"))
    names = {s.name for t, s in catalog(preset if preset in ("tiny", "cpu", "paper") else "paper",
                                        tuple(seeds)).items() if not factorial_key(t)}
    return Returned(a.source, a.configuration, a.corpus_sha256, str(a.device.get("git", "?")),
                    {run_key(a, n, names) for n in a.progress.get("finished", [])},
                    {run_key(a, n, names): step for n, step in a.checkpoints.items()})


def plan(allocs: list[Allocation], configuration: str | None = None) -> dict:
    """The next lease for ``configuration`` (default: this checkout's at the preset the allocations ran,
    :func:`.plan.checkout_configuration`) from what ``allocs`` returned (:func:`.plan.plan`).
    Every returned run's words are checked first; ConfigError when the allocations of this configuration disagree
    (:func:`check_agreement`) or trained another objective or model than the preset trains now (:func:`check_model_form`: the configuration key names
    the environment, not the model, and a plan built on another model's runs would skip runs never trained)."""
    returned = [returned_of(a) for a in allocs]
    if configuration is None:
        presets = {str(a.map_config.get("preset", "paper")) for a in allocs}
        configuration = lease_plan.checkout_configuration(presets.pop() if len(presets) == 1 else "paper")
    same = [a for a in allocs if a.configuration == configuration]
    if same:
        check_agreement(same)
        check_model_form(same)
    return lease_plan.plan(returned, configuration)


EXPORTED = ("config.json", "metrics.jsonl", "final.pt", "measure.json")
"""A returned run's files written under --runs-out (beside a DONE that says where the weights came from)."""


def export_plan(allocs: list[Allocation], merged: dict, dest: Path) -> dict[str, tuple[Allocation, list[str]]]:
    """Run name -> (the allocation it is kept from, the files of :data:`EXPORTED` it has) for every run of
    ``merged`` whose weights came back, as :func:`export_runs` writes them under ``dest``."""
    by_source = {a.source: a for a in allocs}
    plan_: dict[str, tuple[Allocation, list[str]]] = {}
    for name, run in sorted(merged["runs"].items()):
        a = by_source.get(run.get("allocation", {}).get("source"))
        if a is not None and a.weights.get(name) == "returned":
            plan_[name] = (a, [f for f in EXPORTED if (a.root / "runs" / name / f).exists()])
    return plan_


def export_targets(plan_: dict[str, tuple[Allocation, list[str]]], dest: Path) -> list[Path]:
    """Every file :func:`export_runs` would write under ``dest``."""
    return [dest / name / f for name, (_, files) in plan_.items() for f in (*files, "DONE")]


def export_runs(allocs: list[Allocation], merged: dict, dest: Path) -> list[str]:
    """Every run of ``merged`` whose weights came back from the allocation it was kept from, as a run folder under
    ``dest`` (config.json, metrics.jsonl, the device's measure.json, final.pt in float32 and DONE), so that the CPU
    side can probe it (``pokeworld probe --run-dir DEST/NAME --data CORPUS``, on the same seeded corpus);
    returns their names. Every file is checked (:func:`pokeworld.io.check_replaceable`) before the first is
    written, so a user's run folder under ``dest`` is refused whole, never half-replaced."""
    plan_ = export_plan(allocs, merged, dest)
    for path in export_targets(plan_, dest):
        check_replaceable(path)
    for name, (a, files) in plan_.items():
        src, out = a.root / "runs" / name, dest / name
        for f in files:
            save_bytes(out / f, read_regular_bytes(src / f, f"a returned run's {f}", MAX_PACK_BYTES << 2))
        save_text(out / "DONE", f"finished (weights returned from {a.source}: float32 tensors of at least "
                                 f"{COMPACT_MIN_ELEMENTS} elements rounded to bfloat16)\n")
    return list(plan_)


def output_paths(a: argparse.Namespace) -> list[Path]:
    """The files (and the --runs-out folder) the merge writes, as ``a`` asks."""
    outs = [a.out, a.markdown, a.runs_out]
    if not a.no_figure:
        fig = a.figure or a.out.with_suffix(".png")
        outs += [fig.parent / f"{fig.stem}.png", fig.parent / f"{fig.stem}.pdf"]
    return [p for p in outs if p is not None]


# ---------------------------------------------------------------------- the command line


def write_merged(a: argparse.Namespace, allocs: list[Allocation], words: list[str]) -> dict:
    """Merge ``allocs`` and write the record, its report, its figure and the returned runs as ``a`` asks: every
    one of those files checked before the first is written (all or, refused, none)."""
    cert = read_certificates(a.certificates, allocs[0].corpus_sha256) if a.certificates else None
    merged = merge_allocations(allocs, cert, a.tol,
                               command=" ".join(["python scripts/merge_allocations.py", *map(str, words)]))
    if a.cpu_side:
        attach_cpu_side(merged, a.cpu_side)
    previous = read_json(a.out, "an earlier merged record") if a.out.exists() else None
    merged = carry_other_corpora(carry_earlier_runs(merged, previous), previous)
    record = without_machine_paths(merged)  # a record names no machine's paths (the runs' own stay in the packs)
    files = [p for p in output_paths(a) if p != a.runs_out]
    if a.runs_out:
        files += export_targets(export_plan(allocs, merged, a.runs_out), a.runs_out)
    for path in files:
        check_replaceable(path)
    write_json(a.out, record)
    if a.markdown:
        save_text(a.markdown, markdown(record))
    if not a.no_figure:
        fig = a.figure or a.out.with_suffix(".png")
        report.figure(record, fig.parent, stem=fig.stem)
    if a.runs_out:
        names = export_runs(allocs, merged, a.runs_out)
        print(f"[merge_allocations] {len(names)} runs with their weights -> {a.runs_out}")
    return record


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Merge GPU allocations of the paper-budget map into one record, or "
                                             "plan the next allocation (--plan).")
    ap.add_argument("allocations", nargs="+", type=Path,
                    help="allocation folders as returned (device.json beside the records and weights), packs or "
                         "map folders")
    ap.add_argument("--plan", action="store_true", help="print the next allocation's queue and command instead")
    ap.add_argument("--models", type=Path, default=Path("models"),
                    help="where a landed lease's model folders are (default models/, the repository's)")
    ap.add_argument("--commit", default="", help="with --plan: the commit the next allocation runs (default: "
                                                 "ALLOC_COMMIT, else this checkout's)")
    ap.add_argument("--out", type=Path, help="the merged record (results.json format)")
    ap.add_argument("--markdown", type=Path, help="also write its report here")
    ap.add_argument("--certificates", type=Path, help="certify JSON of the same corpus, computed on the CPU side")
    ap.add_argument("--cpu-side", type=Path, help="the work folder of scripts/complete_allocations.py: its MLP "
                                                  "probes, untrained bound, certificates and planning of these runs")
    ap.add_argument("--figure", type=Path, help="the identifiability-map figure (.png, a .pdf beside it); "
                                                "default: --out with .png")
    ap.add_argument("--no-figure", action="store_true", help="write no figure")
    ap.add_argument("--runs-out", type=Path, help="also write each finished run with its returned weights here, as a "
                                                  "run folder the CPU side can probe")
    ap.add_argument("--tol", type=float, default=1e-4, help="ridge difference below which a run trained twice "
                                                            "counts as reproduced")
    a = ap.parse_args(argv)
    if not a.plan and a.out is None:
        ap.error("--out is required (or --plan)")
    try:
        if not a.plan:  # before anything is read: no output may be, or lie inside, an input
            check_apart([*a.allocations, a.certificates, a.cpu_side], output_paths(a))
        with tempfile.TemporaryDirectory(prefix="pokeworld-allocations-") as scratch:
            allocs = open_allocations(a.allocations, Path(scratch), a.models)
            if a.plan:
                print("\n".join(plan_lines(plan(allocs), a.commit or commit())))
                return 0
            merged = write_merged(a, allocs, sys.argv[1:] if argv is None else argv)
    except PokeworldError as e:  # one line, nothing written
        raise SystemExit(f"error: {e}") from None
    missing = {n for al in allocs for n, w in al.weights.items() if w != "returned"}
    print(f"[merge_allocations] {len(merged['runs'])} runs from {len(allocs)} allocations "
          f"({len(merged['provenance']['duplicates'])} trained twice) -> {a.out}"
          + (f"; final weights not returned for {sorted(missing)}" if missing else ""))
    return 0


__all__ = ["DEVICE_FILE", "AGREE", "Allocation", "device_record", "commit", "gpu_name", "write_device", "read_json",
           "unpack", "open_allocation", "lease_groups", "join_lease_parts", "open_lease", "open_allocations",
           "open_landed", "restore_model", "LEASE_INDEX", "MODELS", "check_progress", "check_step", "restore_returned", "training_facts",
           "run_key", "returned_of", "plan", "plan_lines", "corpus_lines", "carry_other_corpora", "carry_earlier_runs",
           "export_plan", "export_targets", "export_runs", "output_paths", "write_merged",
           "allocation_record", "check_agreement", "read_certificates",
           "ridge_difference", "merge_allocations", "allocation_summary", "allocation_lines", "run_lines", "markdown",
           "main"]
