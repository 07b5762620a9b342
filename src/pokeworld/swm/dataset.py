"""pokeworld stores <-> stable-worldmodel datasets, both ways.

Export (:func:`export_store`, ``pokeworld swm-export``) writes a pokeworld store as swm's HDF5 format: one ``.h5``
file with one dataset per column (first axis: every step of every episode, episodes back to back) plus ``ep_len`` /
``ep_offset``, the layout ``stable_worldmodel.data.HDF5Dataset`` reads. HDF5 rather than Lance (``World.collect``'s
default) because at this size it is the exact one: it keeps every array bit for bit in its own dtype, where swm's
Lance writer JPEG-compresses pixel columns and casts every number to float32; it is one file; and pokeworld already
reads and writes HDF5 (h5py), so nothing new is needed to write it.

Columns, in swm's names (those ``swm/PokeWorld-v0`` and ``World.collect`` produce): ``pixels`` (H, W, 3) uint8 (the
grayscale frame in all three channels, what swm's image pipeline expects), ``proprio``, ``touch``, ``action`` (the
action taken after the row's observation; NaN in an episode's last row, swm's mark for "no action"), every
``labels/<name>`` as ``<name>`` per step, every hidden parameter ``params/<name>`` as ``<name>`` repeated along its
episode (the hidden physics as columns), ``split`` and ``step_idx``. The root attribute ``pokeworld`` (JSON) records
which columns are labels and params and the source manifest, so an import restores the store exactly.

Import (:func:`import_dataset`, ``pokeworld swm-import``) reads an swm PokeWorld dataset — our export, or what
``World`` collected from ``swm/PokeWorld-v0`` in HDF5 or Lance — into a pokeworld store (``pokeworld.data.save``:
manifest, content hash, splits) that ``pokeworld.data.load`` and the protocol tools open. It treats the file as
untrusted: HDF5 is read with h5py and Lance through swm's reader (arrow), neither of which runs code; anything
malformed is a :class:`DataError`.

``World.collect`` (swm 0.1.1) records the observation after every step, not the one reset returns, and rotates the
action column so a row holds the action taken after its observation, except the last, which holds the episode's
first action. Either way the last row's action is not a transition of the episode, so an episode of L rows imports
as L observations and the first L-1 actions.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from ..data import SPLITS, Dataset, assign_splits, check_store_destination, load, save
from ..errors import ConfigError, DataError
from ..io import atomic_path, check_outputs, check_writable_dir
from ..sim.core import PARAM_NAMES

EXPORT_FORMAT = "pokeworld-swm-hdf5"
EXPORT_VERSION = 1
INDEX = ("ep_len", "ep_offset")
"""swm's HDF5 episode index datasets."""
STEP_COLUMNS = {"pixels": "frames", "proprio": "proprio", "touch": "touch"}
"""swm column -> pokeworld stream, for the per-observation streams."""
RESERVED = (*STEP_COLUMNS, "action", "split", "step_idx", *INDEX)
LABEL_COLUMNS = ("object_pos", "object_vel", "finger_pos", "finger_vel", "contact", "goal_pos", "distance")
"""Per-step columns of a ``World``-collected PokeWorld dataset kept as store labels."""
DEFAULT_MAX_GIB = 4.0
"""Default budget (GiB) for the total bytes the columns an import reads declare (``ImportConfig.max_gib``): checked
against the file's declared shapes and dtypes before anything is read, so a hostile or compressed file cannot make
the import allocate more. The conversion to a store holds about twice that at its peak."""


# ---------------------------------------------------------------------- export
def _episode_rows(ds: Dataset) -> tuple[np.ndarray, np.ndarray]:
    E, T1 = ds.frames.shape[:2]
    return np.full(E, T1, np.int32), (np.arange(E, dtype=np.int64) * T1)


