"""Reading a tar archive that came from elsewhere (an allocation's ``records.tar.gz``) without letting it make
pokeworld decompress, hold or write more than a bound.

``tarfile`` trusts the headers: opening an archive reads every header, and a pax or GNU long-name header's data (its
declared size, however large) is read into memory before anything can look at it; ``extractall`` writes whatever
the member list holds, tens of thousands of entries included, and a repeated name overwrites the first. So an
archive is first *scanned* (:func:`scan`): its stream decompressed in bounded chunks and its 512-byte headers parsed
here, each declared size refused beyond :class:`TarBounds` before a byte of its data is read, the entries counted,
only regular files, folders and small pax records admitted. Only an archive that passes is then read with
``tarfile`` in streaming mode (:func:`extract`), each member's name checked by tarfile's ``data`` filter, a repeated
name refused, and each file written exclusively (``O_EXCL | O_NOFOLLOW``) into a new private folder.
"""

from __future__ import annotations

import os
import tarfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from .errors import ConfigError
from .io import create_new

BLOCK = 512
READ_CHUNK = 1 << 20
"""Compressed bytes read, and most decompressed bytes produced, at a time."""
ADMITTED_TYPES = {b"0": "file", b"\0": "file", b"5": "folder", b"x": "pax record"}


@dataclass(frozen=True)
class TarBounds:
    """What an archive may hold."""

    members: int = 4096
    """Most entries (files and folders; an allocation's records are a few dozen)."""
    member_bytes: int = 64 << 20
    """Largest declared size of one file."""
    total_bytes: int = 128 << 20
    """Largest sum of declared sizes (files and pax records)."""
    record_bytes: int = 64 << 10
    """Largest pax record (a member's long name, its exact time; tarfile reads it whole into memory)."""


def header_size(block: bytes, where: str) -> int:
    """The size field of a tar header (octal, or GNU base-256); ConfigError when it is neither."""
    field = block[124:136]
    if field[0] & 0x80:  # base-256: a size no allocation's records reach
        return int.from_bytes(field[1:], "big")
    digits = field.replace(b"\0", b" ").strip()
    try:
        return int(digits or b"0", 8)
    except ValueError:
        raise ConfigError(f"{where}: a tar header's size field is not a number; the archive is damaged") from None


def checksum_ok(block: bytes) -> bool:
    """The header's checksum as tar computes it (its own field counted as spaces; signed or unsigned bytes)."""
    try:
        stored = int(block[148:156].replace(b"\0", b" ").strip() or b"-1", 8)
    except ValueError:
        return False
    blanked = block[:148] + b" " * 8 + block[156:]
    unsigned = sum(blanked)
    signed = sum(b - 256 if b > 127 else b for b in blanked)
    return stored in (unsigned, signed)


def chunks(path: Path, compressed: bool, what: str = "an archive") -> Iterator[bytes]:
    """The archive's (decompressed) bytes in pieces of at most :data:`READ_CHUNK`; gzip members one after another."""
    with open(path, "rb") as fh:
        if not compressed:
            while piece := fh.read(READ_CHUNK):
                yield piece
            return
        d = zlib.decompressobj(wbits=31)
        pending = b""
        while True:
            data = pending or fh.read(READ_CHUNK)
            if not data:
                return
            try:
                out = d.decompress(data, READ_CHUNK)
            except zlib.error as e:
                raise ConfigError(f"{path} is not {what} pokeworld wrote (gzip: {e})") from None
            pending = d.unconsumed_tail
            if d.eof:  # another gzip member may follow (tarfile reads concatenated members too)
                pending = d.unused_data
                d = zlib.decompressobj(wbits=31)
            if out:
                yield out


