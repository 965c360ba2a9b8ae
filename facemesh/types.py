"""Frozen dataclasses passed between the stages: landmarks -> pose -> mesh -> asset.

Every array documents its shape, dtype, units and frame (see
:mod:`facemesh.conventions` for the frames). Arrays are copied and made
read-only on construction, so a stage can never change another's data.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:  # heavy optional libraries: imported where used (facemesh.mesh)
    import open3d
    import trimesh

__all__ = [
    "FaceMeshError",
    "InputError",
    "NoFaceError",
    "CameraIntrinsics",
    "FaceKeypoints",
    "FaceModel",
    "FaceLandmarks",
    "HeadPose",
    "FaceMesh",
]


class FaceMeshError(ValueError):
    """Base class of the errors this package raises for bad input.

    The message states the facts (the file, expected vs got). When one of the
    library's own parameters would resolve the error, ``remedy`` names it
    (``"overwrite"``, ``"resume"``, ``"format"``, ``"landmarks"``, ...) and the
    command lines phrase it with their flag; the library never speaks of flags.

    Attributes:
        remedy: the parameter that resolves the error, or None.
    """

    def __init__(self, message: str = "", *, remedy: str | None = None):
        super().__init__(message)
        self.remedy = remedy

    def __reduce__(self) -> Any:  # keep ``remedy`` across processes (worker errors are pickled)
        return (_rebuild_error, (type(self), str(self), self.remedy))


def _rebuild_error(cls: type[FaceMeshError], message: str, remedy: str | None) -> FaceMeshError:
    return cls(message, remedy=remedy)


class InputError(FaceMeshError):
    """An input file or array is missing, unreadable or malformed."""


class NoFaceError(FaceMeshError):
    """The landmark model found no face (or not the face asked for)."""


def _frozen_array(value: ArrayLike, name: str, shape: tuple[int | None, ...], dtype: type = np.float64) -> NDArray[Any]:
    arr: NDArray[Any] = np.array(value, dtype=dtype, copy=True)
    if arr.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, arr.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise InputError(f"{name}: expected shape {want}, got {arr.shape}")
    if np.issubdtype(arr.dtype, np.floating) and not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: contains NaN or infinite values")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class CameraIntrinsics:
    """A pinhole camera with OpenCV distortion.

    Attributes:
        matrix: (3, 3) float64, pixels: ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.
        distortion: (K,) float64, OpenCV order (k1, k2, p1, p2[, k3[, k4, k5, k6]]);
            zeros when the camera has none.
        image_size: (width, height) in pixels of the images this camera takes.
        source: where the values came from: a file path, or ``"default"``.
    """

    matrix: NDArray[np.float64]
    distortion: NDArray[np.float64]
    image_size: tuple[int, int]
    source: str = "default"

    def __post_init__(self) -> None:
        object.__setattr__(self, "matrix", _frozen_array(self.matrix, "camera matrix", (3, 3)))
        dist = np.asarray(self.distortion, dtype=np.float64).ravel()
        if dist.size not in (0, 4, 5, 8, 12, 14):
            raise InputError(f"distortion: expected 4, 5, 8, 12 or 14 coefficients, got {dist.size}")
        object.__setattr__(self, "distortion", _frozen_array(dist, "distortion", (None,)))
        w, h = (int(v) for v in self.image_size)
        if w <= 0 or h <= 0:
            raise InputError(f"image_size: expected positive (width, height), got {self.image_size}")
        object.__setattr__(self, "image_size", (w, h))
        k = self.matrix
        if k[0, 0] <= 0 or k[1, 1] <= 0 or k[2, 2] != 1.0 or k[1, 0] != 0 or k[2, 0] != 0 or k[2, 1] != 0:
            raise InputError(f"camera matrix: expected [[fx,s,cx],[0,fy,cy],[0,0,1]] with fx, fy > 0, got {k.tolist()}")

    @property
    def focal_px(self) -> tuple[float, float]:
        """(fx, fy) in pixels."""
        return float(self.matrix[0, 0]), float(self.matrix[1, 1])

    @property
    def has_distortion(self) -> bool:
        """True when any distortion coefficient is non-zero."""
        return bool(np.any(self.distortion != 0))


@dataclass(frozen=True)
class FaceKeypoints:
    """Indices of the face model points that define a face's reference points (gaze normalization uses them).

    They belong to a face model (:attr:`FaceModel.keypoints`): each loader sets
    them for the layouts it knows, the user gives them for a model of their own.

    Attributes:
        right_eye: (outer, inner) corner indices of the subject's right eye (on the image's left).
        left_eye: (inner, outer) corner indices of the subject's left eye (on the image's right).
        mouth: (right, left) mouth corner indices of the subject, or ``None``.
    """

    right_eye: tuple[int, int]
    left_eye: tuple[int, int]
    mouth: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        for name in ("right_eye", "left_eye", "mouth"):
            value = getattr(self, name)
            if value is None and name == "mouth":
                continue
            pair = tuple(value)
            if len(pair) != 2 or not all(isinstance(i, (int, np.integer)) and int(i) >= 0 for i in pair):
                raise InputError(f"key points {name}: expected two indices >= 0, got {value!r}")
            object.__setattr__(self, name, (int(pair[0]), int(pair[1])))

    def eye(self, side: str) -> tuple[int, int]:
        """The corner indices of the subject's ``"left"`` or ``"right"`` eye."""
        if side not in ("left", "right"):
            raise InputError(f"eye side: expected 'left' or 'right', got {side!r}")
        return self.left_eye if side == "left" else self.right_eye

    @property
    def face_indices(self) -> tuple[int, ...]:
        """The points whose mean is the face centre: the four eye corners and, when known, the mouth corners."""
        return self.right_eye + self.left_eye + (self.mouth or ())

    def as_dict(self) -> dict[str, list[int] | None]:
        """JSON form (as recorded in a ``.glb``): ``{"right_eye": [o, i], "left_eye": [i, o], "mouth": [r, l]}``."""
        return {
            "right_eye": list(self.right_eye),
            "left_eye": list(self.left_eye),
            "mouth": None if self.mouth is None else list(self.mouth),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FaceKeypoints:
        """Inverse of :meth:`as_dict`."""
        try:
            mouth = data.get("mouth")
            return cls(tuple(data["right_eye"]), tuple(data["left_eye"]), None if mouth is None else tuple(mouth))
        except (KeyError, TypeError) as exc:
            raise InputError(f"key points: expected right_eye, left_eye (and mouth) index pairs, got {data!r}") from exc


@dataclass(frozen=True)
class FaceModel:
    """A rigid 3D face model whose point i corresponds to landmark i.

    Attributes:
        name: short identifier (``"mediapipe"``, a file name, ...).
        vertices_mm: (N, 3) float64, millimetres, head frame.
        triangles: (M, 3) int64 vertex indices, counter-clockwise seen from in
            front of the face (normals point out of the face); ``None`` when
            the model has no triangulation.
        keypoints: which points are the eye (and mouth) corners, or ``None``
            when unknown (set by the loader for the layouts it knows, or by the
            user); gaze normalization needs them.
    """

    name: str
    vertices_mm: NDArray[np.float64]
    triangles: NDArray[np.int64] | None = None
    keypoints: FaceKeypoints | None = None

    def __post_init__(self) -> None:
        v = _frozen_array(self.vertices_mm, f"face model {self.name!r} vertices", (None, 3))
        if len(v) < 4:
            raise InputError(f"face model {self.name!r}: expected at least 4 points, got {len(v)}")
        object.__setattr__(self, "vertices_mm", v)
        if self.triangles is not None:
            t = _frozen_array(self.triangles, f"face model {self.name!r} triangles", (None, 3), np.int64)
            if t.size and (t.min() < 0 or t.max() >= len(v)):
                raise InputError(
                    f"face model {self.name!r}: triangle indices must lie in [0, {len(v) - 1}], "
                    f"got [{t.min()}, {t.max()}]"
                )
            object.__setattr__(self, "triangles", t)
        if self.keypoints is not None and max(self.keypoints.face_indices) >= len(v):
            raise InputError(
                f"face model {self.name!r}: key point indices {self.keypoints.face_indices} do not fit "
                f"a {len(v)}-point model"
            )

    def with_keypoints(self, keypoints: FaceKeypoints | None) -> FaceModel:
        """The same model with these key points."""
        return FaceModel(self.name, self.vertices_mm, self.triangles, keypoints)

    @property
    def num_points(self) -> int:
        """Number of model points N."""
        return len(self.vertices_mm)


@dataclass(frozen=True)
class FaceLandmarks:
    """One face's landmarks in one image.

    Attributes:
        points_px: (L, 2) float64, pixels, image frame (distorted, as detected).
        model_name: the landmark model that produced them (``"mediapipe_face_mesh"``, ``"user"``, ...).
        points_3d: (L, 3) float64 or ``None``: the landmark model's own 3D
            output: x, y in pixels (image frame) and z a relative depth in the
            same pixel units, growing away from the camera (MediaPipe's z times
            the image width).
        bbox_px: (x0, y0, x1, y1) bounding box of ``points_px``, pixels.
    """

    points_px: NDArray[np.float64]
    model_name: str
    points_3d: NDArray[np.float64] | None = None
    bbox_px: tuple[float, float, float, float] = field(init=False)

    def __post_init__(self) -> None:
        p = _frozen_array(self.points_px, "landmarks", (None, 2))
        if len(p) < 4:
            raise InputError(f"landmarks: expected at least 4 points, got {len(p)}")
        object.__setattr__(self, "points_px", p)
        if self.points_3d is not None:
            object.__setattr__(self, "points_3d", _frozen_array(self.points_3d, "landmarks 3D", (len(p), 3)))
        lo, hi = p.min(axis=0), p.max(axis=0)
        object.__setattr__(self, "bbox_px", (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])))

    @property
    def num_points(self) -> int:
        """Number of landmarks L."""
        return len(self.points_px)

    @property
    def area_px(self) -> float:
        """Area of the bounding box in square pixels (used to pick the largest face)."""
        x0, y0, x1, y1 = self.bbox_px
        return (x1 - x0) * (y1 - y0)