def export_columns(ds: Dataset) -> dict[str, np.ndarray]:
    """The store's arrays as swm columns (one row per observation, episodes back to back)."""
    E, T1 = ds.frames.shape[:2]
    flat = lambda a: a.reshape(E * T1, *a.shape[2:])  # noqa: E731
    per_step = lambda a: np.repeat(a, T1, axis=0)  # noqa: E731
    action = np.full((E, T1, ds.actions.shape[2]), np.nan, np.float32)
    action[:, :-1] = ds.actions
    cols = {"pixels": flat(np.repeat(ds.frames[..., None], 3, axis=-1)), "proprio": flat(ds.proprio),
            "touch": flat(ds.touch), "action": flat(action)}
    for group in (ds.labels, ds.params):
        clash = sorted(set(group) & (set(cols) | set(RESERVED)))
        if clash:
            raise DataError(f"store labels/params {clash} collide with swm column names; rename them before export")
    clash = sorted(set(ds.labels) & set(ds.params))
    if clash:
        raise DataError(f"{clash} is both a label and a param; swm has one column namespace")
    cols.update({k: flat(v) for k, v in ds.labels.items()})
    cols.update({k: per_step(v) for k, v in ds.params.items()})
    cols["split"] = per_step(ds.split)
    cols["step_idx"] = np.tile(np.arange(T1, dtype=np.int64), E)
    return cols


def export_store(ds: Dataset, out: str | os.PathLike) -> Path:
    """Write ``ds`` as an swm HDF5 dataset at ``out`` (an ``.h5`` file, written atomically)."""
    out = Path(out)
    if out.suffix not in (".h5", ".hdf5"):
        raise ConfigError(f"the swm HDF5 format needs a .h5 or .hdf5 file name, got {out}")
    cols = export_columns(ds)
    lengths, offsets = _episode_rows(ds)
    meta = {"format": EXPORT_FORMAT, "version": EXPORT_VERSION, "labels": sorted(ds.labels),
            "params": sorted(ds.params), "source_manifest": ds.manifest}
    with atomic_path(out) as tmp, h5py.File(tmp, "w", track_order=True) as f:
        for name, a in cols.items():
            # a row per chunk, as swm's HDF5Writer lays them out (its reader slices clips of rows)
            f.create_dataset(name, data=a, chunks=(1, *a.shape[1:]), compression="gzip", compression_opts=1,
                             track_times=False)
        f.create_dataset("ep_len", data=lengths, track_times=False)
        f.create_dataset("ep_offset", data=offsets, track_times=False)
        f.attrs["pokeworld"] = json.dumps(meta, sort_keys=True, default=str)
    return out


