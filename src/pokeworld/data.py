"""The on-disk dataset format shared by simulator corpora and converted RH20T data.

A dataset is a directory holding ``data.h5`` (chunked HDF5) and
``manifest.json``. Arrays, with E episodes of T control steps:

=================  =====================  ===========================================
name               shape / dtype          meaning
=================  =====================  ===========================================
frames             (E, T+1, H, W) uint8   grayscale observation before each step
proprio            (E, T+1, Dp) float32   proprioception at each observation
touch              (E, T+1, Dt) float32   touch / force summarising the step that ended
                                          at this observation (zeros at t = 0)
actions            (E, T, Da) float32     action applied between obs t and t+1
labels/<name>      (E, T+1, ...) float32  privileged per-step labels (object state...)
params/<name>      (E,) float32           per-episode hidden parameters / metadata
split              (E,) int8              0 train, 1 probe-fit, 2 probe-test, 3 held-out
=================  =====================  ===========================================

The manifest records the generator config, seed, format version and a content
hash over all arrays; :func:`load` re-hashes and refuses a store whose bytes do
not match, so a truncated or edited file is never silently used.

A store folder may come from anyone, so :func:`load` reads nothing it has not checked first: ``data.h5`` and
``manifest.json`` must be regular files (a FIFO would hang the reader); every dataset must be stored in the file
itself (no external, soft or virtual links, no external storage) with a real numeric dtype, the shape the
manifest declares and a plausible stored size, and all of them within :data:`MAX_STORE_BYTES`. Writers go
through :func:`check_store_destination` and :func:`store_lock`: pokeworld replaces only a folder it can verify
as a store of its own (:data:`STORE_FILES`), and two writers of one store are refused.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import stat
from pathlib import Path
from typing import Any, Iterator

import h5py
import numpy as np

from .config import MAX_STORE_BYTES, apply_overrides
from .errors import ConfigError, DataError
from .io import OwnedDir, atomic_path, check_owned_dir, check_regular_file, dir_lock, hash_arrays, read_json, write_json
from .sim.core import PhysicsConfig
from .sim.generate_config import generator_config

FORMAT_VERSION = 1
SPLITS = {"train": 0, "probe_fit": 1, "probe_test": 2, "heldout": 3}
STREAMS = ("frames", "proprio", "touch", "actions")
STORE_FILES = (r"data\.h5", r"manifest\.json", r"conversion_report\.json", r"certificates\.json",
               r"certificate_fit_curve\.json")
"""Patterns of the files pokeworld writes in a store folder: the store, an RH20T conversion's report, and what
``pokeworld certify`` and ``certificate-curve`` write beside it; ``certificate_corpus/n<episodes>/`` holds the
certificate corpora (stores themselves, with their ``.n<episodes>.lock``). A folder holding anything else is
not one pokeworld may replace (:func:`check_store_destination`)."""
# certificate_corpus.FOLDER (not imported: certificate_corpus imports the generator, which imports this module)
_CERTIFICATE_CORPORA = OwnedDir(files=(r"\.n\d+\.lock",), dirs=((r"n\d+", OwnedDir(files=STORE_FILES)),))
MAX_MANIFEST_BYTES = 16 << 20
"""A manifest is JSON metadata: a generated store's is about 2 KB; an RH20T store's lists every scene (about 1 KB
each, 4,258 in the largest configuration: a few MB). More is not a manifest, and parsing costs many times a file's
size in memory."""
MAX_EXPANSION = 1100
"""Most a dataset may expand over the bytes it stores (deflate cannot exceed about 1032:1): a declared shape far
beyond what the file holds is a forged or damaged header whose read would only return fill values."""
REAL_NUMERIC_KINDS = "biuf"
"""numpy dtype kinds a stream may have: bool, integers, floats. Complex, object, string, datetime and compound
arrays are refused (a complex NaN would slip past a float-only finite check)."""


@dataclasses.dataclass
class Dataset:
    """In-memory dataset; see module docstring for the array layout."""

    frames: np.ndarray
    proprio: np.ndarray
    touch: np.ndarray
    actions: np.ndarray
    labels: dict[str, np.ndarray]
    params: dict[str, np.ndarray]
    split: np.ndarray
    manifest: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        validate(self)

    @property
    def num_episodes(self) -> int:
        return int(self.frames.shape[0])

    @property
    def num_steps(self) -> int:
        """Control steps per episode (observations are one more)."""
        return int(self.actions.shape[1])

    def episodes(self, split: str) -> np.ndarray:
        """Indices of the episodes in ``split`` (a key of :data:`SPLITS`)."""
        if split not in SPLITS:
            raise DataError(f"unknown split {split!r}; known: {sorted(SPLITS)}")
        return np.flatnonzero(self.split == SPLITS[split])

    def subset(self, idx: np.ndarray) -> "Dataset":
        """Episodes ``idx`` as a new Dataset (arrays are copies)."""
        idx = np.asarray(idx)
        return Dataset(
            frames=self.frames[idx], proprio=self.proprio[idx], touch=self.touch[idx],
            actions=self.actions[idx],
            labels={k: v[idx] for k, v in self.labels.items()},
            params={k: v[idx] for k, v in self.params.items()},
            split=self.split[idx], manifest=dict(self.manifest),
        )

    def arrays(self) -> dict[str, np.ndarray]:
        out = {name: getattr(self, name) for name in STREAMS}
        out.update({f"labels/{k}": v for k, v in self.labels.items()})
        out.update({f"params/{k}": v for k, v in self.params.items()})
        out["split"] = self.split
        return out


def validate(ds: Dataset) -> None:
    """Raise :class:`DataError` on inconsistent shapes, non-real dtypes or non-finite values."""
    if ds.frames.ndim != 4 or ds.frames.dtype != np.uint8:
        raise DataError(f"frames must be (E, T+1, H, W) uint8, got {ds.frames.shape} {ds.frames.dtype}")
    E, T1 = ds.frames.shape[:2]
    if E == 0:
        raise DataError("dataset has no episodes")
    for name in ("proprio", "touch"):
        a = getattr(ds, name)
        if a.ndim != 3 or a.shape[:2] != (E, T1):
            raise DataError(f"{name} must be (E={E}, T+1={T1}, D), got {a.shape}")
    if ds.actions.ndim != 3 or ds.actions.shape[:2] != (E, T1 - 1):
        raise DataError(f"actions must be (E={E}, T={T1 - 1}, Da), got {ds.actions.shape}")
    for name, a in ds.labels.items():
        if a.shape[:2] != (E, T1):
            raise DataError(f"labels/{name} must start with (E={E}, T+1={T1}), got {a.shape}")
    for name, a in ds.params.items():
        if a.shape != (E,):
            raise DataError(f"params/{name} must be (E={E},), got {a.shape}")
    if ds.split.shape != (E,):
        raise DataError(f"split must be (E={E},), got {ds.split.shape}")
    for name, a in ds.arrays().items():
        if a.dtype.kind not in REAL_NUMERIC_KINDS:
            raise DataError(f"{name} has dtype {a.dtype}; streams, labels and params must be real numbers "
                            "(bool, integer or float)")
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            bad = int((~np.isfinite(a)).sum())
            raise DataError(f"{name} contains {bad} non-finite values (NaN/inf); refusing to use it")


def save(ds: Dataset, out_dir: str | os.PathLike, manifest: dict[str, Any] | None = None) -> Path:
    """Write ``ds`` to ``out_dir`` atomically (temporary directory, then rename).

    An existing ``out_dir`` is replaced only if it is empty or a store pokeworld can verify as its own
    (:data:`STORE_FILES` only, and a parseable manifest if it holds data); anything else raises ConfigError.
    """
    out_dir = Path(out_dir)
    arrays = ds.arrays()
    man = dict(ds.manifest)
    man.update(manifest or {})
    man["format_version"] = FORMAT_VERSION
    man["content_sha256"] = hash_arrays(arrays)
    man["num_episodes"] = ds.num_episodes
    man["num_steps"] = ds.num_steps
    man["frame_shape"] = list(ds.frames.shape[2:])
    man["split_counts"] = {k: int((ds.split == v).sum()) for k, v in SPLITS.items()}
    with atomic_path(out_dir, replace=_owned_store(None)) as tmp:
        tmp.mkdir(parents=True)
        # HDF5 is built in memory (compressed, a fraction of the arrays already held) and written by Python: a
        # full disk or a file-size limit is then an OSError here, which atomic_path turns into one line, instead of
        # a failed write inside the HDF5 library, which crashed the interpreter on its way out
        image = io.BytesIO()
        with h5py.File(image, "w", track_order=True) as f:
            for name, a in arrays.items():
                # one chunk per episode, deflate level 1; not LZF: h5py's LZF leaves its hash table
                # uninitialised, so the same array can compress to different bytes from run to run
                per_episode = {"chunks": (1,) + a.shape[1:], "compression": "gzip", "compression_opts": 1}
                chunked = a.ndim >= 2 and a.size > 0  # a width-0 stream (no touch) has no chunk to compress
                f.create_dataset(name, data=a, track_times=False, **(per_episode if chunked else {}))
        with open(tmp / "data.h5", "xb") as fh:  # a new file in our private temporary folder
            fh.write(image.getbuffer())
        del image
        write_json(tmp / "manifest.json", man)
    ds.manifest = man
    return out_dir


def _manifest_json(mf: Path) -> dict[str, Any]:
    """The parsed ``manifest.json`` at ``mf`` (a regular file of bounded size holding a JSON object)."""
    return read_json(mf, "a store manifest", dict, MAX_MANIFEST_BYTES)


def check_manifest_config(manifest: dict[str, Any], where: str | os.PathLike) -> None:
    """DataError (one line naming ``where`` and the field) unless the manifest's generator config is one its
    generator could have written. It is read back as settings (the certificate corpus regenerates from it; stats,
    certify and the probes read its physics) but no content hash covers it, so it is checked like a command
    line: types, finite, ranges (:func:`pokeworld.config.check_fields`) before anything uses it."""
    if "config" not in manifest:
        return
    if manifest.get("generator") == "pokeworld.sim.generate":
        generator_config(manifest, str(where))
        return
    config = manifest["config"]
    physics = config.get("physics", {}) if isinstance(config, dict) else None
    try:
        if not isinstance(physics, dict):
            raise ConfigError(f"its config must be a JSON object and its physics one too, got {config!r:.60}")
        apply_overrides(PhysicsConfig(), physics)
    except ConfigError as e:
        problem = str(e).replace("PhysicsConfig.", "config.physics.", 1)  # the field as the manifest spells it
        raise DataError(f"{where}: {problem}; the store's manifest is damaged or not pokeworld's: regenerate the "
                        "store") from None


def read_manifest(path: str | os.PathLike) -> dict[str, Any]:
    """A dataset directory's manifest (content hash, config, splits) without reading the arrays: what a
    cache check needs before deciding whether to load the store at all."""
    path = Path(path)
    h5, mf = path / "data.h5", path / "manifest.json"
    if not path.is_dir():
        if os.path.lexists(path):
            raise DataError(f"{path} is a file, not a dataset folder (a folder holding data.h5 and manifest.json, as "
                            "`pokeworld generate` writes); name the dataset folder")
        raise DataError(f"dataset directory {path} does not exist (generate it with `pokeworld generate`)")
    if not os.path.lexists(h5) or not os.path.lexists(mf):
        raise DataError(f"{path} is not a pokeworld dataset: expected data.h5 and manifest.json")
    check_regular_file(h5, "a store's data.h5")
    manifest = _manifest_json(mf)
    if manifest.get("format_version") != FORMAT_VERSION:
        raise DataError(f"{path}: format version {manifest.get('format_version')} != supported {FORMAT_VERSION}")
    check_manifest_config(manifest, mf)
    return manifest


def _declared_layout(manifest: dict[str, Any], where: Path) -> tuple[int, int, tuple[int, int]]:
    """(episodes E, steps T, frame shape) the manifest declares, each a positive int."""
    E, T, fs = manifest.get("num_episodes"), manifest.get("num_steps"), manifest.get("frame_shape")
    ok = lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1  # noqa: E731
    if not (ok(E) and ok(T) and isinstance(fs, list) and len(fs) == 2 and all(map(ok, fs))):
        raise DataError(f"{where}: manifest declares num_episodes={E!r}, num_steps={T!r}, frame_shape={fs!r}; "
                        "expected positive integers and [H, W]; the store is corrupt")
    return E, T, (fs[0], fs[1])


def _stored_nodes(f: h5py.File, h5: Path) -> dict[str, h5py.Dataset]:
    """The store's datasets by array name, each checked to be a dataset kept inside this file."""
    missing = [n for n in (*STREAMS, "split") if n not in f]
    if missing:
        raise DataError(f"{h5} lacks datasets {missing}; the store is incomplete")

    def own(group: h5py.Group, name: str, where: str, want: type) -> Any:
        if not isinstance(group.get(name, getlink=True), h5py.HardLink):
            raise DataError(f"{h5}: {where!r} is a link to elsewhere; a store holds its own arrays")
        node = group[name]
        if not isinstance(node, want):
            raise DataError(f"{h5}: {where!r} is not a {'dataset' if want is h5py.Dataset else 'group'}")
        if want is h5py.Dataset and (node.is_virtual or node.external):
            raise DataError(f"{h5}: {where!r} keeps its data outside the file (external storage or a virtual "
                            "dataset); a store holds its own arrays")
        return node

    nodes = {n: own(f, n, n, h5py.Dataset) for n in (*STREAMS, "split")}
    for group_name in ("labels", "params"):
        if group_name in f:
            group = own(f, group_name, group_name, h5py.Group)
            nodes.update({f"{group_name}/{k}": own(group, k, f"{group_name}/{k}", h5py.Dataset) for k in group})
    return nodes


