"""Checkpoint files of a run directory (``ckpt.pt``, ``final.pt``, the flow sensor): written atomically, read
without executing code.

A run directory may come from someone else (a colleague's runs, a shared cluster folder), and ``torch.load``
without ``weights_only`` unpickles arbitrary objects: a crafted ``ckpt.pt`` runs code on the machine that
probes or resumes it. Every checkpoint here is therefore read with ``weights_only=True``, which admits tensors
and plain Python containers and numbers only, and everything a checkpoint holds that is not a tensor is stored
in those forms: the Python and NumPy RNG states become tuples and lists of ints (:func:`rng_state`).
"""

from __future__ import annotations

import os
import pickle
import random
import stat
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .errors import DataError
from .io import atomic_path


class CheckpointError(DataError):
    """A checkpoint that cannot be read safely: damaged, or holding objects a weights-only load refuses."""


def save(obj: Any, path: str | os.PathLike) -> None:
    """``torch.save`` to a temporary sibling, then rename: a killed writer never leaves a half-written file under
    ``path`` (readers see the old checkpoint or the new one)."""
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)  # into atomic_path's private temporary: the output contract


def load(path: str | os.PathLike, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read a checkpoint with ``weights_only=True``; :class:`CheckpointError` naming the file when it needs more
    (a pickled class or function: possibly code, never something pokeworld writes) or is damaged."""
    path = Path(path)
    try:
        # O_NONBLOCK: opening a FIFO planted under a checkpoint's name returns at once instead of waiting for a
        # writer, and fstat then refuses it
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise CheckpointError(f"checkpoint {path} does not exist") from None
    except OSError as e:
        raise CheckpointError(f"cannot open checkpoint {path} ({e.strerror})") from None
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise CheckpointError(f"checkpoint {path} is {file_kind(mode)}, not a regular file; remove it "
                              "(pokeworld reads checkpoints from regular files only)")
    with os.fdopen(fd, "rb") as fh:
        check_records(fh, path)
        fh.seek(0)
        ck = _load_weights(fh, path, map_location)
    if not isinstance(ck, dict):
        raise CheckpointError(f"checkpoint {path} holds a {type(ck).__name__}, expected a dict")
    check_tensors(ck, path)
    return ck


MAX_RECORDS = 100_000
"""Most records a checkpoint's zip may hold (one per tensor storage, plus a few: a paper checkpoint holds ~500)."""


def check_records(fh, path: Path) -> None:
    """Refuse, before ``torch.load`` reads anything, a checkpoint that is not the zip ``torch.save`` writes: every
    record stored uncompressed (torch never compresses; a DEFLATE record can inflate a megabyte into a gigabyte),
    its stored size its size, inside the file, at most :data:`MAX_RECORDS` records."""
    size = os.fstat(fh.fileno()).st_size
    try:
        with zipfile.ZipFile(fh) as zf:
            infos = zf.infolist()
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as e:
        raise CheckpointError(f"cannot read checkpoint {path} ({first_line(e)}); it is damaged or not a torch "
                              "checkpoint (torch.save writes a zip archive)") from None
    if len(infos) > MAX_RECORDS:
        raise CheckpointError(f"checkpoint {path} holds {len(infos)} records, more than {MAX_RECORDS}; refused")
    for info in infos:
        if info.compress_type != zipfile.ZIP_STORED or info.compress_size != info.file_size \
                or info.header_offset + info.file_size > size:
            raise CheckpointError(f"checkpoint {path}: record {info.filename[:80]!r} is compressed or declares "
                                  f"{info.file_size} bytes in a {size}-byte file; torch.save writes records "
                                  "stored as they are, so this one was crafted or damaged: refused before reading")


def tensors_in(obj: Any, where: str = "", depth: int = 0):
    """(key path, tensor) of every tensor in a loaded checkpoint (dicts, lists and tuples walked; at most 64 levels
    deep)."""
    if isinstance(obj, torch.Tensor):
        yield where, obj
    elif depth < 64 and isinstance(obj, dict):
        for k, v in obj.items():
            yield from tensors_in(v, f"{where}.{str(k)[:60]}" if where else str(k)[:60], depth + 1)
    elif depth < 64 and isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            yield from tensors_in(v, f"{where}[{i}]", depth + 1)


def check_tensors(ck: Any, path: Path) -> None:
    """Every tensor of ``ck`` against its storage, before anything converts or copies it: no more elements than
    its storage holds, no zero stride on a dimension of more than one element (a view that repeats one stored
    number: converting it would allocate its whole declared size)."""
    for where, t in tensors_in(ck):
        if t.numel() > 1 and (any(s == 0 and n > 1 for s, n in zip(t.stride(), t.shape))
                              or t.numel() * t.element_size() > t.untyped_storage().nbytes()):
            raise CheckpointError(f"checkpoint {path}: {where} declares {t.numel()} elements but stores "
                                  f"{t.untyped_storage().nbytes()} bytes, repeating them (shape "
                                  f"{list(t.shape)[:6]}, stride {list(t.stride())[:6]}); torch.save writes no such "
                                  "view: the checkpoint was crafted, refused")


def file_kind(mode: int) -> str:
    """What ``os.stat``'s ``st_mode`` describes, for an error message: 'a directory', 'a FIFO', ..."""
    for test, kind in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISLNK, "a symbolic link")):
        if test(mode):
            return kind
    return "a regular file" if stat.S_ISREG(mode) else "a special file"


