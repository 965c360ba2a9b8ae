"""Reading images and writing files safely.

``load_image_rgb`` turns whatever a user hands us (grey, RGBA, 16-bit, ...)
into one form: (H, W, 3) uint8 RGB. ``atomic_write`` guarantees that an output
path either holds a complete file or is untouched: data go to a temporary file
in the same folder, which is renamed over the target only once complete.
"""

from __future__ import annotations

import collections
import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from ._native import native_stderr_silenced
from .outputs import umask_mode
from .types import InputError

__all__ = [
    "load_image_rgb",
    "check_input_file",
    "to_rgb_uint8",
    "atomic_write",
    "save_image_rgb",
    "MIN_IMAGE_SIDE",
    "MAX_IMAGE_PIXELS",
]

#: Images smaller than this (pixels, either side) are refused: no landmark
#: model finds a face in them.
MIN_IMAGE_SIDE = 32


def to_rgb_uint8(image: NDArray[np.generic], name: str = "image") -> NDArray[np.uint8]:
    """Convert an image array of any common layout to (H, W, 3) uint8 RGB.

    Args:
        image: (H, W) grey, (H, W, 1) grey, (H, W, 3) RGB or (H, W, 4) RGBA;
            uint8, uint16 (scaled by 1/257), bool, or float in [0, 1] (above 1.001 refused).
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
        top = float(arr.max()) if arr.size else 0.0
        if top > 1.001:  # a float image of 0-255 levels would be clipped to white
            raise InputError(f"{name}: float pixel values up to {top:g}; expected levels from 0 to 1")
        out = np.round(np.clip(arr, 0.0, 1.0) * 255.0).astype(np.uint8)
    else:
        raise InputError(f"{name}: unsupported pixel type {arr.dtype}")
    h, w = out.shape[:2]
    if min(h, w) < MIN_IMAGE_SIDE:
        raise InputError(f"{name}: image is {w}x{h} pixels; at least {MIN_IMAGE_SIDE} on each side is needed")
    return np.ascontiguousarray(out)


#: Images with more pixels (width x height) than this are refused from their
#: header, before anything is decoded: 100 megapixels is 300 MB as 8-bit RGB
#: (and a few times that while converting), four times ETH-XGaze's 6000 x 4000
#: photos and well below OpenCV's own limit of 2^30 pixels (which it reports
#: as an exception from inside ``cv2.imdecode``).
MAX_IMAGE_PIXELS = 100_000_000
#: Images with a longer side than this are refused from their header too: MediaPipe's detector
#: aborts the whole process (SIGABRT, no Python error) on a side of 32767 px or more.
MAX_IMAGE_SIDE = 16384


def load_image_rgb(path: str | os.PathLike[str]) -> NDArray[np.uint8]:
    """Read an image file as (H, W, 3) uint8 RGB.

    Grey, RGBA, palette and 16-bit files are converted (see :func:`to_rgb_uint8`).
    The image's size is read from its header first (PNG ``IHDR``, JPEG ``SOF``,
    other formats through Pillow when it is installed): images above
    :data:`MAX_IMAGE_PIXELS`, or with a side above :data:`MAX_IMAGE_SIDE`, are refused without
    being decoded.

    The decoders' own lines on stderr (libpng's "iCCP: known incorrect sRGB
    profile", libjpeg's "Corrupt JPEG data") are silenced: a problem that
    matters is this function's InputError.

    Raises:
        InputError: the file is missing, cannot be read (permissions, I/O error),
            is not an image, is truncated, is larger than :data:`MAX_IMAGE_PIXELS`,
            or OpenCV fails to decode it.
    """
    import cv2

    p = Path(path)
    data = _read_bytes(p)
    if data.size == 0:
        raise InputError(f"{p}: the file is empty")
    if not _looks_complete(data):
        raise InputError(f"{p}: the image file is truncated")
    size = _header_size(data, p)
    if size is not None:
        _check_pixel_count(p, *size)
    try:
        with native_stderr_silenced():  # libpng and libjpeg print to descriptor 2 from C (damaged files, iCCP)
            img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:  # e.g. sizes beyond OpenCV's limits, or a decoder assertion
        reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{p}: OpenCV cannot decode the image ({reason})") from exc
    if img is None:
        raise InputError(f"{p}: not an image OpenCV can read (or the file is damaged)")
    _check_pixel_count(p, img.shape[1], img.shape[0])  # formats whose header was not read
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)  # a contiguous copy, much faster than img[..., ::-1]
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA)
    return to_rgb_uint8(img, name=str(p))


def check_input_file(path: str | os.PathLike[str]) -> Path:
    """``path`` as a Path when it names an existing file (not read here); an InputError naming it otherwise.

    Raises:
        InputError: "PATH: no such file" or "PATH: not a file" (a folder, a device).
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file")
    if not p.is_file():
        raise InputError(f"{p}: not a file")
    return p