# ---------------------------------------------------------------------- import: readers
def _checked_index(lengths, offsets, rows: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The episode index as int64, refused unless every episode is 1 or more of the ``rows`` stored rows and no two
    share a row: a file of two rows declaring a million overlapping episodes would otherwise make the gather copy
    those two rows a million times, far past the declared bytes :func:`over_budget` checked."""
    lengths, offsets = np.asarray(lengths), np.asarray(offsets)
    if lengths.ndim != 1 or lengths.shape != offsets.shape or lengths.size == 0:
        raise DataError(f"{where}: episode index must be two equal-length 1-d arrays with at least one episode, "
                        f"got ep_len {lengths.shape}, ep_offset {offsets.shape}")
    if lengths.dtype.kind not in "iu" or offsets.dtype.kind not in "iu":
        raise DataError(f"{where}: ep_len / ep_offset must be integers, got {lengths.dtype} / {offsets.dtype}")
    lengths, offsets = lengths.astype(np.int64), offsets.astype(np.int64)  # a uint64 past int64 turns negative
    # each bound on its own first, so that offset + length cannot wrap around
    if (lengths < 1).any() or (offsets < 0).any() or (lengths > rows).any() or (offsets > rows - lengths).any():
        raise DataError(f"{where}: episode index points outside the {rows} stored rows (or has empty episodes): "
                        f"every episode needs ep_len >= 1, ep_offset >= 0 and ep_offset + ep_len <= {rows}")
    order = np.argsort(offsets, kind="stable")
    starts, ends = offsets[order], offsets[order] + lengths[order]
    shared = np.flatnonzero(starts[1:] < ends[:-1])
    if shared.size:
        a, b = order[shared[0]], order[shared[0] + 1]
        raise DataError(f"{where}: episodes {a} and {b} share stored rows (ep_offset {offsets[a]} + ep_len "
                        f"{lengths[a]} > ep_offset {offsets[b]}); swm stores each episode's rows once, so the episode "
                        "index is corrupt: re-export or re-collect the dataset")
    return lengths, offsets


def wanted_columns(names, meta: dict) -> list[str]:
    """The columns of ``names`` an import reads: the episode index, the observation streams, the action, the split,
    and the labels and params (those our export record ``meta`` names, else the World-collected ones)."""
    labels, params = meta.get("labels", LABEL_COLUMNS), meta.get("params", PARAM_NAMES)
    present = set(names)
    return [k for k in dict.fromkeys([*INDEX, *STEP_COLUMNS, "action", "split", *labels, *params]) if k in present]


def over_budget(path: Path, declared: dict[str, int], max_bytes: int) -> DataError | None:
    """The error for columns whose declared bytes ({name: bytes}) sum past ``max_bytes``, or None."""
    total = sum(declared.values())
    if total <= max_bytes:
        return None
    largest = ", ".join(f"{k} {v / 2**30:.3g}" for k, v in sorted(declared.items(), key=lambda kv: -kv[1])[:3])
    return DataError(f"{path}: the columns an import reads declare {total / 2**30:.3g} GiB in all (largest, GiB: "
                     f"{largest}), over the allowed {max_bytes / 2**30:g} GiB; if the file is trusted and the memory "
                     "is there, raise --max-gib")


MAX_RECORD_DEPTH = 64
"""Deepest nesting of our export record (its source manifest included) an import accepts: a pokeworld manifest nests
a few levels; a deeper one would only make the store's own manifest fail to write or read back."""


def _nesting(obj, limit: int) -> int:
    """How deep JSON ``obj`` nests, walked without recursion and stopping past ``limit``."""
    deepest, todo = 0, [(obj, 1)]
    while todo and deepest <= limit:
        node, depth = todo.pop()
        deepest = max(deepest, depth)
        if isinstance(node, dict):
            todo += [(v, depth + 1) for v in node.values()]
        elif isinstance(node, list):
            todo += [(v, depth + 1) for v in node]
    return deepest


def h5_record(f: h5py.File, path: Path) -> dict:
    """Our export record (the root attribute ``pokeworld``), checked; empty for other writers. A record that is
    not a JSON object of our format (a list, a bare string, nesting deeper than :data:`MAX_RECORD_DEPTH`) is one
    DataError."""
    raw = f.attrs.get("pokeworld")
    if raw is None:
        return {}
    bad = f"{path}: attribute 'pokeworld' is not a {EXPORT_FORMAT} record"
    if not isinstance(raw, (str, bytes)):
        raise DataError(f"{bad} (it holds {type(raw).__name__}, not JSON text); re-export the store")
    try:
        meta = json.loads(raw)
    except (ValueError, RecursionError) as e:  # JSONDecodeError and bad UTF-8 are ValueErrors; deep nesting
        raise DataError(f"{bad} (not valid JSON: {type(e).__name__}); re-export the store") from None
    if not isinstance(meta, dict):
        raise DataError(f"{bad} (a JSON {type(meta).__name__}, not an object); re-export the store")
    if _nesting(meta, MAX_RECORD_DEPTH) > MAX_RECORD_DEPTH:
        raise DataError(f"{bad} (it nests deeper than {MAX_RECORD_DEPTH} levels); re-export the store")
    if not meta:
        return {}
    named = [meta.get(k, []) for k in ("labels", "params")]
    if meta.get("format") != EXPORT_FORMAT or not all(isinstance(v, list) and all(isinstance(n, str) for n in v)
                                                      for v in named):
        raise DataError(f"{bad}; re-export the store")
    if not isinstance(meta.get("source_manifest"), (dict, type(None))):
        raise DataError(f"{bad} (its source_manifest is not a JSON object); re-export the store")
    return meta


def _read_h5(path: Path, max_bytes: int, select=wanted_columns) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray,
                                                                       dict]:
    """Columns, ep_len, ep_offset and our export metadata (empty for other writers) of an swm HDF5 file. Every
    entry's structure is checked (no links, groups or data outside the file); only :func:`wanted_columns` are read,
    after their declared sizes are checked against ``max_bytes``."""
    try:
        with h5py.File(path, "r") as f:
            names = list(f.keys())  # names only: a membership test would follow an external link
            for name in names:
                if not isinstance(f.get(name, getlink=True), h5py.HardLink):
                    raise DataError(f"{path}: {name!r} is a link to elsewhere; an swm dataset holds its own columns")
                node = f[name]
                if not isinstance(node, h5py.Dataset):
                    raise DataError(f"{path}: {name!r} is a group; swm HDF5 datasets hold only flat columns")
                if node.is_virtual or node.external:  # data kept in other files: refuse to read them
                    raise DataError(f"{path}: column {name!r} stores its data outside the file")
            missing = [k for k in INDEX if k not in names]
            if missing:
                raise DataError(f"{path} is not an swm HDF5 dataset: no {missing} (swm's episode index)")
            meta = h5_record(f, path)
            # strings / objects / compounds are no PokeWorld column: left unread (a missing stream is named later)
            nodes = {k: f[k] for k in select(names, meta) if f[k].dtype.kind in "biuf"}
            scalar = [k for k, n in nodes.items() if n.ndim == 0]
            if scalar:
                raise DataError(f"{path}: columns {scalar} hold a single value, not one per row; not an swm dataset")
            error = over_budget(path, {k: n.size * n.dtype.itemsize for k, n in nodes.items()}, max_bytes)
            if error:
                raise error
            cols = {k: n[()] for k, n in nodes.items()}
    except DataError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:  # json.JSONDecodeError is a ValueError
        raise DataError(f"cannot read {path} as an swm HDF5 dataset: {e}") from None
    if any(k not in cols for k in INDEX):
        raise DataError(f"{path}: the episode index {list(INDEX)} must be integer columns")
    lengths, offsets = cols.pop("ep_len"), cols.pop("ep_offset")
    return cols, lengths, offsets, meta


