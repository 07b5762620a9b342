"""What a GPU allocation brings back, re-packed after every measured run and while a run trains, so that a SIGKILL
at any moment loses at most the run in progress.

A device machine returns at most 8 files from its output folder, each at most 16 MiB, 64 MiB together
(:class:`ReturnLimits`). ``scripts/gpu_allocation.sh`` leaves there:

* ``allocation.log`` and ``device.json`` (the script's own), ``.pokeworld-owned`` (:mod:`pokeworld.io`'s record of
  the files it wrote there);
* ``records.tar.gz`` (:data:`RECORDS`): the map's small records (:data:`pokeworld.experiments.stages.PACK_GLOBS`:
  map_config, progress and device JSON, the corpus manifest, each run's config, metrics and measurement) and
  ``returned.json``, the index of what the parts below hold and what was left out;
* ``pack.tar.part00``, ``part01``, ... (:data:`PARTS`): one uncompressed tar cut into parts of at most
  ``part_bytes``, holding ``runs/NAME/final.<sha>.pt``, the final weights of every finished run in the order they
  finished, then ``runs/NAME/ckpt.<sha>.pt``, the latest checkpoint (model, optimizer, scheduler, RNG and sampler
  states) of each run not finished, the one training first.

Why this shape:

* Room. A ``paper`` run's final.pt is 17 MiB and its ckpt.pt (with AdamW's two moments) 51 MiB, more than the
  64 MiB allowed. Both travel *compacted* (:func:`compact`): every float32 tensor of at least
  :data:`COMPACT_MIN_ELEMENTS` elements as bfloat16 (weights and moments alike; biases, norms, normalisation
  statistics and RNG states exact), 8.5 and 25.5 MiB, and are restored to float32 on arrival (:func:`expand`).
  The measurement on the device reads the float32 weights; probes computed later from the returned weights, and a
  run resumed from a returned checkpoint, see them rounded to bfloat16 (returned.json and the resumed run's
  resumed.json say so). :func:`stream_budget`: 3 parts of 15 MiB, beside the four small files and room for the
  leftover of one interrupted write, 45 MiB: five finished ``paper`` runs, or two and a checkpoint.
* Consistency. Each file is replaced atomically (:func:`pokeworld.io.atomic_path`), but a set of parts is not: a
  kill between two parts leaves new and old ones side by side. So every member names the first 16 hex digits of
  its own sha256 and is accepted only when its bytes match (:func:`read_stream`), the tar is built
  deterministically and finished weights only ever get appended, and only the parts whose bytes changed are
  rewritten: a finished run's weights lie in bytes no later write touches. A kill in the fraction of a second a
  snapshot takes to write can cost that snapshot (the run in progress), never a finished run.
"""

from __future__ import annotations

import hashlib
import io
import re
import tarfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from .. import checkpoint
from ..errors import ConfigError, PokeworldError
from ..io import read_regular_bytes, remove_own_file, save_bytes, write_json
from ..experiments import stages
from ..experiments.config import MapConfig
from ..experiments.runs import RunSpec, run_dir

RECORDS = "records.tar.gz"
"""The map's small records and returned.json, in the output folder."""
PARTS = "pack.tar"
"""The stem of the weight and checkpoint parts: pack.tar.part00, pack.tar.part01, ..."""
INDEX = "returned.json"
"""What the parts hold and what was left out; written into the map folder, so it travels inside the records."""
COMPACT_MIN_ELEMENTS = 4096
"""Float32 tensors of at least this many elements travel as bfloat16; smaller ones (biases, norms, statistics)
exactly."""
COMPACT_FORMAT = "pokeworld-compact-1"
MEMBER = re.compile(r"runs/([A-Za-z0-9][A-Za-z0-9._-]{0,199})/(final|ckpt)\.([0-9a-f]{16})\.pt")
"""A part member's name: the run, final weights or a checkpoint, and the start of the content's sha256."""


@dataclass(frozen=True)
class ReturnLimits:
    """What a device machine returns from its output folder (../shared/device/README.md), and how it is shared."""

    files: int = 8
    file_bytes: int = 16 << 20
    total_bytes: int = 64 << 20
    part_bytes: int = 15 << 20
    """Largest part of the weights tar: under the 16 MiB limit whether a MiB or a million bytes is meant."""
    small_files: int = 4
    """allocation.log, device.json, .pokeworld-owned and records.tar.gz."""
    small_bytes: int = 2 << 20
    """Room kept for those four (the log and the records grow; a paper allocation's are a few hundred KiB)."""
    parts: int = 0
    """Parts the weights tar may have in all when several returns carry it (a lease: each of its commands returns
    the parts no earlier command returned, ``scripts/gpu_lease.sh``; :func:`join_returns` puts them together);
    0: what one return folder holds beside the small files."""


