"""Small file helpers: atomic writes, JSON, content hashing, and the guards that keep pokeworld from destroying,
following or hanging on what a user points it at.

The guards, for every writer of an output folder:

* every file pokeworld writes is recorded by name in its folder's ``.pokeworld-owned`` (:func:`record_owned`), and
  an existing file is replaced or appended to only when recorded there (:func:`check_replaceable`): a user's
  ``metrics.jsonl`` or ``plan.md`` in a folder given as ``--out`` is refused, never overwritten, whatever the command
  and whatever ``--overwrite`` says;
* :func:`atomic_path` writes inside a private temporary folder (``.<name>.tmp-<random>``, created exclusively with
  mode 0700, so nobody else can plant a link in it), never writes through or replaces a symbolic link, and replaces
  an existing folder only when an :class:`OwnedDir` verifies it as one pokeworld wrote (removing its files one by
  one, never recursively);
* :func:`open_nofollow` opens a file for writing (lock files, ``metrics.jsonl``) without following a link and
  only if it is a regular file with no other name;
* :func:`check_writable_dir` fails in one line before a long computation whose output could not be written;
* :func:`check_regular_file` / :func:`read_regular_bytes` refuse links, FIFOs, devices and oversized files
  before reading, so a planted special file cannot hang a reader; :func:`read_json` is the one reader of every JSON
  record pokeworld reads back (bounded, regular files only, the top-level type checked, one-line errors).
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import json
import os
import re
import shutil
import stat
import tempfile
import warnings
from pathlib import Path
from typing import IO, Any, Callable, Iterator

import numpy as np

from .errors import ConfigError, DataError
from .faults import crash_point


def _file_kind(mode: int) -> str:
    """A file type in words, for refusals."""
    kinds = ((stat.S_ISLNK, "symbolic link"), (stat.S_ISDIR, "folder"), (stat.S_ISFIFO, "FIFO (named pipe)"),
             (stat.S_ISSOCK, "socket"), (stat.S_ISCHR, "character device"), (stat.S_ISBLK, "block device"))
    for test, name in kinds:
        if test(mode):
            return name
    return "regular file" if stat.S_ISREG(mode) else "special file"


def _link_line(path: Path) -> str:
    try:
        return f"{path} is a symbolic link (to {os.readlink(path)})"
    except OSError:
        return f"{path} is a symbolic link"


@dataclasses.dataclass(frozen=True)
class OwnedDir:
    """What makes an existing folder one pokeworld wrote, and so one it may replace.

    ``files``: patterns (``re.fullmatch``) of the regular files pokeworld writes in it (a store: ``data\\.h5``...);
    ``dirs``: (pattern, :class:`OwnedDir`) of the subfolders it writes there and what those hold. Their temporary
    names (``.<name>.tmp-<random>``, left by an interrupted atomic write, and older ``.<name>.tmp-<pid>`` /
    ``.<name>.old-<pid>``) and the folder's ownership record (``.pokeworld-owned``) count as ours too.
    Anything else inside, at any depth — another file or folder, a link, a FIFO — makes the folder foreign.
    ``verify``, if given, is a further check of an otherwise-owned folder (e.g. that its manifest parses and names
    the same kind of artifact); it raises :class:`~pokeworld.errors.ConfigError` to refuse.
    """

    files: tuple[str, ...]
    dirs: tuple[tuple[str, "OwnedDir"], ...] = ()
    verify: Callable[[Path], None] | None = None

    @staticmethod
    def _matching(patterns, name: str) -> str | None:
        """The pattern ``name`` is (or is a temporary name of), else None."""
        return next((p for p in patterns if re.fullmatch(rf"(?:\.(?:{p})\.(?:tmp|old)-{_TMP_SUFFIX})|(?:{p})", name)),
                    None)

    def owns_file(self, entry: os.DirEntry) -> bool:
        """An entry pokeworld wrote as a file here: a regular file (not a link) named by ``files``, or the folder's
        ownership record."""
        return entry.is_file(follow_symlinks=False) and (
            entry.name == OWNED_RECORD or self._matching(self.files, entry.name) is not None)

    def owns_temporary(self, entry: os.DirEntry) -> bool:
        """A private temporary folder an interrupted :func:`atomic_path` of one of our names left here."""
        m = _TEMPORARY.fullmatch(entry.name)
        return (m is not None and entry.is_dir(follow_symlinks=False)
                and self._matching(self.files + tuple(p for p, _ in self.dirs), m.group(1)) is not None)

    def subfolder(self, entry: os.DirEntry) -> "OwnedDir | None":
        """What an own subfolder (a real folder, not a link, named by ``dirs``) holds; None for anything else."""
        if not entry.is_dir(follow_symlinks=False):
            return None
        pattern = self._matching([p for p, _ in self.dirs], entry.name)
        return None if pattern is None else dict(self.dirs)[pattern]


def foreign_entries(directory: str | os.PathLike, owned: OwnedDir) -> list[str]:
    """Sorted paths, relative to ``directory``, of what pokeworld did not write there (see :class:`OwnedDir`);
    [] when it holds nothing else."""
    foreign = []
    with os.scandir(directory) as it:
        for e in it:
            inner = owned.subfolder(e)
            if inner is not None:
                foreign += [f"{e.name}/{n}" for n in foreign_entries(e.path, inner)]
            elif not (owned.owns_file(e) or owned.owns_temporary(e)):
                foreign.append(e.name)
    return sorted(foreign)


def check_owned_dir(directory: str | os.PathLike, owned: OwnedDir) -> None:
    """Raise ConfigError unless ``directory`` holds only what ``owned`` names (and passes its ``verify``)."""
    foreign = foreign_entries(directory, owned)
    if foreign:
        shown = ", ".join(repr(n) for n in foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
        raise ConfigError(f"{directory} holds {shown}, which pokeworld did not write; it never deletes what it did "
                          "not create: choose another output path, or move those files away yourself")
    if owned.verify is not None:
        owned.verify(Path(directory))


def remove_owned_dir(directory: str | os.PathLike, owned: OwnedDir) -> None:
    """Delete what pokeworld wrote in ``directory`` (its own files and, recursively, its own subfolders; each
    entry checked, never a blind tree removal), then the folder itself.

    A folder that still holds anything else afterwards (it appeared meanwhile) is left in place with a warning.
    """
    directory = Path(directory)
    with os.scandir(directory) as it:
        for e in it:
            inner = owned.subfolder(e)
            if inner is not None:
                remove_owned_dir(e.path, inner)
            elif owned.owns_file(e):  # a file of the folder's own layout (checked above), not a user's
                _unlink_regular(Path(e.path))
            elif owned.owns_temporary(e):
                _discard(Path(e.path))
    try:
        os.rmdir(directory)
    except OSError as e:
        warnings.warn(f"left {directory} in place: {e.strerror} (it holds files pokeworld did not write)",
                      stacklevel=2)


def _unlink_regular(path: Path) -> bool:
    """Unlink ``path`` if it is a regular file (False when missing); a folder, link or special file is refused with
    a ConfigError naming it, so no delete ever reaches through a link to its target."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return False
    if not stat.S_ISREG(mode):
        raise ConfigError(f"{path} is a {_file_kind(mode)} where pokeworld expected a file it wrote; it deletes only "
                          "its own regular files: remove or move it yourself")
    if os.lstat(path).st_uid != os.getuid():
        raise ConfigError(f"{path} belongs to another user, so this user's pokeworld did not write it; it deletes "
                          "only its own files: remove or move it yourself")
    # ownership is proven by the two callers before this: remove_owned_dir (a file of the folder's own OwnedDir
    # layout, in a folder check_owned_dir found holding nothing else) and remove_own_file (listed in the folder's
    # ownership record, or one of our temporary / staging names); a link swapped in after the lstat is itself what
    # unlink removes, never its target
    os.unlink(path)
    return True


