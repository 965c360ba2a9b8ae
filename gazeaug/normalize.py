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
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from facemesh.face_models import FaceKeypoints
from facemesh.types import CameraIntrinsics, HeadPose

from .camera import NormalizedCamera, NormalizedViews, normalized_views, reference_points
from .errors import GazeAugError
from .texture import MipPyramid, region_pyramid, sample

__all__ = [
    "EYES",
    "EYE_KEYPOINTS",
    "NormalizationSettings",
    "EyePatch",
    "FaceLabels",
    "NormalizedSample",
    "reference_points",
    "views_at",
    "face_patch_camera",
    "samples_from_views",
    "source_coordinates",
    "normalize_image",
    "gaze_direction",
    "save_npz",
    "load_npz",
]

#: The subject's eyes, in the order every output lists them.
EYES = ("left", "right")

#: The points of an eye a drawn (redirected) eye patch records (:attr:`EyePatch.keypoints_px`), in
#: this order: the iris's centre (the limbus circle's) and the eye opening's centre (the eye
#: contour's at rest). What ``gazeaug train --keypoint-loss`` teaches the encoder to find.
EYE_KEYPOINTS = ("iris_centre", "opening_centre")


@dataclass(frozen=True)
class NormalizationSettings:
    """The normalized camera and patch (recorded in every output).

    Attributes:
        distance_mm: d_n, distance of the normalized camera from the eye (default 600 mm, the paper's;
            :attr:`DISTANCE_RANGE_MM`).
        focal_px: f_n, its focal length (default 650 px, the paper's; :attr:`FOCAL_RANGE_PX`).
        patch_size_wh: eye patch (width, height) in pixels (default (60, 36)): integers from 4 to
            1024 per side (:attr:`PATCH_SIDE_RANGE`; a 224 x 224 face patch fits, a patch is held
            in memory per pose and per eye).
        antialias: sample a Gaussian pyramid per pixel's footprint (default True);
            False samples the full-resolution image bilinearly, like ``cv2.warpPerspective``.
        face_patch_size_wh: (width, height) in pixels of a normalized *face* patch made beside the
            eyes, or None (default): no face patch. The face camera looks at the face centre with the
            face frame's rotation (the one the labels are in) and its own distance and focal below;
            ETH-XGaze's face patches are 224 x 224.
        face_distance_mm: the face camera's d_n (default 600 mm, ETH-XGaze's ``normalize_data.py``).
        face_focal_px: the face camera's f_n (default 960 px, ETH-XGaze's): at 600 mm a 224 px patch
            spans 140 mm, the face from brow to chin. Both face fields are recorded, and may differ from
            the defaults, only with a face patch.

    Raises:
        GazeAugError: a field of the wrong type (a bool or text for a number, a float for a patch
            side, a non-bool ``antialias``) or out of bounds; a face camera set without a face patch.
    """

    distance_mm: float = 600.0
    focal_px: float = 650.0
    patch_size_wh: tuple[int, int] = (60, 36)
    antialias: bool = True
    face_patch_size_wh: tuple[int, int] | None = None
    face_distance_mm: float = 600.0
    face_focal_px: float = 960.0

    #: Allowed patch width and height, pixels.
    PATCH_SIDE_RANGE: ClassVar[tuple[int, int]] = (4, 1024)
    #: Allowed normalized distances (the eye's and the face's), mm: beyond, the warp's numbers overflow
    #: or vanish (a crafted model file's 1e-300 or 1e308 gave a gaze and an overflow warning).
    DISTANCE_RANGE_MM: ClassVar[tuple[float, float]] = (1.0, 100_000.0)
    #: Allowed normalized focal lengths (the eye's and the face's), px.
    FOCAL_RANGE_PX: ClassVar[tuple[float, float]] = (1.0, 1_000_000.0)

    def __post_init__(self) -> None:
        for name in ("distance_mm", "focal_px", "face_distance_mm", "face_focal_px"):
            v = getattr(self, name)
            lo, hi = self.DISTANCE_RANGE_MM if name.endswith("_mm") else self.FOCAL_RANGE_PX
            if not (_is_number(v) and math.isfinite(v) and lo <= v <= hi):
                raise GazeAugError(f"normalization {name}: expected a number from {lo:g} to {hi:g}, got {v!r}")
            object.__setattr__(self, name, float(v))
        object.__setattr__(self, "patch_size_wh", self._checked_size("patch size", self.patch_size_wh))
        if not isinstance(self.antialias, (bool, np.bool_)):
            raise GazeAugError(f"normalization antialias: expected true or false, got {self.antialias!r}")
        object.__setattr__(self, "antialias", bool(self.antialias))
        if self.face_patch_size_wh is not None:
            object.__setattr__(
                self, "face_patch_size_wh", self._checked_size("face patch size", self.face_patch_size_wh)
            )
        elif (self.face_distance_mm, self.face_focal_px) != (
            _FACE_DEFAULTS["face_distance_mm"],
            _FACE_DEFAULTS["face_focal_px"],
        ):
            raise GazeAugError(
                "normalization: a face camera distance or focal was given without a face patch size "
                f"(face_distance_mm {self.face_distance_mm:g}, face_focal_px {self.face_focal_px:g})"
            )

    @classmethod
    def _checked_size(cls, what: str, size: Any) -> tuple[int, int]:
        """``(width, height)`` as two ints within :attr:`PATCH_SIDE_RANGE`, else the error naming ``what``."""
        lo, hi = cls.PATCH_SIDE_RANGE
        if not (
            isinstance(size, (tuple, list, np.ndarray))
            and len(size) == 2
            and all(_is_integer(v) and lo <= v <= hi for v in size)
        ):
            shown = size.tolist() if isinstance(size, np.ndarray) else size
            raise GazeAugError(
                f"{what}: expected two integers (width, height), each from {lo} to {hi} px, got {shown!r}"
            )
        return (int(size[0]), int(size[1]))

    @classmethod
    def from_dict(cls, data: Any) -> NormalizationSettings:
        """Settings from their recorded form (:meth:`as_dict`, e.g. a model's ``normalization``).

        A key that is absent takes its default; a key that is present must hold a valid value
        (``null`` is not a default), and unknown keys are refused.

        Raises:
            GazeAugError: not a dict, unknown keys, or a value of the wrong type or out of bounds.
        """
        known = [f.name for f in fields(cls)]  # the PATCH_SIDE_RANGE ClassVar is no field
        if not isinstance(data, Mapping):
            raise GazeAugError(
                f"normalization settings: expected a dict of {known}, got {type(data).__name__} {data!r:.80}"
            )
        unknown = sorted(str(k) for k in data if k not in known)
        if unknown:
            raise GazeAugError(f"normalization settings: unknown keys {unknown} (known: {known})")
        return cls(**{str(k): v for k, v in data.items()})

    def without_face(self) -> NormalizationSettings:
        """These settings making no face patch (the eyes' camera and patch unchanged)."""
        return replace(self, **_FACE_DEFAULTS)

    def as_dict(self) -> dict[str, Any]:
        """JSON-serialisable form, as recorded in outputs.

        Without a face patch the face keys are left out, so the record is the one every output made
        before face patches existed carries (a resumed run or a model compares records).
        """
        d = asdict(self)
        d["patch_size_wh"] = list(self.patch_size_wh)
        if self.face_patch_size_wh is None:
            for k in _FACE_DEFAULTS:
                del d[k]
        else:
            d["face_patch_size_wh"] = list(self.face_patch_size_wh)
        return d


