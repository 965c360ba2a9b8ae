"""Landmarks from elsewhere: a user's own detector, dlib-68, ETH-XGaze's 50 points, MPII's 6.

The user gives 2D landmarks (pixels) and the matching 3D face model; the
model's triangles are optional (without them the mesh is made by Ball-Pivoting).

Landmark files:

``.npy``
    (N, 2) float array, pixels, image frame.
``.json``
    ``[[x, y], ...]`` or ``{"landmarks_px": [[x, y], ...]}``.
``.csv``
    two columns x, y (a header row with non-numeric cells is skipped).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..types import FaceLandmarks, FaceModel, InputError

__all__ = ["ArrayLandmarkModel", "load_landmarks_file"]


def load_landmarks_file(path: str | Path) -> NDArray[np.float64]:
    """Read an (N, 2) float64 array of pixel landmarks from .npy, .json or .csv.

    Raises:
        InputError: missing file, unknown suffix, wrong shape, NaN or non-numeric values (naming the file and line).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: landmark file not found")
    suffix = p.suffix.lower()
    try:
        if suffix == ".npy":
            arr = np.asarray(np.load(p, allow_pickle=False), dtype=np.float64)
        elif suffix == ".json":
            data = json.loads(p.read_text(encoding="utf-8"))
            if isinstance(data, dict):
                if "landmarks_px" not in data:
                    raise InputError(f"{p}: expected a list of [x, y] or an object with 'landmarks_px'")
                data = data["landmarks_px"]
            arr = np.asarray(data, dtype=np.float64)
        elif suffix == ".csv":
            rows: list[list[float]] = []
            with p.open(newline="", encoding="utf-8") as fh:
                for lineno, row in enumerate(csv.reader(fh), 1):
                    cells = [c.strip() for c in row if c.strip()]
                    if not cells:
                        continue
                    try:
                        vals = [float(c) for c in cells]
                    except ValueError:
                        if lineno == 1 and not rows:
                            continue  # header
                        raise InputError(f"{p}:{lineno}: expected numbers, got {row}") from None
                    if len(vals) != 2:
                        raise InputError(f"{p}:{lineno}: expected 2 values (x, y), got {len(vals)}")
                    rows.append(vals)
            arr = np.asarray(rows, dtype=np.float64)
        else:
            raise InputError(f"{p}: unknown landmark format {suffix!r} (expected .npy, .json or .csv)")
    except InputError:
        raise
    except (ValueError, TypeError, OSError, EOFError, RecursionError, OverflowError) as exc:
        raise InputError(f"{p}: cannot read landmarks: {exc.__class__.__name__}: {exc}") from exc
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"{p}: expected landmarks of shape (N, 2), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.argwhere(~np.isfinite(arr))[0, 0])
        raise InputError(f"{p}: landmark {bad} is NaN or infinite")
    return arr


class ArrayLandmarkModel:
    """A :class:`~facemesh.landmarks.base.LandmarkModel` over landmarks already known.

    Args:
        points_px: (N, 2) float, pixels, image frame.
        face_model: the N-point 3D model those landmarks correspond to.
        name: identifier written into assets.
    """

    def __init__(self, points_px: ArrayLike, face_model: FaceModel, name: str = "user"):
        self.name = name
        self._landmarks = FaceLandmarks(points_px=np.asarray(points_px, dtype=np.float64), model_name=name)
        if self._landmarks.num_points != face_model.num_points:
            raise InputError(
                f"landmarks: {self._landmarks.num_points} points given, but face model "
                f"{face_model.name!r} has {face_model.num_points}"
            )
        self._model = face_model

    def detect(self, image_rgb: NDArray[np.uint8]) -> list[FaceLandmarks]:
        """The given landmarks (checked to lie inside the image)."""
        h, w = np.asarray(image_rgb).shape[:2]
        x0, y0, x1, y1 = self._landmarks.bbox_px
        if x1 < 0 or y1 < 0 or x0 > w - 1 or y0 > h - 1:
            raise InputError(f"landmarks: all points lie outside the {w}x{h} image")
        return [self._landmarks]

    def face_model(self) -> FaceModel:
        """The model given at construction."""
        return self._model