def staging_path(path: str | os.PathLike) -> Path:
    """A sibling of ``path`` for a third-party writer (h5py, swm's writers) to write into before a rename:
    ``.<stem>.staging-<pid><suffix>`` (the suffix kept: such writers pick the layout from it). The name is what
    :func:`remove_own_file` recognises as a staging copy of ours."""
    path = Path(path)
    return path.with_name(f".{path.stem}.staging-{os.getpid()}{path.suffix}")


_STAGING = re.compile(r"\..+\.staging-\d+(?:\.[A-Za-z0-9]+)?")


def remove_own_file(path: str | os.PathLike) -> None:
    """Delete one file pokeworld wrote (a stale temporary, a damaged cache entry, an output it replaces): only a
    regular file that its folder's :data:`OWNED_RECORD` lists, or one of our temporary (:func:`atomic_path`) or
    staging (:func:`staging_path`) names. A file pokeworld did not record, a folder, a link (whose target a careless
    delete could reach through) or a special file is refused with a ConfigError naming it. A missing file is
    nothing to do."""
    path = Path(path)
    if not os.path.lexists(path):
        return
    ours = (path.name in owned_names(path.parent) or _TEMPORARY.fullmatch(path.name) is not None
            or _STAGING.fullmatch(path.name) is not None)
    if not ours and stat.S_ISREG(os.lstat(path).st_mode):
        raise ConfigError(f"{path} was not written by pokeworld (its folder's {OWNED_RECORD} does not list it); it "
                          "deletes only its own files: remove or move it yourself, or choose another output path")
    _unlink_regular(path)