# HDF5 filters a store may use: pokeworld writes deflate; LZF (h5py's own) in stores of older versions
_ALLOWED_FILTERS = {h5py.h5z.FILTER_DEFLATE: "gzip", h5py.h5z.FILTER_SHUFFLE: "shuffle",
                    h5py.h5z.FILTER_FLETCHER32: "fletcher32", 32000: "lzf"}


def _check_storage(node: h5py.Dataset, name: str, nbytes: int, h5: Path) -> None:
    """Refuse filters we do not write, chunks larger than the array, and declared sizes the stored bytes cannot
    hold (checked from the header only)."""
    plist = node.id.get_create_plist()
    for i in range(plist.get_nfilters()):
        code = plist.get_filter(i)[0]
        if code not in _ALLOWED_FILTERS:
            raise DataError(f"{h5}: {name!r} uses HDF5 filter {code}; a store uses only "
                            f"{sorted(_ALLOWED_FILTERS.values())}")
    if node.chunks is not None:
        chunk_bytes = int(np.prod(node.chunks, dtype=np.int64)) * node.dtype.itemsize
        if chunk_bytes > max(nbytes, 1 << 20):
            raise DataError(f"{h5}: {name!r} declares chunks {node.chunks} ({chunk_bytes} bytes) larger than "
                            f"the array itself ({nbytes} bytes); the store is corrupt")
    stored = node.id.get_storage_size()
    if nbytes > MAX_EXPANSION * stored + (1 << 16):
        raise DataError(f"{h5}: {name!r} declares {node.shape} {node.dtype} ({nbytes} bytes) but the file stores "
                        f"only {stored} bytes of it (at most {MAX_EXPANSION}x expansion allowed); the header is "
                        "forged or the data missing")