def stream_budget(limits: ReturnLimits) -> tuple[int, int]:
    """(most parts, most bytes) the weights tar may take: ``limits.parts`` parts when several returns carry it,
    else what is left in one return beside the small files, keeping one file and one part's bytes for the temporary
    an interrupted write leaves (a kill while a part is written leaves it beside the old part)."""
    if limits.parts:
        return limits.parts, limits.parts * limits.part_bytes
    parts = limits.files - limits.small_files - 1
    room = limits.total_bytes - limits.small_bytes - limits.part_bytes
    return parts, min(parts * limits.part_bytes, room)


# ---------------------------------------------------------------------- compact checkpoints


def compact(ck: dict[str, Any], min_elements: int = COMPACT_MIN_ELEMENTS) -> dict[str, Any]:
    """``ck`` (a final.pt or ckpt.pt) with its large float32 tensors as bfloat16, wrapped with the paths of those
    tensors (lists of keys) so that :func:`expand` restores exactly them."""
    paths: list[list] = []

    def walk(obj: Any, path: list) -> Any:
        if isinstance(obj, torch.Tensor):
            if obj.dtype == torch.float32 and obj.numel() >= min_elements:
                paths.append(path)
                return obj.detach().to("cpu", torch.bfloat16)
            return obj.detach().cpu()
        if isinstance(obj, dict):
            return {k: walk(v, [*path, k]) for k, v in obj.items()}
        if isinstance(obj, list):
            return [walk(v, [*path, i]) for i, v in enumerate(obj)]
        return obj  # tuples (the Python RNG state), numbers, strings: as they are

    return {"format": COMPACT_FORMAT, "dtype": "bfloat16", "min_elements": min_elements,
            "compacted": paths, "checkpoint": walk(ck, [])}


def expand(packed: dict[str, Any], what: str) -> dict[str, Any]:
    """The checkpoint :func:`compact` wrapped, its compacted tensors back in float32; ConfigError naming ``what``
    when it is not one."""
    ck, paths = packed.get("checkpoint"), packed.get("compacted")
    if packed.get("format") != COMPACT_FORMAT or not isinstance(ck, dict) or not isinstance(paths, list):
        raise ConfigError(f"{what} is not a compacted checkpoint pokeworld wrote")
    for path in paths:
        parent, key = ck, None
        try:
            for key in path[:-1]:
                parent = parent[key]
            key = path[-1]
            tensor = parent[key]
        except (KeyError, IndexError, TypeError):
            raise ConfigError(f"{what} names a compacted tensor it does not hold ({path!r:.80}); it is "
                              "damaged") from None
        if not isinstance(tensor, torch.Tensor) or tensor.dtype != torch.bfloat16:
            raise ConfigError(f"{what}: {path!r:.80} is not a bfloat16 tensor; it is damaged")
        parent[key] = tensor.float()
    return ck


def compact_bytes(path: Path) -> tuple[bytes, int]:
    """The compacted form of the checkpoint at ``path`` (read weights-only), serialised, and its step."""
    ck = checkpoint.load(path)
    buf = io.BytesIO()
    torch.save(compact(ck), buf)  # into memory; the pack is written by write_bytes
    return buf.getvalue(), int(ck.get("step", 0))


def member_name(run: str, kind: str, data: bytes) -> str:
    """``runs/RUN/KIND.<sha>.pt``: the name carries the check of its content (see the module docstring)."""
    return f"runs/{run}/{kind}.{hashlib.sha256(data).hexdigest()[:16]}.pt"


# ---------------------------------------------------------------------- the tar and its parts