_TMP_SUFFIX = r"(?:\d+|[a-z0-9_]{8})"
# ".<name>.tmp-<random>": a private folder from tempfile.mkdtemp (8 random characters); "<pid>" names are older ones
_TEMPORARY = re.compile(rf"\.(.+)\.tmp-{_TMP_SUFFIX}")

OWNED_RECORD = ".pokeworld-owned"
"""The file, in every folder pokeworld writes into, that names (one per line) the files it wrote there."""
MAX_OWNED_RECORD_BYTES = 4 << 20


def owned_names(folder: str | os.PathLike) -> set[str]:
    """The names ``folder``'s ownership record lists (empty when it has none)."""
    path = Path(folder) / OWNED_RECORD
    try:
        raw = read_regular_bytes(path, "pokeworld's ownership record", MAX_OWNED_RECORD_BYTES)
    except DataError:
        if not os.path.lexists(path):
            return set()
        raise
    return set(raw.decode("utf-8", errors="replace").splitlines())


def record_owned(path: str | os.PathLike) -> None:
    """Record that pokeworld wrote ``path`` (a line in its folder's :data:`OWNED_RECORD`), so that a later run may
    replace it. Append-only, no link followed: concurrent writers at worst record a name twice."""
    path = Path(path)
    if path.name in owned_names(path.parent):
        return
    with _open_nofollow_raw(path.parent / OWNED_RECORD, "a") as fh:
        fh.write(path.name + "\n")


def check_replaceable(path: str | os.PathLike) -> None:
    """Raise ConfigError unless ``path`` is absent, a folder (checked by its own :class:`OwnedDir`), or a file
    pokeworld recorded writing (:func:`record_owned`): no command ever replaces or appends to a user's file."""
    path = Path(path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISDIR(st.st_mode):
        return
    if stat.S_ISLNK(st.st_mode):
        raise ConfigError(f"{_link_line(path)}; pokeworld does not write through or replace links: remove the link")
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{path} is a {_file_kind(st.st_mode)}, not a regular file; pokeworld writes only regular "
                          "files there: remove it")
    if path.name == OWNED_RECORD or path.name in owned_names(path.parent):
        return
    raise ConfigError(f"{path} exists and pokeworld did not write it (it is not listed in {path.parent / OWNED_RECORD}"
                      "); pokeworld never replaces a file it did not write, not even with --overwrite: move the file "
                      "away or choose another output folder")