def _check_declared(nodes: dict[str, h5py.Dataset], manifest: dict[str, Any], h5: Path) -> None:
    """Each dataset's declared shape and dtype against the manifest and the byte budget, before any read."""
    E, T, (H, W) = _declared_layout(manifest, h5)
    total = 0
    for name, node in nodes.items():
        shape, dtype = tuple(node.shape), node.dtype
        lead = {"frames": (E, T + 1, H, W), "actions": (E, T), "split": (E,)}.get(name, (E, T + 1))
        if name.startswith("params/"):
            lead = (E,)
        exact = name in ("frames", "split") or name.startswith("params/")
        ndim_ok = len(shape) == 3 if name in ("proprio", "touch", "actions") else True
        if (shape != lead if exact else shape[:len(lead)] != lead) or not ndim_ok:
            want = f"{lead}" if exact else f"({', '.join(map(str, lead))}, ...)"
            raise DataError(f"{h5}: {name!r} declares shape {shape}, the manifest implies {want} (num_episodes={E}, "
                            f"num_steps={T}, frame_shape=[{H}, {W}]); the store is corrupt")
        if (name == "frames" and dtype != np.uint8) or dtype.kind not in REAL_NUMERIC_KINDS \
                or (name == "split" and dtype.kind not in "iu"):
            allowed = {"frames": "uint8", "split": "an integer dtype"}.get(name, "bool, integer or float")
            raise DataError(f"{h5}: {name!r} declares dtype {dtype}; allowed: {allowed}")
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        _check_storage(node, name, nbytes, h5)
        total += nbytes
    if total > MAX_STORE_BYTES:
        raise DataError(f"{h5}: its arrays declare {_size(total)} in all (frames {nodes['frames'].shape}); a store "
                        f"may hold at most {_size(MAX_STORE_BYTES)} (data.MAX_STORE_BYTES)")


