"""Data normalization of real camera images (Zhang et al. 2018, the modified version without gaze scaling).

For each eye, the reference point ``e`` is the eye centre: the mean of that
eye's two corners *of the face model at the solved head pose* (as in Zhang's
code; not the detected corner pixels). The face centre is the mean of the four
eye corners and the two mouth corners of the posed model. The normalized
camera (:mod:`gazeaug.camera`) looks at ``e`` from ``d_n`` with focal ``f_n``;
the gaze direction ``target - e`` and the head rotation are expressed in its
frame with ``R`` alone.

The patch is resampled through the exact inverse mapping ``W^-1`` followed by
the real camera's lens distortion (a plain ``cv2.warpPerspective`` ignores the
distortion), with the anti-aliased trilinear sampler of
:mod:`gazeaug.texture` unless ``antialias=False``, which gives exactly
``cv2.warpPerspective(image, W, size)`` with bilinear interpolation on an
undistorted camera.

"Left" and "right" are always the *subject's* eyes: the left eye appears on
the right of a non-mirrored image.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from facemesh.face_models import FaceKeypoints
from facemesh.types import CameraIntrinsics, HeadPose

from .camera import NormalizedCamera, normalized_cameras
from .errors import GazeAugError
from .texture import MipPyramid, region_pyramid, sample

__all__ = [
    "EYES",
    "NormalizationSettings",
    "EyePatch",
    "FaceLabels",
    "NormalizedSample",
    "face_labels",
    "reference_points",
    "eye_cameras",
    "source_coordinates",
    "normalize_image",
    "gaze_direction",
    "save_npz",
    "load_npz",
]

#: The subject's eyes, in the order every output lists them.
EYES = ("left", "right")


@dataclass(frozen=True)
class NormalizationSettings:
    """The normalized camera and patch (recorded in every output).

    Attributes:
        distance_mm: d_n, distance of the normalized camera from the eye (default 600 mm, the paper's).
        focal_px: f_n, its focal length (default 650 px, the paper's).
        patch_size_wh: eye patch (width, height) in pixels (default (60, 36)).
        antialias: sample a Gaussian pyramid per pixel's footprint (default True);
            False samples the full-resolution image bilinearly, like ``cv2.warpPerspective``.
    """

    distance_mm: float = 600.0
    focal_px: float = 650.0
    patch_size_wh: tuple[int, int] = (60, 36)
    antialias: bool = True

    def __post_init__(self) -> None:
        for name in ("distance_mm", "focal_px"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise GazeAugError(f"normalization {name}: expected a finite number > 0, got {v!r}")
        w, h = self.patch_size_wh
        if int(w) != w or int(h) != h or w < 4 or h < 4:
            raise GazeAugError(f"patch size: expected integers (width, height) >= 4, got {self.patch_size_wh}")
        object.__setattr__(self, "patch_size_wh", (int(w), int(h)))

    def as_dict(self) -> dict[str, Any]:
        """JSON-serialisable form, as recorded in outputs."""
        d = asdict(self)
        d["patch_size_wh"] = list(self.patch_size_wh)
        return d


@dataclass(frozen=True)
class EyePatch:
    """One normalized eye.

    Attributes:
        image: (H, W, 3) uint8 RGB patch (H, W from the settings' patch size).
        camera: the normalized camera that produced it.
        head_pose: (2,) float64 radians, (pitch, yaw) of the head in this eye's normalized frame.
        gaze: (2,) float64 radians, (pitch, yaw) gaze in this eye's normalized frame; ``None`` when unknown.
        coverage: fraction of pixels that saw the face (1.0 for a real image;
            below 1 where a render filled background).
    """

    image: NDArray[np.uint8]
    camera: NormalizedCamera
    head_pose: NDArray[np.float64]
    gaze: NDArray[np.float64] | None = None
    coverage: float = 1.0


@dataclass(frozen=True)
class FaceLabels:
    """Labels in the *face's* normalized frame (reference point: the face centre; no patch).

    One frame for the whole face, as in Zhang's face normalization: what the
    HDF5 training sets store as ``head_pose`` and ``gaze``.

    Attributes:
        camera: the face's normalized camera (the eye patch size; only its rotation matters here).
        head_pose: (2,) float64 radians, (pitch, yaw).
        gaze: (2,) float64 radians, (pitch, yaw) of ``target - face centre`` (or the gaze vector); ``None`` if unknown.
    """

    camera: NormalizedCamera
    head_pose: NDArray[np.float64]
    gaze: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class NormalizedSample:
    """Both eyes of one face, normalized (from a real image) or rendered (from a mesh).

    Attributes:
        left: the subject's left eye (on the image's right).
        right: the subject's right eye.
        settings: the normalization settings used.
        head_rotation: (3, 3) float64, head frame -> camera frame of the camera the sample was taken
            (or rendered) with.
        source: ``"normalize"`` or ``"render:<renderer>"``.
        meta: JSON-serialisable extras (sampled yaw and pitch, seed, input name, ...).
        face: labels in the face-centre normalized frame.
    """

    left: EyePatch
    right: EyePatch
    settings: NormalizationSettings
    head_rotation: NDArray[np.float64]
    source: str
    meta: Mapping[str, Any] = field(default_factory=dict)
    face: FaceLabels | None = None

    def eye(self, side: str) -> EyePatch:
        """The ``"left"`` or ``"right"`` eye."""
        if side not in EYES:
            raise GazeAugError(f"eye: expected 'left' or 'right', got {side!r}")
        return self.left if side == "left" else self.right


def reference_points(
    head_rotation: ArrayLike, head_translation_mm: ArrayLike, model_vertices_mm: ArrayLike, keypoints: FaceKeypoints
) -> dict[str, NDArray[np.float64]]:
    """Eye and face centres of the posed face model.

    Args:
        head_rotation: (3, 3) float, head frame -> camera frame.
        head_translation_mm: (3,) float, mm, camera frame.
        model_vertices_mm: (N, 3) float, mm, head frame.
        keypoints: which model points are the eye and mouth corners.

    Returns:
        ``{"left": e_l, "right": e_r, "face": c}``, each (3,) float64, mm, camera frame.
    """
    m = np.asarray(model_vertices_mm, dtype=np.float64)
    idx = keypoints.face_indices
    if m.ndim != 2 or m.shape[1] != 3 or max(idx) >= len(m):
        raise GazeAugError(
            f"face model: expected (N, 3) points with N > {max(idx)} for these eye corners, got {m.shape}"
        )
    posed = m @ np.asarray(head_rotation, dtype=np.float64).T + np.asarray(head_translation_mm, dtype=np.float64)
    return {
        "left": posed[list(keypoints.left_eye)].mean(axis=0),
        "right": posed[list(keypoints.right_eye)].mean(axis=0),
        "face": posed[list(idx)].mean(axis=0),
    }


def eye_cameras(
    head_rotation: ArrayLike,
    head_translation_mm: ArrayLike,
    model_vertices_mm: ArrayLike,
    keypoints: FaceKeypoints,
    settings: NormalizationSettings,
) -> dict[str, NormalizedCamera]:
    """The normalized camera of each eye at a head pose (``{"left": ..., "right": ...}``)."""
    refs = reference_points(head_rotation, head_translation_mm, model_vertices_mm, keypoints)
    return _eye_cameras_at(refs, head_rotation, settings)


def _eye_cameras_at(
    refs: dict[str, NDArray[np.float64]], head_rotation: ArrayLike, settings: NormalizationSettings
) -> dict[str, NormalizedCamera]:
    r = np.asarray(head_rotation, dtype=np.float64)
    cams = normalized_cameras(
        np.stack([refs[side] for side in EYES]),
        np.stack([r, r]),
        distance_mm=settings.distance_mm,
        focal_px=settings.focal_px,
        size_wh=settings.patch_size_wh,
    )
    return dict(zip(EYES, cams))


def source_coordinates(camera: NormalizedCamera, real: CameraIntrinsics) -> NDArray[np.float32]:
    """Where each normalized pixel comes from in the real (distorted) image.

    Returns:
        (H, W, 2) float32 pixel positions (x, y) in the real image.
    """
    import cv2

    rays = camera.ray_directions().reshape(-1, 3)
    if np.any(rays[:, 2] <= 0):
        raise GazeAugError("the normalized view reaches behind the real camera (reference point too far off-axis)")
    pts, _ = cv2.projectPoints(
        rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.asarray(real.matrix), np.asarray(real.distortion)
    )
    w, h = camera.size_wh
    return pts.reshape(h, w, 2).astype(np.float32)


def gaze_direction(
    origin_mm: ArrayLike, gaze_target_mm: ArrayLike | None = None, gaze_vector: ArrayLike | None = None
) -> NDArray[np.float64] | None:
    """The gaze direction from a reference point: ``target - origin``, or the given vector; ``None`` if neither.

    Raises:
        GazeAugError: NaN, infinite or zero gaze, or both a target and a vector.
    """
    if gaze_target_mm is not None and gaze_vector is not None:
        raise GazeAugError("give a gaze target or a gaze vector, not both")
    if gaze_target_mm is None and gaze_vector is None:
        return None
    if gaze_target_mm is not None:
        t = np.asarray(gaze_target_mm, dtype=np.float64)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise GazeAugError(f"gaze target: expected finite (X, Y, Z) mm, got {t.tolist()}")
        g = t - np.asarray(origin_mm, dtype=np.float64)
    else:
        g = np.asarray(gaze_vector, dtype=np.float64)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise GazeAugError(f"gaze vector: expected finite (3,), got {g.tolist()}")
    n = float(np.linalg.norm(g))
    if n < 1e-9:
        raise GazeAugError("gaze: zero-length gaze vector (the target coincides with the eye)")
    return g / n


def normalize_image(
    image_rgb: NDArray[np.uint8],
    camera: CameraIntrinsics,
    pose: HeadPose,
    model_vertices_mm: ArrayLike,
    keypoints: FaceKeypoints,
    *,
    gaze_target_mm: ArrayLike | None = None,
    gaze_vector: ArrayLike | None = None,
    settings: NormalizationSettings | None = None,
    pyramid: MipPyramid | None = None,
    meta: Mapping[str, Any] | None = None,
) -> NormalizedSample:
    """Normalize both eyes of one face in a real image.

    Args:
        image_rgb: (H, W, 3) uint8 RGB, as taken by ``camera``.
        camera: the real camera (its distortion is undone).
        pose: head pose from PnP with ``model_vertices_mm``.
        model_vertices_mm: (N, 3) float, mm, head frame: the face model of the pose.
        keypoints: eye (and mouth) corner indices into the model.
        gaze_target_mm: (3,) float, mm, camera frame: the point looked at (per-eye gaze = target - eye centre).
        gaze_vector: (3,) float, camera frame: a gaze direction shared by both eyes (instead of a target).
        settings: see :class:`NormalizationSettings`.
        pyramid: the whole image's pyramid when already built (default: the pyramid of the region
            around the eyes, built here; see :func:`gazeaug.texture.region_pyramid`).
        meta: extras to record.

    Raises:
        GazeAugError: bad gaze, eyes behind the camera.
    """
    s = settings or NormalizationSettings()
    img = np.ascontiguousarray(image_rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise GazeAugError(f"image: expected (H, W, 3) uint8 RGB, got {img.shape} {img.dtype}")
    if camera.image_size != (img.shape[1], img.shape[0]):
        raise GazeAugError(f"camera is for {camera.image_size} images, the image is {(img.shape[1], img.shape[0])}")
    refs = reference_points(pose.rotation, pose.translation_mm, model_vertices_mm, keypoints)
    cams = _eye_cameras_at(refs, pose.rotation, s)
    coords = np.stack([source_coordinates(cams[side], camera) for side in EYES])
    if pyramid is not None:
        pyr = pyramid
    else:  # only the region around the eyes (the same samples, a fraction of the work)
        pyr, origin = region_pyramid(img, coords)
        coords -= np.asarray(origin, dtype=np.float32)
    valid = np.ones(coords.shape[:3], dtype=bool)
    patches = sample(pyr, coords, valid, antialias=s.antialias, dtype=np.uint8)
    eyes = {}
    for i, side in enumerate(EYES):
        cam = cams[side]
        g = gaze_direction(cam.reference_mm, gaze_target_mm, gaze_vector)
        eyes[side] = EyePatch(
            image=np.ascontiguousarray(patches[i]),
            camera=cam,
            head_pose=cam.head_pose_pitchyaw(pose.rotation),
            gaze=None if g is None else cam.gaze_pitchyaw(g),
        )
    return NormalizedSample(
        left=eyes["left"],
        right=eyes["right"],
        settings=s,
        head_rotation=np.array(pose.rotation),
        source="normalize",
        meta=dict(meta or {}),
        face=face_labels(refs["face"], pose.rotation, s, gaze_target_mm, gaze_vector),
    )


def face_labels(
    face_centre_mm: ArrayLike,
    head_rotation: ArrayLike,
    settings: NormalizationSettings,
    gaze_target_mm: ArrayLike | None = None,
    gaze_vector: ArrayLike | None = None,
) -> FaceLabels:
    """Head pose and gaze in the face centre's normalized frame.

    Args:
        face_centre_mm: (3,) float, mm, camera frame.
        head_rotation: (3, 3) float, head frame -> camera frame.
        settings: normalization settings.
        gaze_target_mm: (3,) float, mm, camera frame, or None.
        gaze_vector: (3,) float, camera frame, or None.
    """
    cam = normalized_cameras(
        np.asarray(face_centre_mm, dtype=np.float64)[None],
        np.asarray(head_rotation, dtype=np.float64)[None],
        distance_mm=settings.distance_mm,
        focal_px=settings.focal_px,
        size_wh=settings.patch_size_wh,
    )[0]
    g = gaze_direction(cam.reference_mm, gaze_target_mm, gaze_vector)
    return FaceLabels(
        camera=cam, head_pose=cam.head_pose_pitchyaw(head_rotation), gaze=None if g is None else cam.gaze_pitchyaw(g)
    )


def save_npz(path: str | Path, sample_: NormalizedSample) -> None:
    """Write a sample as ``.npz`` (atomically: a temporary file renamed into place).

    Keys: ``left_eye``, ``right_eye`` (H, W, 3) uint8 RGB; ``head_pose_left``,
    ``head_pose_right`` (2,) float64 radians (pitch, yaw) in that eye's
    normalized frame; ``R_norm_left``, ``R_norm_right`` (3, 3); ``eye_centre_left_mm``,
    ``eye_centre_right_mm`` (3,) camera frame; ``gaze_left``, ``gaze_right`` (2,)
    when a gaze is known; ``head_rotation`` (3, 3); ``distance_mm``, ``focal_px``,
    ``patch_size_wh``, ``antialias``, ``source`` (``normalize`` or ``render:<renderer>``),
    ``head_pose_face``, ``gaze_face``, ``R_norm_face``, ``face_centre_mm`` (the face centre's normalized frame),
    ``coverage_left``, ``coverage_right``, and ``meta_json`` (a JSON string of the extras).
    """
    import json

    from facemesh.io import atomic_write

    arrays: dict[str, Any] = {}
    for side in EYES:
        e = sample_.eye(side)
        arrays[f"{side}_eye"] = e.image
        arrays[f"head_pose_{side}"] = e.head_pose
        arrays[f"R_norm_{side}"] = e.camera.rotation
        arrays[f"eye_centre_{side}_mm"] = e.camera.reference_mm
        arrays[f"coverage_{side}"] = np.float64(e.coverage)
        if e.gaze is not None:
            arrays[f"gaze_{side}"] = e.gaze
    if sample_.face is not None:
        arrays["head_pose_face"] = sample_.face.head_pose
        arrays["R_norm_face"] = sample_.face.camera.rotation
        arrays["face_centre_mm"] = sample_.face.camera.reference_mm
        if sample_.face.gaze is not None:
            arrays["gaze_face"] = sample_.face.gaze
    s = sample_.settings
    arrays.update(
        head_rotation=sample_.head_rotation,
        distance_mm=np.float64(s.distance_mm),
        focal_px=np.float64(s.focal_px),
        patch_size_wh=np.array(s.patch_size_wh, dtype=np.int64),
        antialias=np.bool_(s.antialias),
        source=np.str_(sample_.source),
        meta_json=np.str_(json.dumps(dict(sample_.meta), default=float)),
    )
    p = Path(path)
    if p.suffix != ".npz":
        raise GazeAugError(f"{p}: the output must end in .npz")
    with atomic_write(p) as fh:
        np.savez(fh, **arrays)


def load_npz(path: str | Path) -> dict[str, Any]:
    """Read a file written by :func:`save_npz` into a plain dict (``meta`` parsed from ``meta_json``)."""
    import json
    import zipfile

    p = Path(path)
    try:
        with np.load(p, allow_pickle=False) as z:
            out = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise GazeAugError(f"{p}: not a readable .npz file ({exc})") from exc
    missing = [k for k in ("left_eye", "right_eye", "head_pose_left", "head_pose_right") if k not in out]
    if missing:
        raise GazeAugError(f"{p}: missing keys {missing} (not written by gazeaug)")
    out["meta"] = json.loads(str(out.pop("meta_json", "{}")))
    return out
