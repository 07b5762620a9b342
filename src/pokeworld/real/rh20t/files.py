"""Which files of a scene may be read: regular files inside the dataset root, each refused otherwise with a reason.

A dataset is untrusted input: a FIFO or device where ``metadata.json``, a pickled stream or a frame is expected
would hang the conversion or stream forever, and a symlink (or a metadata ``calib`` value with ``../`` or an absolute
path) would read files from anywhere on the machine into the store. Every file the converter reads goes through
:func:`dataset_file`: the path is resolved (symlinks followed), must stay inside the dataset root, and must be a
regular file (:mod:`pokeworld.real.regular_files`, which also opens it without blocking).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, BinaryIO

from ..regular_files import NotRegularFileError, check_regular, open_regular
from .skips import SceneSkip


def scene_root(cfg_root: str, scene_dir: Path) -> Path:
    """The folder no file of the scene may resolve outside of: the converted root, else the scene's parent."""
    return Path(cfg_root).resolve() if cfg_root else scene_dir.parent.resolve()


def _inside(path: Path, root: Path | None, what: str) -> Path:
    boundary = (root if root is not None else path.parent).resolve()
    try:
        real = path.resolve()
    except (OSError, RuntimeError) as e:  # a symlink loop
        raise SceneSkip("special_file", f"{what} {path} cannot be resolved ({type(e).__name__}: {e})") from None
    if not real.is_relative_to(boundary):
        raise SceneSkip("outside_root", f"{what} {path} resolves to {real}, outside the dataset root {boundary}")
    return real


def dataset_file(path: Path, root: Path | None, what: str) -> Path | None:
    """The resolved ``path`` if it is a regular file inside ``root`` (``None``: inside the path's own folder); None if
    it is absent. Raises :class:`SceneSkip` ``outside_root`` or ``special_file``."""
    real = _inside(path, root, what)
    try:
        check_regular(real)
    except FileNotFoundError:
        return None
    except NotRegularFileError as e:
        raise SceneSkip("special_file", f"{what}: {e}") from None
    return real


def open_dataset_file(path: Path, root: Path | None, what: str) -> BinaryIO:
    """:func:`dataset_file`'s checks, then the file opened (``special_file`` also if it was swapped meanwhile);
    ``FileNotFoundError`` if it is absent."""
    real = dataset_file(path, root, what)
    if real is None:
        raise FileNotFoundError(f"{what} {path} is absent")
    try:
        return open_regular(real)
    except NotRegularFileError as e:
        raise SceneSkip("special_file", f"{what}: {e}") from None


def read_dataset_file(path: Path, root: Path | None, what: str, max_bytes: int) -> bytes:
    """The bytes of a checked file (:func:`open_dataset_file`); ``ValueError`` beyond ``max_bytes``."""
    with open_dataset_file(path, root, what) as fh:
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise ValueError(f"{what} {path} is larger than {max_bytes} bytes")
    return data


def calibration_folder(scene_dir: Path, calib: Any, root: Path | None) -> Path:
    """``<RH20T_cfgN>/calib/<calib>`` for a metadata ``calib`` value, refused (``outside_root``) when the value is an
    absolute path or climbs out with ``..``, or the folder resolves outside the dataset root."""
    name = str(calib)
    folder = scene_dir.parent / "calib" / name
    if Path(name).is_absolute() or ".." in Path(name).parts or "\x00" in name:
        raise SceneSkip("outside_root", f"metadata calib {name!r:.80} is not a folder name under "
                                        f"{scene_dir.parent / 'calib'}")
    _inside(folder, root if root is not None else scene_dir.parent, "calibration folder")
    return folder


__all__ = ["scene_root", "dataset_file", "open_dataset_file", "read_dataset_file", "calibration_folder"]
