"""Load ``.npy`` files, including pickled object arrays, without letting the file run code.

RH20T stores its streams and calibration as python dicts saved with ``np.save`` (0-d object arrays), which
numpy's own loader, once pickles are allowed, unpickles with the full :mod:`pickle` machinery: a file whose pickle names
``os.system`` (or any other callable) runs it while loading. This loader parses the ``.npy`` header with
:mod:`numpy.lib.format` and

* loads arrays of a plain dtype with ``np.load(..., allow_pickle=False)`` (no pickle involved);
* unpickles object arrays with :class:`RestrictedUnpickler`, whose ``find_class`` admits only the names a pickled
  numpy array of python containers and numbers needs (:data:`ADMITTED_GLOBALS`); every other global, a persistent
  id, or a numpy dtype outside :data:`ADMITTED_DTYPE_RE` raises :class:`UnsafePickleError` **before** anything is
  called. A refused name is never imported or looked up, so not even a module import runs.

What is admitted and why (the opcodes for dict, list, tuple, str, bytes, int, float, bool and None need no global):

* numpy's array and scalar reconstruction, under its numpy 1.x (``numpy.core``) and 2.x (``numpy._core``) module
  names: ``multiarray._reconstruct`` only as numpy's pickles call it (``(numpy.ndarray, (0,), b'b')``; ``ndarray``
  itself is not callable here: ``np.ndarray(shape, object, buffer)`` would turn raw bytes into object pointers),
  ``multiarray.scalar`` for non-object dtypes only, and ``numpy.dtype`` restricted to bool, integer, float, complex,
  str/bytes and object dtypes. Object arrays are admitted because the 0-d wrapper ``np.save`` puts around a dict is
  one; numpy pickles an object array's elements inline in the same stream as a list, so every element of a nested
  object array passes through the same ``find_class`` (``tests/test_rh20t_security.py`` plants a payload inside one);
* the BUILD opcode (``__setstate__``) only on a numpy dtype or array made by the names above, and only with a state
  that cannot change what the object is (:meth:`RestrictedUnpickler.load_build`): a dtype's state must equal the
  state numpy itself writes for that dtype (the byte order is the one thing it may set), an array's state must hold
  such a dtype and exactly as many bytes (or, for an object dtype, list items) as its shape needs. numpy's own
  ``dtype.__setstate__`` accepts any flags, and a dtype whose flags no longer say "holds objects" makes
  ``multiarray.scalar`` or ``ndarray.__setstate__`` read raw bytes from the file as object pointers: a crash with
  an arbitrary address, a call of the attacker's choice with a known one;
* ``builtins`` ``set``, ``frozenset`` and ``complex``: inert value constructors that pickle protocols <= 3 (numpy
  < 2 wrote protocol 3) spell as globals;
* ``_codecs.encode`` with a ``latin1`` encoding only: how protocol 2 (numpy < 1.17) stores ``bytes``, e.g. the
  raw data of a numeric array inside the dict.
"""

from __future__ import annotations

import functools
import itertools
import math
import os
import pickle
import re
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.lib import format as npy_format

from .regular_files import open_regular

try:  # numpy >= 2
    from numpy._core import multiarray as _multiarray
except ImportError:  # numpy 1.x
    from numpy.core import multiarray as _multiarray


class UnsafePickleError(pickle.UnpicklingError):
    """The pickle in an .npy file references something the restricted unpickler does not admit; nothing in it
    was called."""


ADMITTED_DTYPE_RE = re.compile(r"^(b1|[iu][1248]|f(2|4|8|12|16)|c(8|16|24|32)|[US]\d{1,6}|O[48]?)$")
"""dtype specs (the first argument numpy pickles ``numpy.dtype`` with) the unpickler admits: bool, integers,
floats, complex, fixed-width str/bytes (at most 6 digits of width) and object. Structured / void, datetime and user
dtypes are refused."""

MAX_ITEMSIZE = 1 << 20
"""Largest admitted dtype item size [bytes]: ``U999999`` is 4 MB per element, and a scalar or array of it is
allocated before its data is checked."""