def _size(nbytes: int) -> str:
    for unit, shift in (("GiB", 30), ("MiB", 20), ("KiB", 10)):
        if nbytes >= 1 << shift:
            return f"{nbytes / (1 << shift):.1f} {unit}"
    return f"{nbytes} bytes"


@contextlib.contextmanager
def checked_nodes(path: Path, manifest: dict[str, Any]) -> Iterator[dict[str, h5py.Dataset]]:
    """The store's datasets, open, each checked against ``manifest`` before any array is read (see the module
    docstring); an unreadable file is one DataError line."""
    h5 = path / "data.h5"
    try:
        with h5py.File(h5, "r") as f:
            nodes = _stored_nodes(f, h5)
            _check_declared(nodes, manifest, h5)
            yield nodes
    except DataError:
        raise
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as e:
        raise DataError(f"cannot read {h5}: {e}. The file is truncated or corrupt; regenerate it") from None


def load(path: str | os.PathLike, verify: bool = True) -> Dataset:
    """Load a dataset directory, checking presence, structure and (by default) the content hash.

    Every dataset's link type, storage, shape, dtype and size are checked against the manifest before any array
    is read (see the module docstring).
    """
    path = Path(path)
    manifest = read_manifest(path)
    with checked_nodes(path, manifest) as nodes:
        arrays = {n: node[()] for n, node in nodes.items()}
    labels = {n.removeprefix("labels/"): a for n, a in arrays.items() if n.startswith("labels/")}
    params = {n.removeprefix("params/"): a for n, a in arrays.items() if n.startswith("params/")}
    ds = Dataset(labels=labels, params=params, manifest=manifest, **{n: arrays[n] for n in (*STREAMS, "split")})
    if verify:
        digest = hash_arrays(ds.arrays())
        if digest != manifest.get("content_sha256"):
            raise DataError(f"{path}: content hash mismatch (manifest {manifest.get('content_sha256')!s:.12}, "
                            f"data {digest:.12}); the store was modified or is corrupt")
    return ds


