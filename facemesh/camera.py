"""Camera intrinsics: calibration files and the documented default.

Calibration files:

OpenCV FileStorage (``.xml``, ``.yml``, ``.yaml``, ``.json``)
    The camera matrix under one of ``camera_matrix``, ``Camera_Matrix``,
    ``cameraMatrix``, ``K``; the distortion under one of ``cam_distortion``,
    ``dist_coeffs``, ``distortion_coefficients``, ``Distortion_Coefficients``,
    ``distCoeffs``, ``D`` (optional: none means no distortion); the image size,
    when present, under ``image_width``/``image_height`` (any capitalisation).
    MPIIFaceGaze's ``cameraCalib.xml``, ETH-XGaze's ``camXX.xml`` and OpenCV's
    own calibration output all read as is.
MATLAB ``.mat``
    MPIIFaceGaze's ``Calibration/Camera.mat``: ``cameraMatrix`` and ``distCoeffs``.

Without a file, :func:`default_camera` assumes a pinhole camera with focal
length ``max(width, height)`` pixels (a 53 deg field of view across the long
side, typical of webcams and phone cameras), the principal point at the image
centre ``((W - 1) / 2, (H - 1) / 2)`` and no distortion, and warns.

Plausibility checks on every file read (each failure is an :class:`InputError`
naming the file): matrices whose ``rows`` x ``cols`` disagree with their
``data``; non-numeric, NaN or infinite values; image sizes that are not whole
numbers in ``[1, 2^20]``; focal lengths outside
:data:`FOCAL_LENGTH_RANGE` times the image's long side; distortion
coefficients larger than :data:`MAX_DISTORTION_COEFFICIENT` in magnitude; and
a principal point more than :data:`PRINCIPAL_POINT_MARGIN_PX` outside the image
(within that margin it only warns, :class:`PrincipalPointWarning`; anywhere
inside the image, however far from the centre, is accepted).
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .types import CameraIntrinsics, InputError

__all__ = [
    "load_camera",
    "CameraSizeMissing",
    "default_camera",
    "check_calibration",
    "DefaultCameraWarning",
    "PrincipalPointWarning",
    "PRINCIPAL_POINT_MARGIN_PX",
    "FOCAL_LENGTH_RANGE",
    "MAX_DISTORTION_COEFFICIENT",
]

_MATRIX_KEYS = ("camera_matrix", "Camera_Matrix", "cameraMatrix", "CameraMatrix", "K")
_DIST_KEYS = ("cam_distortion", "dist_coeffs", "distortion_coefficients", "Distortion_Coefficients", "distCoeffs", "D")
_WIDTH_KEYS = ("image_width", "image_Width", "Image_Width", "imageWidth", "width")
_HEIGHT_KEYS = ("image_height", "image_Height", "Image_Height", "imageHeight", "height")


#: How far, in pixels, the principal point may lie outside the image (whose
#: edges are at -0.5 and W - 0.5, H - 0.5 with pixel centres at integers)
#: before a calibration is refused. A few pixels out is a rounding or cropping
#: slip and only warns; farther out, the calibration belongs to another image
#: size or another camera (a real lens's optical axis goes through its sensor).
PRINCIPAL_POINT_MARGIN_PX = 5.0

#: Accepted focal lengths, as multiples of the image's long side: 0.05x is a
#: field of view of 169 deg across it (beyond any pinhole model), 1000x one of
#: 0.06 deg. Values outside are typos or garbage (1e300, 0.001) that would make
#: every later stage fail obscurely.
FOCAL_LENGTH_RANGE = (0.05, 1000.0)

#: Largest accepted magnitude of a distortion coefficient. Real calibrations
#: stay within a few units (rational-model k4..k6 within some tens).
MAX_DISTORTION_COEFFICIENT = 1e4

#: Largest image side accepted in a calibration file, pixels (OpenCV's own limit).
_MAX_SIDE_PX = 1 << 20

#: Largest rows or cols accepted in a FileStorage matrix (ours are 3 x 3 and at most 1 x 14).
_MAX_MATRIX_DIM = 1000


class CameraSizeMissing(InputError):
    """A calibration file that gives no image size, read without one (:func:`load_camera`'s ``image_size``).

    Commands that read frames (``gazeaug track``, ``calibrate``) catch it and size the camera by the
    first frame.
    """


class DefaultCameraWarning(UserWarning):
    """No calibration was given; the default intrinsics are used."""


class PrincipalPointWarning(UserWarning):
    """The calibration's principal point lies outside the image, by at most :data:`PRINCIPAL_POINT_MARGIN_PX`."""


def default_camera(width: int, height: int) -> CameraIntrinsics:
    """The documented default camera for a ``width`` x ``height`` image (see the module docstring)."""
    f = float(max(width, height))
    k = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    return CameraIntrinsics(matrix=k, distortion=np.zeros(5), image_size=(width, height), source="default")


def camera_for_image(path: str | Path | None, width: int, height: int, *, warn: bool = True) -> CameraIntrinsics:
    """The calibration in ``path`` checked against the image size, or the default camera (with a warning)."""
    if path is None:
        if warn:
            warnings.warn(
                f"no camera calibration given: assuming focal length {max(width, height)} px, "
                "principal point at the image centre, no distortion",
                DefaultCameraWarning,
                stacklevel=2,
            )
        return default_camera(width, height)
    cam = load_camera(path, image_size=(width, height))
    if cam.image_size != (width, height):
        raise InputError(
            f"{path}: the calibration is for {cam.image_size[0]}x{cam.image_size[1]} images, "
            f"but the image is {width}x{height}"
        )
    return cam


def load_camera(path: str | Path, image_size: tuple[int, int] | None = None) -> CameraIntrinsics:
    """Read a calibration file (formats in the module docstring).

    Args:
        path: the file.
        image_size: (width, height) to use when the file does not say.

    Raises:
        InputError: missing or malformed file, naming it and what is wrong.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: calibration file not found")
    if p.suffix.lower() == ".mat":
        k, dist, size = _read_mat(p)
    else:
        k, dist, size = _read_filestorage(p)
    size = size or image_size
    if size is None:
        raise CameraSizeMissing(f"{p}: the file gives no image size; pass the image's size")
    try:
        cam = CameraIntrinsics(matrix=k, distortion=dist, image_size=size, source=str(p))
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from exc
    check_calibration(cam, str(p))
    return cam


def check_calibration(camera: CameraIntrinsics, name: str | None = None) -> None:
    """Refuse implausible intrinsics; warn about a principal point just outside the image.

    Args:
        camera: the intrinsics, with the size of the images they are for.
        name: what to call them in messages (default: ``camera.source``).

    Raises:
        InputError: a focal length outside :data:`FOCAL_LENGTH_RANGE` times the
            image's long side, a distortion coefficient above
            :data:`MAX_DISTORTION_COEFFICIENT`, or a principal point more than
            :data:`PRINCIPAL_POINT_MARGIN_PX` outside the image.

    Warns:
        PrincipalPointWarning: the principal point lies outside the image, within the margin.
    """
    name = name or camera.source
    w, h = camera.image_size
    k = camera.matrix
    lo, hi = FOCAL_LENGTH_RANGE
    side = max(w, h)
    for label, f in (("fx", k[0, 0]), ("fy", k[1, 1])):
        if not lo * side <= f <= hi * side:
            raise InputError(
                f"{name}: focal length {label} = {f:g} px is implausible for a {w}x{h} image "
                f"(expected {lo:g} to {hi:g} times the long side: {lo * side:g} to {hi * side:g} px)"
            )
    big = np.abs(camera.distortion) > MAX_DISTORTION_COEFFICIENT
    if np.any(big):
        i = int(np.argmax(big))
        raise InputError(
            f"{name}: distortion coefficient {i} = {camera.distortion[i]:g} is implausible "
            f"(expected magnitudes up to {MAX_DISTORTION_COEFFICIENT:g})"
        )
    cx, cy = float(k[0, 2]), float(k[1, 2])
    # pixel centres at integers: the image spans [-0.5, W - 0.5] x [-0.5, H - 0.5]
    outside = max(-0.5 - cx, cx - (w - 0.5), -0.5 - cy, cy - (h - 0.5))
    if outside <= 0:
        return
    where = f"{name}: the principal point ({cx:g}, {cy:g}) px lies {outside:.1f} px outside the {w}x{h} image"
    if outside > PRINCIPAL_POINT_MARGIN_PX:
        raise InputError(
            f"{where} (refused beyond {PRINCIPAL_POINT_MARGIN_PX:g} px: is the calibration for another image "
            "size or another camera?)"
        )
    warnings.warn(f"{where} (accepted within {PRINCIPAL_POINT_MARGIN_PX:g} px)", PrincipalPointWarning, stacklevel=3)


def _read_mat(p: Path) -> tuple[np.ndarray, np.ndarray, tuple[int, int] | None]:
    from scipy.io import loadmat

    try:
        m = loadmat(str(p))
    except Exception as exc:  # scipy raises several types for bad files
        raise InputError(f"{p}: not a readable MATLAB file ({exc})") from exc
    if "cameraMatrix" not in m:
        raise InputError(f"{p}: no 'cameraMatrix' variable (expected MPIIFaceGaze's Camera.mat)")
    k = _mat_numbers(p, "cameraMatrix", m["cameraMatrix"])
    dist = _mat_numbers(p, "distCoeffs", m.get("distCoeffs", np.zeros(5))).ravel()
    if k.shape != (3, 3):
        raise InputError(f"{p}: cameraMatrix: expected shape (3, 3), got {k.shape}")
    return k, dist, None


def _mat_numbers(p: Path, name: str, value: Any) -> np.ndarray:
    """A MATLAB variable as a float64 array, or InputError (text, cells, structs and complex numbers are refused)."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf":
        kind = {"c": "complex numbers", "U": "text", "S": "text", "O": "a cell array", "V": "a struct"}.get(
            arr.dtype.kind, f"values of type {arr.dtype}"
        )
        raise InputError(f"{p}: {name}: expected a real numeric matrix, got {kind}")
    return np.asarray(arr, dtype=np.float64)


def _read_filestorage(p: Path) -> tuple[np.ndarray, np.ndarray, tuple[int, int] | None]:
    import cv2

    try:
        with p.open("rb") as fh:
            head = fh.read(64).lstrip()
    except OSError as exc:
        raise InputError(f"{p}: cannot read the calibration file ({exc.strerror or exc})") from exc
    if not (
        head.startswith(b"<?xml") or head.startswith(b"%YAML") or head.startswith(b"<opencv") or head.startswith(b"{")
    ):
        raise InputError(f"{p}: not an OpenCV FileStorage file (XML, YAML or JSON)")
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError, ValueError, UnicodeError) as exc:  # OpenCV's parser errors surface as these
        raise InputError(f"{p}: malformed calibration file ({_cv_reason(exc)})") from exc
    try:
        if not fs.isOpened():
            raise InputError(f"{p}: cannot open as an OpenCV FileStorage file")
        k = _first_mat(p, fs, _MATRIX_KEYS)
        if k is None:
            raise InputError(f"{p}: no camera matrix (looked for {', '.join(_MATRIX_KEYS)})")
        if k.shape != (3, 3):
            raise InputError(f"{p}: camera matrix: expected shape (3, 3), got {k.shape}")
        dist = _first_mat(p, fs, _DIST_KEYS)
        dist = np.zeros(5) if dist is None else dist.ravel()
        w = _first_int(p, fs, _WIDTH_KEYS)
        h = _first_int(p, fs, _HEIGHT_KEYS)
    except InputError:
        raise
    except (cv2.error, SystemError, ValueError, TypeError, OverflowError, UnicodeError) as exc:
        raise InputError(f"{p}: malformed calibration file ({_cv_reason(exc)})") from exc
    finally:
        fs.release()
    return k, dist, (w, h) if w and h else None


