"""Unpickle untrusted ``.npy`` files in a child process, so that a file which crashes or hangs the unpickler costs
one scene, not the whole conversion.

:mod:`pokeworld.real.safe_pickle` refuses every pickle construct known to run code or to read memory, but the
unpickler and numpy's array reconstruction are large C code paths fed by the file: a crash that nobody has found
yet would otherwise end a many-hour conversion with SIGSEGV and no report. So the parent never unpickles an
untrusted file itself. One long-lived child (``python -m pokeworld.real.npy_child``; started on first use, restarted
after it dies) loads each file with :func:`~pokeworld.real.safe_pickle.load_npy` and sends the result back as JSON
(:func:`encode`), which the parent turns back into python containers and plain-dtype numpy arrays
(:func:`decode`) without any pickle. A child killed by a signal, or silent for longer than the timeout (it is then
killed), makes :func:`load_npy_isolated` raise :class:`UnpicklerDied`, an :class:`UnsafePickleError`. A timeout
verdict is remembered by the file's content (sha256) for the rest of the process, so the same bytes under any name
are refused at once instead of costing the timeout again; across runs, the RH20T conversion caches the scene's
skip like any other ``unsafe_pickle`` verdict.

The reply is bounded: the child refuses to encode more than ``REPLY_BYTES_PER_FILE_BYTE`` times the file's size
(shared references in a pickle, e.g. a list holding itself twice per level, would otherwise expand exponentially
when written out as a tree), and the parent refuses a longer reply.
"""

from __future__ import annotations

import atexit
import base64
import hashlib
import json
import math
import os
import re
import select
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from .regular_files import NotRegularFileError, open_regular
from .safe_pickle import UnsafePickleError

PICKLE_TIMEOUT_S = 120.0
"""Longest wait for one file (a RH20T stream file of a long scene unpickles in well under a second)."""
REPLY_BYTES_PER_FILE_BYTE = 16
"""Reply budget per byte of the file (plus 1 MiB): a legitimate pickle's JSON form is at most a few times larger."""
_HEADER_LEN = 16  # b"OK " or b"ER " + 12-digit length + b"\n"
_TRANSPORT_DTYPE_RE = re.compile(r"^[<>|=]?(b1|[iu][1248]|f(2|4|8|12|16)|c(8|16|24|32)|[US]\d{1,6})$")


class UnpicklerDied(UnsafePickleError):
    """The child unpickling a file was killed by a signal or did not answer within the timeout."""


class UnpicklerTimeout(UnpicklerDied):
    """The child did not answer within the timeout (it was killed); unlike a crash, this may depend on load."""


class NpyReadError(ValueError):
    """The child could not read the file (not an ``.npy``, truncated, inconsistent...); the message says why."""


# ----------------------------------------------------------------------------------------------- transport


class _Budget:
    def __init__(self, limit: int):
        self.left = limit

    def spend(self, n: int) -> None:
        self.left -= n
        if self.left < 0:
            raise NpyReadError("the unpickled object is too large to send back (shared references expanding?)")


def encode(obj: Any, budget: _Budget, seen: dict[int, tuple[Any, Any, int]] | None = None) -> Any:
    """A JSON-able tree for ``obj``: lists stay lists, scalars stay scalars, every other value is a one-key object
    (``d`` dict as key/value pairs, ``t`` tuple, ``s`` set, ``f`` frozenset, ``b`` bytes, ``c`` complex, ``a``
    plain numpy array, ``o`` object array, ``n`` numpy scalar).

    ``seen`` (id -> (object, its tree, what it cost)) encodes each object once: a shared reference reuses the tree
    and is charged its cost again without walking it, so the budget refuses a pickle whose tree doubles per level
    after one walk per level instead of after walking the whole budget."""
    seen = {} if seen is None else seen
    hit = seen.get(id(obj))
    if hit is not None:
        budget.spend(hit[2])
        return hit[1]
    before = budget.left
    tree = _encode_node(obj, budget, seen)
    if isinstance(tree, (list, dict)):  # containers and blobs; the object is held, so its id is not reused
        seen[id(obj)] = (obj, tree, before - budget.left)
    return tree