def check_apart(inputs, outputs) -> None:
    """Raise ConfigError when a command's output would replace or write into one of its own inputs: an output
    that is an input (the same resolved path, or the same file through another name: a hard link, a link), lies
    inside an input folder, or is a folder holding an input. Ownership records say who wrote a file, not which
    command may replace it, so a record pokeworld wrote is protected from the command reading it; checked on
    the paths before anything is read or written."""
    ins = [(Path(i), Path(i).resolve()) for i in inputs if i is not None]
    for o in (Path(o) for o in outputs if o is not None):
        ro = o.resolve()
        for i, ri in ins:
            try:
                same = ro == ri or (os.path.exists(o) and os.path.exists(i) and os.path.samefile(o, i))
            except OSError:
                same = False
            if same or ri in ro.parents or ro in ri.parents:
                how = "is" if same else ("lies inside" if ri in ro.parents else "holds")
                raise ConfigError(f"the output {o} {how} the input {i}: a command never replaces or writes into "
                                  "what it reads; choose another output path")


def adopt_legacy(folder: str | os.PathLike, names) -> list[str]:
    """Record ``names`` (the regular files among them that are there) as pokeworld's in ``folder`` when it has no
    ownership record at all: for a folder its format's owner has verified as one pokeworld wrote before records
    existed (a run folder by its config.json, a map folder by its map_config.json). A folder that cannot be
    written is left as it is (its files are then read, never replaced). Returns the names recorded."""
    folder = Path(folder)
    if os.path.lexists(folder / OWNED_RECORD):
        return []
    found = [n for n in names if os.path.isfile(folder / n) and not os.path.islink(folder / n)]
    try:
        for name in found:
            record_owned(folder / name)
    except OSError:
        return []
    return found


def check_outputs(folder: str | os.PathLike, *names: str) -> Path:
    """The output-folder contract, checked before a command computes anything: ``folder`` can be created and
    written (:func:`check_writable_dir`), and each of the ``names`` it will write there is new, or a file pokeworld
    wrote and may replace (:func:`check_replaceable`), and not a link. Returns the folder."""
    folder = Path(folder)
    check_writable_dir(folder)
    for name in names:
        _refuse_link(folder / name)
        check_replaceable(folder / name)
    return folder


def temporary_folder(final: Path) -> Path:
    """A new private folder beside ``final`` to write it in: ``.<name>.tmp-<random>``, created exclusively with mode
    0700 (:func:`tempfile.mkdtemp`), so its name cannot be predicted and nobody else can plant a link inside it; the
    name :class:`OwnedDir` and :func:`remove_stale_temporaries` recognise."""
    return Path(tempfile.mkdtemp(prefix=f".{final.name}.tmp-", dir=final.parent))


def remove_stale_temporaries(folder: str | os.PathLike, name: str | None = None) -> int:
    """Delete what interrupted atomic writes left directly in ``folder``: private temporary folders
    (``.<name>.tmp-<random>``, walked without following links) and older temporary files (``.<name>.tmp-<pid>``); a
    link under such a name is left alone; with ``name``, only the temporaries of that one output. Only for outputs
    whose writers have all stopped (the caller holds their lock). Returns how many were removed."""
    removed = 0
    with os.scandir(folder) as it:
        for e in it:
            m = _TEMPORARY.fullmatch(e.name)
            if m and (name is None or m.group(1) == name) and (e.is_file(follow_symlinks=False)
                                                                or e.is_dir(follow_symlinks=False)):
                removed += _discard(Path(e.path))
    return removed


def remove_temporary(tmp: str | os.PathLike) -> bool:
    """Remove one private temporary folder this process made with :func:`temporary_folder` (and what it holds,
    no link followed); whether anything was removed."""
    return _discard(Path(tmp))


def _discard(tmp: Path) -> bool:
    """Remove a temporary of ours (a name :data:`_TEMPORARY` matches; any other name is refused): a link there is
    unlinked, never followed; a folder is emptied entry by entry (:func:`_remove_temporary_tree`), and only when it is
    a private folder of this user as :func:`temporary_folder` makes it. Whether anything was removed."""
    if not _TEMPORARY.fullmatch(tmp.name):
        raise ValueError(f"{tmp} is not a pokeworld temporary name; refusing to delete it")
    if tmp.is_symlink() or tmp.is_file():
        # a name only atomic_path / temporary_folder make (checked above), passed by the code that made it, and a file
        # of this user as they make it; unlink of a link removes the link, never its target
        if os.lstat(tmp).st_uid != os.getuid():
            warnings.warn(f"left {tmp} in place: named like a pokeworld temporary, but another user's", stacklevel=2)
            return False
        tmp.unlink()
        return True
    if tmp.is_dir():
        st = os.lstat(tmp)
        if st.st_uid != os.getuid() or stat.S_IMODE(st.st_mode) & 0o077:  # not what temporary_folder makes
            warnings.warn(f"left {tmp} in place: named like a pokeworld temporary, but not a private (0700) folder "
                          "of this user, which is all temporary_folder makes", stacklevel=2)
            return False
        _remove_temporary_tree(tmp)
        return True
    return False


