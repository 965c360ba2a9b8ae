"""GazeCapture with the publicly released supplementary HDF5 (FAZE, Park et al. 2019).

GazeCapture's own JSON files carry no intrinsics, head pose or 3D gaze
target; the supplementary file (``GazeCapture_supplementary.h5``, made by
swook/faze_preprocess) adds them. It holds one group per subject (``00002``,
...) with, per frame:

``file_name`` (N,) bytes
    the image path relative to the dataset root (``00002/frames/00000.jpg``).
``camera_parameters`` (N, 4)
    fx, fy, cx, cy in pixels (OpenCV: pixel centres at integers).
``distortion_parameters`` (N, 4)
    OpenCV k1, k2, p1, p2 (no k3). The reader pads k3 = 0, as the paper
    author's reader does (cedriclmenard/fastgaze ``gazecapture.py`` line 67:
    one zero appended before ``cv2.initUndistortRectifyMap``, which accepts
    4, 5, 8, 12 or 14 values, so the released rows hold 4). Rows of 5 (k1,
    k2, p1, p2, k3) are read as they are.
``head_pose`` (N, 6)
    rotation (Rodrigues vector, radians) then translation (mm) of FAZE's
    face model (``sfm_face_coordinates.npy``): head frame -> OpenCV camera
    frame (x right, y down, z forward), ``p_cam = R p_head + t``.
``3d_gaze_target`` (N, 3)
    the point looked at, mm, OpenCV camera frame.

Image sizes are read from the image headers. docs/datasets.md lists the
reference code this was checked against.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from facemesh.types import CameraIntrinsics, FaceMeshError

from .base import DatasetError, GazeSample, image_size, require_image

__all__ = ["GazeCapture", "SUPPLEMENTARY_NAME", "REQUIRED"]

#: The supplementary file's usual name, looked for in the dataset root.
SUPPLEMENTARY_NAME = "GazeCapture_supplementary.h5"
#: Datasets each subject group must have, with the per-row shapes each may have.
REQUIRED: dict[str, tuple[tuple[int, ...], ...]] = {
    "file_name": ((),),
    "camera_parameters": ((4,),),
    "distortion_parameters": ((4,), (5,)),  # k1, k2, p1, p2 as released; k3 too if given
    "head_pose": ((6,),),
    "3d_gaze_target": ((3,),),
}


def _shape_text(n: int, row_shape: tuple[int, ...]) -> str:
    """``(n, *row_shape)`` as NumPy prints shapes; ``N`` when the row count is unknown."""
    dims = [str(n) if n >= 0 else "N", *map(str, row_shape)]
    return f"({dims[0]},)" if len(dims) == 1 else f"({', '.join(dims)})"


class GazeCapture:
    """Reader of GazeCapture plus its supplementary HDF5.

    Args:
        root: the GazeCapture folder (subject folders ``00002/`` ... with ``frames/``).
        supplementary: the supplementary .h5 (default: ``root/GazeCapture_supplementary.h5``).
    """

    name = "gazecapture"

    def __init__(self, root: str | Path, supplementary: str | Path | None = None):
        from ..io_h5 import open_h5_for_reading

        self.root = Path(root)
        self.supplementary = Path(supplementary) if supplementary else self.root / SUPPLEMENTARY_NAME
        if not self.supplementary.is_file():
            raise DatasetError(f"{self.supplementary}: GazeCapture's supplementary HDF5 not found")
        self._data: list[tuple[str, dict[str, Any]]] = []
        with open_h5_for_reading(self.supplementary, DatasetError) as f:
            for subject in sorted(f.keys()):
                g = f[subject]
                where = f"{self.supplementary}, group {subject!r}"
                missing = [k for k in REQUIRED if k not in g]
                if missing:
                    raise DatasetError(f"{where}: missing datasets {missing}")
                arrays = {k: np.asarray(g[k][()]) for k in REQUIRED}
                n = len(arrays["file_name"]) if arrays["file_name"].ndim == 1 else -1
                for k, shapes in REQUIRED.items():
                    a = arrays[k]
                    if a.ndim < 1 or len(a) != n or a.shape[1:] not in shapes:
                        expected = " or ".join(_shape_text(n, shape) for shape in shapes)
                        raise DatasetError(f"{where}: {k} has shape {a.shape}, expected {expected}")
                self._data.append((subject, arrays))
        if not self._data:
            raise DatasetError(f"{self.supplementary}: no subject groups")

    def __len__(self) -> int:
        return sum(len(a["file_name"]) for _, a in self._data)

    def __iter__(self) -> Iterator[GazeSample]:
        import cv2

        index = 0
        for subject, a in self._data:
            for i in range(len(a["file_name"])):
                where = f"{self.supplementary}, group {subject!r}, row {i}"
                name = a["file_name"][i]
                name = name.decode("utf-8") if isinstance(name, bytes) else str(name)
                image = self.root / name
                require_image(image, where)
                fx, fy, cx, cy = (float(v) for v in a["camera_parameters"][i])
                dist = np.asarray(a["distortion_parameters"][i], dtype=np.float64)
                if dist.size == 4:
                    dist = np.append(dist, 0.0)  # k3 = 0, as the paper author's reader pads it
                try:
                    camera = CameraIntrinsics(
                        matrix=np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64),
                        distortion=dist,
                        image_size=image_size(image),
                        source=str(self.supplementary),
                    )
                except FaceMeshError as exc:
                    raise DatasetError(f"{where}: {exc}") from exc
                hp = np.asarray(a["head_pose"][i], dtype=np.float64)
                if not np.isfinite(hp).all():
                    raise DatasetError(f"{where}: head_pose is not finite")
                try:
                    yield GazeSample(
                        image_path=image,
                        camera=camera,
                        subject=subject,
                        source_index=index,
                        gaze_target_mm=np.asarray(a["3d_gaze_target"][i], dtype=np.float64),
                        head_rotation=np.asarray(cv2.Rodrigues(hp[:3])[0], dtype=np.float64),
                        head_translation_mm=hp[3:],
                        extras={"row": f"{subject}:{i}"},
                    )
                except DatasetError as exc:
                    raise DatasetError(f"{where}: {exc}") from exc
                index += 1
