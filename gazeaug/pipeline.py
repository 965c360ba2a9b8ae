"""From an image (or a saved mesh) to what the gazeaug stages need: landmarks, pose, face model, mesh.

Thin glue over :mod:`facemesh` shared by the command line and by scripts.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from facemesh.build import SAMPLE_NAME, sample_image
from facemesh.camera import camera_for_image, load_camera
from facemesh.face_models import FaceKeypoints, keypoints_for, resolve_face_model
from facemesh.io import load_image_rgb
from facemesh.landmarks.base import LandmarkModel, select_face
from facemesh.mesh import BuildSettings, build_face_mesh
from facemesh.pose import solve_head_pose
from facemesh.types import CameraIntrinsics, FaceLandmarks, FaceMesh, FaceModel, HeadPose

from .errors import GazeAugError

__all__ = [
    "FaceFit",
    "MESH_SETTINGS",
    "load_input_image",
    "landmark_model_for",
    "fit_face",
    "mesh_for_fit",
    "load_mesh",
]

#: Mesh settings for augmentation: a wider texture margin than facemesh's
#: default, so the background rings find the photo's surroundings.
MESH_SETTINGS = BuildSettings(texture_margin=0.4)


@dataclass(frozen=True)
class FaceFit:
    """One face found in one image.

    Attributes:
        image: (H, W, 3) uint8 RGB.
        camera: the image's camera.
        landmarks: the face's landmarks.
        model: the face model the pose was solved with.
        pose: head pose (head frame -> camera frame).
        keypoints: eye and mouth corner indices into the model.
        source: name of the image for messages and metadata.
    """

    image: NDArray[np.uint8]
    camera: CameraIntrinsics
    landmarks: FaceLandmarks
    model: FaceModel
    pose: HeadPose
    keypoints: FaceKeypoints
    source: str


def load_input_image(
    path: str | Path | None, camera_path: str | Path | None
) -> tuple[NDArray[np.uint8], CameraIntrinsics, str]:
    """The image (the built-in sample when ``path`` is None) and its camera (a documented default when none)."""
    if path is None:
        image = sample_image()
        source = SAMPLE_NAME
    else:
        image = load_image_rgb(path)
        source = str(path)
    h, w = image.shape[:2]
    camera = load_camera(camera_path, image_size=(w, h)) if camera_path else camera_for_image(None, w, h)
    return image, camera, source


def landmark_model_for(landmarks_path: str | Path | None, face_model: str | Path | None) -> LandmarkModel:
    """MediaPipe Face Mesh, or the user's own landmarks from a file with their face model."""
    if landmarks_path is not None:
        if face_model is None:
            raise GazeAugError("--landmarks needs --face-model (the 3D points the landmarks correspond to)")
        from facemesh.landmarks.from_arrays import ArrayLandmarkModel, load_landmarks_file

        return ArrayLandmarkModel(load_landmarks_file(landmarks_path), resolve_face_model(face_model))
    from facemesh.landmarks.mediapipe import MediaPipeFaceMesh

    return MediaPipeFaceMesh()


def fit_face(
    image: NDArray[np.uint8],
    camera: CameraIntrinsics,
    detector: LandmarkModel,
    *,
    face_model: FaceModel | None = None,
    face_index: int | None = None,
    source: str = "image",
) -> FaceFit:
    """Detect the face (largest by default), solve its pose and find its key points.

    Raises:
        NoFaceError, PoseError, InputError, GazeAugError: as the stages do.
    """
    face = select_face(detector.detect(image), face_index, source=source)
    model = face_model if face_model is not None else detector.face_model()
    n = model.num_points
    if face.num_points < n:
        raise GazeAugError(f"{source}: {face.num_points} landmarks for a {n}-point face model")
    pose = solve_head_pose(face.points_px[:n], model.vertices_mm, camera)
    try:
        kp = keypoints_for(n)
    except Exception as exc:
        raise GazeAugError(f"{source}: {exc}") from exc
    return FaceFit(image, camera, face, model, pose, kp, source)


def mesh_for_fit(fit: FaceFit, settings: BuildSettings = MESH_SETTINGS) -> FaceMesh:
    """The textured mesh of a fitted face, at the fit's pose (not solved again)."""
    return build_face_mesh(
        fit.image, fit.landmarks, fit.model, fit.camera, settings, extras={"source_image": fit.source}, pose=fit.pose
    )


def load_mesh(path: str | Path) -> FaceMesh:
    """A face mesh saved by ``facemesh build`` (.glb)."""
    from facemesh.gltf import load_glb

    return load_glb(path)