def _remove_temporary_tree(folder: Path) -> None:
    """Delete a temporary folder :func:`atomic_path` made, walking it without following any link: regular files
    and links are unlinked (a link's target is never touched), real subfolders recursed into; anything else (a FIFO, a
    socket, a device) is left, and the folder with it, with a warning naming it."""
    with os.scandir(folder) as it:
        for e in it:
            if e.is_dir(follow_symlinks=False):
                _remove_temporary_tree(Path(e.path))
            elif e.is_symlink() or e.is_file(follow_symlinks=False):
                # inside a 0700 folder of this user that temporary_folder made (checked by _discard): nobody else
                # could have put it there; a link is unlinked, its target untouched
                os.unlink(e.path)
            else:
                warnings.warn(f"left {e.path} in place: not a file, link or folder", stacklevel=2)
    try:
        os.rmdir(folder)
    except OSError as err:
        warnings.warn(f"left temporary folder {folder} in place: {err.strerror}", stacklevel=2)


def _refuse_link(final: Path) -> None:
    if final.is_symlink():
        raise ConfigError(f"{_link_line(final)}; pokeworld does not write through or replace links: remove the "
                          "link or give the real path")


def _install(tmp: Path, final: Path, replace: OwnedDir | None) -> None:
    """Move the finished ``tmp`` (inside its private folder) to ``final``: a plain rename, except over an existing
    folder, which must be empty or verified by ``replace``; that one is moved into the private folder, the new one
    renamed in, and the old one's files removed."""
    _refuse_link(final)
    check_replaceable(final)
    try:
        st = os.lstat(final)
    except FileNotFoundError:
        os.replace(tmp, final)
        return
    tmp_is_dir = tmp.is_dir()
    if not stat.S_ISDIR(st.st_mode):
        if tmp_is_dir:
            raise ConfigError(f"{final} is an existing {_file_kind(st.st_mode)}, not a folder; choose a folder path")
        os.replace(tmp, final)  # a file replacing a file we wrote: the ordinary atomic write
        return
    if not tmp_is_dir:
        raise ConfigError(f"{final} is a folder; cannot write a file under that name")
    if replace is None:
        try:
            os.replace(tmp, final)  # the kernel replaces only an empty folder
        except OSError as e:
            if e.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                raise
            raise ConfigError(f"{final} is a non-empty folder; pokeworld replaces a folder only after verifying "
                              "it wrote it: choose another output path") from None
        return
    check_owned_dir(final, replace)
    old = tmp.parent / ".replaced"
    os.rename(final, old)
    try:
        os.replace(tmp, final)
    except BaseException:
        os.rename(old, final)
        raise
    remove_owned_dir(old, replace)


def _space_error(e: OSError, final: Path) -> ConfigError:
    """One line for a full disk or a file-size limit met while writing ``final``."""
    try:
        free = f"{shutil.disk_usage(final.parent).free} bytes free there"
    except OSError:
        free = "free space unknown"
    what = "no space left on device" if e.errno == errno.ENOSPC else "file size limit reached"
    return ConfigError(f"{what} while writing {final} ({free}); free some space or choose another output folder, "
                       "then run the command again (nothing partial was kept)")


