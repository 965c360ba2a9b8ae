"""Head pose by PnP: OpenCV ``solvePnP`` (SQPnP or EPnP, then Levenberg-Marquardt refinement).

Every solved pose is checked against its landmarks. The *face size* is the RMS
distance of the face model's reprojected points from their centroid, in pixels
(about 50 mm on the face for the shipped 468-point model, MPIIFaceGaze's
6-point model and ETH-XGaze's 50-point model alike: roughly 0.8 times the
inter-ocular distance, whatever the layout). The fit is judged by its worst
landmark, the largest distance between a landmark and its model point's
reprojection:

- above :data:`REPROJECTION_WARN_FRACTION` x the face size (and at least
  :data:`REPROJECTION_WARN_MIN_PX`), a :class:`ReprojectionWarning`;
- above :data:`REPROJECTION_REFUSE_FRACTION` x the face size (and at least
  :data:`REPROJECTION_REFUSE_MIN_PX`), a :class:`PoseError`.

On 16 real faces (frontal to profile, 40 to 200 px between the eyes),
MediaPipe's landmarks against the shipped model have RMS errors of 3-17 px
and a worst landmark at 0.10-0.36 x the face size; a landmark one face size
away (about 50 mm on the face) is not on the feature the model expects, and
the pose it drags is not the face's.
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .types import CameraIntrinsics, FaceMeshError, HeadPose, InputError

__all__ = [
    "PoseError",
    "ReprojectionWarning",
    "REPROJECTION_WARN_FRACTION",
    "REPROJECTION_REFUSE_FRACTION",
    "REPROJECTION_WARN_MIN_PX",
    "REPROJECTION_REFUSE_MIN_PX",
    "solve_head_pose",
    "project_points",
    "undistort_to_rays",
]

#: Warn when a landmark lies farther than this fraction of the face size from its reprojection.
REPROJECTION_WARN_FRACTION = 0.5
#: Refuse the pose (PoseError) when a landmark lies farther than this fraction of the face size from its reprojection.
REPROJECTION_REFUSE_FRACTION = 1.0
#: The warning's threshold is at least this many pixels (tiny faces: detector noise of a few pixels is normal).
REPROJECTION_WARN_MIN_PX = 5.0
#: The refusal's threshold is at least this many pixels.
REPROJECTION_REFUSE_MIN_PX = 10.0


class PoseError(FaceMeshError):
    """PnP found no plausible pose: the face is behind the camera, the solver failed, or the landmarks do not fit."""


class ReprojectionWarning(UserWarning):
    """A landmark lies far from its model point's reprojection (see the module docstring for the thresholds)."""


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


#: Landmarks whose smaller spread (singular value of the centred points) is
#: below this fraction of the larger (or of 1 px) lie on one line: no pose.
_MIN_LANDMARK_SPREAD = 1e-6


def solve_head_pose(
    landmarks_px: ArrayLike,
    model_points_mm: ArrayLike,
    camera: CameraIntrinsics,
    *,
    source: str | None = None,
    check_fit: bool = True,
) -> HeadPose:
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
        source: the image's name, for messages.
        check_fit: judge the fit (module docstring): warn, or refuse a landmark
            farther than :data:`REPROJECTION_REFUSE_FRACTION` x the face size from its reprojection.

    Returns:
        The pose (head frame -> camera frame) with its RMS reprojection error.

    Raises:
        InputError: mismatched or too few points, or landmarks at one point or on one line.
        PoseError: no pose puts the face in front of the camera, or a landmark lies
            too far from its reprojection.

    Warns:
        ReprojectionWarning: a landmark lies far from its reprojection, but not too far.
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
    if not np.all(np.isfinite(img)):
        raise InputError("landmarks_px: expected finite values, got NaN or infinite values")
    spread = np.linalg.svd(img - img.mean(axis=0), compute_uv=False)  # (2,) along the landmarks' two main axes
    if not spread[-1] > _MIN_LANDMARK_SPREAD * max(float(spread[0]), 1.0):
        raise InputError(
            f"landmarks_px: all {len(img)} at one point or on one line (spreads {spread[0]:.3g} and "
            f"{spread[-1]:.3g} px); a head pose needs them spread over the face"
        )
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
        proj = np.asarray(cv2.projectPoints(obj, rvec, tvec, k, dist)[0], dtype=np.float64).reshape(-1, 2)
        rms = float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1))))
        candidates.append((rms, rot, t, proj))
        break  # the first initialiser's refined pose is valid; the second is the fallback
    where = f"{source}: " if source else ""
    if not candidates:
        raise PoseError(f"{where}PnP found no pose with the face in front of the camera")
    rms, rot, t, proj = candidates[0]
    if check_fit:
        _check_fit(img, proj, rms, where)
    return HeadPose(
        rotation=np.asarray(rot, dtype=np.float64),
        translation_mm=np.asarray(t, dtype=np.float64),
        reprojection_error_px=rms,
    )


def _check_fit(landmarks_px: NDArray[np.float64], reprojected_px: NDArray[np.float64], rms: float, where: str) -> None:
    """Warn about, or refuse, a landmark far from its reprojection (thresholds: module docstring)."""
    errors = np.linalg.norm(reprojected_px - landmarks_px, axis=1)
    worst = int(np.argmax(errors))
    err = float(errors[worst])
    size = float(np.sqrt(np.mean(np.sum((reprojected_px - reprojected_px.mean(axis=0)) ** 2, axis=1))))
    refuse = max(REPROJECTION_REFUSE_FRACTION * size, REPROJECTION_REFUSE_MIN_PX)
    warn = max(REPROJECTION_WARN_FRACTION * size, REPROJECTION_WARN_MIN_PX)
    if err <= warn:
        return
    what = (
        f"{where}reprojection error: landmark {worst} lies {err:.1f} px from its face model point's reprojection "
        f"(RMS {rms:.1f} px over {len(errors)} landmarks; the face's size is {size:.1f} px)"
    )
    if err > refuse:
        raise PoseError(
            f"{what}; refused above {REPROJECTION_REFUSE_FRACTION:g} x the face size ({refuse:.1f} px): "
            "the landmarks do not match the face model (wrong order or layout, or a wrong detection)"
        )
    warnings.warn(
        f"{what}; above {REPROJECTION_WARN_FRACTION:g} x the face size ({warn:.1f} px): the pose may be off",
        ReprojectionWarning,
        stacklevel=3,
    )
