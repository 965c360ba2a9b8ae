"""Reading images and writing files safely.

``load_image_rgb`` turns whatever a user hands us (grey, RGBA, 16-bit, ...)
into one form: (H, W, 3) uint8 RGB. ``atomic_write`` guarantees that an output
path either holds a complete file or is untouched: data go to a temporary file
in the same folder, which is renamed over the target only once complete.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from .types import InputError

__all__ = ["load_image_rgb", "to_rgb_uint8", "atomic_write", "save_image_rgb", "MIN_IMAGE_SIDE"]

#: Images smaller than this (pixels, either side) are refused: no landmark
#: model finds a face in them.
MIN_IMAGE_SIDE = 32


def to_rgb_uint8(image: NDArray[np.generic], name: str = "image") -> NDArray[np.uint8]:
    """Convert an image array of any common layout to (H, W, 3) uint8 RGB.

    Args:
        image: (H, W) grey, (H, W, 1) grey, (H, W, 3) RGB or (H, W, 4) RGBA;
            uint8, uint16 (scaled by 1/257), bool, or float in [0, 1].
        name: what to call the image in error messages.

    Returns:
        (H, W, 3) uint8 RGB (alpha dropped; transparent pixels keep their colour).
    """
    arr: NDArray[Any] = np.asarray(image)
    out: NDArray[np.uint8]
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=2)
    elif arr.ndim == 3 and arr.shape[2] == 4:
        arr = arr[..., :3]
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise InputError(f"{name}: expected a grey, RGB or RGBA image, got an array of shape {arr.shape}")
    if arr.dtype == np.uint8:
        out = arr
    elif arr.dtype == np.uint16:
        out = np.round(arr.astype(np.float64) / 257.0).astype(np.uint8)
    elif arr.dtype == np.bool_:
        out = (arr.astype(np.uint8) * 255).astype(np.uint8)
    elif np.issubdtype(arr.dtype, np.floating):
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{name}: contains NaN or infinite values")
        out = np.round(np.clip(arr, 0.0, 1.0) * 255.0).astype(np.uint8)
    else:
        raise InputError(f"{name}: unsupported pixel type {arr.dtype}")
    h, w = out.shape[:2]
    if min(h, w) < MIN_IMAGE_SIDE:
        raise InputError(f"{name}: image is {w}x{h} pixels; at least {MIN_IMAGE_SIDE} on each side is needed")
    return np.ascontiguousarray(out)


def load_image_rgb(path: str | os.PathLike[str]) -> NDArray[np.uint8]:
    """Read an image file as (H, W, 3) uint8 RGB.

    Grey, RGBA, palette and 16-bit files are converted (see :func:`to_rgb_uint8`).

    Raises:
        InputError: the file is missing, is not an image, or is truncated.
    """
    import cv2

    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file")
    if not p.is_file():
        raise InputError(f"{p}: not a file")
    data = np.fromfile(str(p), dtype=np.uint8)
    if data.size == 0:
        raise InputError(f"{p}: the file is empty")
    if not _looks_complete(data):
        raise InputError(f"{p}: the image file is truncated")
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"{p}: not an image OpenCV can read (or the file is damaged)")
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)  # a contiguous copy, much faster than img[..., ::-1]
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA)
    return to_rgb_uint8(img, name=str(p))


def _looks_complete(data: NDArray[np.uint8]) -> bool:
    """True unless a JPEG or PNG visibly lacks its end marker (OpenCV decodes truncated files silently)."""
    head = data[:8].tobytes()
    tail = data[-32:].tobytes()
    if head[:3] == b"\xff\xd8\xff":  # JPEG: must end with EOI (allow trailing padding)
        return b"\xff\xd9" in tail
    if head == b"\x89PNG\r\n\x1a\n":  # PNG: must end with the IEND chunk
        return b"IEND" in tail
    return True


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike[str], mode: str = "wb") -> Iterator[IO[bytes]]:
    """Open a temporary file beside ``path``; rename it onto ``path`` only if the block succeeds.

    On any exception the temporary file is removed and ``path`` is untouched.
    The parent folder is created if missing.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=str(target.parent))
    try:
        with os.fdopen(fd, mode) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def save_image_rgb(path: str | os.PathLike[str], image: NDArray[np.uint8]) -> None:
    """Write an (H, W, 3) uint8 RGB image (format from the suffix, e.g. .png), atomically."""
    import cv2

    target = Path(path)
    ext = target.suffix.lower() or ".png"
    ok, buf = cv2.imencode(ext, np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise InputError(f"{target}: cannot encode an image as {ext}")
    with atomic_write(target) as fh:
        fh.write(buf.tobytes())
