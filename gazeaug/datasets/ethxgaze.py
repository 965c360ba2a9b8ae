"""ETH-XGaze, raw release: per-subject annotation CSVs with the per-camera calibration files.

Layout (as distributed)::

    ROOT/calibration/cam_calibration/cam00.xml ... cam17.xml   (OpenCV FileStorage:
        image_Width, image_Height, Camera_Matrix, Distortion_Coefficients, ...)
    ROOT/data/train/subject0000/frame0000/cam00.JPG ...
    ROOT/data/annotation_train/subject0000.csv

Each training annotation line has 149 comma-separated columns: 0 frame folder
(``frameXXXX``), 1 image name (``camYY.JPG``), 2-3 the gaze point on the
screen, 4-6 the 3D gaze target (mm, that camera's OpenCV frame: x right, y
down, z forward), 7-9 head rotation (Rodrigues vector, radians; ETH-XGaze's
face model frame -> camera) and 10-12 translation (mm), 13-148 68 landmarks
(x, y, pixels of the turned image, see below).

Only the training split is read. ETH-XGaze keeps the test split's gaze labels
for its leaderboard: its test annotations have 144 columns (frame, image, head
pose, landmarks; no gaze) and are refused with that reason.

Cameras 3, 6 and 13 were mounted upside down. ETH-XGaze's own code turns their
images with ``cv2.warpAffine(image, cv2.getRotationMatrix2D((w / 2, h / 2),
180, 1), (w, h))`` and uses the calibration's camera matrix and the labels
with the turned image unchanged. That warp is the exact 180 deg flip moved one
pixel right and down: its pixel (x, y) is the flip's (x - 1, y - 1). The
reader turns the image exactly (:attr:`GazeSample.rotate_180`) and moves the
principal point and the landmarks by :data:`ETH_TURN_OFFSET_PX` (-1 px), so
image, camera and labels are ETH-XGaze's to the pixel (docs/datasets.md lists
the reference code and lines).
"""

from __future__ import annotations

import csv
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from facemesh.camera import load_camera
from facemesh.types import CameraIntrinsics, FaceMeshError

from .base import DatasetError, GazeSample, parse_numbers, require_image

__all__ = ["ETHXGaze", "ROTATED_CAMERAS", "ETH_TURN_OFFSET_PX"]

#: Cameras whose images are stored upside down.
ROTATED_CAMERAS = (3, 6, 13)
#: Pixel offset from ETH-XGaze's turned image to the exact flip: ETH's ``warpAffine`` with
#: ``getRotationMatrix2D((w / 2, h / 2), 180, 1)`` maps source pixel (u, v) to (w - u, h - v),
#: the exact flip to (w - 1 - u, h - 1 - v); so a point at ETH's (x, y) is at (x - 1, y - 1) here.
ETH_TURN_OFFSET_PX = -1.0
_COLUMNS = 149
_TEST_COLUMNS = 144  # frame, image, head rotation (3), translation (3), 68 landmarks: no gaze
_TEST_LABELS = (
    "ETH-XGaze releases no gaze labels for its test split (they are kept for its leaderboard; "
    "xucong-zhang/ETH-XGaze README, FAQ 'Where are the test set labels?'), so it cannot make training "
    "or evaluation samples"
)


class ETHXGaze:
    """Reader of the raw ETH-XGaze layout's training split (see the module docstring).

    Args:
        root: the dataset's root folder.
        split: ``"train"``, the only split with gaze labels; ``"test"`` is refused with the reason.
    """

    name = "ethxgaze"

    def __init__(self, root: str | Path, split: str = "train"):
        self.root = Path(root)
        if split == "test":
            raise DatasetError(f"{self.root}: split 'test': the test split has no gaze labels. {_TEST_LABELS}")
        if split != "train":
            raise DatasetError(f"{self.root}: split: expected 'train', got {split!r}")
        ann_dir = self.root / "data" / "annotation_train"
        if not ann_dir.is_dir():
            if (self.root / "data" / "annotation_test").is_dir():
                raise DatasetError(
                    f"{self.root}: only the test split is here (data/annotation_test/, no data/annotation_train/): "
                    f"it has no gaze labels. {_TEST_LABELS}"
                )
            raise DatasetError(f"{self.root}: no data/annotation_train/ folder (not an ETH-XGaze root)")
        self.split = split
        self._rows: list[tuple[Path, int, list[str]]] = []
        for path in sorted(ann_dir.glob("subject*.csv")):
            with path.open(newline="", encoding="utf-8", errors="replace") as fh:
                for lineno, cols in enumerate(csv.reader(fh), start=1):
                    if not cols:
                        continue
                    if len(cols) != _COLUMNS:
                        hint = (
                            f" (the test split's layout: head pose and landmarks, no gaze target; {_TEST_LABELS})"
                            if len(cols) == _TEST_COLUMNS
                            else ""
                        )
                        raise DatasetError(
                            f"{path}, line {lineno}: expected {_COLUMNS} columns, found {len(cols)}{hint}"
                        )
                    self._rows.append((path, lineno, cols))
        if not self._rows:
            raise DatasetError(f"{ann_dir}: no subjectXXXX.csv annotations")
        self._cameras: dict[int, CameraIntrinsics] = {}

    def __len__(self) -> int:
        return len(self._rows)

    def _camera(self, cam_id: int) -> CameraIntrinsics:
        """The calibration of camera ``cam_id``, for the image as this reader yields it.

        For the turned cameras the principal point moves by :data:`ETH_TURN_OFFSET_PX`: the
        calibration describes ETH-XGaze's turned image, the sample is the exact flip.
        """
        cam = self._cameras.get(cam_id)
        if cam is None:
            path = self.root / "calibration" / "cam_calibration" / f"cam{cam_id:02d}.xml"
            try:
                cam = load_camera(path)
            except FaceMeshError as exc:
                raise DatasetError(str(exc)) from exc
            if cam_id in ROTATED_CAMERAS:
                k = np.array(cam.matrix, dtype=np.float64)
                k[:2, 2] += ETH_TURN_OFFSET_PX
                cam = CameraIntrinsics(
                    matrix=k,
                    distortion=cam.distortion,
                    image_size=cam.image_size,
                    source=f"{path} (principal point moved {ETH_TURN_OFFSET_PX:+g} px: image turned exactly)",
                )
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

            turned = cam_id in ROTATED_CAMERAS
            landmarks = values[11:].reshape(68, 2) + (ETH_TURN_OFFSET_PX if turned else 0.0)
            yield GazeSample(
                image_path=image,
                camera=self._camera(cam_id),
                subject=subject,
                source_index=index,
                gaze_target_mm=values[2:5],
                head_rotation=np.asarray(cv2.Rodrigues(values[5:8])[0], dtype=np.float64),
                head_translation_mm=values[8:11],
                landmarks_px=landmarks,
                rotate_180=turned,
                extras={"annotation": f"{path.name}:{lineno}", "camera_id": cam_id, "frame": frame},
            )