def _encode_node(obj: Any, budget: _Budget, seen: dict) -> Any:
    budget.spend(8)
    if isinstance(obj, np.generic):  # before the python types: np.float64 is a float, np.str_ a str
        if obj.dtype == object:
            raise NpyReadError("cannot send back a numpy object scalar")
        budget.spend(obj.dtype.itemsize * 4 // 3)
        return {"n": [obj.dtype.str, base64.b64encode(obj.tobytes()).decode("ascii")]}
    if obj is None or isinstance(obj, (bool, int, float)):
        return obj
    if isinstance(obj, str):
        budget.spend(len(obj))
        return obj
    if isinstance(obj, list):
        return [encode(x, budget, seen) for x in obj]
    if isinstance(obj, dict):
        return {"d": [[encode(k, budget, seen), encode(v, budget, seen)] for k, v in obj.items()]}
    for tag, kind in (("t", tuple), ("f", frozenset), ("s", set)):
        if isinstance(obj, kind):
            return {tag: [encode(x, budget, seen) for x in obj]}
    if isinstance(obj, (bytes, bytearray)):
        budget.spend(len(obj) * 4 // 3)
        return {"b": base64.b64encode(bytes(obj)).decode("ascii")}
    if isinstance(obj, complex):
        return {"c": [obj.real, obj.imag]}
    if isinstance(obj, np.ndarray) and obj.dtype == object:
        return {"o": [list(obj.shape), [encode(x, budget, seen) for x in obj.reshape(-1)]]}
    if isinstance(obj, np.ndarray):
        budget.spend(obj.nbytes * 4 // 3)
        raw = base64.b64encode(np.ascontiguousarray(obj).tobytes()).decode("ascii")
        return {"a": [obj.dtype.str, list(obj.shape), raw, bool(obj.flags.f_contiguous and obj.ndim > 1)]}
    raise NpyReadError(f"cannot send back a {type(obj).__name__}")


def _plain_dtype(spec: Any) -> np.dtype:
    if not isinstance(spec, str) or not _TRANSPORT_DTYPE_RE.match(spec):
        raise NpyReadError(f"reply names dtype {spec!r:.40}, which is not a plain dtype")
    return np.dtype(spec)


def _array(spec: Any, shape: Any, raw: Any, fortran: Any) -> np.ndarray:
    dt = _plain_dtype(spec)
    if not isinstance(shape, list) or not all(type(n) is int and n >= 0 for n in shape):
        raise NpyReadError(f"reply holds an array shape {shape!r:.40}")
    data = base64.b64decode(raw, validate=True)
    if len(data) != math.prod(shape) * dt.itemsize:
        raise NpyReadError(f"reply holds {len(data)} bytes for a {dt} array of shape {shape}")
    arr = np.frombuffer(data, dt).reshape(shape)
    return np.asfortranarray(arr) if fortran else arr.copy()


def decode(tree: Any) -> Any:
    """The inverse of :func:`encode`; a malformed tree raises :class:`NpyReadError` (nothing in it is executed)."""
    if tree is None or isinstance(tree, (bool, int, float, str)):
        return tree
    if isinstance(tree, list):
        return [decode(x) for x in tree]
    if not isinstance(tree, dict) or len(tree) != 1:
        raise NpyReadError(f"malformed reply node {type(tree).__name__}")
    (tag, val), = tree.items()
    if tag == "d":
        return {decode(k): decode(v) for k, v in val}
    if tag in ("t", "f", "s"):
        return {"t": tuple, "f": frozenset, "s": set}[tag](decode(x) for x in val)
    if tag == "b":
        return base64.b64decode(val, validate=True)
    if tag == "c":
        return complex(*val)
    if tag == "a":
        return _array(*val)
    if tag == "o":
        shape, items = val
        flat = np.empty(len(items), object)
        for i, x in enumerate(items):
            flat[i] = decode(x)
        return flat.reshape(shape)
    if tag == "n":
        return np.frombuffer(base64.b64decode(val[1], validate=True), _plain_dtype(val[0]))[0]
    raise NpyReadError(f"malformed reply node tag {tag!r:.20}")


# ----------------------------------------------------------------------------------------------- child


def _serve(requests: BinaryIO, replies: BinaryIO) -> None:
    """The child's loop: one JSON request line in, one framed reply out, until stdin closes."""
    from ..faults import crash_point
    from .safe_pickle import load_npy

    for line in requests:
        try:
            req = json.loads(line)
            crash_point(f"unpickle:{req['path']}")  # tests kill or stall the child while it reads this file
            arr = load_npy(req["path"])
            status, body = b"OK ", json.dumps(encode(arr, _Budget(req["budget"]))).encode()
        except RecursionError:
            status, body = b"ER ", json.dumps(["NpyReadError", "nesting too deep"]).encode()
        except Exception as e:  # reported to the parent, which decides what it means for the scene
            status, body = b"ER ", json.dumps([type(e).__name__, str(e)[:2000]]).encode()
        replies.write(status + b"%012d\n" % len(body) + body)
        replies.flush()


def _child_main() -> None:
    replies = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything else printed goes to stderr, never into the reply stream
    try:
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30))  # a memory bomb fails here, not the machine
    except (ImportError, ValueError, OSError):
        pass
    _serve(sys.stdin.buffer, replies)


# ----------------------------------------------------------------------------------------------- parent


def content_digest(path: str | os.PathLike) -> str:
    """sha256 of a regular file's bytes (read in the parent without unpickling anything)."""
    digest = hashlib.sha256()
    with open_regular(path) as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


class NpyChild:
    """The parent's handle on one child; :meth:`load` is serialised by a lock."""

    def __init__(self) -> None:
        self.proc: subprocess.Popen | None = None
        self.lock = threading.Lock()
        self.timed_out: dict[str, float] = {}
        """sha256 of a file's content -> the longest timeout [s] it ran past: a load with no longer a timeout is
        refused at once (a file that takes 100 times what a real one needs is hostile, not slow)."""

    def _cached_timeout(self, path: str, timeout_s: float) -> Exception | None:
        """The cached timeout verdict for ``path``'s content, or None (no file timed out yet: nothing hashed)."""
        if not self.timed_out:
            return None
        if self.timed_out.get(content_digest(path), -1.0) < timeout_s:
            return None
        return UnpicklerTimeout(f"unpickling {path} did not finish within {timeout_s:g} s (a file with the same "
                                "content ran past it earlier in this run; refused without retrying)")

    def _remember_timeout(self, path: str, timeout_s: float) -> None:
        try:
            digest = content_digest(path)
        except OSError:  # gone or swapped for a special file since: nothing to remember it by
            return
        self.timed_out[digest] = max(timeout_s, self.timed_out.get(digest, 0.0))

    def _start(self) -> subprocess.Popen:
        src = str(Path(__file__).resolve().parents[2])  # the directory holding the pokeworld package
        env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
               "PYTHONPATH": os.pathsep.join(p for p in (src, os.environ.get("PYTHONPATH", "")) if p)}
        return subprocess.Popen([sys.executable, "-m", "pokeworld.real.npy_child"], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env, close_fds=True)

    def close(self) -> None:
        proc, self.proc = self.proc, None
        if proc is None:
            return
        try:
            proc.stdin.close()
            proc.wait(timeout=5)
        except (OSError, subprocess.TimeoutExpired):
            proc.kill()
            proc.wait()
        proc.stdout.close()

    def _died(self, path: str, timeout_s: float, timed_out: bool) -> Exception:
        """The exception for a child that stopped answering; it is reaped (killed first if ``timed_out``)."""
        proc, self.proc = self.proc, None
        if timed_out:
            proc.kill()
        try:
            rc = proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            rc = proc.wait()
        proc.stdout.close()
        if timed_out:
            self._remember_timeout(path, timeout_s)
            return UnpicklerTimeout(f"unpickling {path} did not finish within {timeout_s:g} s; the child was killed")
        if rc >= 0:  # not the file's doing: the child could not start or run (a broken installation)
            return RuntimeError(f"the .npy loading child ({sys.executable} -m pokeworld.real.npy_child) exited with "
                                f"code {rc} while reading {path}")
        return UnpicklerDied(f"the child process unpickling {path} was killed by signal {-rc}")

    def _read(self, n: int, deadline: float) -> bytes | None:
        """``n`` bytes from the child, or None if it closed its end or the deadline passed."""
        fd, chunks, got = self.proc.stdout.fileno(), [], 0
        while got < n:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                return None
            chunk = os.read(fd, min(n - got, 1 << 20))
            if not chunk:
                return None
            chunks.append(chunk)
            got += len(chunk)
        return b"".join(chunks)

    def load(self, path: str | os.PathLike, timeout_s: float | None = None) -> Any:
        """What :func:`~pokeworld.real.safe_pickle.load_npy` returns for ``path``, read in the child (``timeout_s``:
        :data:`PICKLE_TIMEOUT_S` if None)."""
        path = str(path)
        timeout_s = PICKLE_TIMEOUT_S if timeout_s is None else timeout_s
        budget = REPLY_BYTES_PER_FILE_BYTE * os.stat(path).st_size + (1 << 20)
        with self.lock:
            cached = self._cached_timeout(path, timeout_s)
            if cached is not None:
                raise cached
            if self.proc is None or self.proc.poll() is not None:
                self.proc = self._start()
            deadline = time.monotonic() + timeout_s
            try:
                self.proc.stdin.write(json.dumps({"path": path, "budget": budget}).encode() + b"\n")
                self.proc.stdin.flush()
            except OSError:  # it died between two files
                raise self._died(path, timeout_s, False) from None
            header = self._read(_HEADER_LEN, deadline)
            if header is None:
                raise self._died(path, timeout_s, time.monotonic() >= deadline) from None
            size = int(header[3:15]) if header[3:15].isdigit() else -1
            body = self._read(size, deadline) if 0 <= size <= budget + 4096 else None
            if body is None or header[:3] not in (b"OK ", b"ER "):
                raise self._died(path, timeout_s, True) from None  # a child that breaks the protocol is killed
        try:
            reply = json.loads(body)
            if header[:3] == b"OK ":
                return decode(reply)
            kind, message = reply
        except Exception as e:  # whatever a (possibly subverted) child sent, it becomes one read error
            raise NpyReadError(f"{path}: malformed reply from the unpickling child ({type(e).__name__})") from None
        errors = {"UnsafePickleError": UnsafePickleError, "NotRegularFileError": NotRegularFileError,
                  "FileNotFoundError": FileNotFoundError, "NpyReadError": NpyReadError}
        raise errors.get(kind, NpyReadError)(message if kind in errors else f"{kind}: {message}")


_CHILD = NpyChild()
atexit.register(_CHILD.close)


def load_npy_isolated(path: str | os.PathLike, timeout_s: float | None = None) -> Any:
    """:func:`~pokeworld.real.safe_pickle.load_npy` run in the shared child process (started on first use,
    restarted after it dies); raises :class:`UnpicklerDied` when the child dies or times out on this file."""
    return _CHILD.load(path, timeout_s)


def load_npy_item_isolated(path: str | os.PathLike, timeout_s: float | None = None) -> Any:
    """:func:`load_npy_isolated` with a 0-d object array (how ``np.save`` stores a python object) unwrapped."""
    arr = load_npy_isolated(path, timeout_s)
    return arr.item() if isinstance(arr, np.ndarray) and arr.dtype == object and arr.shape == () else arr


def close_child() -> None:
    """Stop the shared child (a conversion calls this when it ends; the next load starts a fresh one)."""
    with _CHILD.lock:
        _CHILD.close()


__all__ = ["PICKLE_TIMEOUT_S", "UnpicklerDied", "UnpicklerTimeout", "NpyReadError", "NpyChild", "encode", "decode",
           "content_digest", "load_npy_isolated", "load_npy_item_isolated", "close_child"]

if __name__ == "__main__":
    _child_main()