def _read_lance(path: Path, swm, max_bytes: int, select=wanted_columns) -> tuple[dict[str, np.ndarray], np.ndarray,
                                                                                 np.ndarray, dict]:
    """:func:`wanted_columns` of an swm Lance table through swm's own reader; JPEG pixel blobs decoded to (H, W, 3)
    uint8. Lance declares no column sizes up front, so ``max_bytes`` bounds the total as the columns are read."""
    import io

    from PIL import Image

    try:
        reader = swm.data.get_format("lance").open_reader(path)
        lengths, offsets = np.asarray(reader.lengths), np.asarray(reader.offsets)
        cols = {}
        for name in select(reader.column_names, {}):
            data = reader.get_col_data(name)
            if name == "pixels":
                data = np.stack([np.asarray(Image.open(io.BytesIO(bytes(b))).convert("RGB")) for b in data])
            elif data.dtype.kind not in "biuf":
                continue
            elif data.ndim == 2 and data.shape[1] == 1:  # Lance stores every number as a list; scalars as [x]
                data = data[:, 0]
            cols[name] = data
            error = over_budget(path, {k: v.nbytes for k, v in cols.items()}, max_bytes)
            if error:
                raise error
    except DataError:
        raise
    except ImportError as e:  # stable-worldmodel after 0.1.1 moves Lance reading into its [data] extra
        raise DataError(f"reading the Lance table {path} needs stable-worldmodel's Lance support, not installed here "
                        f"({e}); install it (pip install 'stable-worldmodel[data]' for releases after 0.1.1), "
                        "or export the dataset as HDF5") from None
    except Exception as e:  # noqa: BLE001 -- lancedb, arrow and PIL raise many types on a malformed table or image
        raise DataError(f"cannot read {path} as an swm Lance dataset: {type(e).__name__}: {e}") from None
    return cols, lengths, offsets, {}


