"""From landmarks to a textured face mesh: pose -> vertices -> triangles -> texture.

Vertex placement (``BuildSettings.vertex_placement``):

``canonical``
    The face model's points at the solved pose (the paper's choice). The mesh
    keeps the model's shape, so the eyes of a face whose shape differs from
    the model land away from their landmarks (measured: eyes squashed by 25-30%).
``backprojected`` (default)
    Each vertex slides along the camera ray through its detected landmark so
    that it projects exactly onto it, keeping the depth (camera z) the posed
    model gives it. The texture then lines up with the geometry everywhere.
``landmarks3d``
    Like ``backprojected``, but the depth comes from the landmark model's own
    per-face z (MediaPipe's), scaled to mm at the face's distance and centred
    on the posed model's mean depth.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .conventions import pixels_to_uv
from .pose import solve_head_pose, undistort_to_rays
from .reconstruct import BallPivotingSettings, ball_pivoting
from .types import CameraIntrinsics, FaceLandmarks, FaceMesh, FaceModel, HeadPose, InputError

__all__ = ["VERTEX_PLACEMENTS", "TEXTURE_ALIGN", "BuildSettings", "place_vertices", "crop_texture", "build_face_mesh"]

VERTEX_PLACEMENTS = ("canonical", "backprojected", "landmarks3d")

#: The texture crop's origin is a multiple of this many pixels (2 ** 4: four pyramid levels line up).
TEXTURE_ALIGN = 16


@dataclass(frozen=True)
class BuildSettings:
    """How :func:`build_face_mesh` builds a mesh.

    Attributes:
        vertex_placement: one of :data:`VERTEX_PLACEMENTS` (default ``"backprojected"``).
        texture_margin: margin added on every side of the landmarks' bounding
            box when cropping the texture, as a fraction of the box's larger
            side (default 0.15; the outer landmarks are the face contour).
        reconstruction: ``"auto"`` uses the face model's triangles when it has
            them and Ball-Pivoting otherwise; ``"ball_pivoting"`` always
            reconstructs.
        ball_pivoting: settings of the Ball-Pivoting fallback.
    """

    vertex_placement: str = "backprojected"
    texture_margin: float = 0.15
    reconstruction: str = "auto"
    ball_pivoting: BallPivotingSettings = field(default_factory=BallPivotingSettings)

    def __post_init__(self) -> None:
        if self.vertex_placement not in VERTEX_PLACEMENTS:
            raise InputError(f"vertex placement: expected one of {VERTEX_PLACEMENTS}, got {self.vertex_placement!r}")
        if self.reconstruction not in ("auto", "ball_pivoting"):
            raise InputError(f"reconstruction: expected 'auto' or 'ball_pivoting', got {self.reconstruction!r}")
        if not (0.0 <= self.texture_margin <= 2.0):
            raise InputError(f"texture margin: expected 0..2, got {self.texture_margin}")


def place_vertices(
    placement: str,
    landmarks: FaceLandmarks,
    model: FaceModel,
    pose: HeadPose,
    camera: CameraIntrinsics,
) -> NDArray[np.float64]:
    """Mesh vertices for one face (see the module docstring for the placements).

    Returns:
        (N, 3) float64, mm, OpenCV camera frame; N = the model's point count,
        vertex i for landmark i.
    """
    n = model.num_points
    posed = pose.head_to_camera(model.vertices_mm)
    if placement == "canonical":
        return posed
    rays = undistort_to_rays(landmarks.points_px[:n], camera)
    if placement == "backprojected":
        depth = posed[:, 2]
    elif placement == "landmarks3d":
        if landmarks.points_3d is None:
            raise InputError(
                "vertex placement 'landmarks3d' needs a landmark model with 3D output; "
                f"{landmarks.model_name!r} has none"
            )
        z_rel = landmarks.points_3d[:n, 2]
        mean_depth = float(posed[:, 2].mean())
        mm_per_px = mean_depth / camera.focal_px[0]
        depth = mean_depth + (z_rel - z_rel.mean()) * mm_per_px
    else:
        raise InputError(f"vertex placement: expected one of {VERTEX_PLACEMENTS}, got {placement!r}")
    if np.any(depth <= 0):
        raise InputError("vertex placement: some vertices would lie behind the camera")
    return rays * depth[:, None]


def crop_texture(
    image_rgb: NDArray[np.uint8], points_px: ArrayLike, margin: float
) -> tuple[NDArray[np.uint8], tuple[int, int]]:
    """Crop the image to the points' bounding box plus a margin (clipped to the image).

    Args:
        image_rgb: (H, W, 3) uint8 RGB.
        points_px: (N, 2) float, pixels, image frame: what the texture must hold
            (the landmarks, or a mesh's projected vertices).
        margin: added on every side, as a fraction of the box's larger side.

    The crop's top-left corner is rounded down to a multiple of
    :data:`TEXTURE_ALIGN` pixels, so that the texture's image pyramid
    (``cv2.pyrDown`` levels, used for anti-aliased sampling) samples the same
    points as the pyramid of the whole image.

    Returns:
        ``(texture, (x0, y0))``: (h, w, 3) uint8 RGB and its top-left pixel in the image.
    """
    h, w = image_rgb.shape[:2]
    pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    (x0, y0), (x1, y1) = pts.min(axis=0), pts.max(axis=0)
    pad = margin * max(x1 - x0, y1 - y0)
    ix0 = max(0, int(math.floor(x0 - pad)) // TEXTURE_ALIGN * TEXTURE_ALIGN)
    iy0 = max(0, int(math.floor(y0 - pad)) // TEXTURE_ALIGN * TEXTURE_ALIGN)
    ix1 = min(w, int(math.ceil(x1 + pad)) + 1)
    iy1 = min(h, int(math.ceil(y1 + pad)) + 1)
    if ix1 <= ix0 or iy1 <= iy0:
        raise InputError("landmarks: the face lies outside the image")
    return np.ascontiguousarray(image_rgb[iy0:iy1, ix0:ix1]), (ix0, iy0)


def build_face_mesh(
    image_rgb: NDArray[np.uint8],
    landmarks: FaceLandmarks,
    model: FaceModel,
    camera: CameraIntrinsics,
    settings: BuildSettings | None = None,
    extras: Mapping[str, Any] | None = None,
    pose: HeadPose | None = None,
) -> FaceMesh:
    """Solve the head pose (unless given) and build the textured mesh of one face.

    Args:
        image_rgb: (H, W, 3) uint8 RGB, the image the landmarks were found in.
        landmarks: (L >= N) landmarks; the first N correspond to the model's points.
        model: the N-point face model (mm, head frame).
        camera: the image's camera.
        settings: see :class:`BuildSettings`.
        extras: JSON-serialisable metadata to carry into the asset.
        pose: the head pose already solved from these landmarks with this model and camera
            (skips solving it again).

    Raises:
        InputError: mismatched sizes or settings; PoseError: PnP failed.
    """
    s = settings or BuildSettings()
    h, w = image_rgb.shape[:2]
    if camera.image_size != (w, h):
        raise InputError(f"camera is for {camera.image_size[0]}x{camera.image_size[1]} images, the image is {w}x{h}")
    n = model.num_points
    if landmarks.num_points < n:
        raise InputError(f"landmarks: {landmarks.num_points} points, but face model {model.name!r} has {n}")
    if pose is None:
        pose = solve_head_pose(landmarks.points_px[:n], model.vertices_mm, camera)
    vertices = place_vertices(s.vertex_placement, landmarks, model, pose, camera)
    reconstruction: dict[str, Any] = {}
    if model.triangles is not None and s.reconstruction == "auto":
        triangles = np.asarray(model.triangles)
    else:
        rec = ball_pivoting(vertices, viewpoint_mm=(0.0, 0.0, 0.0), settings=s.ball_pivoting)
        triangles = rec.triangles
        reconstruction = rec.as_metadata()
    texture, origin = crop_texture(image_rgb, landmarks.points_px, s.texture_margin)
    uv = pixels_to_uv(landmarks.points_px[:n], origin, (texture.shape[1], texture.shape[0]))
    return FaceMesh(
        vertices_mm=vertices,
        triangles=triangles,
        uv=uv,
        texture=texture,
        texture_origin_px=origin,
        landmarks=landmarks,
        camera=camera,
        pose=pose,
        face_model_name=model.name,
        vertex_placement=s.vertex_placement,
        reconstruction=reconstruction,
        extras=dict(extras or {}),
        model_vertices_mm=model.vertices_mm,
    )