def _load_weights(fh, path: Path, map_location: str | torch.device) -> Any:
    """``torch.load(weights_only=True)`` of an open checkpoint file, its failures as one-line CheckpointErrors."""
    try:
        return torch.load(fh, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as e:
        first = first_line(e)
        raise CheckpointError(
            f"refusing to load {path}: it holds objects other than tensors and plain containers ({first}). "
            "pokeworld never writes such checkpoints; loading it could execute code. If you made it yourself "
            "with an older pokeworld, re-train the run (pokeworld will not unpickle arbitrary objects, whatever "
            "its origin)") from None
    # truncated zip, bad magic, short read; a flipped byte inside the pickle makes the weights-only unpickler fail
    # with whatever its opcode handler hits (KeyError of a memo index, IndexError, struct.error, TypeError...)
    except Exception as e:  # noqa: BLE001 - every one of them means a damaged file
        raise CheckpointError(f"cannot read checkpoint {path} ({type(e).__name__}: {first_line(e)}); it is damaged "
                              "or not a torch checkpoint") from None


def first_line(error: BaseException) -> str:
    """An exception's message cut to its first line (torch's run to pages), for a one-line error."""
    text = str(error).strip()
    return text.splitlines()[0][:300] if text else type(error).__name__


def rng_state() -> dict[str, Any]:
    """Python, NumPy, torch (and CUDA) RNG states in forms a weights-only load admits."""
    name, keys, pos, has_gauss, gauss = np.random.get_state()
    st: dict[str, Any] = {
        "python": random.getstate(),  # (version, tuple of 625 ints, gauss_next): plain Python already
        "numpy": {"name": str(name), "keys": [int(k) for k in keys], "pos": int(pos), "has_gauss": int(has_gauss),
                  "cached_gaussian": float(gauss)},
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available():
        st["cuda"] = torch.cuda.get_rng_state_all()
    return st


def set_rng_state(st: dict[str, Any]) -> None:
    """Restore what :func:`rng_state` saved."""
    version, internal, gauss_next = st["python"]
    random.setstate((int(version), tuple(int(x) for x in internal), gauss_next))
    npst = st["numpy"]
    np.random.set_state((npst["name"], np.asarray(npst["keys"], dtype=np.uint32), npst["pos"], npst["has_gauss"],
                         npst["cached_gaussian"]))
    torch.set_rng_state(st["torch"])
    if "cuda" in st and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(st["cuda"])


__all__ = ["CheckpointError", "MAX_RECORDS", "check_records", "check_tensors", "tensors_in", "save", "load",
           "file_kind", "first_line", "rng_state", "set_rng_state"]