def read_swm(path: str | os.PathLike, max_gib: float = DEFAULT_MAX_GIB, select=wanted_columns
             ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, dict]:
    """(columns, ep_len, ep_offset, export metadata) of an swm HDF5 file or Lance table: only the columns an import
    uses (:func:`wanted_columns`, or ``select(names, meta) -> names`` for another reader such as
    :mod:`pokeworld.swm.factors`), their total bytes within ``max_gib``; DataError if malformed or over it."""
    max_bytes = int(max_gib * 2**30)
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path} does not exist")
    if path.suffix in (".h5", ".hdf5"):
        cols, lengths, offsets, meta = _read_h5(path, max_bytes, select)
    elif str(path).rstrip("/").endswith(".lance"):
        from .require import stable_worldmodel

        cols, lengths, offsets, meta = _read_lance(path, stable_worldmodel(), max_bytes, select)
    else:
        raise DataError(f"{path}: expected an swm .h5/.hdf5 file or a .lance table")
    rows = {len(a) for a in cols.values()}
    if len(rows) > 1:
        raise DataError(f"{path}: columns have different numbers of rows {sorted(rows)}")
    lengths, offsets = _checked_index(lengths, offsets, rows.pop() if rows else 0, str(path))
    return cols, lengths, offsets, meta


# ---------------------------------------------------------------------- import: to a store
def _pixels_to_frames(pixels: np.ndarray, where: str) -> tuple[np.ndarray, str]:
    if pixels.dtype != np.uint8 or pixels.ndim != 4 or pixels.shape[-1] != 3:
        raise DataError(f"{where}: pixels must be (rows, H, W, 3) uint8, got {pixels.shape} {pixels.dtype}")
    if (pixels[..., 1] == pixels[..., 0]).all() and (pixels[..., 2] == pixels[..., 0]).all():
        return pixels[..., 0], "channel0"  # PokeWorld renders gray in all three channels
    luma = pixels.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    return np.clip(np.rint(luma), 0, 255).astype(np.uint8), "luma"  # e.g. JPEG-decoded (Lance) frames


def _episode_length(lengths: np.ndarray, steps: int) -> int:
    """Observations per imported episode: ``steps + 1``, or the commonest episode length when ``steps`` is 0."""
    if steps:
        return steps + 1
    counts = Counter(lengths.tolist())
    return max(counts, key=lambda n: (counts[n], n))


def _check_gather(cols: dict, E: int, T1: int, cfg: ImportConfig) -> None:
    """Refuse, before anything is copied, a gather of ``E`` episodes x ``T1`` rows of ``cols`` (and its row index)
    past ``cfg.max_gib``. :func:`_checked_index` already keeps it within the stored rows; this bounds what the
    import itself allocates whoever built the columns."""
    row_bytes = sum(v.dtype.itemsize * int(np.prod(v.shape[1:], dtype=np.int64)) for v in cols.values()) + 8
    need, allowed = E * T1 * row_bytes, int(cfg.max_gib * 2**30)
    if need > allowed:
        raise DataError(f"{cfg.source}: gathering {E} episodes x {T1} rows needs {need / 2**30:.3g} GiB, over the "
                        f"allowed {cfg.max_gib:g} GiB; if the file is trusted and the memory is there, raise "
                        "--max-gib")


def _gather(cols: dict, lengths: np.ndarray, offsets: np.ndarray, keep: np.ndarray, T1: int) -> dict:
    rows = (offsets[keep][:, None] + np.arange(T1)[None]).reshape(-1)
    E = int(keep.size)
    return {k: v[rows].reshape(E, T1, *v.shape[1:]) for k, v in cols.items()}