#: The face fields' defaults, as the dataclass declares them (left out of a record without a face patch).
_FACE_DEFAULTS: dict[str, Any] = {
    f.name: f.default for f in fields(NormalizationSettings) if f.name.startswith("face_")
}


def _is_number(v: Any) -> bool:
    """A real number (int, float or numpy scalar), not a bool."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _is_integer(v: Any) -> bool:
    """An integer (int or numpy integer), not a bool."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


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
        keypoints_px: (2, 2) float64, px: rows the :data:`EYE_KEYPOINTS` (iris centre, eye
            opening's centre), columns (u, v) in the patch (:meth:`NormalizedCamera.project`:
            pixel centres at whole numbers, principal point (w / 2, h / 2)); known only where the
            eye was drawn (redirected eyes), else ``None``.
    """

    image: NDArray[np.uint8]
    camera: NormalizedCamera
    head_pose: NDArray[np.float64]
    gaze: NDArray[np.float64] | None = None
    coverage: float = 1.0
    keypoints_px: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class FaceLabels:
    """Labels in the *face's* normalized frame (reference point: the face centre; no patch).

    One frame for the whole face, as in Zhang's face normalization: what the
    HDF5 training sets store as ``head_pose`` and ``gaze``.

    Attributes:
        camera: the face's normalized camera (the eye patch size; only its rotation matters here).
        head_pose: (2,) float64 radians, (pitch, yaw).
        gaze: (2,) float64 radians, (pitch, yaw) of ``target - face centre`` (or the gaze vector); ``None`` if unknown.
        image: (H, W, 3) uint8 RGB face patch (H, W from the settings' ``face_patch_size_wh``), seen
            by :func:`face_patch_camera` of ``camera``; ``None`` when the settings ask for no face patch.
        coverage: fraction of the face patch's pixels that saw the head (1.0 for a real image).
    """

    camera: NormalizedCamera
    head_pose: NDArray[np.float64]
    gaze: NDArray[np.float64] | None = None
    image: NDArray[np.uint8] | None = None
    coverage: float = 1.0


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


def views_at(
    model_vertices_mm: ArrayLike,
    keypoints: FaceKeypoints | None,
    rotations: ArrayLike,
    translations_mm: ArrayLike,
    settings: NormalizationSettings,
    *,
    gaze_target_mm: ArrayLike | None = None,
    gaze_vector: ArrayLike | None = None,
) -> NormalizedViews:
    """:func:`gazeaug.camera.normalized_views` with the camera and patch of ``settings``.

    Args:
        model_vertices_mm: (N, 3) float, mm, head frame.
        keypoints: eye (and mouth) corner indices into the model.
        rotations: (P, 3, 3) float, head frame -> camera frame.
        translations_mm: (P, 3) float, mm, camera frame.
        settings: the normalized camera (d_n, f_n) and the eye patch size.
        gaze_target_mm: (3,) or (P, 3) float, mm, camera frame; or None.
        gaze_vector: (3,) or (P, 3) float, camera frame; or None.
    """
    return normalized_views(
        model_vertices_mm,
        keypoints,
        rotations,
        translations_mm,
        distance_mm=settings.distance_mm,
        focal_px=settings.focal_px,
        size_wh=settings.patch_size_wh,
        gaze_target_mm=gaze_target_mm,
        gaze_vector=gaze_vector,
    )


def face_patch_camera(face_camera: NormalizedCamera, settings: NormalizationSettings) -> NormalizedCamera:
    """The camera of the face patch: the face frame's camera with the settings' face distance, focal and size.

    Convention: the kernel's face camera (:func:`gazeaug.camera.normalized_views`, third of each
    pose) defines the face frame the labels are in; the face patch is seen from the same rotation
    and reference point (the face centre), so its pixels and the labels share one frame.

    Args:
        face_camera: the kernel's face camera of one pose.
        settings: with ``face_patch_size_wh`` set.

    Raises:
        GazeAugError: the settings ask for no face patch.
    """
    if settings.face_patch_size_wh is None:
        raise GazeAugError("face patch camera: the normalization settings ask for no face patch (face_patch_size_wh)")
    return NormalizedCamera(
        rotation=face_camera.rotation,
        reference_mm=face_camera.reference_mm,
        distance_mm=settings.face_distance_mm,
        focal_px=settings.face_focal_px,
        size_wh=settings.face_patch_size_wh,
    )


def samples_from_views(
    views: NormalizedViews,
    patches: NDArray[np.uint8],
    settings: NormalizationSettings,
    head_rotations: ArrayLike,
    source: str,
    *,
    coverage: ArrayLike | None = None,
    metas: Sequence[Mapping[str, Any]] | None = None,
    face_patches: NDArray[np.uint8] | None = None,
    face_coverage: ArrayLike | None = None,
    eye_keypoints_px: ArrayLike | None = None,
) -> list[NormalizedSample]:
    """One :class:`NormalizedSample` per pose: the kernel's cameras and labels with the patches sampled through them.

    Args:
        views: the kernel's output for P poses.
        patches: (P, 2, H, W, 3) uint8 RGB, the (left, right) eye patches of each pose.
        settings: the normalization settings used.
        head_rotations: (P, 3, 3) float, head frame -> camera frame.
        source: ``"normalize"`` or ``"render:<renderer>"``.
        coverage: (P, 2) float, fraction of each patch that saw the face (default 1.0).
        metas: P dicts of extras (default empty).
        face_patches: (P, Hf, Wf, 3) uint8 RGB face patches (:func:`face_patch_camera`), given exactly
            when ``settings.face_patch_size_wh`` is set.
        face_coverage: (P,) float, fraction of each face patch that saw the head (default 1.0).
        eye_keypoints_px: (P, 2, 2, 2) float, px: each pose's eyes (left, right), their
            :data:`EYE_KEYPOINTS`, (u, v) in the eye's patch (:attr:`EyePatch.keypoints_px`); None:
            unknown.

    Raises:
        GazeAugError: face patches given without the settings asking for them, or missing, or of another size.
    """
    n = len(views)
    want = settings.face_patch_size_wh
    if (face_patches is None) != (want is None):
        raise GazeAugError(
            f"face patches: the settings ask for {'none' if want is None else f'{want[0]} x {want[1]} px'}, "
            f"got {'none' if face_patches is None else 'some'}"
        )
    if face_patches is not None and want is not None and face_patches.shape != (n, want[1], want[0], 3):
        raise GazeAugError(f"face patches: expected shape {(n, want[1], want[0], 3)}, got {face_patches.shape}")
    face_cov = np.ones(n) if face_coverage is None else np.asarray(face_coverage, dtype=np.float64).reshape(n)
    cov = np.ones((n, 2)) if coverage is None else np.asarray(coverage, dtype=np.float64).reshape(n, 2)
    rot = np.asarray(head_rotations, dtype=np.float64).reshape(n, 3, 3)
    gaze = views.gaze
    kp = None
    if eye_keypoints_px is not None:
        kp = np.asarray(eye_keypoints_px, dtype=np.float64)
        if kp.shape != (n, 2, len(EYE_KEYPOINTS), 2) or not np.isfinite(kp).all():
            raise GazeAugError(
                f"eye keypoints: expected finite {(n, 2, len(EYE_KEYPOINTS), 2)} px, got shape {kp.shape}"
            )
    out = []
    for i in range(n):
        eyes = [
            EyePatch(
                image=np.ascontiguousarray(patches[i, j]),
                camera=views.cameras[i][j],
                head_pose=views.head_pose[i, j],
                gaze=None if gaze is None else gaze[i, j],
                coverage=float(cov[i, j]),
                keypoints_px=None if kp is None else kp[i, j],
            )
            for j in range(2)
        ]
        face = FaceLabels(
            camera=views.cameras[i][2],
            head_pose=views.head_pose[i, 2],
            gaze=None if gaze is None else gaze[i, 2],
            image=None if face_patches is None else np.ascontiguousarray(face_patches[i]),
            coverage=float(face_cov[i]),
        )
        out.append(
            NormalizedSample(
                left=eyes[0],
                right=eyes[1],
                settings=settings,
                head_rotation=rot[i],
                source=source,
                meta=dict(metas[i]) if metas is not None else {},
                face=face,
            )
        )
    return out


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
    keypoints: FaceKeypoints | None,
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
    views = views_at(
        model_vertices_mm,
        keypoints,
        np.asarray(pose.rotation)[None],
        np.asarray(pose.translation_mm)[None],
        s,
        gaze_target_mm=gaze_target_mm,
        gaze_vector=gaze_vector,
    )
    coords = np.stack([source_coordinates(cam, camera) for cam in views.cameras[0][:2]])
    face_coords = None
    if s.face_patch_size_wh is not None:
        face_coords = source_coordinates(face_patch_camera(views.cameras[0][2], s), camera)[None]
    if pyramid is not None:
        pyr = pyramid
    else:  # only the region the patches read (the same samples, a fraction of the work)
        reads = coords if face_coords is None else np.concatenate([coords.reshape(-1, 2), face_coords.reshape(-1, 2)])
        pyr, origin = region_pyramid(img, reads)
        coords -= np.asarray(origin, dtype=np.float32)
        if face_coords is not None:
            face_coords -= np.asarray(origin, dtype=np.float32)
    valid = np.ones(coords.shape[:3], dtype=bool)
    patches = sample(pyr, coords, valid, antialias=s.antialias, dtype=np.uint8)
    face = None
    if face_coords is not None:
        face = sample(
            pyr, face_coords, np.ones(face_coords.shape[:3], dtype=bool), antialias=s.antialias, dtype=np.uint8
        )
    return samples_from_views(
        views, patches[None], s, np.asarray(pose.rotation)[None], "normalize", metas=[meta or {}], face_patches=face
    )[0]


def save_npz(path: str | Path, sample_: NormalizedSample) -> None:
    """Write a sample as ``.npz`` (atomically: a temporary file renamed into place).

    Keys: ``left_eye``, ``right_eye`` (H, W, 3) uint8 RGB; ``head_pose_left``,
    ``head_pose_right`` (2,) float64 radians (pitch, yaw) in that eye's
    normalized frame; ``R_norm_left``, ``R_norm_right`` (3, 3); ``eye_centre_left_mm``,
    ``eye_centre_right_mm`` (3,) camera frame; ``gaze_left``, ``gaze_right`` (2,)
    when a gaze is known; ``head_rotation`` (3, 3); ``distance_mm``, ``focal_px``,
    ``patch_size_wh``, ``antialias``, ``source`` (``normalize`` or ``render:<renderer>``),
    ``head_pose_face``, ``gaze_face``, ``R_norm_face``, ``face_centre_mm`` (the face centre's normalized frame),
    ``coverage_left``, ``coverage_right``, ``face`` (Hf, Wf, 3) uint8 RGB and ``coverage_face``
    when the settings made a face patch (with ``face_patch_size_wh``, ``face_distance_mm``,
    ``face_focal_px``), and ``meta_json`` (a JSON string of the extras).
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
        if sample_.face.image is not None:
            arrays["face"] = sample_.face.image
            arrays["coverage_face"] = np.float64(sample_.face.coverage)
    s = sample_.settings
    if s.face_patch_size_wh is not None:
        arrays.update(
            face_patch_size_wh=np.array(s.face_patch_size_wh, dtype=np.int64),
            face_distance_mm=np.float64(s.face_distance_mm),
            face_focal_px=np.float64(s.face_focal_px),
        )
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
