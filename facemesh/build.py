"""The whole facemesh job in one call: image -> landmarks -> pose -> textured mesh."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .landmarks.base import LandmarkModel, paired_face_model, select_face
from .mesh import BuildSettings, build_face_mesh
from .pose import solve_head_pose
from .types import CameraIntrinsics, FaceMesh, FaceModel

__all__ = ["build_mesh", "sample_image", "SAMPLE_NAME"]

#: Name recorded for the built-in sample (scikit-image's public-domain astronaut photo).
SAMPLE_NAME = "skimage.data.astronaut"


def sample_image() -> NDArray[np.uint8]:
    """The built-in sample: scikit-image's ``astronaut()`` photo (512 x 512 RGB, public domain)."""
    try:
        import skimage.data  # noqa: PLC0415
    except ImportError as exc:
        raise ImportError("the built-in sample needs scikit-image: pip install scikit-image") from exc
    return np.ascontiguousarray(skimage.data.astronaut())


def build_mesh(
    image_rgb: NDArray[np.uint8],
    camera: CameraIntrinsics,
    landmark_model: LandmarkModel,
    *,
    face_model: FaceModel | None = None,
    face_index: int | None = None,
    settings: BuildSettings | None = None,
    source: str | Path = "image",
    extras: Mapping[str, Any] | None = None,
) -> FaceMesh:
    """Detect the face, solve its pose and build its textured mesh.

    Args:
        image_rgb: (H, W, 3) uint8 RGB.
        camera: the image's camera (see :mod:`facemesh.camera`).
        landmark_model: any :class:`~facemesh.landmarks.base.LandmarkModel`.
        face_model: overrides the landmark model's own 3D model: as many points as
            that model or as its landmarks (see
            :func:`~facemesh.landmarks.base.paired_face_model`).
        face_index: which face, largest first (default: the largest).
        settings: see :class:`~facemesh.mesh.BuildSettings`.
        source: name of the image for messages and metadata.
        extras: more JSON-serialisable metadata for the asset.

    Raises:
        NoFaceError: no face (or not the one asked for); InputError: bad input,
        or a face model whose point count does not match the landmark model's;
        PoseError: PnP failed, or the landmarks do not fit the model (see :mod:`facemesh.pose`).

    Warns:
        ReprojectionWarning: a landmark lies far from its reprojection (see :mod:`facemesh.pose`).
    """
    faces = landmark_model.detect(image_rgb)
    face = select_face(faces, face_index, source=str(source))
    model = paired_face_model(face, landmark_model, face_model, source=str(source))
    meta = {"source_image": str(source), "num_faces_found": len(faces), "landmark_model": landmark_model.name}
    meta.update(extras or {})
    h, w = image_rgb.shape[:2]
    pose = None
    if camera.image_size == (w, h):  # otherwise build_face_mesh says what is wrong
        n = model.num_points
        pose = solve_head_pose(face.points_px[:n], model.vertices_mm, camera, source=str(source))
    return build_face_mesh(image_rgb, face, model, camera, settings, extras=meta, pose=pose)