HASHED_NODES_PER_BYTE = 4
"""Budget for hashing dict keys and set elements, in tuple-tree nodes per byte of the file (plus
:data:`HASHED_NODES_BASE`). Python hashes a tuple by walking it as a tree, and the pickle memo lets a tuple hold the
previous one twice per level: 8 bytes of pickle a level, 2**levels nodes to hash. A legitimate key costs a node or
a few per reference, each at least two bytes of pickle."""
HASHED_NODES_BASE = 1 << 20
MAX_KEY_DEPTH = 100
"""Deepest tuple nesting admitted in a dict key or set element: Python hashes (and compares) nested tuples by C
recursion with no depth guard, so a key a million tuples deep crashes the interpreter."""


class _Text(str):
    """A literal piece of :func:`brief`'s output (a bracket or separator), not a value to render."""


_BRACKETS = {tuple: ("(", ")"), list: ("[", "]"), dict: ("{", "}"), set: ("{", "}"), frozenset: ("frozenset({", "})")}


def _pieces(container: Any, limit: int) -> list[Any]:
    """The first ``limit`` items of a container, with separators, in output order (a dict's as key: value)."""
    pieces: list[Any] = []
    items = container.items() if type(container) is dict else ((x,) for x in container)
    for i, item in enumerate(itertools.islice(items, limit)):
        pieces += ([_Text(", ")] if i else []) + [item[0]] + ([_Text(": "), item[1]] if len(item) == 2 else [])
    return pieces


def brief(obj: Any, limit: int = 60) -> str:
    """At most about ``limit`` characters describing an untrusted value, for error messages.

    ``repr`` walks a tuple as a tree, so the repr of a few hundred bytes of shared-reference tuples is exponential
    in time and memory; this walk renders each node as it reaches it and stops at ``limit`` characters, so it
    visits at most ``limit`` nodes whatever the object graph (each node renders as at least one character).
    """
    out: list[str] = []
    size = 0
    todo: list[Any] = [obj]
    while todo and size < limit:
        item = todo.pop()
        if isinstance(item, _Text):
            text = str(item)
        elif type(item) in _BRACKETS:
            opening, closing = _BRACKETS[type(item)]
            closing = ",)" if type(item) is tuple and len(item) == 1 else closing
            todo += [_Text(closing), *reversed(_pieces(item, limit))]
            text = opening
        elif isinstance(item, (str, bytes, bytearray)):
            text = repr(item[:limit])
        elif type(item) is int:
            text = str(item) if item.bit_length() < 200 else f"<int of {item.bit_length()} bits>"
        elif item is None or type(item) in (bool, float, complex):
            text = repr(item)
        elif isinstance(item, np.dtype) and _plain_dtype(item):
            text = f"dtype({item.str!r})"
        else:  # arrays, forged dtypes, functions: their own repr may walk or read what the file planted
            text = f"<{type(item).__name__}>"
        out.append(text)
        size += len(text)
    rendered = "".join(out)
    return rendered[:limit] + "..." if todo or len(rendered) > limit else rendered


def hashed_nodes(obj: Any, known: dict[int, tuple[Any, int, int]]) -> tuple[int, int]:
    """(nodes, depth) of the walk hashing ``obj`` makes (a tuple's hash walks it as a tree, recursing in C), computed
    once per tuple object: ``known`` maps id -> (tuple, nodes, depth) and holds each tuple, so an id is never reused
    while it is in there. Linear in the number of distinct tuples, however often the memo references them."""
    if type(obj) is not tuple:
        return 1, 1  # str / bytes / numbers hash flat; a frozenset's hash is computed once and cached by Python
    todo = [obj]
    while todo:
        t = todo[-1]
        if id(t) in known:
            todo.pop()
            continue
        pending = [x for x in t if type(x) is tuple and id(x) not in known]
        if pending:
            todo += pending
            continue
        todo.pop()
        inner = [known[id(x)][1:] if type(x) is tuple else (1, 1) for x in t]
        known[id(t)] = (t, 1 + sum(n for n, _ in inner), 1 + max((d for _, d in inner), default=0))
    return known[id(obj)][1:]


class _NdarrayType:
    """Stands for ``numpy.ndarray`` in an unpickled stream: only valid as :func:`_reconstruct`'s subtype."""

    def __repr__(self) -> str:
        return "numpy.ndarray (admitted as _reconstruct's subtype only)"


_NDARRAY = _NdarrayType()