def stream_shapes(path: str | os.PathLike) -> dict[str, tuple[int, ...]]:
    """The shapes of a store's streams (frames (E, T+1, H, W), proprio, touch (E, T+1, D), actions (E, T, Da)) from
    its file's header, checked as :func:`load` checks them, without reading any array: what a command compares a
    model's inputs with before it loads the store or does any work."""
    with checked_nodes(Path(path), read_manifest(path)) as nodes:
        return {n: tuple(nodes[n].shape) for n in STREAMS}


def is_complete(path: str | os.PathLike) -> bool:
    """True when ``path`` holds a finished dataset (used to skip regeneration)."""
    path = Path(path)
    return (path / "data.h5").exists() and (path / "manifest.json").exists()


def store_is_current(path: str | os.PathLike, content_config: dict, overwrite: bool = False) -> bool:
    """True when ``path`` already holds an intact store built from ``content_config`` (so the caller skips work).

    False when there is no complete store or ``overwrite`` is set; raises ConfigError when a store
    built from a *different* config is there, so nothing is silently replaced, and DataError naming
    ``--overwrite`` when the store's content does not verify (it is loaded and re-hashed before a skip).
    """
    if overwrite or not is_complete(path):
        return False
    if read_manifest(path).get("config") != content_config:
        raise ConfigError(f"{path} holds a store built with a different config; pass --overwrite or choose another "
                          "--out")
    try:
        load(path, verify=True)
    except DataError as e:
        raise DataError(f"{path} holds this config's store but it is damaged ({e}); pass --overwrite to rebuild "
                        "it") from None
    return True


