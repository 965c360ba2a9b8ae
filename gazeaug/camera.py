"""The normalized camera of Zhang et al. 2018, shared by test-time normalization and training-time rendering.

For a reference point ``e`` (an eye centre or the face centre, camera frame,
mm) and the head rotation ``R_head`` (head frame -> camera frame), the
normalized camera's axes, as rows of ``R``, are::

    z = e / ||e||                    forward: from the camera centre to the reference point
    y = normalize(z x R_head[:, 0])  down: perpendicular to the forward axis and the head's x axis
    x = normalize(y x z)             right: the head's x axis made perpendicular to z

and the image warp is ``W = C_n S R C_r^-1`` with ``S = diag(1, 1, d_n / ||e||)``
and ``C_n = [[f_n, 0, w / 2], [0, f_n, h / 2], [0, 0, 1]]`` (the principal point
Zhang's code uses). ``W`` turns the real camera about its centre by ``R`` and
zooms it by ``d_n / ||e||``: the patch shows the reference point as a camera
``d_n`` away would. A direction ``v`` (gaze, head axes) is normalized by ``R``
alone (the "modified" normalization, which does not scale the gaze).

This module owns "the normalized camera and its labels": :func:`normalized_views`
is the one kernel that turns a face model, its key points and P head poses into
the normalized cameras of the three references (left eye, right eye, face
centre) and the head-pose and gaze labels in each. Test-time normalization
(:func:`gazeaug.normalize.normalize_image`, P = 1) and training-time rendering
(:func:`gazeaug.augment.render_poses`, P poses) both call it, so a rendered patch
and a real image normalized at the same pose agree label for label by
construction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from facemesh.conventions import (
    homogeneous_pixel_centres,
    look_at_rotation,
    rotation_to_head_pitchyaw,
    vector_to_pitchyaw,
)

from .errors import GazeAugError

if TYPE_CHECKING:
    from facemesh.face_models import FaceKeypoints

__all__ = [
    "REFERENCES",
    "MAX_GAZE_COMPONENT",
    "NormalizedCamera",
    "NormalizedViews",
    "normalized_camera",
    "normalized_cameras",
    "normalized_views",
    "reference_points",
    "reference_points_head",
    "pixel_to_ray_matrices",
    "pixel_grid",
]

#: The three reference points of a face, in the order every kernel output lists them.
REFERENCES = ("left", "right", "face")

_EYE3 = np.eye(3)


def pixel_grid(size_wh: tuple[int, int]) -> NDArray[np.float64]:
    """(H, W, 3) float64 homogeneous pixel centres ``(u, v, 1)`` (read-only, cached per size).

    :func:`facemesh.conventions.homogeneous_pixel_centres`, kept once per patch size.
    """
    key = (int(size_wh[0]), int(size_wh[1]))
    grid = _GRIDS.get(key)
    if grid is None:
        grid = homogeneous_pixel_centres(key)
        grid.setflags(write=False)
        _GRIDS[key] = grid
    return grid


_GRIDS: dict[tuple[int, int], NDArray[np.float64]] = {}


@dataclass(frozen=True)
class NormalizedCamera:
    """Zhang's normalized camera for one reference point.

    Attributes:
        rotation: (3, 3) float64; rows are the normalized camera's x, y, z axes
            in the real camera's frame (``R`` of the module docstring).
        reference_mm: (3,) float64, mm, real camera frame: the point the camera looks at.
        distance_mm: d_n, the normalized distance to the reference point.
        focal_px: f_n, the normalized focal length in pixels.
        size_wh: (width, height) of the normalized image in pixels.
    """

    rotation: NDArray[np.float64]
    reference_mm: NDArray[np.float64]
    distance_mm: float
    focal_px: float
    size_wh: tuple[int, int]

    def __post_init__(self) -> None:
        r = np.array(self.rotation, dtype=np.float64)
        e = np.array(self.reference_mm, dtype=np.float64)
        if r.shape != (3, 3) or not float(np.abs(r @ r.T - _EYE3).max()) < 1e-9:
            raise GazeAugError(f"normalized camera rotation: expected a (3, 3) rotation, got {r.tolist()}")
        if e.shape != (3,) or not np.isfinite(e).all():
            raise GazeAugError(f"normalized camera reference point: expected finite (3,), got {e}")
        r.setflags(write=False)
        e.setflags(write=False)
        object.__setattr__(self, "rotation", r)
        object.__setattr__(self, "reference_mm", e)

    @property
    def camera_matrix(self) -> NDArray[np.float64]:
        """(3, 3) float64 ``C_n``: focal f_n, principal point (w / 2, h / 2)."""
        w, h = self.size_wh
        return np.array([[self.focal_px, 0.0, w / 2.0], [0.0, self.focal_px, h / 2.0], [0.0, 0.0, 1.0]])

    @property
    def scale(self) -> float:
        """``d_n / ||e||``, the zoom ``S`` applies."""
        return float(self.distance_mm / np.linalg.norm(self.reference_mm))

    def warp_matrix(self, real_camera_matrix: ArrayLike) -> NDArray[np.float64]:
        """(3, 3) float64 homography ``W = C_n S R C_r^-1`` from real image pixels to normalized pixels."""
        s = np.diag([1.0, 1.0, self.scale])
        return self.camera_matrix @ s @ self.rotation @ np.linalg.inv(np.asarray(real_camera_matrix, dtype=np.float64))

    @property
    def pixel_to_ray(self) -> NDArray[np.float64]:
        """(3, 3) float64 ``R^T S^-1 C_n^-1``: normalized pixel ``(u, v, 1)`` -> ray direction, real camera frame."""
        return pixel_to_ray_matrices([self])[0]

    def ray_directions(self) -> NDArray[np.float64]:
        """(H, W, 3) float64: for each normalized pixel centre, its ray in the real camera frame.

        ``R^T S^-1 C_n^-1 (u, v, 1)``; the rays start at the real camera's centre.
        """
        return pixel_grid(self.size_wh) @ self.pixel_to_ray.T

    def project(self, points_mm: ArrayLike) -> NDArray[np.float64]:
        """Points of the real camera's frame -> their positions in the normalized image, px.

        Convention: ``(u, v, 1) ~ C_n S R p`` (the warp of :meth:`warp_matrix` applied to the
        point's real image position; the inverse of :meth:`pixel_to_ray`): pixel centres at whole
        numbers, x right, y down, the principal point at ``(w / 2, h / 2)``. A point at the
        reference's depth ``||e||``, ``delta`` mm off the axis, lands ``f_n delta / d_n`` px from the
        principal point: as seen from ``d_n`` mm, not from ``||e||``.

        Args:
            points_mm: (..., 3) float, mm, real camera frame, in front of the camera (z > 0).

        Returns:
            (..., 2) float64, px (u, v).

        Raises:
            GazeAugError: not (..., 3), not finite, or a point not in front of the camera.
        """
        p = np.asarray(points_mm, dtype=np.float64)
        if p.ndim < 1 or p.shape[-1] != 3 or not np.isfinite(p).all():
            raise GazeAugError(f"points: expected finite (..., 3) mm, got shape {p.shape}")
        q = p @ (np.diag([1.0, 1.0, self.scale]) @ self.rotation).T  # S R p
        if not (q[..., 2] > 0).all():
            raise GazeAugError("points: expected every point in front of the normalized camera (z > 0)")
        w, h = self.size_wh
        return np.stack(
            [self.focal_px * q[..., 0] / q[..., 2] + w / 2.0, self.focal_px * q[..., 1] / q[..., 2] + h / 2.0], axis=-1
        )

    def normalize_vector(self, vector: ArrayLike) -> NDArray[np.float64]:
        """(3,) direction in the real camera frame -> (3,) unit direction in the normalized frame (``R v``)."""
        v = np.asarray(vector, dtype=np.float64)
        n = np.linalg.norm(v)
        if v.shape != (3,) or not np.isfinite(n) or n == 0:
            raise GazeAugError(f"direction: expected a finite non-zero (3,) vector, got {v}")
        return self.rotation @ (v / n)

    def denormalize_vector(self, vector: ArrayLike) -> NDArray[np.float64]:
        """(3,) direction in the normalized frame -> (3,) unit direction in the real camera frame (``R^T v``)."""
        v = np.asarray(vector, dtype=np.float64)
        return self.rotation.T @ (v / np.linalg.norm(v))

    def head_pose_pitchyaw(self, head_rotation: ArrayLike) -> NDArray[np.float64]:
        """(2,) float64 radians: the head pose (pitch, yaw) in the normalized frame, from ``R @ R_head``."""
        return rotation_to_head_pitchyaw(self.rotation @ np.asarray(head_rotation, dtype=np.float64))

    def gaze_pitchyaw(self, gaze_vector: ArrayLike) -> NDArray[np.float64]:
        """(2,) float64 radians: a real-camera-frame gaze direction as (pitch, yaw) in the normalized frame."""
        return vector_to_pitchyaw(self.normalize_vector(gaze_vector))


def pixel_to_ray_matrices(cameras: Sequence[NormalizedCamera]) -> NDArray[np.float64]:
    """(K, 3, 3) float64 :attr:`NormalizedCamera.pixel_to_ray` of K cameras at once: ``R^T S^-1 C_n^-1``."""
    r = np.stack([c.rotation for c in cameras])
    refs = np.stack([c.reference_mm for c in cameras])
    inv_scale = np.sqrt(np.einsum("ki,ki->k", refs, refs)) / np.array([c.distance_mm for c in cameras])
    f = np.array([c.focal_px for c in cameras])
    size = np.array([c.size_wh for c in cameras], dtype=np.float64)
    k_inv = np.zeros((len(cameras), 3, 3))
    k_inv[:, 0, 0] = k_inv[:, 1, 1] = 1.0 / f
    k_inv[:, 0, 2] = -size[:, 0] / (2.0 * f)
    k_inv[:, 1, 2] = -size[:, 1] / (2.0 * f)
    k_inv[:, 2, 2] = 1.0
    rt_s = np.transpose(r, (0, 2, 1)).copy()
    rt_s[:, :, 2] *= inv_scale[:, None]
    return np.asarray(rt_s @ k_inv, dtype=np.float64)


def normalized_cameras(
    references_mm: ArrayLike,
    head_rotations: ArrayLike,
    *,
    distance_mm: float,
    focal_px: float,
    size_wh: tuple[int, int],
) -> list[NormalizedCamera]:
    """:func:`normalized_camera` for K reference points at once.

    Args:
        references_mm: (K, 3) float, mm, real camera frame.
        head_rotations: (K, 3, 3) float, head frame -> real camera frame.
        distance_mm: d_n.
        focal_px: f_n.
        size_wh: (width, height) of the normalized images.
    """
    e = np.asarray(references_mm, dtype=np.float64).reshape(-1, 3)
    hr = np.asarray(head_rotations, dtype=np.float64).reshape(-1, 3, 3)
    if len(hr) != len(e):
        raise GazeAugError(f"expected one head rotation per reference point, got {len(hr)} and {len(e)}")
    if not np.isfinite(e).all():
        raise GazeAugError("reference points: expected finite values (mm)")
    if (e[:, 2] <= 0).any():
        bad = e[np.argmax(e[:, 2] <= 0)]
        raise GazeAugError(f"reference point {np.round(bad, 1).tolist()} mm is behind the camera (z <= 0)")
    if not (np.isfinite(distance_mm) and distance_mm > 0 and np.isfinite(focal_px) and focal_px > 0):
        raise GazeAugError(f"normalized distance and focal must be > 0, got {distance_mm} mm and {focal_px} px")
    w, h = (int(v) for v in size_wh)
    if w <= 0 or h <= 0:
        raise GazeAugError(f"normalized image size: expected positive (width, height), got {size_wh}")
    try:  # z toward the reference point, x levelled by the head's x axis (the module docstring)
        rot = look_at_rotation(e, right=hr[:, :, 0])
    except ValueError as exc:
        raise GazeAugError(
            "the head's x axis is parallel to the line of sight; the normalized camera is undefined"
        ) from exc
    rot.setflags(write=False)
    e = e.copy()
    e.setflags(write=False)
    return [_built_camera(rot[i], e[i], float(distance_mm), float(focal_px), (w, h)) for i in range(len(e))]


def _built_camera(
    rotation: NDArray[np.float64], reference_mm: NDArray[np.float64], d: float, f: float, wh: tuple[int, int]
) -> NormalizedCamera:
    """A camera whose fields were built and checked by :func:`normalized_cameras` (no copies, no re-checks)."""
    cam = object.__new__(NormalizedCamera)
    for name, value in (
        ("rotation", rotation),
        ("reference_mm", reference_mm),
        ("distance_mm", d),
        ("focal_px", f),
        ("size_wh", wh),
    ):
        object.__setattr__(cam, name, value)
    return cam


def normalized_camera(
    reference_mm: ArrayLike,
    head_rotation: ArrayLike,
    *,
    distance_mm: float,
    focal_px: float,
    size_wh: tuple[int, int],
) -> NormalizedCamera:
    """Build the normalized camera looking at ``reference_mm`` (see the module docstring).

    Args:
        reference_mm: (3,) float, mm, real camera frame: eye or face centre.
        head_rotation: (3, 3) float, head frame -> real camera frame.
        distance_mm: d_n.
        focal_px: f_n.
        size_wh: (width, height) of the normalized image.

    Raises:
        GazeAugError: the point is at or behind the camera centre, or the head's
            x axis is parallel to the line of sight.
    """
    e = np.asarray(reference_mm, dtype=np.float64)
    if e.shape != (3,):
        raise GazeAugError(f"reference point: expected (3,) mm, got shape {e.shape}")
    return normalized_cameras(
        e[None],
        np.asarray(head_rotation, dtype=np.float64)[None],
        distance_mm=distance_mm,
        focal_px=focal_px,
        size_wh=size_wh,
    )[0]


def reference_points_head(model_vertices_mm: ArrayLike, keypoints: FaceKeypoints | None) -> NDArray[np.float64]:
    """The face model's three reference points in its own head frame.

    Args:
        model_vertices_mm: (N, 3) float, mm, head frame: the face model the pose was solved with.
        keypoints: which model points are the eye (and mouth) corners.

    Returns:
        (3, 3) float64, mm, head frame; rows: the left eye centre (mean of its two corners), the
        right eye centre, the face centre (mean of the four eye corners and, when known, the
        two mouth corners), as Zhang's normalization defines them (:data:`REFERENCES`).

    Raises:
        GazeAugError: no key points (``remedy="keypoints"``), or the model has fewer points than they name.
    """
    if keypoints is None:
        raise GazeAugError(
            "the face model does not say which of its points are the eye and mouth corners", remedy="keypoints"
        )
    m = np.asarray(model_vertices_mm, dtype=np.float64)
    idx = keypoints.face_indices
    if m.ndim != 2 or m.shape[1] != 3 or max(idx) >= len(m):
        raise GazeAugError(
            f"face model: expected (N, 3) points with N > {max(idx)} for these key points, got {m.shape}"
        )
    return np.stack(
        [m[list(keypoints.left_eye)].mean(axis=0), m[list(keypoints.right_eye)].mean(axis=0), m[list(idx)].mean(axis=0)]
    )


def reference_points(
    head_rotation: ArrayLike,
    head_translation_mm: ArrayLike,
    model_vertices_mm: ArrayLike,
    keypoints: FaceKeypoints | None,
) -> dict[str, NDArray[np.float64]]:
    """The eye and face centres of the face model posed at one head pose, camera frame.

    Args:
        head_rotation: (3, 3) float, head frame -> camera frame.
        head_translation_mm: (3,) float, mm, camera frame.
        model_vertices_mm: (N, 3) float, mm, head frame.
        keypoints: which model points are the eye and mouth corners.

    Returns:
        ``{"left": e_l, "right": e_r, "face": c}``, each (3,) float64, mm, camera frame.
    """
    r = np.asarray(head_rotation, dtype=np.float64)
    posed = reference_points_head(model_vertices_mm, keypoints) @ r.T + np.asarray(
        head_translation_mm, dtype=np.float64
    )
    return dict(zip(REFERENCES, posed))


@dataclass(frozen=True)
class NormalizedViews:
    """The normalized cameras and labels of a face at P head poses (:func:`normalized_views`).

    Attributes:
        cameras: P tuples ``(left eye, right eye, face)`` of :class:`NormalizedCamera` (the face
            camera has the eye patch size; only its rotation defines the face frame).
        references_mm: (P, 3, 3) float64, mm, camera frame of each pose: the reference points
            (rows in :data:`REFERENCES` order).
        head_pose: (P, 3, 2) float64 radians: (pitch, yaw) of the head in each reference's
            normalized frame (``rotation_to_head_pitchyaw(R_n R_head)``).
        gaze: (P, 3, 2) float64 radians: (pitch, yaw) of the gaze from each reference, in its
            normalized frame (``vector_to_pitchyaw(R_n g)``, ``g`` the unit direction from the
            reference to the target, or the given direction); ``None`` when no gaze was given.
    """

    cameras: tuple[tuple[NormalizedCamera, NormalizedCamera, NormalizedCamera], ...]
    references_mm: NDArray[np.float64]
    head_pose: NDArray[np.float64]
    gaze: NDArray[np.float64] | None

    def __len__(self) -> int:
        return len(self.cameras)


#: Largest |component| of a gaze target (mm) or gaze vector that :func:`normalized_views` accepts: 10 km,
#: far beyond any scene, and far below where ``target - reference`` and its norm lose precision or overflow.
MAX_GAZE_COMPONENT = 1e7


def _per_pose(value: ArrayLike | None, n: int, name: str, unit: str = "") -> NDArray[np.float64] | None:
    """(3,) or (P, 3) -> (P, 3) float64, checked finite and within :data:`MAX_GAZE_COMPONENT` (``unit``: " mm")."""
    if value is None:
        return None
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise GazeAugError(f"{name}: expected (3,) or ({n}, 3) numbers, got {value!r}") from exc
    if v.shape == (3,):
        v = np.broadcast_to(v, (n, 3))
    if v.shape != (n, 3) or not np.isfinite(v).all():
        raise GazeAugError(f"{name}: expected finite (3,) or ({n}, 3) values, got {np.asarray(value).tolist()}")
    big = np.abs(v).max(initial=0.0)
    if big > MAX_GAZE_COMPONENT:
        raise GazeAugError(
            f"{name}: expected components within +-{MAX_GAZE_COMPONENT:g}{unit}, got one of {big:g} "
            f"(in {np.asarray(value).tolist() if v.size <= 12 else f'{n} poses'})"
        )
    return v


def normalized_views(
    model_vertices_mm: ArrayLike,
    keypoints: FaceKeypoints | None,
    rotations: ArrayLike,
    translations_mm: ArrayLike,
    *,
    distance_mm: float,
    focal_px: float,
    size_wh: tuple[int, int],
    gaze_target_mm: ArrayLike | None = None,
    gaze_vector: ArrayLike | None = None,
) -> NormalizedViews:
    """The one normalization kernel: cameras and labels of P head poses, for the three references.

    Args:
        model_vertices_mm: (N, 3) float, mm, head frame: the face model the pose was solved with.
        keypoints: its eye (and mouth) corner indices.
        rotations: (P, 3, 3) float, head frame -> camera frame, one per pose.
        translations_mm: (P, 3) float, mm, camera frame: the head frame's origin at each pose.
        distance_mm: d_n, mm.
        focal_px: f_n, pixels.
        size_wh: the eye patch (width, height), pixels.
        gaze_target_mm: (3,) or (P, 3) float, mm, camera frame of each pose: the point looked at
            (each reference's gaze is ``target - reference``); every component within
            +-:data:`MAX_GAZE_COMPONENT` (1e7 mm, 10 km).
        gaze_vector: (3,) or (P, 3) float, camera frame: a gaze direction shared by the three
            references (instead of a target); components within +-1e7 as well.

    Returns:
        :class:`NormalizedViews` (see there for shapes, units and frames).

    Raises:
        GazeAugError: a target and a vector both given; non-finite, too large (a component beyond
            1e7) or zero gaze; a reference point at or behind the camera; mismatched shapes.
    """
    rot = np.asarray(rotations, dtype=np.float64)
    trans = np.asarray(translations_mm, dtype=np.float64)
    if rot.ndim != 3 or rot.shape[1:] != (3, 3) or trans.shape != (len(rot), 3):
        raise GazeAugError(f"head poses: expected (P, 3, 3) and (P, 3), got {rot.shape} and {trans.shape}")
    if gaze_target_mm is not None and gaze_vector is not None:
        raise GazeAugError("give a gaze target or a gaze vector, not both")
    n = len(rot)
    target = _per_pose(gaze_target_mm, n, "gaze target", " mm")
    vector = _per_pose(gaze_vector, n, "gaze vector")
    refs = np.einsum("pij,ej->pei", rot, reference_points_head(model_vertices_mm, keypoints)) + trans[:, None, :]
    flat = normalized_cameras(
        refs.reshape(-1, 3), np.repeat(rot, 3, axis=0), distance_mm=distance_mm, focal_px=focal_px, size_wh=size_wh
    )
    r_norm = np.stack([c.rotation for c in flat]).reshape(n, 3, 3, 3)
    head = rotation_to_head_pitchyaw(r_norm @ rot[:, None])
    gaze = None
    if target is not None or vector is not None:
        if target is not None:
            g = target[:, None, :] - refs
        else:
            assert vector is not None
            g = np.broadcast_to(vector[:, None, :], refs.shape)
        norms = np.linalg.norm(g, axis=-1, keepdims=True)
        if (norms < 1e-9).any():
            raise GazeAugError("gaze: zero-length gaze vector (the target coincides with an eye or the vector is 0)")
        gaze = vector_to_pitchyaw(np.einsum("peij,pej->pei", r_norm, g / norms))
    cams = tuple((flat[3 * i], flat[3 * i + 1], flat[3 * i + 2]) for i in range(n))
    return NormalizedViews(cameras=cams, references_mm=refs, head_pose=head, gaze=gaze)