@dataclass(frozen=True)
class HeadPose:
    """A rigid head pose: ``p_camera = rotation @ p_head + translation_mm``.

    Attributes:
        rotation: (3, 3) float64, head frame -> OpenCV camera frame.
        translation_mm: (3,) float64, millimetres, camera frame position of the
            head frame's origin (the midpoint between the eyes for the built-in models).
        reprojection_error_px: RMS distance in pixels between the landmarks and
            the projected model points at this pose.
    """

    rotation: NDArray[np.float64]
    translation_mm: NDArray[np.float64]
    reprojection_error_px: float = 0.0

    def __post_init__(self) -> None:
        r = _frozen_array(self.rotation, "head rotation", (3, 3))
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise InputError("head rotation: expected a proper rotation matrix")
        object.__setattr__(self, "rotation", r)
        object.__setattr__(self, "translation_mm", _frozen_array(self.translation_mm, "head translation", (3,)))
        object.__setattr__(self, "reprojection_error_px", float(self.reprojection_error_px))

    @property
    def rvec(self) -> NDArray[np.float64]:
        """(3,) float64 Rodrigues vector of :attr:`rotation` (OpenCV's ``rvec``)."""
        import cv2

        return np.asarray(cv2.Rodrigues(np.asarray(self.rotation))[0], dtype=np.float64).ravel()

    def head_to_camera(self, points_head_mm: ArrayLike) -> NDArray[np.float64]:
        """(N, 3) head frame mm -> (N, 3) camera frame mm."""
        p = np.asarray(points_head_mm, dtype=np.float64)
        return p @ self.rotation.T + self.translation_mm