def _verify_store_folder(kind: str | None, out: Path) -> None:
    """Raise ConfigError unless ``out`` (holding only :data:`STORE_FILES`) is a store pokeworld can verify as its
    own: no data, or a manifest that parses and (if ``kind`` is given) names that kind."""
    if not os.path.lexists(out / "manifest.json"):
        if os.path.lexists(out / "data.h5"):
            raise ConfigError(f"{out} holds data.h5 without manifest.json, so pokeworld cannot tell that it wrote "
                              "it; move or delete it yourself, or choose another --out")
        return  # empty, or only the report / temporary files of a run that wrote no store
    try:
        manifest = _manifest_json(out / "manifest.json")
    except DataError as e:
        raise ConfigError(f"{out} cannot be verified as a pokeworld store ({e}); pokeworld replaces only stores it "
                          "can verify: move or delete it yourself, or choose another --out") from None
    if kind is not None and manifest.get("kind") != kind:
        raise ConfigError(f"{out} holds a store of kind {manifest.get('kind')!r}, not {kind!r}; --overwrite "
                          "replaces only a store of the same kind: choose another --out")


def _owned_store(kind: str | None) -> OwnedDir:
    return OwnedDir(files=STORE_FILES, dirs=(("certificate_corpus", _CERTIFICATE_CORPORA),),
                    verify=lambda out: _verify_store_folder(kind, out))


def check_store_destination(out: str | os.PathLike, kind: str | None, owned: OwnedDir | None = None,
                            what: str = "--out") -> None:
    """Raise ConfigError, before any work, unless a store of ``kind`` may be written at ``out``: it does not
    exist, or is an empty folder, or a folder holding only a store pokeworld verifies as its own of that kind
    (:data:`STORE_FILES`, parseable manifest, same ``kind``; or what ``owned`` names, for a store with more files).
    Links, files and any other folder are refused: pokeworld never deletes what it did not create. Whether an own
    store is kept or replaced is :func:`store_is_current`'s decision (``--overwrite``). ``what`` names the path in
    the refusal (the flag or role it came from)."""
    out = Path(out)
    if out.name in ("", ".", ".."):
        raise ConfigError(f"{what} {str(out)!r} does not name a folder; give the store folder's path")
    try:
        mode = os.lstat(out).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return  # nothing there to protect; whether it can be created is check_writable_dir's question
    if stat.S_ISLNK(mode):
        raise ConfigError(f"{what} {out} is a symbolic link; pokeworld does not write stores through links: give "
                          "the real path")
    if not stat.S_ISDIR(mode):
        raise ConfigError(f"{what} {out} is an existing file, not a folder; choose a folder path for the store")
    check_owned_dir(out, owned or _owned_store(kind))