@contextlib.contextmanager
def atomic_path(final: str | os.PathLike, replace: OwnedDir | None = None) -> Iterator[Path]:
    """Yield a path to write ``final`` under (file or folder); rename it to ``final`` only if the block succeeds.

    The path lies inside a private temporary folder (:func:`temporary_folder`), so a crash never leaves a
    half-written artifact under the final name and no planted link can redirect the write. Safe by default:
    ``final`` must not be a symbolic link, an existing file must be one pokeworld recorded writing
    (:func:`check_replaceable`, checked before the block and again before the rename), and an existing folder is
    replaced only if it is empty or ``replace`` verifies it as pokeworld's own (:class:`OwnedDir`); even then only
    the files it names are deleted, never a tree (:func:`remove_owned_dir`). A full disk reads as one line.
    """
    final = Path(final)
    _refuse_link(final)
    check_replaceable(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    private = temporary_folder(final)
    try:
        yield private / final.name
        crash_point(f"rename:{final.name}")
        _install(private / final.name, final, replace)
        record_owned(final)
    except BaseException as e:
        _discard(private)  # only our own half-written output is in it
        if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
            raise _space_error(e, final) from None
        raise
    try:
        os.rmdir(private)
    except OSError:  # a file that appeared in a replaced folder meanwhile: never deleted, left with a warning
        warnings.warn(f"left {private} in place: it holds files pokeworld did not write", stacklevel=2)


def check_writable_dir(directory: str | os.PathLike) -> None:
    """Create ``directory`` if needed and prove it writable by creating an unnamed temporary file there, so that a
    long computation does not end in a write error; raise ConfigError saying why not."""
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(f"cannot create output folder {directory}: {e.strerror or e}; choose another output "
                          "path") from None
    try:
        # an unnamed file where the OS offers one (O_TMPFILE): nothing is left to delete, not even our own probe
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as e:
        raise ConfigError(f"output folder {directory} is not writable ({e.strerror or e}); choose another output "
                          "path or fix its permissions") from None


_WRITE_FLAGS = {"a": os.O_WRONLY | os.O_CREAT | os.O_APPEND, "a+": os.O_RDWR | os.O_CREAT | os.O_APPEND,
                "w": os.O_WRONLY | os.O_CREAT}
# no link followed at open; no blocking on a FIFO (its open fails or the fstat check refuses it)
_SAFE_OPEN = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)


def _refuse_unwritable_name(path: Path, st: os.stat_result) -> None:
    if stat.S_ISLNK(st.st_mode):
        raise ConfigError(f"{_link_line(path)}; pokeworld does not write through links (it would overwrite the "
                          "target): remove the link")
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{path} is a {_file_kind(st.st_mode)}, not a regular file; pokeworld writes only "
                          "regular files there: remove it")
    if st.st_nlink > 1:
        raise ConfigError(f"{path} has {st.st_nlink} hard links; writing it would change the other names' file "
                          "too: remove it (or replace it by a copy)")


def _open_nofollow_raw(path: str | os.PathLike, mode: str = "a") -> IO[str]:
    """:func:`open_nofollow` without the ownership check (for the ownership record itself)."""
    if mode not in _WRITE_FLAGS:
        raise ValueError(f"open_nofollow mode must be one of {sorted(_WRITE_FLAGS)}, got {mode!r}")
    path = Path(path)
    try:
        _refuse_unwritable_name(path, os.lstat(path))
    except FileNotFoundError:
        pass
    try:
        fd = os.open(path, _WRITE_FLAGS[mode] | _SAFE_OPEN, 0o666)
    except OSError as e:
        if e.errno in (errno.ELOOP, errno.ENXIO, errno.EISDIR):  # a link, a FIFO without reader, a folder
            _refuse_unwritable_name(path, os.lstat(path))
        raise
    try:
        _refuse_unwritable_name(path, os.fstat(fd))
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        if mode == "w":
            os.ftruncate(fd, 0)
        return os.fdopen(fd, mode)
    except BaseException:
        os.close(fd)
        raise


def open_nofollow(path: str | os.PathLike, mode: str = "a") -> IO[str]:
    """Open ``path`` for writing (text ``mode`` "a", "a+" or "w") without following a symbolic link, and only if it
    is new or a file pokeworld recorded writing (:func:`check_replaceable`); a new file is recorded as ours.

    Refuses (ConfigError naming the path) a user's file, a link, anything but a regular file (a FIFO would block, a
    device be written), and a file with other hard links, so a planted link never makes pokeworld truncate or
    append to another file. The check is made on the opened descriptor too (``O_NOFOLLOW``, ``fstat``), so swapping
    the name between check and open does not get past it. "w" truncates only after those checks.
    """
    path = Path(path)
    try:  # a link, a special file or another name of the same file is named as such, before whose file it is
        _refuse_unwritable_name(path, os.lstat(path))
    except FileNotFoundError:
        pass
    check_replaceable(path)
    fh = _open_nofollow_raw(path, mode)
    try:
        record_owned(path)
    except BaseException:
        fh.close()
        raise
    return fh


