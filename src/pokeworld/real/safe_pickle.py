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
  names: ``multiarray._reconstruct`` only with ``numpy.ndarray`` as its subtype (``ndarray`` itself is not
  callable here: ``np.ndarray(shape, object, buffer)`` would turn raw bytes into object pointers),
  ``multiarray.scalar`` and ``numpy.dtype`` restricted to bool, integer, float, complex, str/bytes and object
  dtypes. Object arrays are admitted because the 0-d wrapper ``np.save`` puts around a dict is one; numpy
  pickles an object array's elements inline in the same stream (``ndarray.__setstate__`` refuses an object
  array whose data is not a list), so every element of a nested object array passes through the same
  ``find_class`` (``tests/test_rh20t_security.py`` plants a payload inside one);
* ``builtins`` ``set``, ``frozenset`` and ``complex``: inert value constructors that pickle protocols <= 3 (numpy
  < 2 wrote protocol 3) spell as globals;
* ``_codecs.encode`` with a ``latin1`` encoding only: how protocol 2 (numpy < 1.17) stores ``bytes``, e.g. the
  raw data of a numeric array inside the dict.
"""

from __future__ import annotations

import pickle
import re
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.lib import format as npy_format

try:  # numpy >= 2
    from numpy._core import multiarray as _multiarray
except ImportError:  # numpy 1.x
    from numpy.core import multiarray as _multiarray


class UnsafePickleError(pickle.UnpicklingError):
    """The pickle in an .npy file references something the restricted unpickler does not admit; nothing in it
    was called."""


ADMITTED_DTYPE_RE = re.compile(r"^(b1|[iu][1248]|f(2|4|8|12|16)|c(8|16|24|32)|[US]\d+|O[48]?)$")
"""dtype specs (the first argument numpy pickles ``numpy.dtype`` with) the unpickler admits: bool, integers,
floats, complex, fixed-width str/bytes and object. Structured / void, datetime and user dtypes are refused."""


class _NdarrayType:
    """Stands for ``numpy.ndarray`` in an unpickled stream: only valid as :func:`_reconstruct`'s subtype."""

    def __repr__(self) -> str:
        return "numpy.ndarray (admitted as _reconstruct's subtype only)"


_NDARRAY = _NdarrayType()


def _reconstruct(subtype: Any, shape: Any, dtype: Any) -> np.ndarray:
    if subtype is not _NDARRAY:
        raise UnsafePickleError(f"_reconstruct called with subtype {subtype!r}; only numpy.ndarray is admitted")
    return _multiarray._reconstruct(np.ndarray, shape, dtype)


def _dtype(spec: Any, align: Any = False, copy: Any = False) -> np.dtype:
    if not isinstance(spec, str) or not ADMITTED_DTYPE_RE.match(spec):
        raise UnsafePickleError(f"numpy dtype {spec!r} is not admitted (only bool, int, float, complex, str, "
                                "bytes and object dtypes)")
    return np.dtype(spec, align=bool(align), copy=bool(copy))


def _scalar(dtype: Any, data: Any = None) -> Any:
    if not isinstance(dtype, np.dtype):
        raise UnsafePickleError(f"numpy scalar reconstruction with a non-dtype {type(dtype).__name__}")
    return _multiarray.scalar(dtype) if data is None else _multiarray.scalar(dtype, data)


def _codecs_encode(obj: Any, encoding: Any = "utf-8", errors: Any = "strict") -> bytes:
    if not isinstance(obj, str) or encoding not in ("latin1", "latin-1") or errors != "strict":
        raise UnsafePickleError(f"_codecs.encode is admitted only as protocol 2's bytes encoding (a str, 'latin1'), "
                                f"got {type(obj).__name__}, {encoding!r}")
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


class RestrictedUnpickler(pickle.Unpickler):
    """An unpickler whose globals are exactly :data:`ADMITTED_GLOBALS` (and no persistent ids)."""

    def find_class(self, module: str, name: str) -> Any:
        try:
            return ADMITTED_GLOBALS[(module, name)]
        except (KeyError, TypeError):
            raise UnsafePickleError(f"pickle references {module}.{name}, which is not admitted") from None

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError(f"pickle uses a persistent id ({pid!r:.60}), which is not admitted")


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
    with open(path, "rb") as fp:
        shape, fortran_order, dtype = _read_header(fp)
        if not dtype.hasobject:
            return np.load(path, allow_pickle=False)
        # numpy.lib.format.write_array pickles the whole object array (the outer wrapper included)
        arr = RestrictedUnpickler(fp, fix_imports=True, encoding="ASCII").load()
    if not isinstance(arr, np.ndarray) or arr.dtype != dtype or arr.shape != tuple(shape):
        raise ValueError(f"{path}: pickle holds {type(arr).__name__} "
                         f"{getattr(arr, 'dtype', '')}{getattr(arr, 'shape', '')}, header says {dtype}{shape}")
    return arr


def load_npy_item(path: str | Path) -> Any:
    """:func:`load_npy`, with a 0-d object array (how ``np.save`` stores a python object) unwrapped to the object:
    the safe way to read RH20T's pickled dicts (0-d object arrays)."""
    arr = load_npy(path)
    return arr.item() if arr.dtype == object and arr.shape == () else arr


__all__ = ["UnsafePickleError", "RestrictedUnpickler", "ADMITTED_GLOBALS", "ADMITTED_DTYPE_RE", "load_npy",
           "load_npy_item"]
