"""A lease's return landed in the repository: what it brought back, kept where anyone can re-measure, resume or
extend it (``python scripts/land_lease.py RETURN... --record docs/results/leases/ID``).

* Every run of the factorial whose final weights came back becomes a released model, ``models/<name>/``
  (:data:`MODELS`; ``pokeworld export``'s folder: the card, config.json, ``model.safetensors`` holding the float32
  tensors of at least 4,096 elements in bfloat16 as the device returned them, so nothing is rounded twice, and the
  device's measure.json and metrics beside them). Its card names the environment, the objective, the corpus hash,
  the device and the date, and the command that re-measures it on a CPU.
* The lease's record (``--record``): the latest return's records, log and device record as they came back, and
  :data:`LEASE_INDEX`: which model folder holds which returned run (the sha256 of its weights file and of the
  member it came from), and the parts of the weights tar kept for what no model folder holds (a checkpoint of a
  run the lease cut, another experiment's weights). The merge, ``--plan`` and the CPU side read the record with
  the model folders as they read the returned folders (:func:`.allocations.open_allocations`).

Nothing is replaced that pokeworld did not write (every output checked before the first write); a model folder
already holding this run's weights is kept as it is.
"""

from __future__ import annotations

import argparse
import hashlib
import tempfile
from pathlib import Path

from ..errors import ConfigError, PokeworldError
from ..io import check_outputs, read_regular_bytes, save_bytes, write_json
from . import allocations
from .pack import INDEX, RECORDS, part_path
from .queue import catalog, factorial_key

LEASE_INDEX = allocations.LEASE_INDEX
MODELS = allocations.MODELS
RECORD_FILES = (RECORDS, allocations.DEVICE_FILE, "allocation.log")


def model_name(variant: str, preset: str, seed: int) -> str:
    """The released model folder's name of a run of the factorial: ``xjepa-VFX-paper-s0``."""
    return f"xjepa-{variant}-{preset}-s{seed}"


def factorial_runs(a: allocations.Allocation) -> dict[str, str]:
    """Run name -> model folder name, for every run of ``a``'s factorial whose final weights came back."""
    preset = str(a.map_config.get("preset", "paper"))
    seeds = (0, 1, 2) + tuple(int(s) for s in a.map_config.get("seeds", []) if isinstance(s, int) and s > 2)
    names = {s.name: s for t, s in catalog(preset, seeds).items() if factorial_key(t)}
    return {n: model_name(names[n].train["variant"], preset, names[n].seed)
            for n in a.progress.get("finished", []) if n in names and a.weights.get(n) == "returned"}


def sha256_file(path: Path, what: str) -> str:
    return hashlib.sha256(read_regular_bytes(path, what, 1 << 30)).hexdigest()


def provenance(a: allocations.Allocation, lease: str, name: str, member: dict) -> dict:
    """What a released model's card says of where it came from: no machine's paths."""
    device = a.device
    return {"lease": lease, "run": name, "device": device.get("device"), "date": device.get("date"),
            "torch": device.get("torch"), "commit": device.get("git"), "corpus_sha256": a.corpus_sha256,
            "environment": a.map_config.get("environment", "reference"), "preset": a.map_config.get("preset"),
            "member_sha256": member.get("sha256"),
            "returned": "float32 tensors of at least 4,096 elements rounded to bfloat16 for the trip back; the "
                        "device measured the float32 weights"}


def land(returns: list[Path], record: Path, models: Path, lease: str, data_command: str = "") -> dict:
    """Land the lease ``returns`` (every folder its commands returned) as :data:`LEASE_INDEX` and the records
    under ``record`` and a model folder per returned run of the factorial under ``models``; returns the index."""
    from ..export import ExportConfig, run as export_run

    with tempfile.TemporaryDirectory(prefix="pokeworld-land-") as tmp:
        scratch = Path(tmp)
        group = allocations.lease_groups(list(returns))
        if len(group) != 1:
            raise ConfigError(f"the folders given are {len(group)} allocations, not one lease's returns; land "
                              "each lease on its own")
        a = allocations.open_lease(group[0], scratch)
        index = allocations.read_json(a.root / INDEX, "an allocation's index of returned weights")
        members = {m["run"]: m for m in index.get("members", []) if isinstance(m, dict) and m.get("kind") == "final"}
        runs = factorial_runs(a)
        keep_parts = bool(a.checkpoints) or any(n not in runs for n in members)
        check_outputs(record, *RECORD_FILES, LEASE_INDEX)
        merged = allocations.merge_allocations([a])
        run_dirs = scratch / "runs"
        allocations.export_runs([a], merged, run_dirs)
        rows = {}
        for name, folder in runs.items():
            export_run(ExportConfig(run_dir=str(run_dirs / name), out=str(models / folder), data_command=data_command,
                                    dtype="bfloat16", provenance=provenance(a, lease, name, members.get(name, {}))))
            rows[name] = {"model": folder, "model_sha256": sha256_file(models / folder / "model.safetensors",
                                                                         "a model's weights"),
                          "member_sha256": members.get(name, {}).get("sha256")}
        latest = group[0][-1]
        for f in RECORD_FILES:
            save_bytes(record / f, read_regular_bytes(latest / f, f"a returned {f}", 64 << 20))
        parts = []
        if keep_parts:
            joined = scratch / "parts"
            allocations.join_lease_parts(group[0], index, joined)
            for i in range(len(index.get("part_sha256", []))):
                if part_path(joined, i).exists():
                    save_bytes(part_path(record, i), read_regular_bytes(part_path(joined, i), "a part of the weights", 1 << 30))
                    parts.append(part_path(record, i).name)
        lease_index = {"format": 1, "lease": lease, "returns": [f.name for f in group[0]], "runs": rows,
                       "parts": parts, "finished": a.progress.get("finished", []),
                       "checkpoints": dict(a.checkpoints)}
        write_json(record / LEASE_INDEX, lease_index)
    return lease_index


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Land a GPU lease's returned folders in the repository: its record "
                                             "and a released model per returned run of the factorial.")
    ap.add_argument("returns", nargs="+", type=Path, help="every folder the lease's commands returned")
    ap.add_argument("--record", type=Path, required=True, help="the lease's record folder (docs/results/leases/ID)")
    ap.add_argument("--models", type=Path, default=MODELS, help="where the model folders go (default models/)")
    ap.add_argument("--lease", default="", help="the lease's name on the cards (default: the record folder's)")
    ap.add_argument("--data-command", default="pokeworld map --preset paper --experiments factorial OUT   "
                                              "# DIR = OUT/data/standard",
                    help="how the training store DIR is made, quoted on the cards")
    a = ap.parse_args(argv)
    try:
        index = land(a.returns, a.record, a.models, a.lease or a.record.name, a.data_command)
    except PokeworldError as e:
        raise SystemExit(f"error: {e}") from None
    print(f"[land_lease] {len(index['runs'])} released models under {a.models} "
          f"({', '.join(r['model'] for r in index['runs'].values()) or 'none'}), "
          f"{len(index['parts'])} parts kept; the lease's record -> {a.record / LEASE_INDEX}")
    return 0


__all__ = ["LEASE_INDEX", "MODELS", "model_name", "factorial_runs", "provenance", "land", "main"]

if __name__ == "__main__":
    raise SystemExit(main())
