"""Sparse landmark layouts as subsets of MediaPipe's 468: dlib's 68 points and ETH-XGaze's 50.

For tests, examples and measurements of surfaces built from sparse landmark
models (:mod:`facemesh.reconstruct`): a MediaPipe detection taken at these
indices stands in for a dlib or ETH-XGaze detector, and the built-in model's
points at the same indices are its 3D face model (no triangles).

Convention: dlib / iBUG 68-point order, 0-based. Points 0-16 run along the
jaw from the image's left (the subject's right ear) to the image's right, 8 is
the chin; 17-21 the subject's right eyebrow (outer to inner), 22-26 the left
(inner to outer); 27-30 the nose bridge down to its tip, 31-35 the nostrils
image left to right; 36-41 the subject's right eye (outer corner, two upper
lid points, inner corner, two lower lid points), 42-47 the left eye (inner
corner, upper lid, outer corner, lower lid); 48-59 the outer lip contour from
the right mouth corner over the upper lip, 60-67 the inner contour likewise.

How the map was chosen (one MediaPipe index per dlib point, no averages):
anatomical correspondence on MediaPipe's topology, checked two ways by
``tests/test_face_models.py``: the map commutes with the left-right mirror
(MediaPipe's mirror partners map onto dlib's), and the 50 ETH-XGaze points
fit ETH-XGaze's own 3D face model (a different face: similarity fit, about
5 mm RMS, every point within 11 mm) better with this choice of the two dropped
inner mouth corners than with any other pair.

ETH-XGaze's 50-point face model (``face_model.txt`` of its code) is dlib's
68 without the jaw (but the chin, 8) and without the inner mouth corners
(60, 64); its normalization uses rows 20, 23, 26, 29 (eye corners) and 15, 19
(nostrils).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..types import FaceKeypoints, FaceModel, InputError
from . import KEYPOINTS

__all__ = ["MEDIAPIPE_TO_DLIB68", "DLIB68_TO_ETH50", "MEDIAPIPE_TO_ETH50", "SPARSE_LAYOUTS", "sparse_face_model"]

#: (68,) MediaPipe landmark index of each dlib / iBUG 68-point landmark, in dlib order.
MEDIAPIPE_TO_DLIB68: tuple[int, ...] = (
    # jaw 0-16, the chin is 8
    127, 234, 93, 132, 58, 136, 150, 176, 152, 400, 379, 365, 288, 361, 323, 454, 356,
    # eyebrows 17-21 (subject's right), 22-26 (left)
    70, 63, 105, 66, 107, 336, 296, 334, 293, 300,
    # nose bridge 27-30 (30: the tip), nostrils 31-35
    168, 197, 5, 1, 98, 97, 2, 326, 327,
    # right eye 36-41, left eye 42-47
    33, 160, 158, 133, 153, 144, 362, 385, 387, 263, 373, 380,
    # outer lips 48-59, inner lips 60-67
    61, 40, 37, 0, 267, 270, 291, 321, 314, 17, 84, 91,
    78, 81, 13, 311, 308, 402, 14, 178,
)  # fmt: skip

#: (50,) dlib index of each row of ETH-XGaze's 50-point face model.
DLIB68_TO_ETH50: tuple[int, ...] = (8, *range(17, 60), 61, 62, 63, 65, 66, 67)

#: (50,) MediaPipe landmark index of each row of ETH-XGaze's 50-point face model.
MEDIAPIPE_TO_ETH50: tuple[int, ...] = tuple(MEDIAPIPE_TO_DLIB68[i] for i in DLIB68_TO_ETH50)

#: Layout name -> (MediaPipe indices, key points in the layout's own indexing).
SPARSE_LAYOUTS: dict[str, tuple[tuple[int, ...], FaceKeypoints]] = {
    "dlib68": (MEDIAPIPE_TO_DLIB68, KEYPOINTS["dlib68"]),
    "eth50": (MEDIAPIPE_TO_ETH50, KEYPOINTS["eth50"]),
}


def sparse_face_model(layout: str, dense: FaceModel | None = None) -> tuple[FaceModel, NDArray[np.int64]]:
    """A sparse layout's face model: the dense model's points at the layout's MediaPipe indices, no triangles.

    Args:
        layout: ``"dlib68"`` or ``"eth50"`` (:data:`SPARSE_LAYOUTS`).
        dense: a 468-point MediaPipe-topology model (default: the built-in one).

    Returns:
        ``(model, indices)``: the (K,)-point :class:`FaceModel` (mm, head frame,
        ``triangles=None``, the layout's key points) and the (K,) int64
        MediaPipe indices to take a MediaPipe detection's landmarks at.

    Raises:
        InputError: an unknown layout, or a dense model that is not 468 points.
    """
    if layout not in SPARSE_LAYOUTS:
        raise InputError(f"layout: expected one of {sorted(SPARSE_LAYOUTS)}, got {layout!r}")
    if dense is None:
        from . import builtin_face_model

        dense = builtin_face_model()
    if dense.num_points < 468:
        raise InputError(f"dense model: expected MediaPipe's 468 points, got {dense.num_points}")
    idx, kp = SPARSE_LAYOUTS[layout]
    indices = np.asarray(idx, dtype=np.int64)
    model = FaceModel(name=f"{dense.name}:{layout}", vertices_mm=np.asarray(dense.vertices_mm)[indices], keypoints=kp)
    return model, indices