def _cv_reason(exc: BaseException) -> str:
    """The last line of an OpenCV error (its message), or the exception's text."""
    cause = exc.__cause__ or exc.__context__
    text = str(cause if isinstance(exc, SystemError) and cause is not None else exc).strip()
    line = text.splitlines()[-1] if text else type(exc).__name__
    return re.sub(r"^OpenCV\([^)]*\)\s+\S+:\d+: error: \([^)]*\)\s*", "", line)


def _describe(node: Any) -> str:
    """What a FileStorage node holds, for messages."""
    if node.isString():
        return f"the text {node.string()!r}"
    if node.isSeq():
        return f"a sequence of {node.size()} items"
    if node.isMap():
        return "a map"
    return "an empty value" if node.isNone() or node.empty() else "an unknown value"


def _is_number(node: Any) -> bool:
    return bool(node.isInt() or node.isReal())


def _first_mat(p: Path, fs: Any, keys: tuple[str, ...]) -> np.ndarray | None:
    """The first of ``keys`` that holds an ``opencv-matrix``, checked against its ``rows``, ``cols`` and ``data``."""
    for key in keys:
        node = fs.getNode(key)
        if node.empty() or node.isNone():
            continue
        if not node.isMap():
            continue  # not a matrix (as before: another key may hold it)
        parts = {name: node.getNode(name) for name in ("rows", "cols", "dt", "data")}
        missing = [name for name, n in parts.items() if n.empty() or n.isNone()]
        if missing:
            raise InputError(
                f"{p}: {key}: an opencv-matrix needs rows, cols, dt and data; {', '.join(missing)} missing"
            )
        dims = []
        for name in ("rows", "cols"):
            n = parts[name]
            v = n.real() if _is_number(n) else math.nan
            if not (math.isfinite(v) and v == int(v) and 0 <= v <= _MAX_MATRIX_DIM):
                got = f"{v:g}" if _is_number(n) else _describe(n)
                raise InputError(f"{p}: {key}: {name}: expected a whole number in [0, {_MAX_MATRIX_DIM}], got {got}")
            dims.append(int(v))
        dt = parts["dt"].string() if parts["dt"].isString() else ""
        channels = int(dt[:-1]) if len(dt) > 1 and dt[:-1].isdigit() else 1
        if len(dt) < 1 or dt[-1] not in "ucwsifdh" or not 1 <= channels <= 4:
            raise InputError(
                f"{p}: {key}: dt: expected one of u, c, w, s, i, f, d, h, got {dt or _describe(parts['dt'])}"
            )
        data = parts["data"]
        if not data.isSeq() and not _is_number(data):
            raise InputError(f"{p}: {key}: data: expected a sequence of numbers, got {_describe(data)}")
        items = [data.at(i) for i in range(data.size())] if data.isSeq() else [data]
        bad = [i for i, item in enumerate(items) if not _is_number(item)]
        if bad:
            raise InputError(f"{p}: {key}: data item {bad[0]} is {_describe(items[bad[0]])}, not a number")
        declared = dims[0] * dims[1] * channels
        if len(items) != declared:
            raise InputError(
                f"{p}: {key}: rows x cols = {dims[0]} x {dims[1]}{f' x {channels} channels' if channels > 1 else ''}"
                f" declares {declared} values, but data holds {len(items)}"
            )
        # The values as written (node.mat() reinterprets the raw bytes of integer items as dt, e.g. '600' as a double).
        values = np.array([item.real() for item in items], dtype=np.float64)
        return values.reshape((dims[0], dims[1], channels) if channels > 1 else (dims[0], dims[1]))
    return None


def _first_int(p: Path, fs: Any, keys: tuple[str, ...]) -> int | None:
    """The first of ``keys`` present, as a whole number of pixels in [1, 2^20]."""
    for key in keys:
        node = fs.getNode(key)
        if node.empty() or node.isNone():
            continue
        v = node.real() if _is_number(node) else math.nan
        if not (math.isfinite(v) and v == int(v) and 1 <= v <= _MAX_SIDE_PX):
            got = f"{v:g}" if _is_number(node) else _describe(node)
            raise InputError(f"{p}: {key}: expected a whole number of pixels in [1, {_MAX_SIDE_PX}], got {got}")
        return int(v)
    return None
