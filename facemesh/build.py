"""The path every command takes from its input to a fitted face: image, camera, detector, face, pose, mesh.

:func:`load_input` (the image, or the built-in sample, and its camera),
:func:`landmark_model_for` (MediaPipe, or the user's own landmarks with their
face model), :func:`fit_face` (the face chosen, its face model paired, its pose
solved) and :func:`build_mesh` (fit + textured mesh) serve ``facemesh build``
and every gazeaug stage alike.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .landmarks.base import LandmarkModel, paired_face_model, select_face
from .mesh import BuildSettings, build_face_mesh
from .pose import solve_head_pose
from .types import CameraIntrinsics, FaceKeypoints, FaceLandmarks, FaceMesh, FaceModel, HeadPose, InputError

__all__ = [
    "FaceFit",
    "load_input",
    "landmark_model_for",
    "fit_face",
    "build_mesh",
    "mesh_for_fit",
    "sample_image",
    "SAMPLE_NAME",
]

#: Name recorded for the built-in sample (scikit-image's public-domain astronaut photo).
SAMPLE_NAME = "skimage.data.astronaut"


def sample_image() -> NDArray[np.uint8]:
    """The built-in sample: scikit-image's ``astronaut()`` photo (512 x 512 RGB, public domain)."""
    try:
        import skimage.data  # noqa: PLC0415
    except ImportError as exc:
        raise ImportError("the built-in sample needs scikit-image: pip install scikit-image") from exc
    return np.ascontiguousarray(skimage.data.astronaut())


@dataclass(frozen=True)
class FaceFit:
    """One face found in one image, with its pose.

    Attributes:
        image: (H, W, 3) uint8 RGB.
        camera: the image's camera.
        landmarks: the face's landmarks (pixels, image frame).
        model: the face model the pose was solved with (its key points, when known, say
            which points are the eye and mouth corners).
        pose: head pose (head frame -> camera frame).
        source: name of the image for messages and metadata.
        faces_found: how many faces the landmark model found in the image.
    """

    image: NDArray[np.uint8]
    camera: CameraIntrinsics
    landmarks: FaceLandmarks
    model: FaceModel
    pose: HeadPose
    source: str
    faces_found: int = 1

    @property
    def keypoints(self) -> FaceKeypoints | None:
        """The face model's key points (``None`` when the model does not say)."""
        return self.model.keypoints


def load_input(
    path: str | Path | None, camera_path: str | Path | None
) -> tuple[NDArray[np.uint8], CameraIntrinsics, str]:
    """The image (the built-in sample when ``path`` is None), its camera (a documented default when none) and name.

    Raises:
        InputError: unreadable image or calibration, or a calibration for another image size.
    """
    from .camera import camera_for_image
    from .io import EXIF_ORIENTATIONS, exif_orientation, load_image_rgb

    if path is None:
        image, source = sample_image(), SAMPLE_NAME
    else:
        image, source = load_image_rgb(path), str(path)
        orientation = exif_orientation(path)
        if orientation != 1:
            import warnings

            warnings.warn(
                f"{path}: EXIF orientation {orientation} (viewers show it {EXIF_ORIENTATIONS[orientation]}) "
                "is not applied: the image is read as stored and every result is in the stored image's "
                "frame (turn the file upright first to work upright)",
                stacklevel=2,
            )
    h, w = image.shape[:2]
    return image, camera_for_image(camera_path or None, w, h), source


