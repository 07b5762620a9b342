"""Small file helpers: atomic writes, JSON, content hashing."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .errors import ConfigError
from .faults import crash_point


@contextlib.contextmanager
def atomic_path(final: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary sibling path; rename it to ``final`` only if the block succeeds.

    Works for files and directories, so a crash never leaves a half-written
    artifact under the final name.
    """
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = final.with_name(f".{final.name}.tmp-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp) if tmp.is_dir() else tmp.unlink()
    try:
        yield tmp
        crash_point(f"rename:{final.name}")
        if final.exists() and final.is_dir() and tmp.is_dir():
            shutil.rmtree(final)
        os.replace(tmp, final)
    except BaseException:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True) if tmp.is_dir() else tmp.unlink()
        raise


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Atomically write ``obj`` as indented JSON."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, sort_keys=True, default=_json_default) + "\n")


def append_jsonl(path: str | os.PathLike, obj: Any) -> None:
    with open(path, "a") as fh:
        fh.write(json.dumps(obj, sort_keys=True, default=_json_default) + "\n")


def read_jsonl(path: str | os.PathLike) -> list[dict]:
    path = Path(path)
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if line:
            out.append(json.loads(line))
    return out


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


def hash_arrays(arrays: dict[str, np.ndarray]) -> str:
    """sha256 over names, dtypes, shapes and bytes, in sorted-name order."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(name.encode())
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def make_tmpdir(prefix: str = "pokeworld-") -> Path:
    return Path(tempfile.mkdtemp(prefix=prefix))


def lock_holder_line() -> str:
    """Who holds a lock, for the message a refused second writer prints: pid, host, start time and command."""
    import socket
    import sys
    import time

    started = time.strftime("%Y-%m-%d %H:%M:%S %Z", time.localtime())
    command = " ".join(Path(sys.argv[0]).name if i == 0 else a for i, a in enumerate(sys.argv)) if sys.argv else "?"
    return f"pid {os.getpid()} on {socket.gethostname()} since {started} (`{command}`)"


@contextlib.contextmanager
def dir_lock(directory: str | os.PathLike, lock_name: str, refusal: str, enabled: bool = True) -> Iterator[str]:
    """Hold an exclusive lock on ``directory/lock_name`` for the block; yields the previous holder's line when a
    stale lock (its process gone) was taken over, else "".

    The lock is the kernel's (``flock``): it goes away with the process that held it, so a crashed or killed
    holder never blocks the next one; the file only keeps :func:`lock_holder_line` of the last holder, which a
    refused second writer gets in its :class:`~pokeworld.errors.ConfigError` (``refusal`` formatted with
    ``path`` and ``holder``). No-op where ``fcntl`` is unavailable or ``enabled`` is False.
    """
    try:
        import fcntl
    except ImportError:  # not POSIX
        enabled = False
    if not enabled:
        yield ""
        return

    path = Path(directory)
    path.mkdir(parents=True, exist_ok=True)
    fh = open(path / lock_name, "a+")
    try:
        fh.seek(0)
        previous = fh.read().strip()
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            holder = fh.read().strip() or "another process"
            raise ConfigError(refusal.format(path=path, holder=holder)) from None
        fh.seek(0)
        fh.truncate()
        fh.write(lock_holder_line() + "\n")
        fh.flush()
        yield previous  # left by a holder that is gone (it released the flock by exiting without clearing it)
        fh.seek(0)
        fh.truncate()  # a clean exit leaves an empty lock file: nothing stale to report next time
        fh.flush()
    finally:
        fh.close()


@contextlib.contextmanager
def run_lock(run_dir: str | os.PathLike, enabled: bool = True) -> Iterator[None]:
    """Hold an exclusive lock on ``run_dir`` (``run_dir/.lock``) while training it (:func:`dir_lock`).

    A second writer — e.g. a worker of an interrupted ``pokeworld map`` that outlived its parent, and the
    resumed map — gets a clear error instead of interleaving checkpoints and metrics in one run directory.
    ``enabled`` is False on non-zero DDP ranks, which never write the run directory.
    """
    with dir_lock(run_dir, ".lock", "{path} is being trained by {holder}; wait for it or stop it before resuming "
                  "(two writers would interleave its checkpoints)", enabled):
        yield


def save_figure(fig, out: Path, stem: str, dpi: int = 150) -> list[Path]:
    """Write ``fig`` as ``out/stem.png`` and ``.pdf``, each atomically (temporary name, then rename); closes it."""
    import matplotlib.pyplot as plt

    paths = [Path(out) / f"{stem}.png", Path(out) / f"{stem}.pdf"]
    try:
        for p in paths:
            with atomic_path(p) as tmp:
                fig.savefig(tmp, dpi=dpi, format=p.suffix[1:])
    finally:
        plt.close(fig)
    return paths