def _reconstruct(subtype: Any, shape: Any, dtype: Any) -> np.ndarray:
    if subtype is not _NDARRAY:
        raise UnsafePickleError(f"_reconstruct called with subtype {brief(subtype)}; only numpy.ndarray is admitted")
    # numpy's array_reduce always writes (ndarray, (0,), b'b'): an empty placeholder its BUILD then fills
    if shape != (0,) or dtype not in (b"b", "b"):
        raise UnsafePickleError(f"_reconstruct admitted only as numpy pickles it, with shape (0,) and dtype b'b', "
                                f"got {brief(shape)}, {brief(dtype)}")
    return _multiarray._reconstruct(np.ndarray, (0,), b"b")


def _dtype(spec: Any, align: Any = False, copy: Any = True) -> np.dtype:
    if not isinstance(spec, str) or not ADMITTED_DTYPE_RE.match(spec):
        raise UnsafePickleError(f"numpy dtype {brief(spec)} is not admitted (only bool, int, float, complex, str, "
                                "bytes and object dtypes)")
    dt = np.dtype(spec, align=bool(align), copy=True)  # always a fresh object: its BUILD must not touch numpy's own
    if dt.itemsize > MAX_ITEMSIZE:
        raise UnsafePickleError(f"numpy dtype {spec!r} has {dt.itemsize} bytes per item (> {MAX_ITEMSIZE})")
    return dt


def _canonical_state(dt: np.dtype) -> tuple:
    """The BUILD state numpy writes for a plain dtype equal to ``dt`` with ``dt``'s byte order."""
    return np.dtype(dt.str).__reduce__()[2]


def _plain_dtype(dt: Any) -> bool:
    """True for a bool / number / str / bytes / object dtype whose flags, size and alignment are numpy's own."""
    return (isinstance(dt, np.dtype) and dt.names is None and dt.subdtype is None and dt.kind in "biufcUSO"
            and dt.itemsize <= MAX_ITEMSIZE and dt.__reduce__()[2] == _canonical_state(dt))


def _scalar(dtype: Any, data: Any = None) -> Any:
    if not _plain_dtype(dtype) or dtype.hasobject:
        raise UnsafePickleError(f"numpy scalar reconstruction admitted only for plain non-object dtypes, got "
                                f"{brief(dtype)}")
    if not isinstance(data, bytes) or len(data) != dtype.itemsize:
        raise UnsafePickleError(f"numpy scalar of {dtype} needs exactly {dtype.itemsize} bytes of data, got "
                                f"{type(data).__name__}")
    return _multiarray.scalar(dtype, data)


def _codecs_encode(obj: Any, encoding: Any = "utf-8", errors: Any = "strict") -> bytes:
    if not isinstance(obj, str) or encoding not in ("latin1", "latin-1") or errors != "strict":
        raise UnsafePickleError(f"_codecs.encode is admitted only as protocol 2's bytes encoding (a str, 'latin1'), "
                                f"got {type(obj).__name__}, {brief(encoding)}")
    return obj.encode("latin1")


def _admitted() -> dict[tuple[str, str], Any]:
    table: dict[tuple[str, str], Any] = {}
    for mod in ("numpy.core.multiarray", "numpy._core.multiarray"):
        table[(mod, "_reconstruct")] = _reconstruct
        table[(mod, "scalar")] = _scalar
    table[("numpy", "ndarray")] = _NDARRAY
    table[("numpy", "dtype")] = _dtype
    for mod in ("builtins", "__builtin__"):  # __builtin__: a python-2-era protocol <= 2 stream
        table[(mod, "set")] = set
        table[(mod, "frozenset")] = frozenset
        table[(mod, "complex")] = complex
    table[("_codecs", "encode")] = _codecs_encode
    return table


ADMITTED_GLOBALS: dict[tuple[str, str], Any] = _admitted()
"""(module, name) -> the object ``find_class`` returns for it; every other global is refused."""


def _check_dtype_state(inst: np.dtype, state: Any) -> None:
    """A dtype's BUILD may only restate numpy's own state for it, or that of its other byte order."""
    variants = [inst] + ([inst.newbyteorder("<"), inst.newbyteorder(">")] if inst.byteorder != "|" else [])
    if not isinstance(state, tuple) or all(state != v.__reduce__()[2] for v in variants):
        raise UnsafePickleError(f"BUILD state {brief(state, 80)} would change numpy dtype {inst} (only numpy's own "
                                "state for a plain dtype is admitted)")