def check_regular_file(path: str | os.PathLike, what: str, max_bytes: int | None = None) -> os.stat_result:
    """Raise DataError unless ``path`` is a regular file (not a link, FIFO, device or folder) of at most
    ``max_bytes``: reading a FIFO blocks forever and a device never ends. Returns its ``lstat``."""
    path = Path(path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        raise DataError(f"{path} does not exist ({what})") from None
    if stat.S_ISLNK(st.st_mode):
        raise DataError(f"{_link_line(path)}; {what} must be a regular file inside the folder, not a link")
    if not stat.S_ISREG(st.st_mode):
        raise DataError(f"{path} is a {_file_kind(st.st_mode)}, not a regular file; refusing to read it as {what}")
    if max_bytes is not None and st.st_size > max_bytes:
        raise DataError(f"{path} is {st.st_size} bytes; {what} may be at most {max_bytes} bytes")
    return st


def read_regular_bytes(path: str | os.PathLike, what: str, max_bytes: int) -> bytes:
    """The bytes of ``path`` after :func:`check_regular_file`, checked again on the opened descriptor (no link
    followed, no blocking open) and never more than ``max_bytes``."""
    check_regular_file(path, what, max_bytes)
    try:
        fd = os.open(path, os.O_RDONLY | _SAFE_OPEN)
    except OSError as e:
        raise DataError(f"cannot open {path} ({what}): {e.strerror or e}") from None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise DataError(f"{path} changed into a non-regular file while being opened; refusing to read it")
        data = fh.read(min(st.st_size, max_bytes) + 1)  # read(n) allocates n bytes up front: ask for what is there
    if len(data) > max_bytes:
        raise DataError(f"{path} is over {max_bytes} bytes; {what} may be at most {max_bytes} bytes")
    return data


def save_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Atomically write ``data`` to ``path`` under the output contract (:func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def create_new(path: str | os.PathLike, data: bytes) -> None:
    """Create the file ``path`` holding ``data``: never an existing name (FileExistsError), never through a link
    (O_NOFOLLOW), mode 0600. For files inside a folder being built — an untrusted archive unpacked into a fresh
    scratch folder, a synthetic corpus inside :func:`atomic_path`'s private temporary — where the folder as a whole
    is the output and an atomic rename per file would replace a planted entry instead of refusing it."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)


def save_text(path: str | os.PathLike, text: str) -> None:
    """Atomically write ``text`` (UTF-8) to ``path`` under the output contract (:func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def save_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray], compressed: bool = False) -> None:
    """Atomically write ``arrays`` as an ``.npz`` to ``path`` under the output contract (:func:`atomic_path`); numpy
    writes through an open file so it never appends its own ``.npz`` to the temporary's name."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        (np.savez_compressed if compressed else np.savez)(fh, **arrays)


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Atomically write ``obj`` as indented JSON."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, sort_keys=True, default=_json_default) + "\n")


def append_jsonl(path: str | os.PathLike, obj: Any) -> None:
    """Append ``obj`` as one JSON line; a link or special file under ``path`` is refused (:func:`open_nofollow`)."""
    with open_nofollow(path, "a") as fh:
        fh.write(json.dumps(obj, sort_keys=True, default=_json_default) + "\n")


MAX_JSON_BYTES = 4 << 20
"""The default bound on a JSON record pokeworld reads back: its manifests, configs and measurements are kilobytes,
and parsing costs up to ~25 times a file's size in memory, so a larger file is refused before it is read."""

_JSON_TYPES = {dict: "object", list: "array", str: "string", int: "number", float: "number", bool: "true/false"}


def _json_type(obj: Any) -> str:
    return "null" if obj is None else _JSON_TYPES.get(type(obj), type(obj).__name__)


def parse_json(raw: bytes, path: str | os.PathLike, what: str, remedy: str = "", error: type = DataError) -> Any:
    """``raw`` (bytes already read within a bound, e.g. one line of a log) parsed as JSON; ``error`` naming ``path``,
    ``what`` it should be and the ``remedy`` when it is not."""
    try:
        return json.loads(raw.decode("utf-8"))
    except (ValueError, RecursionError) as e:  # JSONDecodeError, bad UTF-8, a 5000-digit int; nesting too deep
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise error(f"{path} is not valid JSON ({first}), so not {what} pokeworld wrote; "
                    f"{remedy or 'restore it or write it again with the command that made it'}") from None


def read_json(path: str | os.PathLike, what: str, expect: type | tuple[type, ...] | None = dict,
              max_bytes: int = MAX_JSON_BYTES, remedy: str = "", error: type = DataError) -> Any:
    """The one reader of a JSON record pokeworld reads back (manifests, configs, earlier outputs): a regular file of
    at most ``max_bytes`` (no link, FIFO or device; :func:`read_regular_bytes`), valid JSON, its top level of type
    ``expect`` (None: any); otherwise one line (``error``, DataError by default) naming the file, ``what`` it should
    be and the ``remedy``."""
    path = Path(path)
    try:
        raw = read_regular_bytes(path, what, max_bytes)
    except DataError as e:
        raise error(str(e)) from None
    obj = parse_json(raw, path, what, remedy, error)
    if expect is not None and not isinstance(obj, expect):
        want = " or ".join(sorted({_JSON_TYPES.get(t, t.__name__) for t in
                                   (expect if isinstance(expect, tuple) else (expect,))}))
        raise error(f"{path} is not {what} pokeworld wrote (it holds a JSON {_json_type(obj)}, not a JSON {want}); "
                    f"{remedy or 'restore it or write it again with the command that made it'}")
    return obj


def read_json_if_present(path: str | os.PathLike, what: str, expect: type | tuple[type, ...] | None = dict,
                         max_bytes: int = MAX_JSON_BYTES, remedy: str = "", error: type = DataError) -> Any:
    """:func:`read_json`, or None when nothing (not even a link) is at ``path``."""
    return read_json(path, what, expect, max_bytes, remedy, error) if os.path.lexists(path) else None


def read_jsonl(path: str | os.PathLike, what: str = "a JSON-lines record", max_bytes: int = 64 << 20) -> list[dict]:
    """The JSON objects, one a line, of a bounded regular file (:func:`read_json`'s checks); [] when absent."""
    path = Path(path)
    if not os.path.lexists(path):
        return []
    out = []
    for i, line in enumerate(read_regular_bytes(path, what, max_bytes).splitlines()):
        if len(line) > MAX_JSON_BYTES:  # parsing costs ~25x a line's size: the same bound as a whole record's
            raise DataError(f"{path} line {i + 1} is {len(line)} bytes; a line of {what} may be at most "
                            f"{MAX_JSON_BYTES} bytes; restore it or write it again")
        if line.strip():
            row = parse_json(line, path, f"{what} (line {i + 1})")
            if not isinstance(row, dict):
                raise DataError(f"{path} line {i + 1} is not {what} pokeworld wrote (it holds a JSON "
                                f"{_json_type(row)}, not a JSON object); restore it or write it again")
            out.append(row)
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
    fh = open_nofollow(path / lock_name, "a+")  # a planted link must not make the lock truncate its target
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
    return save_figure_as(fig, [Path(out) / f"{stem}.png", Path(out) / f"{stem}.pdf"], dpi)


def save_figure_as(fig, paths: list[Path], dpi: int = 150) -> list[Path]:
    """Write ``fig`` to each of ``paths`` (the format from its suffix, png without one), each atomically; closes it."""
    import matplotlib.pyplot as plt

    try:
        for p in paths:
            with atomic_path(p) as tmp:
                fig.savefig(tmp, dpi=dpi, format=Path(p).suffix[1:] or "png")
    finally:
        plt.close(fig)
    return [Path(p) for p in paths]