def landmark_model_for(
    landmarks_path: str | Path | None,
    face_model: str | Path | None,
    keypoints: FaceKeypoints | None = None,
) -> tuple[LandmarkModel, FaceModel | None]:
    """The landmark model and the face model that replaces its own, as the command lines choose them.

    Args:
        landmarks_path: the user's own landmarks (N x 2 px file); they need ``face_model``.
        face_model: a built-in name or a model file; with ``landmarks_path``, the model of
            those landmarks; without, a replacement for MediaPipe's own (same point count).
        keypoints: the face model's key points, replacing what its loader knows.

    Returns:
        ``(detector, face_model_override)``: MediaPipe Face Mesh or an
        :class:`~facemesh.landmarks.ArrayLandmarkModel`; the model to pass to
        :func:`fit_face` as ``face_model`` (``None``: the detector's own).

    Raises:
        InputError: landmarks without their face model (``remedy="face_model"``), unreadable files.
    """
    from .face_models import resolve_face_model

    model = None if face_model is None else resolve_face_model(face_model, keypoints)
    if landmarks_path is not None:
        if model is None:
            raise InputError("landmarks given without their face model", remedy="face_model")
        from .landmarks.from_arrays import ArrayLandmarkModel, load_landmarks_file

        p = Path(landmarks_path)
        return ArrayLandmarkModel(load_landmarks_file(p), model, name=f"user:{p.name}"), None
    from .landmarks.mediapipe import MediaPipeFaceMesh

    detector = MediaPipeFaceMesh()
    if model is None and keypoints is not None:
        model = detector.face_model().with_keypoints(keypoints)
    return detector, model


def fit_face(
    image_rgb: NDArray[np.uint8],
    camera: CameraIntrinsics,
    landmark_model: LandmarkModel,
    *,
    face_model: FaceModel | None = None,
    face_index: int | None = None,
    source: str | Path = "image",
) -> FaceFit:
    """Detect the faces, choose one (largest first), pair its face model and solve its pose.

    Args:
        image_rgb: (H, W, 3) uint8 RGB.
        camera: the image's camera (its image size must be the image's).
        landmark_model: any :class:`~facemesh.landmarks.base.LandmarkModel`.
        face_model: overrides the landmark model's own 3D model: as many points as
            that model or as its landmarks (see
            :func:`~facemesh.landmarks.base.paired_face_model`).
        face_index: which face, largest first (default: the largest).
        source: name of the image for messages and metadata.

    Raises:
        NoFaceError: no face (or not the one asked for); InputError: a camera for another
        image size, or a face model whose point count does not match the landmark model's;
        PoseError: PnP failed, or the landmarks do not fit the model (see :mod:`facemesh.pose`).

    Warns:
        ReprojectionWarning: a landmark lies far from its reprojection (see :mod:`facemesh.pose`).
    """
    name = str(source)
    h, w = image_rgb.shape[:2]
    if camera.image_size != (w, h):
        raise InputError(
            f"{name}: the camera ({camera.source}) is for {camera.image_size[0]}x{camera.image_size[1]} images, "
            f"the image is {w}x{h}"
        )
    faces = landmark_model.detect(image_rgb)
    face = select_face(faces, face_index, source=name)
    model = paired_face_model(face, landmark_model, face_model, source=name)
    pose = solve_head_pose(face.points_px[: model.num_points], model.vertices_mm, camera, source=name)
    return FaceFit(image_rgb, camera, face, model, pose, name, len(faces))


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
    """Detect the face, solve its pose and build its textured mesh (:func:`fit_face`, then the mesh).

    Args:
        image_rgb: (H, W, 3) uint8 RGB.
        camera: the image's camera (see :mod:`facemesh.camera`).
        landmark_model: any :class:`~facemesh.landmarks.base.LandmarkModel`.
        face_model: overrides the landmark model's own 3D model (see :func:`fit_face`).
        face_index: which face, largest first (default: the largest).
        settings: see :class:`~facemesh.mesh.BuildSettings`.
        source: name of the image for messages and metadata.
        extras: more JSON-serialisable metadata for the asset.

    Raises:
        NoFaceError, InputError, PoseError: as :func:`fit_face`.
    """
    fit = fit_face(image_rgb, camera, landmark_model, face_model=face_model, face_index=face_index, source=source)
    return mesh_for_fit(fit, settings, extras)


def mesh_for_fit(
    fit: FaceFit, settings: BuildSettings | None = None, extras: Mapping[str, Any] | None = None
) -> FaceMesh:
    """The textured mesh of a fitted face, at the fit's pose (not solved again)."""
    meta: dict[str, Any] = {
        "source_image": fit.source,
        "num_faces_found": fit.faces_found,
        "landmark_model": fit.landmarks.model_name,
    }
    meta.update(extras or {})
    return build_face_mesh(fit.image, fit.landmarks, fit.model, fit.camera, settings, extras=meta, pose=fit.pose)