def _check_array_state(inst: np.ndarray, state: Any, plain_dtypes: dict[int, np.dtype]) -> None:
    """An array's BUILD: a fresh placeholder, a plain dtype, and exactly the data its shape needs."""
    if not isinstance(state, tuple) or len(state) not in (4, 5):
        raise UnsafePickleError(f"numpy array BUILD state must be a 4- or 5-tuple, got {type(state).__name__}")
    shape, dt, _, data = state[-4:]
    if inst.shape != (0,) or inst.dtype != np.int8:
        raise UnsafePickleError("BUILD on a numpy array that is not a fresh _reconstruct placeholder")
    if not isinstance(shape, tuple) or not all(type(n) is int and n >= 0 for n in shape):
        raise UnsafePickleError(f"numpy array shape {brief(shape)} is not a tuple of non-negative ints")
    if id(dt) not in plain_dtypes:
        if not _plain_dtype(dt):
            raise UnsafePickleError(f"numpy array dtype {brief(dt)} is not a plain dtype with numpy's own flags")
        plain_dtypes[id(dt)] = dt
    size = math.prod(shape)
    if dt.hasobject:
        if type(data) is not list or len(data) != size:
            raise UnsafePickleError(f"object array of shape {shape} needs a list of {size} items, got "
                                    f"{type(data).__name__}")
    elif not isinstance(data, (bytes, bytearray)) or len(data) != size * dt.itemsize:
        got = f"{len(data)} bytes" if isinstance(data, (bytes, bytearray)) else type(data).__name__
        raise UnsafePickleError(f"{dt} array of shape {shape} needs {size * dt.itemsize} bytes of data, got {got}")