def tar_size(sizes: list[int]) -> int:
    """Bytes of the uncompressed tar :func:`tar_bytes` writes for members of these sizes."""
    blocks = sum(512 + -(-s // 512) * 512 for s in sizes) + 1024
    return -(-blocks // tarfile.RECORDSIZE) * tarfile.RECORDSIZE


def tar_bytes(members: list[tuple[str, bytes]]) -> bytes:
    """An uncompressed tar of ``members`` (name, bytes), byte for byte the same for the same members: no dates,
    owners or modes of the machine, so appending a member leaves every earlier byte as it was."""
    buf = io.BytesIO()
    # built in memory; the parts reach disk through write_bytes (the output contract)
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.USTAR_FORMAT) as tar:  # into memory: write_bytes writes
        for name, data in members:
            info = tarfile.TarInfo(name)
            info.size, info.mode, info.mtime = len(data), 0o644, 0
            tar.addfile(info, io.BytesIO(data))
    return buf.getvalue()


def part_path(folder: Path, index: int) -> Path:
    return folder / f"{PARTS}.part{index:02d}"


def split_bytes(data: bytes, part_bytes: int) -> list[bytes]:
    """``data`` cut into consecutive pieces of at most ``part_bytes`` (none for no data)."""
    return [data[i:i + part_bytes] for i in range(0, len(data), part_bytes)]


def write_parts(folder: Path, data: bytes, part_bytes: int, written: dict[int, str] | None = None) -> int:
    """Write ``data`` as ``pack.tar.part00``... into ``folder``, one atomic file each, skipping a part whose bytes
    are already there (``written``: index -> sha256 of what this process wrote, kept current), then delete the parts
    beyond the new last one. Returns the number of parts."""
    written = {} if written is None else written
    pieces = split_bytes(data, part_bytes)
    for i, piece in enumerate(pieces):
        sha = hashlib.sha256(piece).hexdigest()
        path = part_path(folder, i)
        if written.get(i) == sha and path.exists():
            continue
        save_bytes(path, piece)
        written[i] = sha
    i = len(pieces)
    while part_path(folder, i).exists() or i in written:
        remove_own_file(part_path(folder, i))
        written.pop(i, None)
        i += 1
    return len(pieces)


def join_parts(folder: Path, limits: ReturnLimits = ReturnLimits()) -> bytes:
    """The parts in ``folder`` joined, from part00 up to the first missing one (regular files only, each at most
    ``limits.file_bytes``, at most ``limits.files`` of them)."""
    chunks, i, most = [], 0, max(limits.files, limits.parts)
    while part_path(folder, i).exists():
        if i >= most:
            raise ConfigError(f"{folder} holds more than {most} parts of {PARTS}; not an allocation's")
        try:
            chunks.append(read_regular_bytes(part_path(folder, i), "a part of an allocation's pack", limits.file_bytes))
        except PokeworldError as e:
            raise ConfigError(str(e)) from None
        i += 1
    return b"".join(chunks)


@dataclass
class Member:
    """A verified member of the parts: its run, kind ('final' or 'ckpt') and bytes."""

    run: str
    kind: str
    data: bytes


MAX_MEMBERS = 256
"""Most entries read from the parts (a paper allocation's are at most six: five final weights and a checkpoint)."""


def read_stream(folder: Path, limits: ReturnLimits = ReturnLimits()) -> list[Member]:
    """The members of the parts in ``folder`` whose bytes match the sha256 their name carries, in order, each
    (run, kind) once. Nothing is extracted by its name (each member is read into memory and checked; only regular
    files are read). A tail that a kill cut short or mixed with an older write ends the reading, and so do a
    second member of a (run, kind) already read (an older write's) and more than :data:`MAX_MEMBERS` entries:
    what came before stands."""
    data = join_parts(folder, limits)
    if not data:
        return []
    found: list[Member] = []
    seen: set[tuple[str, str]] = set()
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:") as tar:
            for n, info in enumerate(tar):
                m = MEMBER.fullmatch(info.name)
                if n >= MAX_MEMBERS or (m and (m.group(1), m.group(2)) in seen):
                    break
                if not (info.isreg() and m and info.size <= len(data)):
                    continue
                body = tar.extractfile(info).read()
                if len(body) == info.size and hashlib.sha256(body).hexdigest()[:16] == m.group(3):
                    found.append(Member(m.group(1), m.group(2), body))
                    seen.add((m.group(1), m.group(2)))
    except (tarfile.TarError, EOFError, OSError):
        pass  # the damaged tail of an interrupted write
    return found


def load_member(member: Member, scratch: Path) -> dict[str, Any]:
    """A verified member's checkpoint, read weights-only (:func:`pokeworld.checkpoint.load`) and expanded to
    float32; ConfigError when it is not one."""
    path = scratch / f"{member.run}.{member.kind}.pt"
    save_bytes(path, member.data)
    try:
        return expand(checkpoint.load(path), f"{member.kind} of {member.run}")
    except PokeworldError as e:
        raise ConfigError(f"the returned {member.kind} of {member.run} does not load ({e})") from None


def check_return_folder(folder: Path, limits: ReturnLimits = ReturnLimits()) -> list[str]:
    """What in ``folder`` would not come back from a device machine ([] when all of it does): more than
    ``limits.files`` files, a file over ``limits.file_bytes``, more than ``limits.total_bytes`` together."""
    files = [p for p in folder.rglob("*") if p.is_file()]
    sizes = {p: p.stat().st_size for p in files}
    problems = [f"{p.name} is {s / 2 ** 20:.1f} MiB" for p, s in sizes.items() if s > limits.file_bytes]
    if len(files) > limits.files:
        problems.append(f"{len(files)} files, more than {limits.files}")
    if sum(sizes.values()) > limits.total_bytes:
        problems.append(f"{sum(sizes.values()) / 2 ** 20:.1f} MiB together, more than {limits.total_bytes >> 20}")
    return problems


# ---------------------------------------------------------------------- the packer


@dataclass
class Packer:
    """Re-packs an allocation's output folder from its map folder (:meth:`pack`): thread-safe, so that a snapshot
    thread (:class:`Snapshots`) and the map's own thread may both call it."""

    c: MapConfig
    specs: list[RunSpec]
    out: Path
    started: float
    limits: ReturnLimits = ReturnLimits()
    facts: dict[str, dict] = field(default_factory=dict)
    """run -> what the allocation measured of it (s/step, wall seconds), written into returned.json."""
    committed: dict[str, tuple[str, bytes]] = field(default_factory=dict)
    """run -> (member name, bytes) of its final weights, in the order the runs finished: never removed or moved."""
    left_out: dict[str, str] = field(default_factory=dict)
    """Finished run -> why its weights do not come back."""
    written: dict[int, str] = field(default_factory=dict)
    """Part index -> sha256 of the bytes this process wrote there (unchanged parts are not rewritten)."""
    cache: dict[str, tuple[tuple, bytes]] = field(default_factory=dict)
    """run -> ((mtime, size) of its ckpt.pt, the compacted bytes): a snapshot re-reads only a changed checkpoint."""
    steps: dict[str, int] = field(default_factory=dict)
    """member name -> the step of the checkpoint it holds."""
    share: dict = field(default_factory=dict)
    """How the allocation shared its GPU among runs (:meth:`.share.SharedRuns.record`), if it did."""
    lock: threading.Lock = field(default_factory=threading.Lock)

    def pack(self, running: str = "", training: frozenset[str] = frozenset()) -> dict:
        """Write progress.json, the parts (finished weights, then checkpoints, ``running``'s first, while room
        is left) and the records into the output folder; returns the index (returned.json). The checkpoints of
        ``training`` (runs training now in other processes) are left out: they change while the others' parts
        travel, and a run is admitted only when it is predicted to finish."""
        with self.lock:
            prog = stages.write_progress(self.c, self.specs, self.started)
            _, room = stream_budget(self.limits)
            for name in prog["finished"]:
                if name not in self.committed and name not in self.left_out:
                    self.commit(name, room)
            self.cache = {n: v for n, v in self.cache.items() if n in prog["partial"]}
            members, skipped = list(self.committed.values()), {}
            for name in sorted(prog["partial"], key=lambda n: n != running):  # the run training first
                if name in training:
                    continue
                why = self.add_checkpoint(name, members, room)
                if why:
                    skipped[name] = why
            data = tar_bytes(members)
            parts = write_parts(self.out, data, self.limits.part_bytes, self.written)
            index = {**self.index(members, parts), "checkpoints_left_out": skipped}
            write_json(Path(self.c.out) / INDEX, index)
            stages.pack_results(self.c, self.out / RECORDS, quiet=True)
        ckpts = [m for m in index["members"] if m["kind"] == "ckpt"]
        print(f"[allocation] returned: {len(prog['finished'])} finished runs' records, "
              f"{len(index['members']) - len(ckpts)} final weights, "
              + (", ".join(f"{m['run']} checkpoint at step {m['step']}" for m in ckpts) or "no checkpoint")
              + f" ({len(data) / 2 ** 20:.1f} MiB in {parts} parts)"
              + (f"; left out: {self.left_out | skipped}" if self.left_out or skipped else ""), flush=True)
        return index

    def commit(self, name: str, room: int) -> None:
        """Append finished run ``name``'s compacted weights, or record why they do not come back."""
        data, _ = compact_bytes(run_dir(self.c, name) / "final.pt")
        sizes = [len(d) for _, d in self.committed.values()] + [len(data)]
        if tar_size(sizes) > room:
            self.left_out[name] = (f"final weights ({len(data) / 2 ** 20:.1f} MiB): no room left in the "
                                   f"{room / 2 ** 20:.0f} MiB a device returns beside the records")
            return
        self.committed[name] = (member_name(name, "final", data), data)

    def add_checkpoint(self, name: str, members: list[tuple[str, bytes]], room: int) -> str:
        """Add the compacted ckpt.pt of unfinished run ``name`` to ``members`` when it fits (re-serialised only
        when the file changed); returns why not otherwise ('' when added or when there is none)."""
        path = run_dir(self.c, name) / "ckpt.pt"
        try:
            st = path.stat()
        except FileNotFoundError:
            return ""
        key = (st.st_mtime_ns, st.st_size)
        if self.cache.get(name, ((), b""))[0] != key:
            data, step = compact_bytes(path)
            self.cache[name] = (key, data)
            self.steps[member_name(name, "ckpt", data)] = step
        data = self.cache[name][1]
        if tar_size([len(d) for _, d in members] + [len(data)]) > room:
            return (f"checkpoint ({len(data) / 2 ** 20:.1f} MiB): no room left in the {room / 2 ** 20:.0f} MiB "
                    "beside the finished runs' weights")
        members.append((member_name(name, "ckpt", data), data))
        return ""

    def index(self, members: list[tuple[str, bytes]], parts: int) -> dict:
        """returned.json: each member (run, kind, step, sha256, bytes), how they were compacted, what was left out."""
        rows = []
        for name, data in members:
            m = MEMBER.fullmatch(name)
            run, kind = m.group(1), m.group(2)
            step = self.steps.get(name) if kind == "ckpt" else None
            rows.append({"member": name, "run": run, "kind": kind, "step": step,
                         "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)})
        return {"format": 1, "parts": parts, "part_bytes": self.limits.part_bytes,
                "part_sha256": [self.written.get(i, "") for i in range(parts)],
                "compacted": f"float32 tensors of at least {COMPACT_MIN_ELEMENTS} elements as bfloat16 "
                             "(the device measured the float32 weights)",
                "members": rows, "left_out": dict(self.left_out), "runs": dict(self.facts),
                **({"share": dict(self.share)} if self.share else {})}


class Snapshots:
    """While a run trains, re-pack the output folder whenever its ckpt.pt changed, at most every ``every_s``
    seconds, so that a kill leaves the latest checkpoint in the output folder (a context manager)."""

    def __init__(self, packer: Packer, name: str, every_s: float):
        self.packer, self.name, self.every_s = packer, name, every_s
        self.path = run_dir(packer.c, name) / "ckpt.pt"
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.watch, name=f"snapshots-{name}", daemon=True)

    def __enter__(self) -> Snapshots:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join()

    def watch(self) -> None:
        seen = None
        while not self.stop.wait(self.every_s):
            try:
                st = self.path.stat()
            except FileNotFoundError:
                continue
            if (st.st_mtime_ns, st.st_size) == seen:
                continue
            seen = (st.st_mtime_ns, st.st_size)
            try:
                self.packer.pack(running=self.name)
            except (PokeworldError, OSError, RuntimeError, tarfile.TarError) as e:
                # a file replaced while it was read (metrics.jsonl on resume): the next snapshot takes it
                print(f"[allocation] snapshot of {self.name} skipped ({type(e).__name__}: {e})", flush=True)


__all__ = ["RECORDS", "PARTS", "INDEX", "COMPACT_MIN_ELEMENTS", "MEMBER", "ReturnLimits", "stream_budget", "compact",
           "expand", "compact_bytes", "member_name", "tar_size", "tar_bytes", "part_path", "split_bytes",
           "write_parts", "join_parts", "Member", "MAX_MEMBERS", "read_stream", "load_member",
           "check_return_folder", "Packer",
           "Snapshots"]
