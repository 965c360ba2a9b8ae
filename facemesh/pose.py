"""Head pose by PnP: OpenCV ``solvePnP`` (SQPnP or EPnP, then Levenberg-Marquardt refinement)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .types import CameraIntrinsics, FaceMeshError, HeadPose, InputError

__all__ = ["PoseError", "solve_head_pose", "project_points", "undistort_to_rays"]


class PoseError(FaceMeshError):
    """PnP found no plausible pose (the face would be behind the camera, or the solver failed)."""


def project_points(points_camera_mm: ArrayLike, camera: CameraIntrinsics) -> NDArray[np.float64]:
    """Project camera-frame points through the camera, with its distortion.

    Args:
        points_camera_mm: (N, 3) float, mm, OpenCV camera frame.
        camera: intrinsics and distortion.

    Returns:
        (N, 2) float64, pixels, image frame.
    """
    import cv2

    p = np.asarray(points_camera_mm, dtype=np.float64).reshape(-1, 1, 3)
    out, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), np.asarray(camera.matrix), np.asarray(camera.distortion))
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def undistort_to_rays(points_px: ArrayLike, camera: CameraIntrinsics) -> NDArray[np.float64]:
    """Camera rays through image points, undoing the distortion.

    Args:
        points_px: (N, 2) float, pixels, image frame (as observed, distorted).
        camera: intrinsics and distortion.

    Returns:
        (N, 3) float64 ray directions ``(x, y, 1)`` in the OpenCV camera frame
        (normalised image coordinates; multiply by a depth z in mm to get a point).
    """
    import cv2

    p = np.asarray(points_px, dtype=np.float64).reshape(-1, 1, 2)
    if camera.has_distortion:
        n = cv2.undistortPointsIter(  # type: ignore[call-overload]
            p,
            np.asarray(camera.matrix),
            np.asarray(camera.distortion),
            None,
            None,
            (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10),
        ).reshape(-1, 2)
    else:
        k = camera.matrix
        q = p.reshape(-1, 2)
        y = (q[:, 1] - k[1, 2]) / k[1, 1]
        x = (q[:, 0] - k[0, 2] - k[0, 1] * y) / k[0, 0]
        n = np.stack([x, y], axis=1)
    return np.column_stack([n, np.ones(len(n))])


def solve_head_pose(landmarks_px: ArrayLike, model_points_mm: ArrayLike, camera: CameraIntrinsics) -> HeadPose:
    """Rigid pose of a face model that best explains its landmarks.

    SQPnP gives the initial pose and Levenberg-Marquardt (``SOLVEPNP_ITERATIVE``
    with the initial guess) refines it; EPnP replaces SQPnP when that fails or
    puts the face behind the camera. (Refined from EPnP's start or from SQPnP's,
    the pose is the same within 2e-5 deg on the test photos; from SQPnP's, the
    refinement needs fewer iterations: 0.6 instead of 0.85 ms for 468 points.)

    Args:
        landmarks_px: (N, 2) float, pixels, image frame (as observed, distorted).
        model_points_mm: (N, 3) float, mm, head frame; row i matches landmark i.
        camera: intrinsics and distortion of the image.

    Returns:
        The pose (head frame -> camera frame) with its RMS reprojection error.

    Raises:
        InputError: mismatched or too few points.
        PoseError: no pose puts the face in front of the camera.
    """
    import cv2

    img = np.ascontiguousarray(landmarks_px, dtype=np.float64)
    obj = np.ascontiguousarray(model_points_mm, dtype=np.float64)
    if img.ndim != 2 or img.shape[1] != 2:
        raise InputError(f"landmarks_px: expected shape (N, 2), got {img.shape}")
    if obj.shape != (len(img), 3):
        raise InputError(f"model_points_mm: expected shape ({len(img)}, 3) to match the landmarks, got {obj.shape}")
    if len(img) < 4:
        raise InputError(f"PnP needs at least 4 points, got {len(img)}")
    k = np.asarray(camera.matrix)
    dist = np.asarray(camera.distortion)
    candidates = []
    for flag in (cv2.SOLVEPNP_SQPNP, cv2.SOLVEPNP_EPNP):
        try:
            ok, rvec, tvec = cv2.solvePnP(obj, img, k, dist, flags=flag)
        except cv2.error:
            continue
        if not ok or not np.all(np.isfinite(rvec)) or not np.all(np.isfinite(tvec)):
            continue
        try:
            ok, rvec, tvec = cv2.solvePnP(
                obj, img, k, dist, rvec, tvec, useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE
            )
        except cv2.error:
            continue
        if not ok:
            continue
        rot = cv2.Rodrigues(rvec)[0]
        t = tvec.ravel()
        if np.any(obj @ rot[2] + t[2] <= 0):  # a point behind the camera
            continue
        proj = cv2.projectPoints(obj, rvec, tvec, k, dist)[0].reshape(-1, 2)
        rms = float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1))))
        candidates.append((rms, rot, t))
        break  # the first initialiser's refined pose is valid; the second is the fallback
    if not candidates:
        raise PoseError("PnP found no pose with the face in front of the camera")
    rms, rot, t = candidates[0]
    return HeadPose(
        rotation=np.asarray(rot, dtype=np.float64),
        translation_mm=np.asarray(t, dtype=np.float64),
        reprojection_error_px=rms,
    )
