"""ETH-XGaze's normalized release (``subjectXXXX.h5``), for training without augmentation.

Each file holds, per sample: ``face_patch`` (N, S, S, 3) uint8 **BGR**, the face
normalized by ETH-XGaze's code (focal 960 px for S = 448, scaled with S;
distance 300 mm; principal point (S/2, S/2)); ``face_gaze`` (N, 2) (pitch, yaw)
radians in that normalized frame (MPIIGaze convention); ``face_head_pose``,
``face_mat_norm``, ``frame_index``, ``cam_index`` and ``facial_landmarks``.

A face patch is itself an image taken by a (virtual) pinhole camera, the
normalized one, in which the gaze vector is ``pitchyaw_to_vector(face_gaze)``.
The reader yields each patch as such an image with that camera and gaze
direction, so the rest of the pipeline (MediaPipe, PnP, our eye
normalization at d_n, f_n) runs on it unchanged and the training set has the
same eye patches and labels as every other dataset. The test split has no
gaze labels and is refused.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from facemesh.conventions import pitchyaw_to_vector
from facemesh.types import CameraIntrinsics

from .base import DatasetError, GazeSample, H5ImageRef

__all__ = ["ETHXGazeNormalized", "looks_like_ethxgaze_normalized", "FOCAL_AT_448"]

#: The normalized camera's focal length for 448-pixel patches (ETH-XGaze's ``focal_norm``).
FOCAL_AT_448 = 960.0


def looks_like_ethxgaze_normalized(path: Path) -> bool:
    """True for a folder of ``subject*.h5`` files with a ``face_patch`` dataset."""
    import h5py

    files = sorted(path.glob("subject*.h5"))
    if not files:
        return False
    try:
        with h5py.File(files[0], "r") as f:
            return "face_patch" in f
    except OSError:
        return False


class ETHXGazeNormalized:
    """Reader of ETH-XGaze's normalized ``subjectXXXX.h5`` files (see the module docstring).

    Args:
        root: the folder holding the ``subject*.h5`` files (e.g. ``xgaze_224/train``).
    """

    name = "ethxgaze_normalized"

    def __init__(self, root: str | Path):
        import h5py

        self.root = Path(root)
        files = sorted(self.root.glob("subject*.h5"))
        if not files:
            raise DatasetError(f"{self.root}: no subject*.h5 files (not ETH-XGaze's normalized release)")
        self._files: list[tuple[Path, int, int]] = []
        for p in files:
            try:
                f = h5py.File(p, "r")
            except OSError as exc:
                raise DatasetError(f"{p}: not a readable HDF5 file ({exc})") from exc
            with f:
                for k in ("face_patch", "face_gaze"):
                    if k not in f:
                        raise DatasetError(f"{p}: missing dataset {k!r} (the test split has no gaze labels)")
                n, s = f["face_patch"].shape[0], f["face_patch"].shape[1]
                if f["face_patch"].shape[1:] != (s, s, 3) or f["face_gaze"].shape != (n, 2):
                    raise DatasetError(
                        f"{p}: face_patch {f['face_patch'].shape} / face_gaze {f['face_gaze'].shape}: "
                        "expected (N, S, S, 3) and (N, 2)"
                    )
            self._files.append((p, n, s))

    def __len__(self) -> int:
        return sum(n for _, n, _ in self._files)

    def __iter__(self) -> Iterator[GazeSample]:
        import h5py

        index = 0
        for p, n, size in self._files:
            f_px = FOCAL_AT_448 * size / 448.0
            camera = CameraIntrinsics(
                matrix=np.array([[f_px, 0.0, size / 2.0], [0.0, f_px, size / 2.0], [0.0, 0.0, 1.0]]),
                distortion=np.zeros(5),
                image_size=(size, size),
                source=f"{p} (ETH-XGaze normalized camera)",
            )
            with h5py.File(p, "r") as f:
                gaze = np.asarray(f["face_gaze"][()], dtype=np.float64)
                cams = f["cam_index"][()].ravel() if "cam_index" in f else np.full(n, -1)
            for i in range(n):
                if not np.isfinite(gaze[i]).all():
                    raise DatasetError(f"{p}, row {i}: face_gaze is not finite")
                yield GazeSample(
                    image_path=p,
                    camera=camera,
                    subject=p.stem,
                    source_index=index,
                    gaze_vector=pitchyaw_to_vector(gaze[i]),
                    image_ref=H5ImageRef(p, "face_patch", i, bgr=True),
                    extras={"row": f"{p.name}:{i}", "camera_id": int(cams[i])},
                )
                index += 1