def _read_bytes(p: Path) -> NDArray[np.uint8]:
    """The file's bytes, or an InputError naming it: missing, not a file, or unreadable (permissions, I/O error)."""
    try:
        check_input_file(p)
        return np.fromfile(str(p), dtype=np.uint8)
    except OSError as exc:
        raise InputError(f"{p}: cannot read the file ({exc.strerror or exc.__class__.__name__})") from exc


def _check_pixel_count(p: Path, width: int, height: int) -> None:
    """Refuse an image of ``width`` x ``height`` pixels too large to read.

    Above :data:`MAX_IMAGE_PIXELS`, or with a side above :data:`MAX_IMAGE_SIDE`.
    """
    if width * height > MAX_IMAGE_PIXELS:
        raise InputError(
            f"{p}: the image is {width}x{height} pixels ({width * height / 1e6:.1f} megapixels); "
            f"images above {MAX_IMAGE_PIXELS / 1e6:g} megapixels are refused (downscale it first)"
        )
    if max(width, height) > MAX_IMAGE_SIDE:
        raise InputError(
            f"{p}: the image is {width}x{height} pixels; a side above {MAX_IMAGE_SIDE} px is refused "
            "(downscale it first)"
        )


#: JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic), which carry the image size.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def _header_size(data: NDArray[np.uint8], p: Path) -> tuple[int, int] | None:
    """(width, height) from the file's header, or None when the header is not understood.

    PNG and JPEG are parsed here; other formats go through Pillow's header reader
    (when Pillow is installed). Nothing is decoded.
    """
    head = data[:8].tobytes()
    if head == b"\x89PNG\r\n\x1a\n":
        ihdr = data[8:24].tobytes()
        if len(ihdr) == 16 and ihdr[4:8] == b"IHDR":
            return int.from_bytes(ihdr[8:12], "big"), int.from_bytes(ihdr[12:16], "big")
        return None
    if head[:2] == b"\xff\xd8":
        return _jpeg_size(data)
    return _pillow_size(data, p)


#: What :func:`_jpeg_segments` yields for a byte where a marker should start and none does.
_JPEG_MALFORMED = -1


