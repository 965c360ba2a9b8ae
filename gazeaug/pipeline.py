"""From an image (or a saved mesh) to what the gazeaug stages need: landmarks, pose, face model, mesh.

Thin glue over :mod:`facemesh` shared by the command line and by scripts.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from facemesh.build import SAMPLE_NAME, sample_image
from facemesh.camera import camera_for_image
from facemesh.conventions import pixels_to_uv
from facemesh.face_models import FaceKeypoints, keypoints_for, resolve_face_model
from facemesh.io import load_image_rgb
from facemesh.landmarks.base import LandmarkModel, paired_face_model, select_face
from facemesh.mesh import BuildSettings, build_face_mesh, crop_texture
from facemesh.pose import project_points, solve_head_pose
from facemesh.reconstruct import orient_triangles_toward
from facemesh.types import CameraIntrinsics, FaceLandmarks, FaceMesh, FaceModel, HeadPose

from .datasets.base import DatasetError, GazeSample
from .errors import GazeAugError

__all__ = [
    "FaceFit",
    "MESH_SETTINGS",
    "load_input_image",
    "landmark_model_for",
    "fit_face",
    "mesh_for_fit",
    "load_mesh",
    "fit_from_dataset",
    "dataset_mesh",
    "load_obj_mesh",
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
    """The image (the built-in sample when ``path`` is None) and its camera (a documented default when none).

    Raises:
        InputError: unreadable image or calibration, or a calibration for another image size.
    """
    if path is None:
        image = sample_image()
        source = SAMPLE_NAME
    else:
        image = load_image_rgb(path)
        source = str(path)
    h, w = image.shape[:2]
    camera = camera_for_image(camera_path or None, w, h)  # checks the calibration's image size against the image
    return image, camera, source


def landmark_model_for(landmarks_path: str | Path | None, face_model: str | Path | None) -> LandmarkModel:
    """MediaPipe Face Mesh, or the user's own landmarks from a file with their face model."""
    if landmarks_path is not None:
        if face_model is None:
            raise GazeAugError("landmarks given without their face model", remedy="face_model")
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

    ``face_model`` replaces the detector's own model only when the point counts
    match (see :func:`facemesh.landmarks.base.paired_face_model`).

    Raises:
        NoFaceError, PoseError, InputError, GazeAugError: as the stages do (InputError:
        a face model whose point count does not match the detector's; PoseError: no
        pose, or landmarks that do not fit the model, see :mod:`facemesh.pose`).
    """
    face = select_face(detector.detect(image), face_index, source=source)
    model = paired_face_model(face, detector, face_model, source=source)
    n = model.num_points
    pose = solve_head_pose(face.points_px[:n], model.vertices_mm, camera, source=source)
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


#: Name of the 6-point layout of a dataset's own 3D landmarks (UT Multiview).
DATASET_LANDMARKS = "dataset6"


def fit_from_dataset(sample: GazeSample, image: NDArray[np.uint8]) -> FaceFit:
    """The face as the dataset describes it (its head pose and 3D landmarks), nothing detected.

    For samples with ``landmarks_3d_mm`` (six points: the subject's right eye's
    two corners, the left eye's two, the mouth's two) and a head pose. The
    face model is those six points in the head frame, re-centred between the
    eyes (the head frame's origin in this package), so eye centres and the
    normalized cameras come from the dataset's own landmarks.

    Raises:
        DatasetError: no 3D landmarks or head pose, or a head frame whose axes do
            not follow the convention (x toward the subject's left eye, y toward the chin).
    """
    where = f"sample {sample.source_index} ({sample.image_path})"
    if sample.landmarks_3d_mm is None or sample.head_rotation is None or sample.head_translation_mm is None:
        raise DatasetError(f"{where}: the dataset gives no 3D landmarks and head pose")
    marks = np.asarray(sample.landmarks_3d_mm, dtype=np.float64)
    if marks.shape != (6, 3):
        raise DatasetError(f"{where}: 3D landmarks: expected (6, 3), got {marks.shape}")
    r, t = np.asarray(sample.head_rotation), np.asarray(sample.head_translation_mm)
    head = (marks - t) @ r  # head frame
    kp = keypoints_for(6)
    right, left = head[list(kp.right_eye)].mean(axis=0), head[list(kp.left_eye)].mean(axis=0)
    mid = 0.5 * (right + left)
    eye_line = (left - right) / max(float(np.linalg.norm(left - right)), 1e-9)
    down = head[[4, 5]].mean(axis=0) - mid  # the mouth corners
    down /= max(float(np.linalg.norm(down)), 1e-9)
    if eye_line[0] < np.cos(np.radians(30)) or down[1] < np.cos(np.radians(45)):
        raise DatasetError(
            f"{where}: the dataset's head rotation does not follow the head-frame convention "
            f"(x toward the subject's left eye, y toward the chin): in its frame the eye line points "
            f"{np.round(eye_line, 3).tolist()} and the mouth lies toward {np.round(down, 3).tolist()}"
        )
    model = FaceModel(DATASET_LANDMARKS, head - mid)
    pose = HeadPose(r, t + r @ mid)
    landmarks = FaceLandmarks(project_points(marks, sample.camera), DATASET_LANDMARKS)
    return FaceFit(image, sample.camera, landmarks, model, pose, kp, str(sample.image_path))


_OBJ_CACHE: dict[str, tuple[NDArray[np.float64], NDArray[np.int64]]] = {}


def load_obj_mesh(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Vertices and triangles of an OBJ file, in file order (nothing merged; the last file is cached).

    Returns:
        ``(vertices, triangles)``: (V, 3) float64 in the file's units and frame; (T, 3) int64.

    Raises:
        DatasetError: missing, unreadable or empty file.
    """
    key = str(path)
    if key in _OBJ_CACHE:
        return _OBJ_CACHE[key]
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"{p}: mesh file not found")
    import trimesh

    try:
        mesh = trimesh.load(p, file_type="obj", process=False, maintain_order=True, force="mesh", skip_materials=True)
    except Exception as exc:  # trimesh raises many kinds on malformed files
        raise DatasetError(f"{p}: cannot read the mesh ({exc})") from exc
    v = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    f = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(v) < 3 or len(f) < 1 or not np.isfinite(v).all():
        raise DatasetError(f"{p}: no usable triangles (vertices {len(v)}, faces {len(f)})")
    _OBJ_CACHE.clear()
    _OBJ_CACHE[key] = (v, f)
    return v, f


def dataset_mesh(fit: FaceFit, sample: GazeSample, settings: BuildSettings = MESH_SETTINGS) -> FaceMesh:
    """The dataset's own face mesh of this capture, textured from this sample's image.

    The mesh (``sample.mesh_path``, mm, moved into this camera's frame by
    ``sample.mesh_to_camera``) is projected into the image: each vertex's
    texture coordinate is where the camera sees it, as for meshes built from
    landmarks (parts hidden from this camera take the colour of what hides them).

    Raises:
        DatasetError: the mesh is missing or unreadable, or its size is not that of a face in mm.
    """
    if sample.mesh_path is None or sample.mesh_to_camera is None:
        raise DatasetError(f"sample {sample.source_index} ({sample.image_path}): no dataset mesh")
    v, tri = load_obj_mesh(sample.mesh_path)
    m = np.asarray(sample.mesh_to_camera)
    v = v @ m[:, :3].T + m[:, 3]
    extent = float(np.ptp(v, axis=0).max())
    if not 50.0 <= extent <= 1000.0:
        raise DatasetError(f"{sample.mesh_path}: the mesh spans {extent:.3g} units; expected a face in millimetres")
    if (v[:, 2] <= 0).any():
        raise DatasetError(f"{sample.mesh_path}: part of the mesh lies behind camera {sample.camera.source}")
    tri = orient_triangles_toward(v, tri, np.zeros(3))  # normals toward the camera at the origin
    px = project_points(v, sample.camera)
    texture, origin = crop_texture(fit.image, px, settings.texture_margin)
    uv = pixels_to_uv(px, origin, (texture.shape[1], texture.shape[0]))
    return FaceMesh(
        vertices_mm=v,
        triangles=tri,
        uv=uv,
        texture=texture,
        texture_origin_px=origin,
        landmarks=fit.landmarks,
        camera=fit.camera,
        pose=fit.pose,
        face_model_name=DATASET_LANDMARKS,
        vertex_placement="dataset",
        reconstruction={"method": "dataset", "mesh": str(sample.mesh_path)},
        extras={"source_image": fit.source},
        model_vertices_mm=fit.model.vertices_mm,
    )