def scan(path: Path, bounds: TarBounds = TarBounds(), compressed: bool = True, what: str = "an archive") -> int:
    """Check ``path``'s tar headers against ``bounds`` without reading any member's data into memory (a pax
    record, at most ``bounds.record_bytes``, is read: it may override the next member's size); returns the number
    of entries. ConfigError naming the archive and the first entry over a bound, of another type (link, device,
    sparse or GNU long-name), or with a damaged header."""
    entries, declared, skip, keep, buf, pax = 0, 0, 0, 0, b"", b""
    for piece in chunks(path, compressed, what):
        buf += piece
        while True:
            if skip:
                dropped = min(skip, len(buf))
                pax += buf[:min(dropped, keep)]
                keep = max(keep - dropped, 0)
                buf, skip = buf[dropped:], skip - dropped
                if skip:
                    break
            if len(buf) < BLOCK:
                break
            block, buf = buf[:BLOCK], buf[BLOCK:]
            if block == bytes(BLOCK):
                return entries  # the end-of-archive marker: tarfile reads no further
            is_pax = block[156:157] == b"x"
            size = check_header(block, path, bounds, entries, pax_size(pax, path) if not is_pax else None)
            pax = b"" if not is_pax else pax
            declared += size
            entries += not is_pax
            if entries > bounds.members:
                raise ConfigError(f"{path} holds more than {bounds.members} entries; an allocation's records are a "
                                  "few dozen files: not an archive pokeworld wrote")
            if declared > bounds.total_bytes:
                raise ConfigError(f"{path} declares more than {bounds.total_bytes >> 20} MiB of content; refused "
                                  "before reading it (an allocation's records are a few MiB)")
            skip = -(-size // BLOCK) * BLOCK
            keep = size if is_pax else 0
    if skip or buf:
        raise ConfigError(f"{path} ends inside an entry; the archive is truncated or damaged")
    return entries


PAX_KEYS = {"path", "mtime", "atime", "ctime", "uid", "gid", "uname", "gname", "size", "comment", "hdrcharset"}
"""The pax keywords a file's record may hold (tarfile writes path, mtime and the owners); others (GNU sparse maps,
link names, global records) are refused."""


def pax_size(record: bytes, path: Path) -> int | None:
    """The ``size`` a pax record sets for the next member (None when it sets none); ConfigError for a keyword
    outside :data:`PAX_KEYS` or a malformed record."""
    size = None
    rest = record.rstrip(b"\0")
    while rest:
        length, _, tail = rest.partition(b" ")
        try:
            n = int(length)
            key, _, value = rest[len(length) + 1:n - 1].partition(b"=")
            word = key.decode("ascii")
        except (ValueError, UnicodeDecodeError):
            raise ConfigError(f"{path}: a pax record is malformed; the archive is damaged") from None
        if n <= len(length) or word not in PAX_KEYS:
            raise ConfigError(f"{path}: a pax record holds {word[:40]!r}; only {sorted(PAX_KEYS)} are read")
        if word == "size":
            try:
                size = int(value)
            except ValueError:
                raise ConfigError(f"{path}: a pax record's size is not a number; the archive is damaged") from None
        rest = rest[n:]
    return size


def check_header(block: bytes, path: Path, bounds: TarBounds, index: int, override: int | None = None) -> int:
    """One header's declared size (``override``: a preceding pax record's), after its checksum, type and size are
    checked against ``bounds``."""
    if not checksum_ok(block):
        raise ConfigError(f"{path}: tar header {index + 1} has a wrong checksum; the archive is damaged")
    kind = ADMITTED_TYPES.get(block[156:157])
    name = block[:100].split(b"\0", 1)[0].decode("utf-8", "replace")[:80]
    if kind is None:
        raise ConfigError(f"{path}: entry {name!r} is of tar type {block[156:157]!r} (a link, device, sparse file "
                          "or GNU long name); only files and folders are read")
    size = header_size(block, str(path)) if override is None else override
    if size < 0:
        raise ConfigError(f"{path}: {kind} {name!r} declares a negative size; the archive is damaged")
    limit = bounds.record_bytes if kind == "pax record" else bounds.member_bytes
    if size > limit:
        raise ConfigError(f"{path}: {kind} {name!r} declares {size} bytes, more than the {limit} allowed; refused "
                          "before reading it")
    if kind == "folder" and size:
        raise ConfigError(f"{path}: folder {name!r} declares {size} bytes of content; the archive is damaged")
    return size


def write_new(path: Path, data: bytes) -> None:
    """Create ``path`` (never an existing name, never through a link) holding ``data``: an untrusted archive unpacks
    into the caller's fresh scratch folder, where the only safe write is an exclusive create (:func:`io.create_new`;
    an atomic rename would replace a planted entry)."""
    create_new(path, data)


def extract(path: Path, dest: Path, bounds: TarBounds = TarBounds(), compressed: bool = True,
            what: str = "an archive") -> int:
    """Unpack the archive at ``path`` into the new, empty folder ``dest`` after :func:`scan` passed it: tarfile in
    streaming mode, each member through tarfile's ``data`` filter (no absolute name, no ``..``, no link), a
    repeated name refused, files created exclusively. Returns the number of files. ConfigError on anything else."""
    scan(path, bounds, compressed, what)
    seen: set[str] = set()
    files = 0
    try:
        with tarfile.open(path, "r|gz" if compressed else "r|") as tar:
            for info in tar:
                try:
                    info = tarfile.data_filter(info, str(dest))
                except tarfile.FilterError as e:
                    raise ConfigError(f"{path}: entry {info.name[:80]!r} is refused ({e})") from None
                name = os.path.normpath(info.name)
                if name in seen:
                    raise ConfigError(f"{path} holds {name[:80]!r} twice; an archive pokeworld wrote names each "
                                      "file once")
                seen.add(name)
                target = dest / name
                if info.isdir():
                    target.mkdir(parents=True, exist_ok=True)
                    continue
                if not info.isfile():
                    raise ConfigError(f"{path}: entry {name[:80]!r} is neither a file nor a folder")
                target.parent.mkdir(parents=True, exist_ok=True)
                write_new(target, tar.extractfile(info).read(bounds.member_bytes + 1))
                files += 1
    except (tarfile.TarError, EOFError, OSError) as e:
        raise ConfigError(f"{path} is not {what} pokeworld wrote ({type(e).__name__}: {e})") from None
    return files


__all__ = ["TarBounds", "scan", "extract", "check_header", "header_size", "checksum_ok", "chunks", "write_new",
           "pax_size",
           "PAX_KEYS"]
