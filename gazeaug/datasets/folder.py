"""A plain folder of a user's own data: images plus a ``labels.csv`` (or ``labels.jsonl``).

Columns (CSV header, or keys of each JSON line):

``image``
    image path, relative to the folder (required).
``subject``
    subject id (default ``"s0"``).
``fx``, ``fy``, ``cx``, ``cy``
    intrinsics in pixels; or ``camera``: a calibration file (OpenCV
    FileStorage or MPIIFaceGaze ``Camera.mat``), relative to the folder.
``k1``, ``k2``, ``p1``, ``p2``, ``k3``
    distortion (optional, default 0).
``target_x``, ``target_y``, ``target_z``
    the 3D point looked at, mm, OpenCV camera frame (x right, y down, z forward);
    or ``gaze_x``, ``gaze_y``, ``gaze_z``: a gaze direction in the camera frame.
``width``, ``height``
    image size (optional; read from the image when absent).

Example ``labels.csv``::

    image,subject,fx,fy,cx,cy,target_x,target_y,target_z
    s01/0001.jpg,s01,960,960,640,360,-120.5,40.0,-10.0
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from facemesh.camera import load_camera
from facemesh.types import CameraIntrinsics, FaceMeshError

from .base import DatasetError, GazeSample, image_size, require_image

__all__ = ["FolderDataset", "LABEL_FILES", "write_labels_csv"]

#: The label files a folder dataset may have, in the order they are looked for.
LABEL_FILES = ("labels.csv", "labels.jsonl")

_TARGET = ("target_x", "target_y", "target_z")
_VECTOR = ("gaze_x", "gaze_y", "gaze_z")
_INTRINSICS = ("fx", "fy", "cx", "cy")
_DISTORTION = ("k1", "k2", "p1", "p2", "k3")


class FolderDataset:
    """Reader of the plain folder format (see the module docstring).

    Args:
        root: the folder holding ``labels.csv`` or ``labels.jsonl`` and the images.
    """

    name = "folder"

    def __init__(self, root: str | Path):
        self.root = Path(root)
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: not a folder")
        label_file = next((self.root / n for n in LABEL_FILES if (self.root / n).is_file()), None)
        if label_file is None:
            raise DatasetError(f"{self.root}: no {' or '.join(LABEL_FILES)} (not a folder dataset)")
        self.label_file = label_file
        self._rows: list[tuple[int, dict[str, Any]]] = []
        text = label_file.read_text(encoding="utf-8-sig", errors="replace")  # -sig: a BOM is not part of column 1
        if label_file.suffix == ".csv":
            reader = csv.DictReader(text.splitlines())
            header = reader.fieldnames or []
            self._check_columns(list(header), f"{label_file}, line 1")
            for lineno, row in enumerate(reader, start=2):
                if None in row or any(v is None for v in row.values()):
                    raise DatasetError(f"{label_file}, line {lineno}: expected {len(header)} columns")
                self._rows.append((lineno, dict(row)))
        else:
            for lineno, line in enumerate(text.splitlines(), start=1):
                if not line.strip():
                    continue
                try:
                    row = json.loads(line)
                except json.JSONDecodeError as exc:
                    raise DatasetError(f"{label_file}, line {lineno}: not valid JSON ({exc.msg})") from exc
                except RecursionError as exc:
                    raise DatasetError(f"{label_file}, line {lineno}: JSON nested too deeply to read") from exc
                if not isinstance(row, dict):
                    raise DatasetError(f"{label_file}, line {lineno}: expected a JSON object")
                self._check_columns(list(row), f"{label_file}, line {lineno}")
                self._rows.append((lineno, row))
        self._cameras: dict[str, CameraIntrinsics] = {}

    @staticmethod
    def _check_columns(columns: list[str], where: str) -> None:
        cols = set(columns)
        missing = []
        if "image" not in cols:
            missing.append("image")
        if not (set(_INTRINSICS) <= cols or "camera" in cols):
            missing.append("fx, fy, cx, cy (or camera)")
        if not (set(_TARGET) <= cols or set(_VECTOR) <= cols):
            missing.append("target_x, target_y, target_z (or gaze_x, gaze_y, gaze_z)")
        if missing:
            raise DatasetError(f"{where}: missing columns: {'; '.join(missing)}")

    def __len__(self) -> int:
        return len(self._rows)

    def _float(self, row: Mapping[str, Any], key: str, where: str, default: float | None = None) -> float:
        v = row.get(key, "")
        if v in ("", None):
            if default is None:
                raise DatasetError(f"{where}: empty value in column {key!r}")
            return default
        try:
            f = float(v)
        except (TypeError, ValueError) as exc:
            raise DatasetError(f"{where}: column {key!r}: not a number ({v!r})") from exc
        if not np.isfinite(f):
            raise DatasetError(f"{where}: column {key!r}: not finite ({v!r})")
        return f

    def _camera(self, row: Mapping[str, Any], image: Path, where: str) -> CameraIntrinsics:
        if "width" in row and "height" in row and row["width"] not in ("", None):
            size = (int(self._float(row, "width", where)), int(self._float(row, "height", where)))
        else:
            size = image_size(image)
        if row.get("camera") not in (None, ""):
            key = f"{row['camera']}@{size}"
            if key not in self._cameras:
                try:
                    self._cameras[key] = load_camera(self.root / str(row["camera"]), image_size=size)
                except FaceMeshError as exc:
                    raise DatasetError(f"{where}: {exc}") from exc
            return self._cameras[key]
        fx, fy, cx, cy = (self._float(row, k, where) for k in _INTRINSICS)
        dist = [self._float(row, k, where, 0.0) for k in _DISTORTION]
        try:
            return CameraIntrinsics(
                matrix=np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64),
                distortion=np.array(dist, dtype=np.float64),
                image_size=size,
                source=str(self.label_file),
            )
        except FaceMeshError as exc:
            raise DatasetError(f"{where}: {exc}") from exc

    def __iter__(self) -> Iterator[GazeSample]:
        for index, (lineno, row) in enumerate(self._rows):
            where = f"{self.label_file}, line {lineno}"
            image = self.root / str(row["image"])
            require_image(image, where)
            target = vector = None
            # the target columns when any of them holds a value or there are no gaze columns (so an
            # empty target cell is reported as such); the gaze direction columns otherwise
            if any(row.get(k) not in (None, "") for k in _TARGET) or not all(k in row for k in _VECTOR):
                target = [self._float(row, k, where) for k in _TARGET]
            else:
                vector = [self._float(row, k, where) for k in _VECTOR]
            try:
                yield GazeSample(
                    image_path=image,
                    camera=self._camera(row, image, where),
                    subject=str(row.get("subject") or "s0"),
                    source_index=index,
                    gaze_target_mm=None if target is None else np.asarray(target),
                    gaze_vector=None if vector is None else np.asarray(vector),
                    extras={"annotation": f"{self.label_file.name}:{lineno}"},
                )
            except DatasetError as exc:
                if str(exc).startswith(str(self.label_file)):
                    raise
                raise DatasetError(f"{where}: {exc}") from exc


def write_labels_csv(path: str | Path, rows: Sequence[Mapping[str, Any]]) -> None:
    """Write ``labels.csv`` rows (dicts with the columns above) atomically."""
    from facemesh.io import atomic_write

    if not rows:
        raise DatasetError("no rows to write")
    import io

    columns = list(rows[0])
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow(r)
    with atomic_write(path) as fh:
        fh.write(buf.getvalue().encode("utf-8"))
