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
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from .types import CameraIntrinsics, InputError

__all__ = ["load_camera", "default_camera", "DefaultCameraWarning"]

_MATRIX_KEYS = ("camera_matrix", "Camera_Matrix", "cameraMatrix", "CameraMatrix", "K")
_DIST_KEYS = ("cam_distortion", "dist_coeffs", "distortion_coefficients", "Distortion_Coefficients", "distCoeffs", "D")
_WIDTH_KEYS = ("image_width", "image_Width", "Image_Width", "imageWidth", "width")
_HEIGHT_KEYS = ("image_height", "image_Height", "Image_Height", "imageHeight", "height")


class DefaultCameraWarning(UserWarning):
    """No calibration was given; the default intrinsics are used."""


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
        raise InputError(f"{p}: the file gives no image size; pass the image's size")
    try:
        return CameraIntrinsics(matrix=k, distortion=dist, image_size=size, source=str(p))
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from exc


def _read_mat(p: Path) -> tuple[np.ndarray, np.ndarray, tuple[int, int] | None]:
    from scipy.io import loadmat

    try:
        m = loadmat(str(p))
    except Exception as exc:  # scipy raises several types for bad files
        raise InputError(f"{p}: not a readable MATLAB file ({exc})") from exc
    if "cameraMatrix" not in m:
        raise InputError(f"{p}: no 'cameraMatrix' variable (expected MPIIFaceGaze's Camera.mat)")
    k = np.asarray(m["cameraMatrix"], dtype=np.float64)
    dist = np.asarray(m.get("distCoeffs", np.zeros(5)), dtype=np.float64).ravel()
    if k.shape != (3, 3):
        raise InputError(f"{p}: cameraMatrix: expected shape (3, 3), got {k.shape}")
    return k, dist, None


def _read_filestorage(p: Path) -> tuple[np.ndarray, np.ndarray, tuple[int, int] | None]:
    import cv2

    head = p.read_bytes()[:64].lstrip()
    if not (
        head.startswith(b"<?xml") or head.startswith(b"%YAML") or head.startswith(b"<opencv") or head.startswith(b"{")
    ):
        raise InputError(f"{p}: not an OpenCV FileStorage file (XML, YAML or JSON)")
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV's parser errors surface as either
        raise InputError(f"{p}: malformed calibration file ({str(exc).strip().splitlines()[-1]})") from exc
    try:
        if not fs.isOpened():
            raise InputError(f"{p}: cannot open as an OpenCV FileStorage file")
        k = _first_mat(fs, _MATRIX_KEYS)
        if k is None:
            raise InputError(f"{p}: no camera matrix (looked for {', '.join(_MATRIX_KEYS)})")
        if k.shape != (3, 3):
            raise InputError(f"{p}: camera matrix: expected shape (3, 3), got {k.shape}")
        dist = _first_mat(fs, _DIST_KEYS)
        dist = np.zeros(5) if dist is None else dist.ravel()
        w = _first_int(fs, _WIDTH_KEYS)
        h = _first_int(fs, _HEIGHT_KEYS)
    finally:
        fs.release()
    return k, dist, (w, h) if w and h else None


def _first_mat(fs: "object", keys: tuple[str, ...]) -> np.ndarray | None:
    for key in keys:
        node = fs.getNode(key)  # type: ignore[attr-defined]
        if not node.empty():
            m = node.mat()
            if m is None:
                continue
            return np.asarray(m, dtype=np.float64)
    return None


def _first_int(fs: "object", keys: tuple[str, ...]) -> int | None:
    for key in keys:
        node = fs.getNode(key)  # type: ignore[attr-defined]
        if not node.empty() and (node.isReal() or node.isInt()):
            return int(node.real())
    return None