@dataclass(frozen=True)
class FaceMesh:
    """A textured face mesh whose vertex i is landmark i.

    Attributes:
        vertices_mm: (N, 3) float64, millimetres, OpenCV camera frame of the
            source image's camera.
        triangles: (M, 3) int64, counter-clockwise seen from the camera
            (normals toward the camera for a face that looks at it).
        uv: (N, 2) float64 glTF texture coordinates of each vertex into ``texture``.
        texture: (H, W, 3) uint8 RGB: the source image cropped around the face.
        texture_origin_px: (x0, y0) pixel of the source image that is the
            texture's top-left pixel.
        landmarks: the detected landmarks (may hold more points than vertices,
            e.g. MediaPipe's 10 iris points).
        camera: the source image's camera.
        pose: the head pose solved by PnP (head frame -> camera frame).
        face_model_name: name of the :class:`FaceModel` used for the pose.
        vertex_placement: ``"canonical"``, ``"backprojected"`` or ``"landmarks3d"``.
        reconstruction: ``{}`` when the triangles came from the face model;
            otherwise how they were made, e.g. ``{"method": "ball_pivoting",
            "backend": "open3d", "radii_mm": [...]}``.
        extras: any further JSON-serialisable metadata (package version, source image name, ...).
        model_vertices_mm: (N, 3) float64, millimetres, head frame: the face
            model's points the pose was solved with (``None`` when unknown).
            Consumers that need the model's reference points (eye centres for
            gaze normalization) read them here, so they agree with the pose.
        model_keypoints: that face model's key points (``None`` when unknown).
    """

    vertices_mm: NDArray[np.float64]
    triangles: NDArray[np.int64]
    uv: NDArray[np.float64]
    texture: NDArray[np.uint8]
    texture_origin_px: tuple[int, int]
    landmarks: FaceLandmarks
    camera: CameraIntrinsics
    pose: HeadPose
    face_model_name: str
    vertex_placement: str
    reconstruction: Mapping[str, Any] = field(default_factory=dict)
    extras: Mapping[str, Any] = field(default_factory=dict)
    model_vertices_mm: NDArray[np.float64] | None = None
    model_keypoints: FaceKeypoints | None = None

    def __post_init__(self) -> None:
        v = _frozen_array(self.vertices_mm, "mesh vertices", (None, 3))
        if self.model_vertices_mm is not None:
            object.__setattr__(
                self, "model_vertices_mm", _frozen_array(self.model_vertices_mm, "face model vertices", (None, 3))
            )
        object.__setattr__(self, "vertices_mm", v)
        t = _frozen_array(self.triangles, "mesh triangles", (None, 3), np.int64)
        if t.size and (t.min() < 0 or t.max() >= len(v)):
            raise InputError(f"mesh triangles: indices must lie in [0, {len(v) - 1}]")
        object.__setattr__(self, "triangles", t)
        object.__setattr__(self, "uv", _frozen_array(self.uv, "mesh uv", (len(v), 2)))
        tex = np.array(self.texture, dtype=np.uint8, copy=True)
        if tex.ndim != 3 or tex.shape[2] != 3:
            raise InputError(f"texture: expected (H, W, 3) uint8, got {tex.shape}")
        tex.setflags(write=False)
        object.__setattr__(self, "texture", tex)
        object.__setattr__(self, "texture_origin_px", (int(self.texture_origin_px[0]), int(self.texture_origin_px[1])))
        object.__setattr__(self, "reconstruction", dict(self.reconstruction))
        object.__setattr__(self, "extras", dict(self.extras))

    @property
    def num_vertices(self) -> int:
        """Number of vertices N."""
        return len(self.vertices_mm)

    @property
    def num_triangles(self) -> int:
        """Number of triangles M."""
        return len(self.triangles)

    def to_open3d(self, *, frame: str = "gltf") -> open3d.geometry.TriangleMesh:
        """Open3D ``TriangleMesh`` whose vertex i is this mesh's vertex i (landmark i).

        Default: metres, glTF frame; ``frame="camera"``: millimetres, OpenCV
        camera frame. Shapes, dtypes, frames and texture coordinates:
        :func:`facemesh.mesh.to_open3d`, which this calls.
        """
        from . import mesh  # lazily: facemesh.mesh imports this module

        return mesh.to_open3d(self, frame=frame)

    def to_trimesh(self, *, frame: str = "gltf") -> trimesh.Trimesh:
        """``trimesh.Trimesh`` whose vertex i is this mesh's vertex i (landmark i).

        Default: metres, glTF frame; ``frame="camera"``: millimetres, OpenCV
        camera frame. Shapes, dtypes, frames and texture coordinates:
        :func:`facemesh.mesh.to_trimesh`, which this calls.
        """
        from . import mesh  # lazily: facemesh.mesh imports this module

        return mesh.to_trimesh(self, frame=frame)
