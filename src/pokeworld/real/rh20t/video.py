"""Camera frames: timestamps, mp4 / extracted-image decoding, nearest frame per grid time, crop and resize."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from .config import ConvertConfig
from .files import open_dataset_file, read_dataset_file
from .records import load_pickled_dict
from .skips import SceneSkip

MAX_FRAME_PIXELS = 4096 * 4096
"""Largest frame (width x height) decoded: RH20T's cameras record 1280 x 720. Checked in the image header (PIL reads
only the header on open) or the video stream's declared size before any decoding, so a small file declaring a
16384 x 16384 frame (a 261 KB PNG) cannot allocate gigabytes. PIL's own ``Image.MAX_IMAGE_PIXELS`` (a process-wide
setting, left as it is) is larger; its ``DecompressionBombError`` is counted the same way."""
MAX_IMAGE_FILE_BYTES = 64 << 20
"""Largest extracted frame file read [bytes]."""


def crop_resize(gray: np.ndarray, crop: tuple[float, ...], out_hw: tuple[int, int], rotate: int = 0) -> np.ndarray:
    """Rotate (degrees counter-clockwise, multiple of 90), crop (fractions, or a square: centred, or bottom for a
    rotated camera) and area-resize one grayscale image."""
    import cv2

    if rotate % 360:
        code = {90: cv2.ROTATE_90_COUNTERCLOCKWISE, 180: cv2.ROTATE_180, 270: cv2.ROTATE_90_CLOCKWISE}[rotate % 360]
        gray = cv2.rotate(gray, code)
    h, w = gray.shape
    if rotate % 360 and not crop:  # sideways camera: bottom square, as the RH20T authors' loader crops it
        s = min(h, w)
        box = gray[h - s:, (w - s) // 2: (w - s) // 2 + s]
    elif crop:
        t, l, b, r = crop
        box = gray[int(round(t * h)): max(int(round(b * h)), int(round(t * h)) + 1),
                   int(round(l * w)): max(int(round(r * w)), int(round(l * w)) + 1)]
    else:
        s = min(h, w)
        y0, x0 = (h - s) // 2, (w - s) // 2
        box = gray[y0: y0 + s, x0: x0 + s]
    return cv2.resize(box, (out_hw[1], out_hw[0]), interpolation=cv2.INTER_AREA)


def read_camera(cam_dir: Path, t_grid: np.ndarray, cfg: ConvertConfig, out_hw: tuple[int, int],
                rotate: int = 0, root: Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Camera timestamps (ms, sorted) and, if ``t_grid`` is given, the nearest frame for each grid time.

    ``color.mp4`` + ``timestamps.npy`` is used when present, else extracted ``color/<ts>.jpg``.
    With ``t_grid=None`` only the timestamps are returned (frames empty). Every file read must be a regular file
    inside ``root`` (``None``: inside ``cam_dir``).
    """
    root = cam_dir if root is None else root
    mp4, tsf, jpg_dir = cam_dir / "color.mp4", cam_dir / "timestamps.npy", cam_dir / "color"
    if os.path.lexists(mp4):
        meta = load_pickled_dict(tsf, "camera timestamps.npy", root)
        if "color" not in meta:
            raise SceneSkip("bad_stream", f"{tsf} has no 'color' key (keys: {sorted(meta)})")
        try:
            ts = np.asarray(meta["color"], np.int64).reshape(-1)
        except (TypeError, ValueError, OverflowError) as e:
            raise SceneSkip("bad_stream", f"{tsf} 'color' is not a list of integer timestamps "
                                          f"({type(e).__name__}: {e})") from None
        if ts.size == 0:
            raise SceneSkip("empty_video", f"{tsf} lists no color frames")
        if not np.all((ts > 1e12) & (ts < 1e13)) or np.any(np.diff(ts) <= 0):
            raise SceneSkip("bad_timestamps", f"{tsf} color timestamps are not increasing 13-digit milliseconds")
        if t_grid is None:
            return ts, np.zeros((0, *out_hw), np.uint8)
        idx = _nearest(ts, t_grid, cfg.frame_tolerance_s, cam_dir.name)
        frames = _decode_mp4(mp4, root, len(ts), np.unique(idx), cfg.crop, out_hw, rotate)
        return ts, np.stack([frames[i] for i in idx])
    if jpg_dir.is_dir():
        files = {}
        for f in jpg_dir.iterdir():
            if f.suffix.lower() in (".jpg", ".jpeg", ".png") and f.stem[:13].isdigit():
                files[int(f.stem[:13])] = f
        if not files:
            raise SceneSkip("empty_video", f"{jpg_dir} holds no <timestamp>.jpg frames")
        ts = np.asarray(sorted(files), np.int64)
        if not np.all(ts > 1e12):
            raise SceneSkip("bad_timestamps", f"{jpg_dir} image names are not 13-digit millisecond timestamps")
        if t_grid is None:
            return ts, np.zeros((0, *out_hw), np.uint8)
        idx = _nearest(ts, t_grid, cfg.frame_tolerance_s, cam_dir.name)
        cache: dict[int, np.ndarray] = {}
        for i in np.unique(idx):
            img = _read_gray_image(files[int(ts[i])], root)
            cache[int(i)] = crop_resize(img, cfg.crop, out_hw, rotate)
        return ts, np.stack([cache[int(i)] for i in idx])
    raise SceneSkip("missing_stream", f"{cam_dir} has neither color.mp4 nor a color/ image folder")