def to_store(cols: dict, lengths: np.ndarray, offsets: np.ndarray, meta: dict, cfg: ImportConfig) -> Dataset:
    """An in-memory pokeworld :class:`Dataset` from swm columns (see the module docstring for the mapping)."""
    where = cfg.source
    missing = [k for k in (*STEP_COLUMNS, "action") if k not in cols]
    if missing:
        raise DataError(f"{where}: not a PokeWorld dataset, missing columns {missing}")
    T1 = _episode_length(lengths, cfg.steps)
    keep = np.flatnonzero(lengths >= T1)
    if T1 < 2 or keep.size == 0:
        raise DataError(f"{where}: no episode has {T1} observations ({T1 - 1} steps); episode lengths "
                        f"{sorted(set(lengths.tolist()))}")
    labels = meta.get("labels", [k for k in LABEL_COLUMNS if k in cols])
    params = meta.get("params", [k for k in PARAM_NAMES if k in cols])
    wanted = [*STEP_COLUMNS, "action", *labels, *params, *(["split"] if "split" in cols else [])]
    absent = [k for k in wanted if k not in cols]
    if absent:
        raise DataError(f"{where}: columns {absent} named in its pokeworld record are missing")
    _check_gather({k: cols[k] for k in wanted}, int(keep.size), T1, cfg)
    ep = _gather({k: cols[k] for k in wanted}, lengths, offsets, keep, T1)
    frames, how = _pixels_to_frames(ep["pixels"].reshape(-1, *ep["pixels"].shape[2:]), where)
    E = keep.size
    per_episode = {}
    for name in [*params, *(["split"] if "split" in ep else [])]:
        v = ep[name]
        if v.ndim != 2 or not (v == v[:, :1]).all():
            raise DataError(f"{where}: column {name!r} is not constant within episodes; not a per-episode value")
        per_episode[name] = v[:, 0]
    if "split" in per_episode:
        split = per_episode.pop("split")
        if split.dtype.kind not in "iu" or not np.isin(split, list(SPLITS.values())).all():
            raise DataError(f"{where}: split column holds values outside {sorted(SPLITS.values())}")
        split = split.astype(np.int8)
    else:
        split = assign_splits(E, tuple(cfg.split_fractions), np.random.default_rng(cfg.seed))
    if not meta:  # a World-collected dataset: derive the log-parameters the probes read, as generate does
        per_episode = {k: v.astype(np.float32) for k, v in per_episode.items()}
        for src, dst in (("mass", "log_m"), ("stiffness", "log_k")):
            if src in per_episode and (per_episode[src] > 0).all():
                per_episode[dst] = np.log(per_episode[src]).astype(np.float32)
    step = lambda k: ep[k] if meta else ep[k].astype(np.float32)  # noqa: E731
    manifest = {"kind": "swm-import", "source": str(cfg.source), "frames_from_pixels": how,
                "swm_episodes": int(lengths.size), "dropped_short_episodes": int(lengths.size - E),
                "source_manifest": meta.get("source_manifest")}
    return Dataset(frames=frames.reshape(E, T1, *frames.shape[1:]), proprio=step("proprio"), touch=step("touch"),
                   actions=step("action")[:, :-1], labels={k: step(k) for k in labels}, params=per_episode,
                   split=split, manifest=manifest)


def import_dataset(cfg: ImportConfig) -> Dataset:
    """Read ``cfg.source`` (swm HDF5 or Lance) into a validated in-memory pokeworld Dataset."""
    cols, lengths, offsets, meta = read_swm(cfg.source, cfg.max_gib)
    return to_store(cols, lengths, offsets, meta, cfg)


# ---------------------------------------------------------------------- configs / CLI
@dataclass
class ExportConfig:
    """Export a pokeworld store to stable-worldmodel's HDF5 dataset format (``pokeworld swm-export STORE OUT``)."""

    store: str = ""
    """pokeworld store directory (data.h5 + manifest.json) to export."""
    out: str = "out/swm/pokeworld.h5"
    """Output .h5 file (swm's HDF5 format; written atomically)."""
    overwrite: bool = False
    """Replace an existing output file."""


