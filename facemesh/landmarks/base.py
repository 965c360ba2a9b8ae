"""The interface every landmark model implements, and face selection."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from ..types import FaceLandmarks, FaceModel, InputError, NoFaceError

__all__ = ["LandmarkModel", "select_face", "paired_face_model"]


@runtime_checkable
class LandmarkModel(Protocol):
    """Anything that finds faces and knows its own 3D face model.

    Landmark ``i`` of every :class:`FaceLandmarks` it returns corresponds to
    point ``i`` of :meth:`face_model` (the model may have fewer points than
    the detector gives, e.g. MediaPipe's 10 extra iris points; those come last).
    """

    #: Short identifier written into every asset.
    name: str

    def detect(self, image_rgb: NDArray[np.uint8]) -> list[FaceLandmarks]:
        """All faces found in an (H, W, 3) uint8 RGB image, in the detector's order (may be empty)."""
        ...

    def face_model(self) -> FaceModel:
        """The rigid 3D face model (mm, head frame), with its triangulation when it has one."""
        ...


def select_face(
    faces: Sequence[FaceLandmarks], face_index: int | None = None, *, source: str = "image"
) -> FaceLandmarks:
    """Pick one face: the largest (bounding-box area) by default, or ``faces_by_size[face_index]``.

    Faces are ranked largest first, so ``face_index=0`` is the default choice
    and ``1`` the second largest.

    Raises:
        NoFaceError: no face, or ``face_index`` out of range (the message names ``source``).
    """
    if not faces:
        raise NoFaceError(f"{source}: no face found")
    ranked = sorted(faces, key=lambda f: -f.area_px)
    if face_index is None:
        return ranked[0]
    if not isinstance(face_index, (int, np.integer)) or face_index < 0:
        raise InputError(f"face index: expected an integer >= 0, got {face_index!r}")
    if face_index >= len(ranked):
        raise NoFaceError(f"{source}: face index {face_index} asked for, but only {len(ranked)} face(s) found")
    return ranked[int(face_index)]


def paired_face_model(
    face: FaceLandmarks, detector: LandmarkModel, face_model: FaceModel | None = None, *, source: str = "image"
) -> FaceModel:
    """The face model whose point i is paired with landmark i of ``face``.

    The detector's own model by default. A model given instead must have as
    many points as the detector's own model or as its landmarks (MediaPipe:
    468 or 478): pairing is by index, so a model of another layout (MPII's 6
    points, dlib's 68, ...) would be paired with unrelated landmarks. Such a
    model needs its own landmarks (an :class:`~facemesh.landmarks.ArrayLandmarkModel`,
    ``--landmarks`` on the command lines).

    Raises:
        InputError: the counts do not match (the message names the model, both counts and the way out).
    """
    own = detector.face_model()
    model = own if face_model is None else face_model
    n, m = model.num_points, face.num_points
    if face_model is not None and n not in (own.num_points, m):
        raise InputError(
            f"{source}: face model {model.name!r} has {n} points, but the landmark model {detector.name!r} gives {m} "
            f"landmarks (its own face model has {own.num_points}); landmark i is paired with model point i, so the "
            f"counts must match",
            remedy="landmarks",
        )
    if m < n:
        raise InputError(f"{source}: the landmark model gives {m} points, the face model {model.name!r} has {n}")
    return model