def check_image_header(data: bytes, path: Path) -> None:
    """Refuse (``huge_image``) a frame whose header declares more than :data:`MAX_FRAME_PIXELS` pixels, and
    (``unreadable_video``) one whose header cannot be parsed; PIL's ``Image.open`` reads the header only."""
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as im:
            w, h = im.size
    except Image.DecompressionBombError as e:  # PIL's own, larger limit spoke first
        raise SceneSkip("huge_image", f"image {path}: {e} (MAX_FRAME_PIXELS = {MAX_FRAME_PIXELS})") from None
    except Exception as e:  # PIL.UnidentifiedImageError, damaged headers
        raise SceneSkip("unreadable_video", f"cannot read the header of image {path}: "
                                            f"{type(e).__name__}: {e}") from None
    if w * h > MAX_FRAME_PIXELS:
        raise SceneSkip("huge_image", f"image {path} declares {w} x {h} pixels (> MAX_FRAME_PIXELS = "
                                      f"{MAX_FRAME_PIXELS})")


def _read_gray_image(path: Path, root: Path) -> np.ndarray:
    """Decode one extracted frame to grayscale; a truncated file skips the scene.

    OpenCV decodes a JPEG cut short without an error (libjpeg only warns and fills the missing rows with gray),
    so a frame must end with its end-of-image marker (JPEG ``FFD9``, PNG ``IEND`` chunk) before it is decoded;
    its header's size is checked first (:func:`check_image_header`).
    """
    import cv2

    try:
        data = read_dataset_file(path, root, "image", MAX_IMAGE_FILE_BYTES)
    except SceneSkip:  # a DataError, hence a ValueError: not a read failure
        raise
    except (OSError, ValueError) as e:  # vanished, or larger than any frame
        raise SceneSkip("unreadable_video", f"cannot read image {path}: {e}") from None
    end = data.rstrip(b"\x00")  # zero padding after the end marker is harmless
    complete = end.endswith(b"IEND\xaeB`\x82") if path.suffix.lower() == ".png" else end.endswith(b"\xff\xd9")
    if not complete:
        raise SceneSkip("unreadable_video", f"image {path} is truncated (no end-of-image marker, {len(data)} bytes)")
    check_image_header(data, path)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise SceneSkip("unreadable_video", f"cannot decode image {path}")
    return img


def _nearest(ts: np.ndarray, t_grid: np.ndarray, tol_s: float, what: str) -> np.ndarray:
    j = np.clip(np.searchsorted(ts, t_grid), 1, len(ts) - 1) if len(ts) > 1 else np.zeros(len(t_grid), int)
    if len(ts) > 1:
        j = np.where(np.abs(ts[j - 1] - t_grid) <= np.abs(ts[j] - t_grid), j - 1, j)
    off = np.abs(ts[j] - t_grid) / 1000.0
    if off.max() > tol_s:
        k = int(off.argmax())
        raise SceneSkip("frame_gap", f"{what}: nearest frame to grid time {t_grid[k]:.0f} is {off[k]:.3f} s away "
                                     f"(> frame_tolerance_s={tol_s})")
    return j


def _check_stream_size(stream, path: Path) -> None:
    """Refuse (``huge_image``) a video stream that declares frames larger than :data:`MAX_FRAME_PIXELS`."""
    w, h = int(stream.codec_context.width or 0), int(stream.codec_context.height or 0)
    if w * h > MAX_FRAME_PIXELS:
        raise SceneSkip("huge_image", f"{path} declares {w} x {h} frames (> MAX_FRAME_PIXELS = {MAX_FRAME_PIXELS})")


def _decode_mp4(path: Path, root: Path, n_expected: int, wanted: np.ndarray, crop, out_hw,
                rotate: int = 0) -> dict[int, np.ndarray]:
    try:
        fh = open_dataset_file(path, root, "color video")
    except OSError as e:
        raise SceneSkip("unreadable_video", f"cannot open {path}: {e}") from None
    with fh:
        if os.fstat(fh.fileno()).st_size == 0:
            raise SceneSkip("empty_video", f"{path} is an empty file")
        return _decode_container(fh, path, n_expected, wanted, crop, out_hw, rotate)


def _decode_container(fh, path: Path, n_expected: int, wanted: np.ndarray, crop, out_hw,
                      rotate: int) -> dict[int, np.ndarray]:
    import av

    wanted_set = set(int(i) for i in wanted)
    out: dict[int, np.ndarray] = {}
    n = 0
    try:
        with av.open(fh) as container:
            if not container.streams.video:
                raise SceneSkip("empty_video", f"{path} has no video stream")
            _check_stream_size(container.streams.video[0], path)
            for frame in container.decode(video=0):
                if n in wanted_set:
                    out[n] = crop_resize(frame.to_ndarray(format="gray"), crop, out_hw, rotate)
                n += 1
    except SceneSkip:
        raise
    except Exception as e:  # av.error.* (invalid data, EOF...) for damaged containers
        if n == 0:
            raise SceneSkip("unreadable_video", f"cannot decode {path}: {type(e).__name__}: {e}") from None
        raise SceneSkip("truncated_video", f"{path}: decoding stopped after {n} of {n_expected} frames "
                                           f"({type(e).__name__}: {e})") from None
    if n == 0:
        raise SceneSkip("empty_video", f"{path} decodes to 0 frames")
    if n < n_expected:
        raise SceneSkip("truncated_video", f"{path} has {n} frames but timestamps.npy lists {n_expected}")
    if n > n_expected:
        raise SceneSkip("frame_count_mismatch", f"{path} has {n} frames but timestamps.npy lists only {n_expected}")
    return out
