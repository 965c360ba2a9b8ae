"""Face sources: what a user passes as face pictures, turned into single-face RGB pictures.

:func:`face_sources` takes a list of entries and gives one :class:`FaceSource`
per usable face picture, each with a stable name, its origin and the person it
shows:

``None``
    the built-in sample photo (:func:`facemesh.build.sample_image`), whole, as
    :func:`facemesh.build.load_input` gives it; named ``astronaut`` (with
    ``all_faces``, its face's crop, as for an image file).
an image file
    the whole picture (the simulator uses its largest face, as before), named by
    the file's stem; with ``all_faces``, one square crop per detected face
    instead, named ``STEM#faceK`` (K = 1, 2, ... in the detector's largest-first
    order, counted over every face found, so a skipped face leaves a gap).
a video file (``.mp4``, ``.avi``, ``.mov``, ``.mkv``, ``.webm``)
    ``per_video`` crops of frames spread in head pose, named ``STEM@t=SS.SSs``
    (the frame's time), all with ``person`` = the video's stem: a video shows
    one person (the largest face of each frame).

Crops (:func:`face_crop`): a square of :data:`CROP_SCALE` times the larger side
of the face's landmark box, centred on the box; the parts outside the picture
are filled with its edge pixels, repeated and blurred (more so farther out);
scaled up (Lanczos) so that the face is at least :data:`MIN_CROP_FACE_PX` wide,
or down (area averaging) so that the crop is at most :data:`MAX_CROP_SIDE` on a
side. Every crop is checked by running the detector on it, since the simulator
fits the crop's largest face: the face it was cut around must be found in it
(which also drops the detector's rare false faces) and be its largest (else a
tighter crop, :data:`TIGHT_CROP_SCALE`, must have it as its largest).

Faces are skipped (and reported in :attr:`FaceSources.skipped`) when they are
too small: inter-ocular distance (between the two eyes' corner midpoints) below
``min_face_px`` in the source picture (default :data:`MIN_FACE_PX`, 12 px: the
eye is then about 5 px wide, too little to texture an eye region). With
``all_faces``, small faces are also looked for in overlapping tiles of the
picture (MediaPipe's short-range face detector misses faces that fill a small
part of the picture), at most :data:`MAX_TILES` detector runs per picture.

Video frames (:func:`video_face_sources`): at most :data:`MAX_VIDEO_CANDIDATES`
frames at a fixed stride over the whole video (every 5th of the first 300 when
the container does not tell its frame count; long videos are read by seeking)
are decoded and fitted (:func:`facemesh.build.fit_face`
with the default camera); a frame is a candidate when its face is large enough,
its eyes are open (:func:`eye_openness` at least :data:`MIN_EYE_OPENNESS`), its
head pose is within :data:`MAX_YAW_DEG` / :data:`MAX_PITCH_DEG` (the simulator
re-renders the face at other poses: a profile textures half a face) and it is not
blurred (its face's Laplacian variance at least :data:`BLUR_RATIO` times the
candidates' median). The most frontal candidate comes first, then greedy
farthest-point selection on (yaw, pitch): the order of the result.

Nothing is written to disk; the input files are only read. Memory: one decoded
frame at a time plus the candidates' crops (at most 60 x 800 x 800 x 3 bytes).
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from facemesh.types import FaceMeshError, InputError, NoFaceError

__all__ = [
    "FaceSource",
    "FaceSources",
    "face_sources",
    "image_face_sources",
    "video_face_sources",
    "face_crop",
    "crop_region",
    "eye_openness",
    "inter_ocular_px",
    "VIDEO_SUFFIXES",
    "MIN_FACE_PX",
    "CROP_SCALE",
    "TIGHT_CROP_SCALE",
    "MIN_CROP_FACE_PX",
    "MAX_CROP_SIDE",
    "MAX_TILES",
    "MAX_VIDEO_CANDIDATES",
    "MAX_YAW_DEG",
    "MAX_PITCH_DEG",
    "MIN_EYE_OPENNESS",
    "BLUR_RATIO",
]

#: File suffixes (any case) read as videos; everything else is read as an image.
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm")
#: Faces whose inter-ocular distance (px, in the source picture) is below this are skipped.
MIN_FACE_PX = 12.0
#: A crop's side over the larger side of the face's landmark box.
CROP_SCALE = 2.2
#: The crop tried when the detector finds another face as the largest in a :data:`CROP_SCALE` crop.
TIGHT_CROP_SCALE = 1.6
#: Crops are scaled up so that the face's landmark box is at least this wide.
MIN_CROP_FACE_PX = 200
#: Crops are scaled down to at most this many pixels on a side.
MAX_CROP_SIDE = 800
#: Most detector runs on tiles of one picture (``all_faces``).
MAX_TILES = 64
#: Most video frames decoded and fitted as candidates.
MAX_VIDEO_CANDIDATES = 60
#: Video frames whose head yaw (deg, default camera) is beyond this are not used.
MAX_YAW_DEG = 45.0
#: Video frames whose head pitch (deg) is beyond this are not used.
MAX_PITCH_DEG = 35.0
#: Video frames whose mean eye openness (:func:`eye_openness`) is below this are blinks: not used.
MIN_EYE_OPENNESS = 0.16
#: Video frames whose face is less sharp than this share of the candidates' median are not used.
BLUR_RATIO = 0.5

#: Frames of videos with more frames than this are reached by seeking (OpenCV decodes from the keyframe
#: before each: about 0.1-0.2 s a seek), not by decoding every frame (about 3 ms a 720p frame).
_SEEK_ABOVE_FRAMES = 6000
#: Stride over the frames of a video whose frame count is unknown.
_UNKNOWN_COUNT_STRIDE = 5
#: MediaPipe's eye landmarks: (outer corner, inner corner, upper lid, lower lid) per eye.
_MP_EYES = ((33, 133, 159, 145), (263, 362, 386, 374))


@dataclass(frozen=True, eq=False)
class FaceSource:
    """One single-face picture for the simulator.

    Attributes:
        name: stable, unique within one :func:`face_sources` call: ``STEM``, ``STEM#faceK`` or
            ``STEM@t=SS.SSs`` (a stem seen twice becomes ``STEM-2``, ...).
        image: (H, W, 3) uint8 RGB.
        origin: where it comes from: the path, ``PATH#faceK`` or ``PATH@t=SS.SSs``.
        person: who it shows: the name, or for every frame of one video the video's stem.
        time_s: the frame's time in its video (None for pictures).
        pitch_yaw_deg: the head pose (pitch, yaw) measured in the frame with the default camera
            (video frames only).
        region_px: (x0, y0, x1, y1): the part of the source picture (or frame) the image shows, in its
            pixels (a crop's square may reach outside the picture: that part is filled).
    """

    name: str
    image: NDArray[np.uint8] = field(repr=False)
    origin: str
    person: str = ""
    time_s: float | None = None
    pitch_yaw_deg: tuple[float, float] | None = None
    region_px: tuple[int, int, int, int] | None = None

    def __post_init__(self) -> None:
        if not self.person:
            object.__setattr__(self, "person", self.name)


class FaceSources(list[FaceSource]):
    """The sources (a list), with :attr:`skipped`: one line per face or frame left out, and why."""

    def __init__(self, items: Iterable[FaceSource] = (), skipped: Iterable[str] = ()):
        super().__init__(items)
        self.skipped: list[str] = list(skipped)


def face_sources(
    entries: Sequence[str | os.PathLike[str] | None] | str | os.PathLike[str] | None,
    *,
    detector: Any = None,
    per_video: int = 8,
    all_faces: bool = False,
    min_face_px: float = MIN_FACE_PX,
) -> FaceSources:
    """Single-face pictures from images, videos and the built-in sample (module docstring).

    Args:
        entries: paths (image or video files) and ``None`` (the built-in sample); one path or
            ``None`` alone is taken as a list of one.
        detector: a :class:`~facemesh.landmarks.base.LandmarkModel` (default: MediaPipe Face Mesh,
            created for this call and closed after it).
        per_video: frames per video (fewer when the video has fewer usable frames).
        all_faces: one crop per face of each image (the built-in sample included) instead of the
            whole image; videos always give the largest face of each frame.
        min_face_px: smallest inter-ocular distance (px, source picture) of a face that is used.

    Returns:
        The sources in the entries' order; ``.skipped`` lists what was left out.

    Raises:
        InputError: a missing or unreadable file, a file that is neither an image nor a video,
            a video without a decodable frame, bad arguments.
        NoFaceError: an entry without a usable face.
    """
    if entries is None or isinstance(entries, (str, os.PathLike)):
        entries = [entries]
    if isinstance(per_video, bool) or not isinstance(per_video, (int, np.integer)) or per_video < 1:
        raise InputError(f"frames per video: expected an integer >= 1, got {per_video!r}")
    if not math.isfinite(float(min_face_px)) or min_face_px < 0:
        raise InputError(f"smallest face: expected a number of pixels >= 0, got {min_face_px!r}")
    own = detector is None
    if own:
        from .pipeline import default_landmark_model

        detector = default_landmark_model()
    out = FaceSources()
    stems: set[str] = set()
    try:
        for entry in entries:
            if entry is None:
                from facemesh.build import SAMPLE_NAME, sample_image

                stem = _unique("astronaut", stems)
                found = image_face_sources(
                    sample_image(), stem, SAMPLE_NAME, detector, all_faces=all_faces, min_face_px=min_face_px
                )
            else:
                path = Path(entry)
                stem = _unique(path.stem or path.name or "face", stems)
                if path.suffix.lower() in VIDEO_SUFFIXES:
                    found = video_face_sources(path, detector, per_video=per_video, min_face_px=min_face_px, stem=stem)
                else:
                    if path.is_dir():
                        raise InputError(f"{path}: a folder; expected an image or video file")
                    from facemesh.io import load_image_rgb

                    found = image_face_sources(
                        load_image_rgb(path), stem, str(path), detector, all_faces=all_faces, min_face_px=min_face_px
                    )
            out.extend(found)
            out.skipped.extend(found.skipped)
    finally:
        if own and hasattr(detector, "close"):
            detector.close()
    return out


def _unique(stem: str, used: set[str]) -> str:
    """``stem``, or ``stem-2``, ``stem-3``, ... when taken; recorded in ``used``."""
    name, k = stem, 1
    while name in used:
        k += 1
        name = f"{stem}-{k}"
    used.add(name)
    return name


# ----------------------------------------------------------------------------------------------- measures


def _eye_pairs(points: NDArray[np.float64], detector: Any) -> tuple[tuple[int, int], tuple[int, int]] | None:
    """The detector's eye-corner index pairs (right eye, left eye), or None when it does not say."""
    kp = None
    try:
        kp = detector.face_model().keypoints
    except Exception:  # noqa: BLE001 - a detector without a face model: no key points
        kp = None
    if kp is None and len(points) >= 468:
        from facemesh.face_models import KEYPOINTS

        kp = KEYPOINTS["mediapipe"]
    if kp is None or max(*kp.right_eye, *kp.left_eye) >= len(points):
        return None
    return kp.right_eye, kp.left_eye


def inter_ocular_px(points: NDArray[np.float64], detector: Any = None) -> float:
    """Distance between the two eyes' corner midpoints (px); 0.45 x the landmark box's width when unknown."""
    pts = np.asarray(points, dtype=np.float64)
    pairs = _eye_pairs(pts, detector)
    if pairs is None:
        return 0.45 * float(np.ptp(pts[:, 0]))
    r, left = pairs
    return float(np.linalg.norm(pts[list(r)].mean(axis=0) - pts[list(left)].mean(axis=0)))


def eye_openness(points: NDArray[np.float64]) -> float | None:
    """Mean over both eyes of lid gap / eye width (MediaPipe's 468 or 478 landmarks; else None).

    About 0.3-0.45 for open eyes, below 0.1 for closed ones (a blink, or AFLW's
    ``examples_alfw1``: 0.07).
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 468:
        return None
    ratios = []
    for outer, inner, up, low in _MP_EYES:
        width = float(np.linalg.norm(pts[outer] - pts[inner]))
        ratios.append(float(np.linalg.norm(pts[up] - pts[low])) / max(width, 1e-6))
    return float(np.mean(ratios))


def _box(points: NDArray[np.float64]) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) of the landmarks."""
    lo, hi = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _sharpness(image: NDArray[np.uint8], points: NDArray[np.float64]) -> float:
    """Variance of the Laplacian of the face's landmark box, scaled to 128 px wide, grey."""
    import cv2

    x0, y0, x1, y1 = _box(points)
    h, w = image.shape[:2]
    xa, ya = max(0, int(x0)), max(0, int(y0))
    xb, yb = min(w, int(math.ceil(x1)) + 1), min(h, int(math.ceil(y1)) + 1)
    if xb - xa < 4 or yb - ya < 4:
        return 0.0
    grey = cv2.cvtColor(np.ascontiguousarray(image[ya:yb, xa:xb]), cv2.COLOR_RGB2GRAY)
    k = 128.0 / (xb - xa)
    interp = cv2.INTER_AREA if k < 1 else cv2.INTER_CUBIC
    grey = cv2.resize(grey, (128, max(4, round((yb - ya) * k))), interpolation=interp)
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


# ----------------------------------------------------------------------------------------------- crops


def crop_region(points: NDArray[np.float64], *, scale: float = CROP_SCALE) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1): the square, in the picture's pixels, that :func:`face_crop` cuts (it may reach outside).

    Its side is ``scale`` times the larger side of the landmark box (at least 8 px), its centre the box's.
    """
    x0, y0, x1, y1 = _box(np.asarray(points, dtype=np.float64))
    n = max(8, round(scale * max(x1 - x0, y1 - y0)))
    sx0, sy0 = round((x0 + x1) / 2.0 - n / 2.0), round((y0 + y1) / 2.0 - n / 2.0)
    return sx0, sy0, sx0 + n, sy0 + n


def face_crop(
    image: NDArray[np.uint8],
    points: NDArray[np.float64],
    *,
    scale: float = CROP_SCALE,
    min_face_px: int = MIN_CROP_FACE_PX,
    max_side: int = MAX_CROP_SIDE,
) -> NDArray[np.uint8]:
    """A square crop around a face's landmarks (module docstring), (S, S, 3) uint8 RGB.

    Args:
        image: (H, W, 3) uint8 RGB.
        points: (N, 2) landmarks, pixels of ``image``.
        scale: the crop's side over the larger side of the landmark box.
        min_face_px: the face's box is scaled to at least this width (Lanczos).
        max_side: the crop is scaled to at most this side (area averaging; wins over ``min_face_px``).
    """
    import cv2

    x0, y0, x1, y1 = _box(np.asarray(points, dtype=np.float64))
    face_w = max(x1 - x0, 1.0)
    sx0, sy0, sx1, sy1 = crop_region(points, scale=scale)
    n = sx1 - sx0
    zoom = min(max(1.0, min_face_px / face_w), max_side / n)
    out_side = max(8, round(n * zoom))
    # the part of the crop's square inside the image
    h, w = image.shape[:2]
    ix0, iy0, ix1, iy1 = max(sx0, 0), max(sy0, 0), min(sx1, w), min(sy1, h)
    if ix1 <= ix0 or iy1 <= iy0:
        raise InputError("face crop: the face lies outside the picture")
    k = out_side / n
    left, top = round((ix0 - sx0) * k), round((iy0 - sy0) * k)
    inner_w = max(1, min(out_side - left, round((ix1 - sx0) * k) - left))
    inner_h = max(1, min(out_side - top, round((iy1 - sy0) * k) - top))
    part = np.ascontiguousarray(image[iy0:iy1, ix0:ix1])
    interp = cv2.INTER_AREA if k < 1 else (cv2.INTER_LANCZOS4 if k > 1 else cv2.INTER_LINEAR)
    if (inner_w, inner_h) != (part.shape[1], part.shape[0]):
        part = cv2.resize(part, (inner_w, inner_h), interpolation=interp)
    pads = (top, out_side - top - inner_h, left, out_side - left - inner_w)
    crop = cv2.copyMakeBorder(part, *pads, cv2.BORDER_REPLICATE)
    if any(pads):
        # the filled border: the picture's edge pixels repeated, then blurred, more so farther from the picture
        # (a plain, out-of-focus surround instead of streaks); the picture's own pixels are kept as they are
        outside = np.ones((out_side, out_side), np.uint8)
        outside[top : top + inner_h, left : left + inner_w] = 0
        dist = cv2.distanceTransform(outside, cv2.DIST_L2, 3)
        sigma = 0.06 * out_side
        blurred = cv2.GaussianBlur(crop, (0, 0), sigma)
        w8 = np.clip(dist / (2.0 * sigma), 0.0, 1.0)[..., None]
        crop = np.round(crop * (1.0 - w8) + blurred * w8).astype(np.uint8)
    return np.ascontiguousarray(crop, dtype=np.uint8)


def _matches(crop: NDArray[np.uint8], detector: Any, scale: float) -> tuple[bool, bool]:
    """(found, largest): whether the detector finds, in ``crop``, the face it was cut around, and as its largest.

    The face cut around lies at the crop's centre (within 0.2 of its side) with a landmark box of
    about ``1 / scale`` of its side (0.6-1.6 times that).
    """
    faces = sorted(detector.detect(crop), key=lambda f: -f.area_px)
    side = crop.shape[0]
    for rank, face in enumerate(faces):
        x0, y0, x1, y1 = _box(face.points_px)
        centre_off = math.hypot((x0 + x1) / 2 - (side - 1) / 2, (y0 + y1) / 2 - (side - 1) / 2)
        size = max(x1 - x0, y1 - y0) * scale / side
        if centre_off < 0.2 * side and 0.6 < size < 1.6:
            return True, rank == 0
    return False, False


def _found_again(crop: NDArray[np.uint8], detector: Any, scale: float) -> bool:
    """Whether the largest face the detector finds in ``crop`` is the one it was cut around."""
    return _matches(crop, detector, scale)[1]


def _checked_crop(
    image: NDArray[np.uint8], points: NDArray[np.float64], detector: Any
) -> tuple[NDArray[np.uint8], tuple[int, int, int, int]] | None:
    """The face's crop (and :func:`crop_region`) that the detector finds again as its largest face; or None.

    The face must be found in its :data:`CROP_SCALE` crop; when another face is the largest
    there, the :data:`TIGHT_CROP_SCALE` crop is used if the face is the largest in it.
    """
    crop = face_crop(image, points, scale=CROP_SCALE)
    found, largest = _matches(crop, detector, CROP_SCALE)
    if not found:
        return None
    if largest:
        return crop, crop_region(points, scale=CROP_SCALE)
    tight = face_crop(image, points, scale=TIGHT_CROP_SCALE)
    if _found_again(tight, detector, TIGHT_CROP_SCALE):
        return tight, crop_region(points, scale=TIGHT_CROP_SCALE)
    return None


# ----------------------------------------------------------------------------------------------- images


def _tiles(w: int, h: int) -> Iterator[tuple[int, int, int]]:
    """(x, y, side) of overlapping square tiles, half and a third of the shorter side, half a tile apart."""
    budget = MAX_TILES
    short = min(w, h)
    for frac in (2, 3):
        side = short // frac
        if side < 96 or budget <= 0:
            continue
        stride = max(side // 2, 1)
        nx, ny = math.ceil((w - side) / stride) + 1, math.ceil((h - side) / stride) + 1
        while nx * ny > budget:
            stride = int(stride * 1.25) + 1
            nx, ny = math.ceil((w - side) / stride) + 1, math.ceil((h - side) / stride) + 1
        budget -= nx * ny
        for j in range(ny):
            for i in range(nx):
                yield min(i * stride, w - side), min(j * stride, h - side), side


def _iou(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> float:
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def _all_faces(image: NDArray[np.uint8], detector: Any, tiles: bool = True) -> list[NDArray[np.float64]]:
    """Landmarks (N, 2, image pixels) of every face, largest first: the whole picture, then tiles.

    A face found in a tile counts when its landmark box keeps clear of the tile's
    inner edges (a face cut by the tile is found whole in another one) and
    overlaps no face found before (IoU above 0.3).
    """
    h, w = image.shape[:2]
    found = [np.asarray(f.points_px, dtype=np.float64) for f in detector.detect(image)]
    boxes = [_box(p) for p in found]
    if tiles:
        for tx, ty, side in _tiles(w, h):
            tile = np.ascontiguousarray(image[ty : ty + side, tx : tx + side])
            margin = 0.02 * side
            for f in detector.detect(tile):
                pts = np.asarray(f.points_px, dtype=np.float64) + (tx, ty)
                x0, y0, x1, y1 = b = _box(pts)
                cut = (
                    (tx > 0 and x0 < tx + margin)
                    or (ty > 0 and y0 < ty + margin)
                    or (tx + side < w and x1 > tx + side - margin)
                    or (ty + side < h and y1 > ty + side - margin)
                )
                if cut or any(_iou(b, o) > 0.3 for o in boxes):
                    continue
                found.append(pts)
                boxes.append(b)
    order = sorted(range(len(found)), key=lambda i: -(boxes[i][2] - boxes[i][0]) * (boxes[i][3] - boxes[i][1]))
    return [found[i] for i in order]


def image_face_sources(
    image: NDArray[np.uint8],
    stem: str,
    origin: str,
    detector: Any,
    *,
    all_faces: bool = False,
    min_face_px: float = MIN_FACE_PX,
) -> FaceSources:
    """The sources of one picture: the whole picture (its largest face checked), or one crop per face.

    Raises:
        NoFaceError: no face, or (``all_faces``) none usable.
    """
    from facemesh.landmarks.base import select_face

    if not all_faces:
        select_face(detector.detect(image), source=origin)  # NoFaceError, as the simulator would raise it
        h, w = image.shape[:2]
        return FaceSources([FaceSource(stem, image, origin, person=stem, region_px=(0, 0, w, h))])
    faces = _all_faces(image, detector)
    if not faces:
        raise NoFaceError(f"{origin}: no face found")
    out = FaceSources()
    for k, pts in enumerate(faces, start=1):
        iod = inter_ocular_px(pts, detector)
        if iod < min_face_px:
            out.skipped.append(f"{origin}#face{k}: too small (inter-ocular {iod:.1f} px < {min_face_px:g} px)")
            continue
        checked = _checked_crop(image, pts, detector)
        if checked is None:
            out.skipped.append(f"{origin}#face{k}: not found again in its crop")
            continue
        crop, region = checked
        out.append(FaceSource(f"{stem}#face{k}", crop, f"{origin}#face{k}", region_px=region))
    if not out:
        raise NoFaceError(f"{origin}: no usable face ({'; '.join(out.skipped)})")
    return out


# ----------------------------------------------------------------------------------------------- videos


@dataclass
class _Candidate:
    index: int
    time_s: float
    pitch_yaw_deg: tuple[float, float]
    crop: NDArray[np.uint8]
    region: tuple[int, int, int, int]
    sharpness: float


def _frames(cap: Any, count: int) -> Iterator[tuple[int, NDArray[np.uint8]]]:
    """(index, BGR frame) of at most :data:`MAX_VIDEO_CANDIDATES` frames at a fixed stride."""
    from facemesh._native import native_stderr_silenced

    if count > 0:
        stride = max(1, math.ceil(count / MAX_VIDEO_CANDIDATES))
    else:
        stride = _UNKNOWN_COUNT_STRIDE
    if count > _SEEK_ABOVE_FRAMES:
        for index in range(0, count, stride)[:MAX_VIDEO_CANDIDATES]:
            with native_stderr_silenced():
                cap.set(_cv2().CAP_PROP_POS_FRAMES, index)
                ok, frame = cap.read()
            if ok and frame is not None:
                yield index, frame
        return
    index, taken = 0, 0
    while taken < MAX_VIDEO_CANDIDATES:
        with native_stderr_silenced():
            ok = cap.grab()
            if ok and index % stride == 0:
                ok, frame = cap.retrieve()
                if not ok or frame is None:
                    return
        if not ok:
            return
        if index % stride == 0:
            taken += 1
            yield index, frame
        index += 1


def _cv2() -> Any:
    import cv2

    return cv2


def video_face_sources(
    path: str | os.PathLike[str],
    detector: Any,
    *,
    per_video: int = 8,
    min_face_px: float = MIN_FACE_PX,
    stem: str | None = None,
) -> FaceSources:
    """``per_video`` crops of one video's frames, spread in head pose (module docstring).

    Raises:
        InputError: missing file, or no frame OpenCV can decode (also: a frame above the
            image size limit).
        NoFaceError: no usable face in any candidate frame.
    """
    import cv2

    from facemesh._native import native_stderr_silenced
    from facemesh.camera import camera_for_image
    from facemesh.conventions import rotation_to_head_pitchyaw
    from facemesh.io import MAX_IMAGE_PIXELS, check_input_file

    from .pipeline import fit_face

    p = check_input_file(path)
    stem = stem or p.stem
    if not os.access(p, os.R_OK):
        raise InputError(f"{p}: cannot read the file (permission denied)")
    with native_stderr_silenced():  # FFmpeg's lines on damaged files ("moov atom not found")
        cap = cv2.VideoCapture(str(p))
    try:
        if not cap.isOpened():
            raise InputError(f"{p}: not a video OpenCV can decode (or the file is damaged)")
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        fw, fh = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH) or 0), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT) or 0)
        if fw * fh > MAX_IMAGE_PIXELS:
            raise InputError(f"{p}: frames of {fw}x{fh} pixels; above {MAX_IMAGE_PIXELS / 1e6:g} megapixels")
        decoded = 0
        reasons: dict[str, int] = {}
        cands: list[_Candidate] = []
        for index, bgr in _frames(cap, count):
            if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
                continue
            if bgr.shape[0] * bgr.shape[1] > MAX_IMAGE_PIXELS:
                raise InputError(f"{p}: frames of {bgr.shape[1]}x{bgr.shape[0]} pixels; above the size limit")
            decoded += 1
            frame: NDArray[np.uint8] = np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)
            del bgr
            h, w = frame.shape[:2]
            t = index / fps if fps > 0 else float(cap.get(cv2.CAP_PROP_POS_MSEC) or 0.0) / 1000.0
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # reprojection warnings: the pose is only a selection cue
                    fit = fit_face(frame, camera_for_image(None, w, h, warn=False), detector, source=f"{p}@{t:.2f}s")
            except FaceMeshError:
                reasons["no face"] = reasons.get("no face", 0) + 1
                continue
            pts = np.asarray(fit.landmarks.points_px, dtype=np.float64)
            pitch, yaw = (float(v) for v in np.degrees(rotation_to_head_pitchyaw(fit.pose.rotation)))
            openness = eye_openness(pts)
            if inter_ocular_px(pts, detector) < min_face_px:
                why = "face too small"
            elif abs(yaw) > MAX_YAW_DEG or abs(pitch) > MAX_PITCH_DEG:
                why = "head turned too far"
            elif openness is not None and openness < MIN_EYE_OPENNESS:
                why = "eyes closed"
            else:
                cands.append(
                    _Candidate(index, t, (pitch, yaw), face_crop(frame, pts), crop_region(pts), _sharpness(frame, pts))
                )
                continue
            reasons[why] = reasons.get(why, 0) + 1
    finally:
        cap.release()
    if decoded == 0:
        raise InputError(f"{p}: no decodable frame (an empty or damaged video)")
    if cands:
        floor = BLUR_RATIO * float(np.median([c.sharpness for c in cands]))
        sharp = [c for c in cands if c.sharpness >= floor]
        if len(sharp) < len(cands):
            reasons["blurred"] = len(cands) - len(sharp)
        cands = sharp
    summary = ", ".join(f"{n} {why}" for why, n in sorted(reasons.items()))
    if not cands:
        raise NoFaceError(f"{p}: no usable face in {decoded} frames ({summary or 'none found'})")
    out = FaceSources(skipped=[f"{p}: {decoded} frames looked at; left out: {summary}"] if summary else [])
    for c in _spread(cands, per_video, detector, out.skipped, str(p)):
        tag = f"@t={c.time_s:.2f}s"
        out.append(
            FaceSource(
                f"{stem}{tag}",
                c.crop,
                f"{p}{tag}",
                person=stem,
                time_s=c.time_s,
                pitch_yaw_deg=c.pitch_yaw_deg,
                region_px=c.region,
            )
        )
    if not out:
        raise NoFaceError(f"{p}: no frame's face was found again in its crop")
    return out


def _spread(cands: list[_Candidate], n: int, detector: Any, skipped: list[str], name: str) -> list[_Candidate]:
    """The most frontal candidate, then greedy farthest-point on (pitch, yaw); each crop checked by the detector."""
    pose = np.array([c.pitch_yaw_deg for c in cands], dtype=np.float64)
    times = np.array([c.time_s for c in cands], dtype=np.float64)
    left = list(range(len(cands)))
    chosen: list[int] = []
    while left and len(chosen) < n:
        if chosen:
            d = np.linalg.norm(pose[left][:, None, :] - pose[chosen][None, :, :], axis=2).min(axis=1)
            gap = np.abs(times[left][:, None] - times[chosen][None, :]).min(axis=1)
            # farthest in pose; among equals (to 0.1 deg), farthest in time
            best = left[max(range(len(left)), key=lambda i: (round(float(d[i]), 1), float(gap[i])))]
        else:
            best = left[int(np.argmin(np.linalg.norm(pose[left], axis=1)))]
        left.remove(best)
        if _found_again(cands[best].crop, detector, CROP_SCALE):
            chosen.append(best)
        else:
            skipped.append(f"{name}@t={cands[best].time_s:.2f}s: not found again in its crop")
    return [cands[i] for i in chosen]
