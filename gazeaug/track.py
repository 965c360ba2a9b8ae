"""Gaze per frame from a video, a folder of images or a camera: what ``gazeaug track`` runs.

Per frame: MediaPipe Face Mesh landmarks (video mode: the face is tracked from
frame to frame and detected again when lost), PnP head pose, normalization
(Zhang 2018), the gaze model (:mod:`gazeaug.estimator`: ``.pt`` or ``.onnx``),
denormalization into the camera frame, One-Euro smoothing
(:mod:`gazeaug.selection`), and with a rig (:class:`gazeaug.sampling.Rig`)
the point of gaze and the target looked at (:mod:`gazeaug.scene`) and dwell
selections. Frames without a face, and frames whose eyes are closed (a blink:
:func:`gazeaug.faces.eye_openness` below ``TrackSettings.blink_openness``),
are flagged in the output, never given a guessed gaze.

Outputs in the output folder (each written under a temporary name and moved in
place when the run ends, also on Ctrl-C, so a file is complete up to the last
frame processed and an older run's file is only replaced by a complete one):

``gaze.csv``
    One row per input frame (:data:`COLUMNS`; with a rig also :data:`RIG_COLUMNS`).
    Empty cells where a value does not exist (no face, eyes closed).
``selections.csv`` (with a rig)
    One row per selection: ``frame,time_s,target,dwell_start_s``.
``overlay.mp4`` (unless ``video=False``)
    The frames with the face box, the gaze arrow, and with a rig the targets,
    the one looked at, the dwell's progress and each selection.
``summary.json``
    What :func:`track` returns.

Columns (camera frame: OpenCV, x right, y down, z forward, mm; angles
:mod:`facemesh.conventions`' pitch/yaw, degrees):

- ``frame`` (0-based input frame), ``time_s`` (video time; a folder: frame / fps;
  a camera: seconds since the start), ``status`` (``ok``, ``no_face``,
  ``eyes_closed``, ``unreadable`` (a frame that could not be decoded),
  ``failed`` (pose or normalization failed; ``note`` says why)), ``face_found`` (0/1);
- ``gaze_x, gaze_y, gaze_z``: the unit gaze direction (smoothed when smoothing
  is on), and ``pitch_deg, yaw_deg`` of it; ``raw_pitch_deg, raw_yaw_deg``: the
  model's, before smoothing;
- ``head_pitch_deg, head_yaw_deg``: the head pose (the direction the face points);
- ``eye_x_mm, eye_y_mm, eye_z_mm``: the midpoint of the two eye centres;
  ``origin_x_mm, origin_y_mm, origin_z_mm``: the face centre, where the gaze
  ray starts (the model's labels are directions from it: Zhang's
  normalization);
- ``openness``: the eyes' lid gap over width (about 0.3-0.45 open);
- with a rig, rig frame: ``pog_x_mm, pog_y_mm, pog_z_mm`` (the point of gaze:
  the ray's first hit on a target or plane), ``surface`` (what it lies on),
  ``target`` (the target looked at, with the selection's angular margin),
  ``selected`` (the target selected at this frame).
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import time
import warnings
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from facemesh.types import CameraIntrinsics

from .background import interrupt_between_steps
from .errors import GazeAugError
from .selection import DwellSelector, OneEuroFilter, SelectionSettings, SmoothingSettings

__all__ = [
    "TrackSettings",
    "Frame",
    "FrameSource",
    "open_source",
    "track",
    "COLUMNS",
    "RIG_COLUMNS",
    "STAGES",
    "IMAGE_SUFFIXES",
]

#: The columns of ``gaze.csv`` (module docstring).
COLUMNS = (
    "frame",
    "time_s",
    "status",
    "face_found",
    "gaze_x",
    "gaze_y",
    "gaze_z",
    "pitch_deg",
    "yaw_deg",
    "raw_pitch_deg",
    "raw_yaw_deg",
    "head_pitch_deg",
    "head_yaw_deg",
    "eye_x_mm",
    "eye_y_mm",
    "eye_z_mm",
    "origin_x_mm",
    "origin_y_mm",
    "origin_z_mm",
    "openness",
    "note",
)
#: The columns added with a rig.
RIG_COLUMNS = ("pog_x_mm", "pog_y_mm", "pog_z_mm", "surface", "target", "selected")
#: The timed stages (milliseconds per frame in the summary).
STAGES = ("decode", "landmarks", "pose", "normalize", "model", "rig", "output")
#: The files a run writes in its output folder (besides ``summary.json``); an older run's that this
#: run does not write are removed when it ends.
OUTPUT_FILES = ("gaze.csv", "selections.csv", "overlay.mp4")
#: Image files a folder source reads, in name order.
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
#: The frame rates a folder of images may have, frames per second.
MIN_FPS, MAX_FPS = 1.0, 1000.0
#: The largest camera index taken (``/dev/videoN`` names any device).
MAX_CAMERA_INDEX = 1024
#: Consecutive undecodable video frames after which a video is taken to have ended.
MAX_BAD_FRAMES = 25


@dataclass(frozen=True)
class TrackSettings:
    """How :func:`track` runs (defaults documented per field).

    Attributes:
        smoothing: One-Euro settings for the gaze (:class:`SmoothingSettings`); None turns smoothing off.
        selection: dwell and margin settings (:class:`SelectionSettings`), used with a rig.
        blink_ratio: eyes are closed (a blink) when their openness (lid gap over width,
            :func:`gazeaug.faces.eye_openness`) falls below this share of the person's own recent
            openness: the median over the last ``blink_baseline_s`` of frames with open eyes
            (default 0.6). Openness differs much between people and with the gaze (lids lower
            when looking down: 0.1-0.15 for a simulated wheelchair user looking at a table, 0.3-0.45
            for a frontal photo), so a fixed threshold flags open eyes of some and misses blinks of others.
        blink_baseline_s: the window of that median, seconds (default 5).
        blink_openness: below this the eyes are closed while the window holds fewer than 5 frames
            (the first frames; a folder of unrelated photos), default 0.1 (closed eyes measure
            below 0.1).
        tracking: MediaPipe's video mode (default True); False detects every frame afresh.
        max_frames: stop after this many input frames (default: all).
        folder_fps: frame rate of a folder of images (default: its ``sequence.json``'s ``fps``, else 30).
        video: write ``overlay.mp4`` (default True).
        show: show the overlay in a window while running (needs a display; default False).
    """

    smoothing: SmoothingSettings | None = SmoothingSettings()
    selection: SelectionSettings = SelectionSettings()
    blink_ratio: float = 0.6
    blink_baseline_s: float = 5.0
    blink_openness: float = 0.1
    tracking: bool = True
    max_frames: int | None = None
    folder_fps: float | None = None
    video: bool = True
    show: bool = False

    def __post_init__(self) -> None:
        for name in ("blink_openness", "blink_ratio"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v < 1):
                raise GazeAugError(f"{name}: expected a number from 0 to below 1, got {v!r}")
        b = self.blink_baseline_s
        if not (isinstance(b, (int, float)) and not isinstance(b, bool) and math.isfinite(b) and b > 0):
            raise GazeAugError(f"blink_baseline_s: expected a number > 0, got {b!r}")
        if self.max_frames is not None and not (
            isinstance(self.max_frames, int) and not isinstance(self.max_frames, bool) and self.max_frames >= 1
        ):
            raise GazeAugError(f"max_frames: expected an integer >= 1, got {self.max_frames!r}")
        f = self.folder_fps
        if f is not None and not (isinstance(f, (int, float)) and math.isfinite(f) and MIN_FPS <= f <= MAX_FPS):
            raise GazeAugError(f"folder_fps: expected a number from {MIN_FPS:g} to {MAX_FPS:g}, got {f!r}")


@dataclass(frozen=True)
class Frame:
    """One input frame.

    ``bgr``: (H, W, 3) uint8 as decoded (OpenCV's channel order), or None when the frame could not be
    decoded (``error`` says why). ``time_s``: seconds from the start of the source.
    """

    index: int
    time_s: float
    bgr: NDArray[np.uint8] | None
    error: str | None = None


@dataclass
class FrameSource:
    """Frames of a video file, a folder of images or a camera, in order (:func:`open_source`).

    Attributes:
        name: the source as given.
        kind: ``video``, ``folder``, ``image`` (one image file, read as a folder of one is) or ``camera``.
        fps: frames per second (a camera's as it reports it; 30 when it does not say).
        frame_count: frames in a video or folder (None for a camera, or a video that does not say).
    """

    name: str
    kind: str
    fps: float
    frame_count: int | None
    _capture: Any = None
    _files: list[Path] = field(default_factory=list)

    def __iter__(self) -> Iterator[Frame]:
        if self.kind in ("folder", "image"):
            return self._folder()
        return self._video()

    def prefetched(self, depth: int = 4) -> Generator[Frame, None, None]:
        """The frames, decoded ``depth`` ahead in a background thread.

        OpenCV decodes without holding the GIL, so decoding overlaps the work on the previous
        frame. A camera is read in the calling thread: frames queued ahead of a slower loop would
        only add latency.
        """
        if self.kind == "camera":
            yield from self
            return
        from .background import read_ahead

        yield from read_ahead(lambda: iter(self), depth, "track-decode")

    def _folder(self) -> Iterator[Frame]:
        import cv2

        for i, p in enumerate(self._files):
            why = "not a readable image"
            try:
                data = np.fromfile(str(p), dtype=np.uint8) if p.is_file() else np.zeros(0, np.uint8)
                bgr = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
            except (OSError, cv2.error) as exc:  # unreadable, or a header claiming billions of pixels
                bgr, why = None, f"not a readable image ({str(exc).strip().splitlines()[-1][:120]})"
            if bgr is None:
                yield Frame(i, i / self.fps, None, f"{p.name}: {why}")
                continue
            yield Frame(i, i / self.fps, np.asarray(bgr, dtype=np.uint8))

    def _video(self) -> Iterator[Frame]:
        """The frames of a video or camera.

        Times increase: a video's from its timestamps (``CAP_PROP_POS_MSEC``), else frame / fps; a
        camera's since the start. A video frame that does not decode is yielded (image None) only
        once a later frame decodes: frames that fail after the last good one are the end (a
        container's frame count is often an overestimate), as are 25 failures in a row.
        """
        import cv2

        cap = self._capture
        i, start, last_t = 0, time.monotonic(), -math.inf
        pending: list[Frame] = []  # frames that did not decode, waiting for a good one after them
        while True:
            ok, bgr = cap.read()
            if self.kind == "camera":
                t = time.monotonic() - start
            else:
                ms = cap.get(cv2.CAP_PROP_POS_MSEC) if ok else 0.0
                t = ms / 1000.0 if ms and ms > 0 and i > 0 else i / self.fps
            if not t > last_t:  # a timestamp that went back, or a frame without one: after the last
                t = last_t + 1.0 / self.fps
            last_t = t
            if ok and bgr is not None:
                yield from pending
                pending = []
                yield Frame(i, t, np.asarray(bgr, dtype=np.uint8))
            else:
                if self.kind == "camera" or len(pending) >= MAX_BAD_FRAMES:
                    return  # a camera that stops delivering, or a video that stopped decoding
                if self.frame_count is not None and i >= self.frame_count:
                    return
                pending.append(Frame(i, t, None, "frame could not be decoded"))
            i += 1

    def close(self) -> None:
        """Release the video or camera."""
        if self._capture is not None:
            self._capture.release()
            self._capture = None


def _is_camera(spec: str) -> bool:
    return spec.isdigit() or spec.startswith("/dev/video")


def open_source(spec: str | os.PathLike[str], folder_fps: float | None = None) -> FrameSource:
    """Open a video file, a folder of images (sorted by name), one image or a camera (``0``, ``/dev/video0``).

    Raises:
        GazeAugError: nothing at that path, a folder without images, a video or camera that does
            not open.
    """
    import cv2

    name = str(spec)
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # FFmpeg's own log lines (a corrupt video's): off
    if _is_camera(name):
        if name.isdigit() and int(name) > MAX_CAMERA_INDEX:
            raise GazeAugError(f"camera {name}: expected a camera index from 0 to {MAX_CAMERA_INDEX}")
        from facemesh._native import native_stderr_silenced

        try:
            with native_stderr_silenced():  # OpenCV's own "[ WARN ...] can't open camera by index" lines
                cap = cv2.VideoCapture(int(name) if name.isdigit() else name)
        except cv2.error as exc:
            raise GazeAugError(f"camera {name}: cannot be opened ({str(exc).strip().splitlines()[-1][:120]})") from exc
        if not cap.isOpened():
            raise GazeAugError(f"camera {name}: cannot be opened (is it connected, and free?)")
        fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
        return FrameSource(name, "camera", float(fps), None, cap)
    p = Path(name)
    if p.is_dir():
        files = sorted(q for q in p.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES and not q.name.startswith("."))
        if not files:
            raise GazeAugError(f"{p}: the folder has no images ({', '.join(IMAGE_SUFFIXES)})")
        seq_fps = _sequence_fps(p)
        if folder_fps is not None and seq_fps is not None and abs(folder_fps - seq_fps) > 1e-9:
            raise GazeAugError(f"{p}: --fps {folder_fps:g} contradicts its sequence.json's fps {seq_fps:g}")
        fps = folder_fps or seq_fps or 30.0
        return FrameSource(name, "folder", float(fps), len(files), None, files)
    if not p.exists():
        raise GazeAugError(f"{p}: no such video, folder or camera")
    if p.suffix.lower() in IMAGE_SUFFIXES:  # decoded as a folder's images are (and predict's), not by FFmpeg
        return FrameSource(name, "image", float(folder_fps or 30.0), 1, None, [p])
    cap = cv2.VideoCapture(str(p))
    if not cap.isOpened():
        cap.release()
        raise GazeAugError(f"{p}: cannot be opened as a video")
    fps = cap.get(cv2.CAP_PROP_FPS)
    fps = float(fps) if fps and math.isfinite(fps) and 0 < fps <= MAX_FPS else 30.0
    count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0) or None
    return FrameSource(name, "video", fps, count, cap)


def _sequence_fps(folder: Path) -> float | None:
    """The ``fps`` of a simulated sequence's ``sequence.json`` in ``folder``; None without that file.

    Raises:
        GazeAugError: a ``sequence.json`` that is not JSON or has no usable ``fps``.
    """
    p = folder / "sequence.json"
    if not p.is_file():
        return None
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise GazeAugError(f"{p}: not a readable sequence file ({exc.__class__.__name__})") from exc
    fps = data.get("fps") if isinstance(data, dict) else None
    if not (isinstance(fps, (int, float)) and not isinstance(fps, bool) and MIN_FPS <= fps <= MAX_FPS):
        raise GazeAugError(f"{p}: fps: expected a number from {MIN_FPS:g} to {MAX_FPS:g}, got {fps!r}")
    return float(fps)


class _Outputs:
    """The output files, written under temporary names and moved in place by :meth:`close`."""

    def __init__(self, out_dir: Path, columns: tuple[str, ...], with_rig: bool, source: str):
        _check_output_folder(out_dir, source)
        # the folders this run makes: removed again when it keeps nothing ("nothing written")
        self._made = [p for p in (out_dir, *out_dir.parents) if not p.exists()]
        out_dir.mkdir(parents=True, exist_ok=True)
        self.dir = out_dir
        self.final: dict[str, Path] = {"gaze": out_dir / "gaze.csv"}
        self.part: dict[str, Path] = {"gaze": out_dir / ".gaze.csv.part"}
        self._gaze = open(self.part["gaze"], "w", newline="", encoding="utf-8")  # noqa: SIM115
        self._gw = csv.DictWriter(self._gaze, fieldnames=list(columns), lineterminator="\n", extrasaction="ignore")
        self._gw.writeheader()
        self._sel = None
        if with_rig:
            self.final["selections"] = out_dir / "selections.csv"
            self.part["selections"] = out_dir / ".selections.csv.part"
            self._sel = open(self.part["selections"], "w", newline="", encoding="utf-8")  # noqa: SIM115
            self._sel.write("frame,time_s,target,dwell_start_s\n")
        self._video: Any = None
        self._writer: Any = None
        self._encode_error: str | None = None
        self._closed = False

    def open_video(self, size_wh: tuple[int, int], fps: float) -> None:
        import cv2

        self.final["video"] = self.dir / "overlay.mp4"
        self.part["video"] = self.dir / ".overlay.part.mp4"
        self._video = cv2.VideoWriter(str(self.part["video"]), cv2.VideoWriter.fourcc(*"mp4v"), fps, size_wh)
        self._video_size = (int(size_wh[0]), int(size_wh[1]))
        if not self._video.isOpened():
            self._video = None
            self.final.pop("video")
            self.part.pop("video").unlink(missing_ok=True)
            raise GazeAugError(f"{self.dir}: OpenCV cannot write an mp4 video here (no mp4v encoder?); use --no-video")

    def row(self, values: dict[str, Any]) -> None:
        self._gw.writerow(values)

    def selection(self, frame: int, t: float, target: str, start: float) -> None:
        assert self._sel is not None
        self._sel.write(f"{frame},{t:.4f},{target},{start:.4f}\n")
        self._sel.flush()

    def frame(self, bgr: NDArray[np.uint8]) -> None:
        """Queue one overlay frame; a background thread encodes it (OpenCV encodes without the GIL).

        A frame of another size than the video's first (a folder's images may differ) is scaled into
        it, its aspect kept, the rest black: OpenCV's writer drops such frames without a word.
        """
        if self._video is None:
            return
        if (bgr.shape[1], bgr.shape[0]) != self._video_size:
            bgr = _letterboxed(bgr, self._video_size)
        if self._writer is None:
            import queue
            import threading

            self._queue: Any = queue.Queue(maxsize=4)
            self._writer = threading.Thread(target=self._encode, name="track-encode", daemon=True)
            self._writer.start()
        import queue

        while True:
            if self._encode_error is not None or not self._writer.is_alive():
                raise GazeAugError(
                    f"{self.dir}: writing overlay.mp4 failed ({self._encode_error or 'encoder stopped'})"
                )
            try:
                self._queue.put(bgr, timeout=0.5)
                return
            except queue.Full:
                continue

    def _encode(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            try:
                self._video.write(item)
            except Exception as exc:  # noqa: BLE001 - reported by the next frame() in the main thread
                self._encode_error = str(exc).splitlines()[0][:200] or exc.__class__.__name__
                return

    def close(self, keep: bool = True) -> dict[str, str]:
        """Close every file and move it in place (``keep``) or delete it.

        Returns {kind: final path} of what was moved in place. A second call does nothing.
        """
        if self._closed:
            return {}
        self._closed = True
        self._gaze.close()
        if self._sel is not None:
            self._sel.close()
        if self._writer is not None:
            if self._writer.is_alive():
                self._queue.put(None)  # the encoder takes frames until this one
            self._writer.join()
        if self._video is not None:
            self._video.release()
        out = {}
        for k, part in self.part.items():
            if part.exists():
                if keep:
                    os.replace(part, self.final[k])
                    out[k] = str(self.final[k])
                else:
                    part.unlink()
        if not keep:
            for folder in self._made:  # innermost first; a folder something else wrote into stays
                try:
                    folder.rmdir()
                except OSError:
                    break
        if keep:  # an older run's outputs that this run did not write would pass for this run's
            for name in OUTPUT_FILES:
                stale = self.dir / name
                if str(stale) not in out.values() and stale.is_file():
                    stale.unlink()
        return out


def _letterboxed(bgr: NDArray[np.uint8], size_wh: tuple[int, int]) -> NDArray[np.uint8]:
    """``bgr`` (H, W, 3) uint8 scaled to fit (W', H') = ``size_wh``, centred, its aspect kept, on black."""
    import cv2

    w, h = size_wh
    scale = min(w / bgr.shape[1], h / bgr.shape[0])
    nw, nh = max(1, min(w, round(bgr.shape[1] * scale))), max(1, min(h, round(bgr.shape[0] * scale)))
    out = np.zeros((h, w, 3), np.uint8)
    x, y = (w - nw) // 2, (h - nh) // 2
    out[y : y + nh, x : x + nw] = cv2.resize(bgr, (nw, nh), interpolation=cv2.INTER_AREA)
    return out


def _check_output_folder(out_dir: Path, source: str) -> None:
    """Refuse a folder whose files a run would replace or remove but that ``track`` did not write.

    A folder holding any of :data:`OUTPUT_FILES` must also hold a ``summary.json`` that ``track``
    wrote (the user's own ``gaze.csv`` or video is never replaced), and the source must not be one
    of the files a run writes.
    """
    src = Path(source).resolve() if not _is_camera(source) else None
    for name in (*OUTPUT_FILES, "summary.json"):
        if src is not None and (out_dir / name).resolve() == src:
            raise GazeAugError(
                f"{source}: the source is one of the files track writes into {out_dir}; choose another -o"
            )
    present = [n for n in OUTPUT_FILES if (out_dir / n).exists()]
    if present and not _written_by_track(out_dir / "summary.json"):
        raise GazeAugError(
            f"{out_dir}: holds {', '.join(present)} that gazeaug track did not write (no summary.json of a track run); "
            "choose an empty or new output folder"
        )


def _written_by_track(path: Path) -> bool:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return False
    return isinstance(data, dict) and data.get("written_by") == "gazeaug track"


def _fmt(v: float | None, digits: int) -> str:
    return "" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


@dataclass
class _Timer:
    ms: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))
    _t: float = 0.0

    def start(self) -> None:
        self._t = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.ms[stage] += (now - self._t) * 1000.0
        self._t = now


class _FrameGaze:
    """The per-frame work of :func:`track`: landmarks to gaze to the rig, as one row of ``gaze.csv``."""

    def __init__(
        self,
        estimator: Any,
        camera: CameraIntrinsics | Path | None,
        rig: Any,
        settings: TrackSettings,
        timer: _Timer,
        calibration: Any = None,
    ):
        from facemesh.landmarks.mediapipe import MediaPipeFaceMesh

        self.estimator, self.camera, self.rig, self.settings = estimator, camera, rig, settings
        self.calibration = calibration
        self.timer = timer
        self._size: tuple[int, int] | None = None
        self.detector = MediaPipeFaceMesh(static_image_mode=not settings.tracking, max_num_faces=1)
        self.filter = OneEuroFilter(settings.smoothing) if settings.smoothing is not None else None
        self.selector = DwellSelector(settings.selection)
        self.scene = rig.scene if rig is not None else None
        self.r_rig = rig.camera_rotation() if rig is not None else None
        self.c_rig = np.asarray(rig.camera_position_mm) if rig is not None else None
        self._cams: dict[tuple[int, int], CameraIntrinsics] = {}
        self._openness: list[tuple[float, float]] = []  # (time, openness) of the recent frames with a face

    def _closed(self, t_s: float, openness: float) -> bool:
        """Whether the eyes are closed: relative to the person's recent openness (:class:`TrackSettings`)."""
        s = self.settings
        recent = [o for t, o in self._openness if t_s - s.blink_baseline_s <= t <= t_s]
        closed = openness < (s.blink_ratio * float(np.median(recent)) if len(recent) >= 5 else s.blink_openness)
        self._openness = [(t, o) for t, o in self._openness if t >= t_s - s.blink_baseline_s]
        if not closed or len(recent) < 5:  # once it has 5, the baseline takes open eyes only (a long closure
            self._openness.append((t_s, openness))  # does not lower it); until then every frame counts
        return bool(closed)

    def camera_for(self, w: int, h: int) -> CameraIntrinsics:
        """The user's camera (checked against the frame size), else per frame size the rig's or the default."""
        from facemesh.camera import camera_for_image, load_camera

        if isinstance(self.camera, Path):  # a calibration file without an image size: the first frame's
            self.camera = load_camera(self.camera, image_size=(w, h))
        if self.camera is not None:
            if self.camera.image_size != (w, h):
                c = self.camera
                raise GazeAugError(
                    f"the camera ({c.source}) is for {c.image_size[0]}x{c.image_size[1]} frames, "
                    f"the source's are {w}x{h}"
                )
            return self.camera
        if (w, h) not in self._cams:  # a folder's images may differ in size
            if self.rig is not None and tuple(self.rig.image_size_wh) == (w, h):
                self._cams[(w, h)] = self.rig.camera()
            else:
                self._cams[(w, h)] = camera_for_image(None, w, h, warn=not self._cams)
        return self._cams[(w, h)]

    def __call__(
        self, fr: Frame, bgr: NDArray[np.uint8], cam: CameraIntrinsics
    ) -> tuple[dict[str, Any], tuple[NDArray[np.float64], NDArray[np.float64]] | None]:
        """One decoded frame -> (its row, what the overlay draws: (landmarks px, gaze origin mm) or None)."""
        import cv2

        from facemesh.conventions import pitchyaw_to_vector, rotation_to_head_pitchyaw, vector_to_pitchyaw
        from facemesh.landmarks.base import paired_face_model, select_face
        from facemesh.pose import solve_head_pose
        from facemesh.types import FaceMeshError

        from .camera import reference_points
        from .faces import eye_openness
        from .normalize import normalize_image

        s, timer = self.settings, self.timer
        row: dict[str, Any] = {"frame": fr.index, "time_s": f"{fr.time_s:.4f}", "face_found": 0}
        image = np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)
        if self._size is not None and self._size != (image.shape[0], image.shape[1]):
            self.detector.close()  # another picture, not the next frame: the track starts afresh
        self._size = (int(image.shape[0]), int(image.shape[1]))
        faces = self.detector.detect(image)
        timer.lap("landmarks")
        if not faces:
            row["status"] = "no_face"
            if self.filter is not None:
                self.filter.reset()
            return row, None
        row["face_found"] = 1
        face = select_face(faces, None, source=f"frame {fr.index}")
        model = paired_face_model(face, self.detector, None)
        openness = eye_openness(face.points_px)
        row["openness"] = _fmt(openness, 3)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # a far-off landmark (ReprojectionWarning): per frame, not news
                pose = solve_head_pose(face.points_px[: model.num_points], model.vertices_mm, cam)
        except FaceMeshError as exc:  # PoseError: the frame is flagged, the run goes on
            row.update(status="failed", note=str(exc).splitlines()[0][:200])
            timer.lap("pose")
            return row, None
        timer.lap("pose")
        refs = reference_points(pose.rotation, pose.translation_mm, model.vertices_mm, model.keypoints)
        hp = np.degrees(rotation_to_head_pitchyaw(pose.rotation))
        eye_mid = (refs["left"] + refs["right"]) / 2
        row.update(
            head_pitch_deg=_fmt(hp[0], 3),
            head_yaw_deg=_fmt(hp[1], 3),
            **{f"eye_{a}_mm": _fmt(v, 2) for a, v in zip("xyz", eye_mid)},
            **{f"origin_{a}_mm": _fmt(v, 2) for a, v in zip("xyz", refs["face"])},
        )
        drawn = (face.points_px, refs["face"])  # what the overlay draws
        if openness is not None and self._closed(fr.time_s, openness):
            row["status"] = "eyes_closed"
            return row, drawn
        try:
            sample = normalize_image(
                image, cam, pose, model.vertices_mm, model.keypoints, settings=self.estimator.normalization
            )
        except GazeAugError as exc:
            row.update(status="failed", note=str(exc).splitlines()[0][:200])
            timer.lap("normalize")
            return row, drawn
        timer.lap("normalize")
        assert sample.face is not None
        face_patch = None if sample.face.image is None else sample.face.image[None]
        pred = self.estimator.predict(
            sample.left.image[None], sample.right.image[None], sample.face.head_pose[None], face_patch
        )[0]
        row["_model_pitchyaw"], row["_normalized_camera"] = pred, sample.face.camera  # for calibrate (not written)
        if self.calibration is not None:
            pred = self.calibration.apply(pred)
        g = sample.face.camera.denormalize_vector(pitchyaw_to_vector(pred))
        raw = np.degrees(vector_to_pitchyaw(g))
        py = self.filter(fr.time_s, raw) if self.filter is not None else raw
        g = pitchyaw_to_vector(np.radians(py))
        timer.lap("model")
        row.update(
            status="ok",
            gaze_x=_fmt(g[0], 6),
            gaze_y=_fmt(g[1], 6),
            gaze_z=_fmt(g[2], 6),
            pitch_deg=_fmt(py[0], 3),
            yaw_deg=_fmt(py[1], 3),
            raw_pitch_deg=_fmt(raw[0], 3),
            raw_yaw_deg=_fmt(raw[1], 3),
        )
        if self.scene is not None:
            from facemesh.conventions import camera_to_rig_directions, camera_to_rig_points

            assert self.r_rig is not None and self.c_rig is not None

            o = camera_to_rig_points(refs["face"], self.r_rig, self.c_rig)
            d = camera_to_rig_directions(g, self.r_rig)
            look = self.scene.look(o, d, s.selection.margin_deg)
            row.update(
                **{f"pog_{a}_mm": _fmt(v, 2) for a, v in zip("xyz", look.point_mm)},
                surface=look.surface or "",
                target=look.target or "",
            )
        return row, drawn


def track(
    source: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    estimator: Any,
    *,
    camera: CameraIntrinsics | str | Path | None = None,
    rig: Any = None,
    settings: TrackSettings = TrackSettings(),
    progress: bool = True,
    calibration: Any = None,
    on_row: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Track gaze through ``source`` and write the outputs (module docstring) into ``out_dir``.

    Args:
        source: a video file, a folder of images, one image file, or a camera (``0``, ``/dev/video0``).
        out_dir: the output folder (created).
        estimator: a :class:`gazeaug.estimator.GazeEstimator`.
        camera: the source's intrinsics (checked against the frame size), or a calibration file
            that gives no image size (:class:`facemesh.camera.CameraSizeMissing`), read with the first
            frame's size; default: the rig's camera when the frames have the rig's image size, else
            facemesh's documented default.
        rig: a :class:`gazeaug.sampling.Rig` for the point of gaze and selections (its targets and
            planes), or None.
        settings: :class:`TrackSettings`.
        progress: print a progress bar to stderr.
        calibration: a :class:`gazeaug.calibration.Calibration` of this user for this model, applied
            to the model's output before anything else.
        on_row: called with each frame's row (what ``gaze.csv`` gets; with a gaze also
            ``_model_pitchyaw``, the model's (2,) radians before calibration, and
            ``_normalized_camera``, the frame's :class:`gazeaug.camera.NormalizedCamera`).

    Returns:
        The summary: ``frames``, ``frames_with_face``, ``frames_eyes_closed``, ``unreadable_frames``,
        ``failed_frames``, ``fps`` (end to end, decoding included), ``ms_per_frame`` per stage
        (:data:`STAGES`; decoding runs ahead in its own thread, so ``decode`` is the wait for it),
        ``latency_ms`` (from taking a decoded frame to its gaze: median and 95th percentile),
        ``selections``, ``outputs`` (paths), ``interrupted``.

    Raises:
        GazeAugError: a source that does not open, a camera for another frame size (nothing is
            written then, and older outputs stay), a calibration fitted for another model file or
            for the model read the other way (:meth:`gazeaug.calibration.Calibration.check_for`).
        KeyboardInterrupt: after the outputs were closed and moved in place (complete up to the last frame).
    """
    from .sequence import read_truth, sequence_accuracy

    s = settings
    if calibration is not None:  # tied to a model file's bytes and to how it is read
        calibration.check_for(estimator.model_sha256, estimator.mirror_average)
    estimator.warm_up()  # its one-time costs before the timed loop (and its failures before any output)
    src = open_source(source, s.folder_fps)
    if s.folder_fps is not None and src.kind not in ("folder", "image"):
        warnings.warn(f"--fps sets a folder's frame rate; the {src.kind}'s own timing is used", stacklevel=2)
    truth = read_truth(src.name, frames=src.frame_count) if src.kind == "folder" else None
    kept: list[dict[str, Any]] = []  # the rows, when a simulated sequence's truth is there to score them
    with_rig = rig is not None
    try:
        outputs = _Outputs(Path(out_dir), COLUMNS + (RIG_COLUMNS if with_rig else ()), with_rig, str(source))
    except BaseException:
        src.close()
        raise
    timer = _Timer()
    counts = dict.fromkeys(
        ("frames", "frames_with_face", "frames_eyes_closed", "unreadable_frames", "failed_frames"), 0
    )
    try:  # a failure here (the landmark model, the window) leaves no part file and no folder behind
        work = _FrameGaze(estimator, Path(camera) if isinstance(camera, str) else camera, rig, s, timer, calibration)
        window = _open_window() if s.show else None
    except BaseException:
        outputs.close(keep=False)
        src.close()
        raise
    selections: list[dict[str, Any]] = []
    latencies: list[float] = []
    cam: CameraIntrinsics | None = None
    interrupted = False
    bar = None
    if progress:
        from tqdm import tqdm

        total = src.frame_count if s.max_frames is None else min(src.frame_count or s.max_frames, s.max_frames)
        bar = tqdm(total=total, unit="frame", desc="track", dynamic_ncols=True)
    last_sel: tuple[str, float] | None = None
    marks: dict[tuple[int, int], list[tuple[str, tuple[int, int], int]]] = {}  # per frame size: _target_marks
    frames = src.prefetched()
    guard = contextlib.ExitStack()
    guard.enter_context(_one_torch_thread(estimator))
    interrupted_now = guard.enter_context(interrupt_between_steps())  # Ctrl-C taken between frames
    wall0 = time.perf_counter()
    try:
        while s.max_frames is None or counts["frames"] < s.max_frames:
            if interrupted_now():
                raise KeyboardInterrupt
            timer.start()
            fr = next(frames, None)
            if fr is None:
                break
            t_read = time.perf_counter()
            timer.lap("decode")
            drawn = None
            if fr.bgr is None:
                row: dict[str, Any] = {
                    "frame": fr.index,
                    "time_s": f"{fr.time_s:.4f}",
                    "face_found": 0,
                    "status": "unreadable",
                    "note": fr.error or "",
                }
            else:
                h, w = fr.bgr.shape[:2]
                cam = work.camera_for(w, h)
                if s.video and "video" not in outputs.part:
                    outputs.open_video((w, h), src.fps)
                row, drawn = work(fr, fr.bgr, cam)
            if with_rig:
                sel = work.selector.update(fr.index, fr.time_s, row.get("target") or None)
                if sel is not None:
                    selections.append({"frame": sel.frame, "time_s": sel.time_s, "target": sel.target})
                    outputs.selection(sel.frame, sel.time_s, sel.target, sel.start_s)
                    row["selected"] = sel.target
                    last_sel = (sel.target, fr.time_s)
                timer.lap("rig")
            if row.get("status") == "ok":
                latencies.append((time.perf_counter() - t_read) * 1000.0)
            outputs.row(row)
            _count(counts, row)  # counted as written: a frame Ctrl-C cut short is in neither
            if truth is not None:
                kept.append(row)
            if on_row is not None:
                on_row(row)
            if fr.bgr is not None and cam is not None and (s.video or window is not None):
                if rig is not None and cam.image_size not in marks:
                    marks[cam.image_size] = _target_marks(rig, cam)
                pic = _overlay(
                    fr.bgr, cam, drawn, row, rig, marks.get(cam.image_size, []), work.selector, fr.time_s, last_sel
                )
                outputs.frame(pic)
                if window is not None and not _show(window, pic):
                    break
            timer.lap("output")
            if bar is not None:
                bar.update(1)
    except KeyboardInterrupt:
        interrupted = True
    except BaseException:
        outputs.close(keep=False)  # a bad input found mid-run: no half-made outputs, older ones stay
        raise
    finally:
        guard.close()
        if bar is not None:
            bar.close()
        # no frame decoded (a folder of damaged images gives 'unreadable' rows): an older run's outputs stay
        written = outputs.close(keep=counts["frames"] > counts["unreadable_frames"])
        frames.close()  # stops the decoding thread before the capture is released
        src.close()
        work.detector.close()
        if window is not None:
            _close_window()
    if counts["frames"] == counts["unreadable_frames"]:
        if interrupted:
            raise KeyboardInterrupt
        if src.kind == "image":
            raise GazeAugError(f"{src.name}: the image could not be decoded; nothing written")
        if counts["frames"]:
            raise GazeAugError(
                f"{src.name}: none of the {counts['frames']} images read could be decoded; nothing written"
            )
        raise GazeAugError(f"{src.name}: no frame could be read (an empty or undecodable video?); nothing written")
    wall = time.perf_counter() - wall0
    n = counts["frames"]
    lat = np.asarray(latencies)
    summary: dict[str, Any] = {
        "written_by": "gazeaug track",
        "source": src.name,
        "kind": src.kind,
        **counts,
        "fps": round(counts["frames"] / wall, 2) if wall > 0 else None,
        "seconds": round(wall, 3),
        "ms_per_frame": {k: round(v / n, 3) for k, v in timer.ms.items()},
        "latency_ms": {
            "median": round(float(np.median(lat)), 2) if lat.size else None,
            "p95": round(float(np.percentile(lat, 95)), 2) if lat.size else None,
        },
        "camera": cam.source if cam is not None else None,
        "model": str(estimator.path),
        "model_kind": estimator.kind,
        "mirror_average": estimator.mirror_average,
        "smoothing": s.smoothing is not None,
        "calibration": calibration.kind if calibration is not None else None,
        "rig": rig.name if with_rig else None,
        "selections": selections if with_rig else None,
        "outputs": {**written, "summary": str(Path(out_dir) / "summary.json")},
        "interrupted": interrupted,
    }
    if truth is not None and rig is not None and kept:
        last = max(int(r["frame"]) for r in kept)  # the frames tracked (--max-frames, Ctrl-C)
        summary["accuracy"] = sequence_accuracy(
            kept,
            selections,
            [t for t in truth if t["frame"] <= last],
            s.selection.dwell_s,
            late_s=s.selection.gap_s + 0.1,
            targets={t.name for t in rig.targets},
        )
    from facemesh.io import atomic_write

    with atomic_write(Path(out_dir) / "summary.json") as fh:
        fh.write(json.dumps(summary, indent=1).encode("utf-8"))
    if interrupted:
        raise KeyboardInterrupt
    return summary


_STATUS_COUNTS = {"eyes_closed": "frames_eyes_closed", "unreadable": "unreadable_frames", "failed": "failed_frames"}


def _count(counts: dict[str, int], row: dict[str, Any]) -> None:
    """Count one written row in the summary's totals."""
    counts["frames"] += 1
    counts["frames_with_face"] += int(row.get("face_found") == 1)
    key = _STATUS_COUNTS.get(str(row.get("status")))
    if key is not None:
        counts[key] += 1


def _one_torch_thread(estimator: Any) -> contextlib.AbstractContextManager[None]:
    """PyTorch on one thread while the block runs (a PyTorch estimator only), then as it was."""
    if getattr(estimator, "kind", None) != "pytorch":
        return contextlib.nullcontext()
    from .models import one_torch_thread

    return one_torch_thread()


_WINDOW = "gazeaug track"


def _open_window() -> Any:
    """A window for ``--show``, or None (with a warning) when there is no display."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) and os.name != "nt":
        warnings.warn("--show: no display (DISPLAY is not set); the overlay is not shown", stacklevel=3)
        return None
    try:
        import cv2

        cv2.namedWindow(_WINDOW, cv2.WINDOW_NORMAL)
    except Exception as exc:  # noqa: BLE001 - a headless OpenCV build raises cv2.error
        warnings.warn(f"--show: OpenCV cannot open a window ({str(exc).splitlines()[0][:120]})", stacklevel=3)
        return None
    return _WINDOW


def _show(window: Any, bgr: NDArray[np.uint8]) -> bool:
    """Show one frame; False when the user pressed q or Esc."""
    import cv2

    cv2.imshow(window, bgr)
    return (cv2.waitKey(1) & 0xFF) not in (ord("q"), 27)


def _close_window() -> None:
    import cv2

    try:
        cv2.destroyWindow(_WINDOW)
    except Exception:  # noqa: BLE001, S110 - already closed by the user
        pass


def _target_marks(rig: Any, cam: CameraIntrinsics) -> list[tuple[str, tuple[int, int], int]]:
    """Where the rig camera's image shows each target: (name, centre px, radius px), for the targets in view.

    Fixed for a run (the rig's camera does not move): computed once per camera, not per frame.
    """
    from facemesh.conventions import rig_to_camera_points
    from facemesh.pose import project_points

    h, w = cam.image_size[1], cam.image_size[0]
    r, c = rig.camera_rotation(), np.asarray(rig.camera_position_mm)
    marks = []
    for tg in rig.targets:
        centre = rig_to_camera_points(tg.centre, r, c)
        if centre[2] <= 1:
            continue
        u, v = project_points(centre[None], cam)[0]
        if not (np.isfinite(u) and np.isfinite(v) and abs(u) < 4 * w and abs(v) < 4 * h):
            continue
        rad = 0.0
        if hasattr(tg, "radius_mm"):
            rad = tg.radius_mm * cam.matrix[0, 0] / centre[2]
        else:
            corners = np.array(
                [
                    [x, y, z]
                    for x in (tg.min_mm[0], tg.max_mm[0])
                    for y in (tg.min_mm[1], tg.max_mm[1])
                    for z in (tg.min_mm[2], tg.max_mm[2])
                ]
            )
            pc = rig_to_camera_points(corners, r, c)
            if (pc[:, 2] > 1).all():
                rad = float(np.max(np.linalg.norm(project_points(pc, cam) - [u, v], axis=1)))
        marks.append((tg.name, (int(round(u)), int(round(v))), max(3, int(round(min(rad, 2 * w))))))
    return marks


def _overlay(
    bgr: NDArray[np.uint8],
    cam: CameraIntrinsics,
    drawn: tuple[NDArray[np.float64], NDArray[np.float64]] | None,
    row: dict[str, Any],
    rig: Any,
    marks: list[tuple[str, tuple[int, int], int]],
    selector: DwellSelector,
    t_s: float,
    last_sel: tuple[str, float] | None,
) -> NDArray[np.uint8]:
    """The frame (BGR, for the video) with the face box, the gaze arrow, the targets and the dwell.

    ``drawn``: the face's landmarks (N, 2) px and the gaze origin (3,) mm, camera frame; ``marks``:
    :func:`_target_marks` for this camera.
    """
    import cv2

    from facemesh.draw import put_label
    from facemesh.pose import project_points

    pic = bgr  # drawn on in place: the decoded frame is not used after this
    h, w = pic.shape[:2]
    th = max(1, w // 500)
    status = row.get("status", "")
    if rig is not None:
        looked = row.get("target") or None

        def colour(name: str) -> tuple[int, int, int]:
            """Green: just selected; yellow: looked at; else grey."""
            if last_sel is not None and last_sel[0] == name and t_s - last_sel[1] < 0.5:
                return (0, 220, 0)
            return (0, 200, 255) if name == looked else (200, 200, 200)

        for name, (u, v), rad in marks:
            cv2.circle(pic, (u, v), rad, colour(name), th, cv2.LINE_AA)
            put_label(pic, name, (u + 4, v - 4), 0.4 * th, colour(name), th)
        # the targets by name, bottom right (most lie outside a camera that looks up at the face)
        y = h - 12
        for tg in reversed(rig.targets):
            (tw, _), _ = cv2.getTextSize(tg.name, cv2.FONT_HERSHEY_SIMPLEX, 0.5 * th, th)
            put_label(pic, tg.name, (w - tw - 10, y), 0.5 * th, colour(tg.name), th)
            y -= int(22 * th)
        if selector.current is not None and status == "ok":
            p = selector.progress(t_s)
            cv2.rectangle(pic, (10, h - 20), (10 + int(150 * p), h - 10), (0, 200, 255), -1)
            cv2.rectangle(pic, (10, h - 20), (160, h - 10), (200, 200, 200), 1)
        if last_sel is not None and t_s - last_sel[1] < 1.0:
            put_label(pic, f"selected: {last_sel[0]}", (10, 50), 0.6 * th, (0, 220, 0), th)
    if drawn is not None:
        points_px, origin = drawn
        x0, y0 = points_px.min(axis=0)
        x1, y1 = points_px.max(axis=0)
        cv2.rectangle(pic, (int(x0), int(y0)), (int(x1), int(y1)), (255, 200, 0), th)
        if status == "ok":
            g = np.array([float(row["gaze_x"]), float(row["gaze_y"]), float(row["gaze_z"])])
            a, b = project_points(np.stack([origin, origin + 150.0 * g]), cam)
            if np.isfinite(a).all() and np.isfinite(b).all():
                cv2.arrowedLine(
                    pic,
                    tuple(int(round(v)) for v in a),
                    tuple(int(round(v)) for v in b),
                    (40, 40, 255),
                    2 * th,
                    cv2.LINE_AA,
                    tipLength=0.15,
                )
    put_label(pic, f"{row['frame']}  {status}", (10, 22), 0.5 * th, (255, 255, 255), th)
    return pic