@dataclass
class ImportConfig:
    """Import a stable-worldmodel PokeWorld dataset into a pokeworld store (``pokeworld swm-import SWMDATA OUT``)."""

    source: str = ""
    """swm dataset: an .h5/.hdf5 file (exact) or a .lance table (frames come back JPEG-decoded)."""
    out: str = "out/swm/store"
    """Output pokeworld store directory (written atomically)."""
    steps: int = 0
    """Control steps per imported episode (a store has one length): longer episodes are cut, shorter dropped;
    0 takes the commonest episode length (World's truncation length)."""
    split_fractions: tuple[float, float, float] = (0.6, 0.2, 0.2)
    """Train / probe-fit / probe-test fractions, for sources without a split column (World-collected data)."""
    seed: int = 0
    """Seed of that split assignment."""
    overwrite: bool = False
    """Replace an existing output store."""
    max_gib: float = DEFAULT_MAX_GIB
    """Budget for the total bytes the columns the import reads declare (GiB), checked before any is read."""

    def __post_init__(self) -> None:
        if self.steps < 0:
            raise ConfigError(f"steps must be >= 0, got {self.steps}")
        if not self.max_gib > 0:
            raise ConfigError(f"max_gib must be > 0, got {self.max_gib}")


def _refuse_existing(out: Path, overwrite: bool) -> None:
    if os.path.lexists(out) and not overwrite:
        raise ConfigError(f"{out} exists; pass --overwrite or choose another --out")


def check_export_destination(out: Path, overwrite: bool) -> None:
    """Raise ConfigError, before the store is loaded and converted, unless :func:`export_store` may write ``out``:
    an .h5/.hdf5 name, absent or (with ``overwrite``) a regular file pokeworld wrote, in a writable folder."""
    if out.suffix not in (".h5", ".hdf5"):
        raise ConfigError(f"the swm HDF5 format needs a .h5 or .hdf5 file name, got {out}")
    _refuse_existing(out, overwrite)
    if out.is_dir() and not out.is_symlink():
        raise ConfigError(f"--out {out} is a folder, not a regular file; choose a file path for the export")
    check_outputs(out.parent, out.name)  # no link, no special file, never a file pokeworld did not write


def run_export(cfg: ExportConfig) -> Path:
    """Load ``cfg.store`` (hash-verified) and write it as swm HDF5 to ``cfg.out``."""
    if not cfg.store:
        raise ConfigError("swm-export needs the store to export")
    out = Path(cfg.out)
    check_export_destination(out, cfg.overwrite)
    ds = load(cfg.store)
    export_store(ds, out)
    print(f"[swm-export] wrote {ds.num_episodes} episodes x {ds.num_steps + 1} rows to {out} "
          f"(columns: pixels, proprio, touch, action, {len(ds.labels)} labels, {len(ds.params)} params)")
    return out


def run_import(cfg: ImportConfig) -> Path:
    """Import ``cfg.source`` and save it as a pokeworld store at ``cfg.out``."""
    if not cfg.source:
        raise ConfigError("swm-import needs the swm dataset to import")
    out = Path(cfg.out)
    _refuse_existing(out, cfg.overwrite)
    check_store_destination(out, None)  # a folder save would refuse is refused before the file is read
    check_writable_dir(out.parent)
    ds = import_dataset(cfg)
    save(ds, out)
    m = ds.manifest
    print(f"[swm-import] wrote {ds.num_episodes} episodes x {ds.num_steps} steps to {out} "
          f"({m['dropped_short_episodes']} shorter episodes dropped; splits {m['split_counts']})")
    return out


__all__ = [
    "ExportConfig",
    "ImportConfig",
    "check_export_destination",
    "export_columns",
    "export_store",
    "import_dataset",
    "read_swm",
    "wanted_columns",
    "run_export",
    "run_import",
    "to_store",
]
