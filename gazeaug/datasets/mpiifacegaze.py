"""MPIIFaceGaze, raw release: ``pXX/pXX.txt`` annotations with ``pXX/Calibration/Camera.mat``.

Each annotation line has 28 whitespace-separated columns (the dataset's
``readme.txt``): 1 image path (relative to ``pXX/``), 2-3 gaze point on the
screen (px), 4-15 six landmarks (x, y; four eye corners then two mouth
corners), 16-18 head rotation (Rodrigues) and 19-21 translation (mm) of the
6-point model, 22-24 face centre ``fc`` (mm, camera frame), 25-27 gaze target
``gt`` (mm, camera frame), 28 which eye the evaluation subset used.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from facemesh.camera import load_camera
from facemesh.types import CameraIntrinsics, FaceMeshError

from .base import DatasetError, GazeSample, image_size, parse_numbers, require_image

__all__ = ["MPIIFaceGaze"]

_COLUMNS = 28


class MPIIFaceGaze:
    """Reader of the raw MPIIFaceGaze layout.

    Args:
        root: the folder holding ``p00`` ... ``p14`` (or any subset).
        subjects: only these subjects (default: every ``pXX`` folder with a ``pXX.txt``).
    """

    name = "mpiifacegaze"

    def __init__(self, root: str | Path, subjects: list[str] | None = None):
        self.root = Path(root)
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: not a folder")
        found = sorted(p.name for p in self.root.iterdir() if p.is_dir() and (p / f"{p.name}.txt").is_file())
        if subjects is not None:
            missing = sorted(set(subjects) - set(found))
            if missing:
                raise DatasetError(f"{self.root}: no annotations for subjects {missing}")
            found = [s for s in found if s in subjects]
        if not found:
            raise DatasetError(f"{self.root}: no pXX/pXX.txt annotation files (not an MPIIFaceGaze folder)")
        self.subjects = found
        self._rows: list[tuple[str, int, list[str]]] = []
        for s in found:
            path = self.root / s / f"{s}.txt"
            for lineno, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
                if not line.strip():
                    continue
                cols = line.split()
                if len(cols) != _COLUMNS:
                    raise DatasetError(f"{path}, line {lineno}: expected {_COLUMNS} columns, found {len(cols)}")
                self._rows.append((s, lineno, cols))
        self._cameras: dict[str, CameraIntrinsics] = {}

    def __len__(self) -> int:
        return len(self._rows)

    def _camera(self, subject: str, first_image: Path) -> CameraIntrinsics:
        cam = self._cameras.get(subject)
        if cam is None:
            path = self.root / subject / "Calibration" / "Camera.mat"
            if not path.is_file():
                raise DatasetError(f"{path}: calibration file not found")
            try:
                cam = load_camera(path, image_size=image_size(first_image))
            except FaceMeshError as exc:
                raise DatasetError(str(exc)) from exc
            self._cameras[subject] = cam
        return cam

    def __iter__(self) -> Iterator[GazeSample]:
        for index, (subject, lineno, cols) in enumerate(self._rows):
            ann = self.root / subject / f"{subject}.txt"
            values = parse_numbers(cols[1:27], f"{ann}, line {lineno}")
            image = self.root / subject / cols[0]
            require_image(image, f"{ann}, line {lineno}")
            import cv2

            landmarks = values[2:14].reshape(6, 2)
            rvec, tvec = values[14:17], values[17:20]
            yield GazeSample(
                image_path=image,
                camera=self._camera(subject, image),
                subject=subject,
                source_index=index,
                gaze_target_mm=values[23:26],
                gaze_origin_mm=values[20:23],
                head_rotation=np.asarray(cv2.Rodrigues(rvec)[0], dtype=np.float64),
                head_translation_mm=tvec,
                landmarks_px=landmarks,
                extras={"annotation": f"{ann.name}:{lineno}", "screen_px": values[0:2].tolist(), "eval_eye": cols[27]},
            )