@contextlib.contextmanager
def store_lock(out: str | os.PathLike) -> Iterator[None]:
    """Hold the store folder ``out`` exclusively for the block (:func:`pokeworld.io.dir_lock`), so a second
    writer is refused with the holder's pid and command instead of silently replacing the first one's store.

    The lock file is ``.<name>.lock`` in the parent folder, beside the store: the store itself is replaced by a
    rename, so a lock inside it would go away with the old folder while its holder still writes.
    """
    out = Path(out)
    shown = str(out).replace("{", "{{").replace("}", "}}")
    refusal = f"{shown} is being written by {{holder}}; wait for it to finish or stop it, or choose another --out"
    with dir_lock(out.parent, f".{out.name}.lock", refusal):
        yield


def concatenate(datasets: list[Dataset], names: list[str] | None = None) -> Dataset:
    """One store from several with the same episode length, frame size and stream widths (e.g. two
    RH20T configurations for a configuration-blind model).

    Episodes keep their split. Labels and params present in every input (with equal trailing shapes)
    are kept, the rest dropped (``scene_index`` offset per input so scenes of different inputs stay distinct); ``params/source`` records the input index of every episode (for
    evaluation and bookkeeping only: the model never reads params). Streams are concatenated as stored,
    so each input keeps its own normalisation (converted RH20T stores are whitened with their own
    train statistics).
    """
    if len(datasets) < 2:
        raise DataError("concatenate needs at least two datasets")
    first = datasets[0]
    for i, ds in enumerate(datasets[1:], 1):
        for name in STREAMS:
            a, b = getattr(first, name), getattr(ds, name)
            if a.shape[1:] != b.shape[1:]:
                raise DataError(f"cannot concatenate: {name} of dataset {i} is {b.shape[1:]} per episode, "
                                f"dataset 0 has {a.shape[1:]} (same episode length, frame size and widths needed)")
    common = lambda attr: [k for k in getattr(first, attr)  # noqa: E731
                           if all(k in getattr(d, attr) and getattr(d, attr)[k].shape[1:] == getattr(first, attr)[k].shape[1:]
                                  for d in datasets)]
    cat = lambda arrs: np.concatenate(arrs, 0)  # noqa: E731
    params = {k: cat([d.params[k] for d in datasets]) for k in common("params") if k != "source"}
    params["source"] = cat([np.full(d.num_episodes, i, np.float32) for i, d in enumerate(datasets)])
    if "scene_index" in params:  # each input numbers its scenes from 0: offset them so scenes stay distinct
        offsets = np.cumsum([0] + [d.params["scene_index"].max() + 1 for d in datasets[:-1]])
        params["scene_index"] = cat([d.params["scene_index"] + o for d, o in zip(datasets, offsets)]).astype(
            params["scene_index"].dtype)
    manifest = {"kind": "concat", "sources": names or [str(i) for i in range(len(datasets))],
                "source_manifests": [{k: d.manifest.get(k) for k in ("kind", "robot", "content_sha256", "hz")}
                                     for d in datasets]}
    hz = {d.manifest.get("hz") for d in datasets}
    if len(hz) == 1:
        manifest["hz"] = hz.pop()
    return Dataset(frames=cat([d.frames for d in datasets]), proprio=cat([d.proprio for d in datasets]),
                   touch=cat([d.touch for d in datasets]), actions=cat([d.actions for d in datasets]),
                   labels={k: cat([d.labels[k] for d in datasets]) for k in common("labels")},
                   params=params, split=cat([d.split for d in datasets]), manifest=manifest)


def assign_splits(num_episodes: int, fractions: tuple[float, float, float], rng: np.random.Generator) -> np.ndarray:
    """Random disjoint train / probe-fit / probe-test assignment with the given fractions."""
    if len(fractions) != 3 or min(fractions) < 0 or abs(sum(fractions) - 1) > 1e-6:
        raise DataError(f"split fractions must be three non-negative numbers summing to 1, got {fractions}")
    counts = np.floor(np.asarray(fractions) * num_episodes).astype(int)
    counts[0] += num_episodes - counts.sum()
    split = np.repeat(np.arange(3, dtype=np.int8), counts)
    rng.shuffle(split)
    return split