def _jpeg_segments(buf: bytes | memoryview) -> Iterator[tuple[int, int, int]]:
    """The markers of a JPEG's headers, in order: ``(offset, marker, length)``.

    Walked from just after SOI; ``length`` is the segment's length field (0 for markers without
    one: TEM, RSTn, SOI). Stops after yielding SOS (0xDA, the entropy-coded data follows) or EOI
    (0xD9), after yielding ``_JPEG_MALFORMED`` where no marker starts (or a length below 2), and
    silently where the data ends inside the headers (a truncated file).
    """
    n = len(buf)
    i = 2
    while i + 4 <= n:
        if buf[i] != 0xFF:
            yield i, _JPEG_MALFORMED, 0
            return
        marker = buf[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD8:  # markers without a length
            yield i, marker, 0
            i += 2
            continue
        if marker in (0xD9, 0xDA):
            yield i, marker, 0
            return
        length = (buf[i + 2] << 8) | buf[i + 3]
        if length < 2:
            yield i, _JPEG_MALFORMED, 0
            return
        yield i, marker, length
        i += 2 + length


def _jpeg_size(data: NDArray[np.uint8]) -> tuple[int, int] | None:
    """(width, height) from a JPEG's SOF segment, walking the segments before it; None if not found."""
    buf = memoryview(np.ascontiguousarray(data).data)  # indexing gives ints; nothing is copied
    for i, marker, length in _jpeg_segments(buf):
        if marker in _JPEG_SOF:
            if i + 9 > len(buf) or length < 7:
                return None
            height = (buf[i + 5] << 8) | buf[i + 6]
            width = (buf[i + 7] << 8) | buf[i + 8]
            return (width, height) if width and height else None  # height 0: given later (DNL); decode
    return None  # end of image, or scan data before any frame header, or a malformed header


def _pillow_size(data: NDArray[np.uint8], p: Path) -> tuple[int, int] | None:
    """(width, height) as Pillow reads it from the header (no pixel is decoded); None without Pillow or a match."""
    import io as _io
    import warnings

    try:
        from PIL import Image
    except ImportError:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(_io.BytesIO(data.tobytes())) as im:
                w, h = im.size
    except Image.DecompressionBombError as exc:  # above Pillow's own limit, which is above ours
        raise InputError(
            f"{p}: the image is larger than Pillow's limit of {2 * (Image.MAX_IMAGE_PIXELS or 0) / 1e6:g} "
            f"megapixels; images above {MAX_IMAGE_PIXELS / 1e6:g} megapixels are refused ({exc})"
        ) from exc
    except Exception:  # noqa: BLE001 - an unknown or damaged header: OpenCV decides
        return None
    return int(w), int(h)


#: EXIF orientation values (TIFF tag 0x0112): how a viewer shows the stored image, to show it upright.
EXIF_ORIENTATIONS = {
    1: "as stored",
    2: "mirrored left-right",
    3: "turned 180 deg",
    4: "mirrored top-bottom",
    5: "transposed",
    6: "turned 90 deg clockwise",
    7: "transversed",
    8: "turned 90 deg counter-clockwise",
}


def exif_orientation(path: str | os.PathLike[str]) -> int:
    """A JPEG file's EXIF orientation (1-8, :data:`EXIF_ORIENTATIONS`); 1 when it has none.

    :func:`load_image_rgb` does not apply it: an image is read as stored, so that a camera
    calibration (made in the sensor's orientation) and every pixel coordinate stay in one frame.
    Read from the file's APP1 segment only (nothing is decoded); unreadable or odd EXIF gives 1.
    """
    try:
        with open(path, "rb") as fh:
            raw = fh.read(1 << 18)  # the APP segments come first; EXIF's APP1 holds at most 64 kB
    except OSError:
        return 1
    if raw[:2] != b"\xff\xd8":
        return 1
    for i, marker, length in _jpeg_segments(raw):
        if marker == 0xE1 and raw[i + 4 : i + 10] == b"Exif\x00\x00":
            return _tiff_orientation(raw[i + 10 : i + 2 + length])
    return 1  # no EXIF before the scan


def _tiff_orientation(tiff: bytes) -> int:
    """The orientation tag (0x0112) of a TIFF header's first IFD; 1 when absent or unreadable."""
    order = {b"II": "little", b"MM": "big"}.get(tiff[:2])
    if order is None or len(tiff) < 8:
        return 1

    def num(at: int, size: int) -> int:
        return int.from_bytes(tiff[at : at + size], order)  # type: ignore[arg-type]

    ifd = num(4, 4)
    if ifd + 2 > len(tiff):
        return 1
    for k in range(num(ifd, 2)):
        entry = ifd + 2 + 12 * k
        if entry + 12 > len(tiff):
            return 1
        if num(entry, 2) == 0x0112 and num(entry + 2, 2) == 3:  # SHORT: its value in the entry itself
            value = num(entry + 8, 2)
            return value if value in EXIF_ORIENTATIONS else 1
    return 1


def _looks_complete(data: NDArray[np.uint8]) -> bool:
    """True unless a JPEG or PNG visibly lacks its end (OpenCV decodes truncated files silently).

    Bytes after the end are allowed (a phone's "motion photo" appends a video to its JPEG).
    JPEG: the segments are walked from SOI to the first SOS (so that an EXIF thumbnail's own EOI,
    inside APP1, does not count), then an EOI must follow. PNG: the chunks are walked by their
    lengths up to IEND, which must lie inside the file.
    """
    buf = memoryview(np.ascontiguousarray(data).data)  # indexing gives ints; nothing is copied
    if bytes(buf[:3]) == b"\xff\xd8\xff":
        for i, marker, _ in _jpeg_segments(buf):
            if marker in (_JPEG_MALFORMED, 0xD9):  # a layout this walk does not know: the decoder decides
                return True
            if marker == 0xDA:  # SOS: the entropy-coded data follows, then (more scans and) EOI
                return data[i:].tobytes().find(b"\xff\xd9") >= 0
        return False  # the file ends inside its headers
    if bytes(buf[:8]) == b"\x89PNG\r\n\x1a\n":
        i = 8
        while i + 8 <= len(buf):
            if bytes(buf[i + 4 : i + 8]) == b"IEND":
                return True
            i += 12 + int.from_bytes(buf[i : i + 4], "big")  # length, type, data, CRC
        return False
    return True


#: How many files :func:`atomic_write` has finished in this process, and the last of them
#: (:func:`files_written_since`: what a command wrote before a Ctrl-C).
_written_count = 0
_WRITTEN_LAST: collections.deque[Path] = collections.deque(maxlen=16)
#: Runs of consecutive finished files in one folder, ``[index of the first, folder, how many]``,
#: the last 1024 runs: beyond :data:`_WRITTEN_LAST`, a file whose folder was removed since (a
#: command's scratch folder) is not counted by :func:`files_written_since`.
_WRITTEN_RUNS: collections.deque[list[Any]] = collections.deque(maxlen=1024)


def files_written_count() -> int:
    """How many files :func:`atomic_write` has finished in this process (a mark for :func:`files_written_since`)."""
    return _written_count


def files_written_since(mark: int) -> tuple[list[Path], int]:
    """The files :func:`atomic_write` finished since ``mark`` (:func:`files_written_count`), in order.

    A file removed since (one a command wrote into a scratch folder of its own and removed with
    it, as ``gazeaug simulate`` and ``gazeaug calibrate`` do) is left out of both the names and
    the count. The last 16 files are checked one by one; before them, files are counted by
    folder: those in a folder removed since are left out, a single file removed from a folder
    that is still there cannot be seen and is counted.

    Returns:
        The last of them still there (at most 16; none when all of the last 16 were removed)
        and how many there are in all.
    """
    n = _written_count - mark
    if n <= 0:
        return [], 0
    last = list(_WRITTEN_LAST)[-n:]
    kept = [p for p in last if p.exists()]
    older_end = _written_count - len(last)  # files [mark, older_end) are beyond the last 16
    older = older_end - mark
    for first, folder, count in _WRITTEN_RUNS:
        overlap = min(first + count, older_end) - max(first, mark)
        if overlap > 0 and not folder.is_dir():
            older -= overlap
    return kept, older + len(kept)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike[str], mode: str = "wb") -> Iterator[IO[bytes]]:
    """Open a temporary file beside ``path``; rename it onto ``path`` only if the block succeeds.

    On any exception the temporary file is removed and ``path`` is untouched.
    The parent folder is created if missing. The file gets the permissions the
    umask gives (``0666 & ~umask``), as a plain ``open`` would. Each file finished is
    counted (:func:`files_written_since`).
    """
    global _written_count
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=str(target.parent))
    try:
        os.fchmod(fd, umask_mode())  # mkstemp makes 0600; outputs follow the umask like any other file
        with os.fdopen(fd, mode) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.replace(tmp, target)
        except OSError as exc:  # name the file asked for, not the temporary one beside it
            raise OSError(exc.errno, exc.strerror, str(target)) from exc
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    if _WRITTEN_RUNS and _WRITTEN_RUNS[-1][1] == target.parent:
        _WRITTEN_RUNS[-1][2] += 1
    else:
        _WRITTEN_RUNS.append([_written_count, target.parent, 1])
    _written_count += 1
    _WRITTEN_LAST.append(target)


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