class RestrictedUnpickler(pickle._Unpickler):
    """An unpickler whose globals are exactly :data:`ADMITTED_GLOBALS`, with no persistent ids, and whose BUILD
    opcode only completes numpy dtypes and arrays with states numpy itself writes (:meth:`load_build`).

    It is the pure-python unpickler (``pickle._Unpickler``), the only one whose opcodes can be overridden: the C
    unpickler calls ``__setstate__`` directly, and numpy's ``dtype.__setstate__`` admits any flags.
    """

    def find_class(self, module: str, name: str) -> Any:
        try:
            found = ADMITTED_GLOBALS[(module, name)]
        except (KeyError, TypeError):
            raise UnsafePickleError(f"pickle references {module}.{name}, which is not admitted") from None
        if found is set or found is frozenset:  # they hash their elements: charged like a dict's keys
            return functools.partial(self._hashed_collection, found)
        return found

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError(f"pickle uses a persistent id ({brief(pid)}), which is not admitted")

    def __init__(self, *args: Any, hash_budget: int = HASHED_NODES_BASE, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.plain_dtypes: dict[int, np.dtype] = {}
        """id -> dtype already checked by :func:`_plain_dtype` (a pickle reuses one dtype object for many arrays;
        the dtype is held, so its id is not reused, and a later BUILD on it is itself checked)."""
        self.hash_budget = hash_budget
        """Tuple-tree nodes left to hash as dict keys and set elements (:data:`HASHED_NODES_PER_BYTE`)."""
        self.hashed: dict[int, tuple[Any, int, int]] = {}
        """:func:`hashed_nodes`' memo: each tuple is measured once, however many keys share it."""

    def _charge_hashing(self, keys: Any) -> None:
        """Refuse, before Python hashes them, keys whose tree walks would exceed what is left of the budget."""
        for key in keys:
            nodes, depth = hashed_nodes(key, self.hashed)
            if depth > MAX_KEY_DEPTH:
                raise UnsafePickleError(f"a dict key / set element nests tuples {depth} deep (more than "
                                        f"{MAX_KEY_DEPTH}); hashing it would overflow the C stack")
            self.hash_budget -= nodes
            if self.hash_budget < 0:
                raise UnsafePickleError(f"dict keys / set elements such as {brief(key)} expand (through shared "
                                        "references) to more tuple nodes than the file could hold; hashing them "
                                        "would take exponential time")

    def _hashed_collection(self, kind: type, items: Any = ()) -> Any:
        items = list(items)  # whatever the file made it (a list, a tuple, an object array...), each element hashed
        self._charge_hashing(items)
        return kind(items)

    def _dict_target(self) -> dict:
        target = self.stack[-1]
        if type(target) is not dict:  # numpy's and python's pickles set items only on dicts
            raise UnsafePickleError(f"SETITEM(S) on {type(target).__name__} is not admitted (only on a dict)")
        return target

    def load_dict(self) -> None:
        items = self.pop_mark()
        self._charge_hashing(items[0::2])
        self.append({items[i]: items[i + 1] for i in range(0, len(items), 2)})

    def load_setitem(self) -> None:
        value, key = self.stack.pop(), self.stack.pop()
        self._charge_hashing((key,))
        self._dict_target()[key] = value

    def load_setitems(self) -> None:
        items = self.pop_mark()
        target = self._dict_target()
        self._charge_hashing(items[0::2])
        for i in range(0, len(items), 2):
            target[items[i]] = items[i + 1]

    def load_additems(self) -> None:
        items = self.pop_mark()
        if type(self.stack[-1]) is not set:
            raise UnsafePickleError(f"ADDITEMS on {type(self.stack[-1]).__name__} is not admitted (only on a set)")
        self._charge_hashing(items)
        self.stack[-1].update(items)

    def load_frozenset(self) -> None:
        items = self.pop_mark()
        self._charge_hashing(items)
        self.append(frozenset(items))

    def load_build(self) -> None:
        state = self.stack.pop()
        inst = self.stack[-1]
        if isinstance(inst, np.dtype):
            _check_dtype_state(inst, state)
        elif type(inst) is np.ndarray:
            _check_array_state(inst, state, self.plain_dtypes)
        else:
            raise UnsafePickleError(f"BUILD (__setstate__) on {type(inst).__name__} is not admitted")
        inst.__setstate__(state)

    dispatch = {**pickle._Unpickler.dispatch, pickle.BUILD[0]: load_build, pickle.DICT[0]: load_dict,
                pickle.SETITEM[0]: load_setitem, pickle.SETITEMS[0]: load_setitems, pickle.ADDITEMS[0]: load_additems,
                pickle.FROZENSET[0]: load_frozenset}


def _read_header(fp: BinaryIO) -> tuple[tuple[int, ...], bool, np.dtype]:
    version = npy_format.read_magic(fp)  # ValueError unless the file starts with the .npy magic
    if version == (1, 0):
        return npy_format.read_array_header_1_0(fp)
    if version in ((2, 0), (3, 0)):
        # 3.0 differs from 2.0 only in decoding the header as utf-8 (for non-ascii field names), which an
        # object-array header (descr '|O') never has; numpy's reader refuses anything else
        return npy_format.read_array_header_2_0(fp)
    raise ValueError(f"unsupported .npy format version {version}")


def load_npy(path: str | Path) -> np.ndarray:
    """The array stored in an ``.npy`` file, unpickling an object array only through :class:`RestrictedUnpickler`.

    Raises :class:`UnsafePickleError` for a refused pickle; ``ValueError`` / ``EOFError`` /
    ``pickle.UnpicklingError`` and friends for a file that is not a well-formed ``.npy`` (a bare pickle without
    the ``.npy`` magic, which numpy's pickle-allowing loader would unpickle, is refused as not an ``.npy``).
    """
    path = Path(path)
    with open_regular(path) as fp:
        shape, fortran_order, dtype = _read_header(fp)
        if not dtype.hasobject:
            fp.seek(0)
            return np.load(fp, allow_pickle=False)
        # numpy.lib.format.write_array pickles the whole object array (the outer wrapper included)
        budget = HASHED_NODES_PER_BYTE * os.fstat(fp.fileno()).st_size + HASHED_NODES_BASE
        arr = RestrictedUnpickler(fp, fix_imports=True, encoding="ASCII", hash_budget=budget).load()
    if not isinstance(arr, np.ndarray) or arr.dtype != dtype or arr.shape != tuple(shape):
        raise ValueError(f"{path}: pickle holds {type(arr).__name__} "
                         f"{getattr(arr, 'dtype', '')}{getattr(arr, 'shape', '')}, header says {dtype}{shape}")
    return arr


def load_npy_item(path: str | Path) -> Any:
    """:func:`load_npy`, with a 0-d object array (how ``np.save`` stores a python object) unwrapped to the object:
    the safe way to read RH20T's pickled dicts (0-d object arrays)."""
    arr = load_npy(path)
    return arr.item() if arr.dtype == object and arr.shape == () else arr


__all__ = ["UnsafePickleError", "RestrictedUnpickler", "ADMITTED_GLOBALS", "ADMITTED_DTYPE_RE", "MAX_ITEMSIZE",
           "HASHED_NODES_PER_BYTE", "HASHED_NODES_BASE", "MAX_KEY_DEPTH", "brief", "hashed_nodes", "load_npy",
           "load_npy_item"]
