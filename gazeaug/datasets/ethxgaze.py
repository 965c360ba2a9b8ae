"""ETH-XGaze, raw release: per-subject annotation CSVs with the per-camera calibration files.

Layout (as distributed)::

    ROOT/calibration/cam_calibration/cam00.xml ... cam17.xml   (OpenCV FileStorage:
        image_Width, image_Height, Camera_Matrix, Distortion_Coefficients, ...)
    ROOT/data/train/subject0000/frame0000/cam00.JPG ...
    ROOT/data/annotation_train/subject0000.csv

Each annotation line has 149 comma-separated columns: 0 frame folder
(``frameXXXX``), 1 image name (``camYY.JPG``), 2-3 the gaze point on the
screen, 4-6 the 3D gaze target (mm, that camera's frame), 7-9 head rotation
(Rodrigues) and 10-12 translation (mm) of ETH-XGaze's face model, 13-148 68
landmarks (x, y, pixels). Cameras 3, 6 and 13 were mounted upside down: their
images are turned by 180 deg before use, as the dataset's own normalization
code does, and the labels refer to the turned image. The split (``train`` or
``test``) is chosen with ``split``.
"""

from __future__ import annotations

import csv
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from facemesh.camera import load_camera
from facemesh.types import CameraIntrinsics, FaceMeshError

from .base import DatasetError, GazeSample, parse_numbers, require_image

__all__ = ["ETHXGaze", "ROTATED_CAMERAS"]

#: Cameras whose images are stored upside down.
ROTATED_CAMERAS = (3, 6, 13)
_COLUMNS = 149


class ETHXGaze:
    """Reader of the raw ETH-XGaze layout (see the module docstring).

    Args:
        root: the dataset's root folder.
        split: ``"train"`` (default) or ``"test"`` (annotations in ``annotation_<split>``).
    """

    name = "ethxgaze"

    def __init__(self, root: str | Path, split: str = "train"):
        self.root = Path(root)
        ann_dir = self.root / "data" / f"annotation_{split}"
        if not ann_dir.is_dir():
            raise DatasetError(f"{self.root}: no data/annotation_{split}/ folder (not an ETH-XGaze root)")
        self.split = split
        self._rows: list[tuple[Path, int, list[str]]] = []
        for path in sorted(ann_dir.glob("subject*.csv")):
            with path.open(newline="", encoding="utf-8", errors="replace") as fh:
                for lineno, cols in enumerate(csv.reader(fh), start=1):
                    if not cols:
                        continue
                    if len(cols) != _COLUMNS:
                        raise DatasetError(f"{path}, line {lineno}: expected {_COLUMNS} columns, found {len(cols)}")
                    self._rows.append((path, lineno, cols))
        if not self._rows:
            raise DatasetError(f"{ann_dir}: no subjectXXXX.csv annotations")
        self._cameras: dict[int, CameraIntrinsics] = {}

    def __len__(self) -> int:
        return len(self._rows)

    def _camera(self, cam_id: int) -> CameraIntrinsics:
        cam = self._cameras.get(cam_id)
        if cam is None:
            path = self.root / "calibration" / "cam_calibration" / f"cam{cam_id:02d}.xml"
            try:
                cam = load_camera(path)
            except FaceMeshError as exc:
                raise DatasetError(str(exc)) from exc
            self._cameras[cam_id] = cam
        return cam

    def __iter__(self) -> Iterator[GazeSample]:
        for index, (path, lineno, cols) in enumerate(self._rows):
            where = f"{path}, line {lineno}"
            frame, image_name = cols[0], cols[1]
            try:
                cam_id = int(Path(image_name).stem[3:5])
            except ValueError as exc:
                raise DatasetError(f"{where}: image name {image_name!r} is not camXX.JPG") from exc
            values = parse_numbers(cols[2:], where)
            subject = path.stem
            image = self.root / "data" / self.split / subject / frame / image_name
            require_image(image, where)
            import cv2

            yield GazeSample(
                image_path=image,
                camera=self._camera(cam_id),
                subject=subject,
                source_index=index,
                gaze_target_mm=values[2:5],
                head_rotation=np.asarray(cv2.Rodrigues(values[5:8])[0], dtype=np.float64),
                head_translation_mm=values[8:11],
                landmarks_px=values[11:].reshape(68, 2),
                rotate_180=cam_id in ROTATED_CAMERAS,
                extras={"annotation": f"{path.name}:{lineno}", "camera_id": cam_id, "frame": frame},
            )
