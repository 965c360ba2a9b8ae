"""ETH-XGaze's normalized release (``subjectXXXX.h5``), for training without augmentation.

Each file holds, per sample (xucong-zhang/ETH-XGaze ``normalization_example.py``
writes them): ``face_patch`` (N, S, S, 3) uint8 **BGR**; ``face_gaze`` (N, 2)
(pitch, yaw) radians of the gaze vector ``g`` = gaze target - face centre in
the normalized camera's OpenCV frame, ``pitch = asin(-g_y)``, ``yaw =
atan2(-g_x, -g_z)`` for unit ``g`` (the MPIIGaze convention, so ``g =
pitchyaw_to_vector(face_gaze)``); ``face_head_pose``, ``face_mat_norm``,
``frame_index``, ``cam_index`` and ``facial_landmarks``.

The normalized camera: ETH-XGaze's code makes 448 x 448 patches with focal
960 px at 300 mm and principal point (224, 224) (pixel centres at integers).
Other sizes are that patch resized with ``cv2.resize(..., INTER_AREA)`` (the
code's own recipe for the 224 release), which maps 448-pixel position ``u``
to ``(u + 0.5) S / 448 - 0.5``: focal ``960 S / 448`` and principal point
``(224.5 S / 448 - 0.5)`` on both axes, 111.75 (not 112) for S = 224
(:func:`normalized_intrinsics`). ``resized_from_448=False`` reads patches
rendered at their own size (principal point S / 2) instead.

A face patch is itself an image taken by a (virtual) pinhole camera, the
normalized one, in which the gaze vector is ``pitchyaw_to_vector(face_gaze)``.
The reader yields each patch as such an image with that camera and gaze
direction, so the rest of the pipeline (MediaPipe, PnP, our eye
normalization at d_n, f_n) runs on it unchanged and the training set has the
same eye patches and labels as every other dataset. The test split has no
gaze labels (they are kept for ETH-XGaze's leaderboard) and is refused.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from facemesh.conventions import pitchyaw_to_vector
from facemesh.types import CameraIntrinsics

from .base import DatasetError, GazeSample, H5ImageRef

__all__ = [
    "ETHXGazeNormalized",
    "looks_like_ethxgaze_normalized",
    "normalized_intrinsics",
    "FOCAL_AT_448",
    "ETH_PATCH_SIZE",
]

#: The normalized camera's focal length for 448-pixel patches (ETH-XGaze's ``focal_norm``).
FOCAL_AT_448 = 960.0
#: The size ETH-XGaze's code normalizes faces at (its ``roiSize``); other sizes are resized from it.
ETH_PATCH_SIZE = 448


def normalized_intrinsics(size: int, resized_from_448: bool = True) -> tuple[float, float]:
    """(focal, principal point) in pixels of an S x S ETH-XGaze face patch's virtual camera.

    Args:
        size: S, the patch's side in pixels.
        resized_from_448: the patch is ETH-XGaze's 448 patch (focal 960, principal point
            224) resized with ``cv2.INTER_AREA``, which maps position ``u`` to
            ``(u + 0.5) S / 448 - 0.5`` (pixel centres at integers); ``False``: rendered at
            size S directly, principal point ``S / 2``.

    Returns:
        ``(f, c)``: focal ``960 S / 448``; ``c`` on both axes.
    """
    scale = size / ETH_PATCH_SIZE
    centre = (ETH_PATCH_SIZE / 2 + 0.5) * scale - 0.5 if resized_from_448 else size / 2.0
    return FOCAL_AT_448 * scale, centre


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
        resized_from_448: patches of another size than 448 are ETH's 448 patches resized with
            ``cv2.INTER_AREA`` (default, the released 224 files); ``False``: rendered at their size.
    """

    name = "ethxgaze_normalized"

    def __init__(self, root: str | Path, resized_from_448: bool = True):
        from ..io_h5 import open_h5_for_reading

        self.root = Path(root)
        self.resized_from_448 = bool(resized_from_448)
        files = sorted(self.root.glob("subject*.h5"))
        if not files:
            raise DatasetError(f"{self.root}: no subject*.h5 files (not ETH-XGaze's normalized release)")
        self._files: list[tuple[Path, int, int]] = []
        for p in files:
            with open_h5_for_reading(p, DatasetError) as f:
                if "left_eye_patch" in f or "right_eye_patch" in f:
                    raise DatasetError(
                        f"{p}: has left_eye_patch / right_eye_patch, so it was made by "
                        "X-Shi/Data-Normalization-Gaze-Estimation's nor_eye_face.py (focal 960 px at 600 mm "
                        "whatever the patch size), not ETH-XGaze's release (focal 960 px at 448 px, 300 mm): "
                        "its patches' camera is not the one this reader gives; not supported"
                    )
                for k in ("face_patch", "face_gaze"):
                    if k not in f:
                        raise DatasetError(
                            f"{p}: missing dataset {k!r} (the test split has no gaze labels: ETH-XGaze keeps "
                            "them for its leaderboard)"
                        )
                shape = tuple(f["face_patch"].shape)
                n, s = (shape[0], shape[1]) if len(shape) == 4 else (0, 0)
                if len(shape) != 4 or shape[1:] != (s, s, 3) or s < 1 or f["face_gaze"].shape != (n, 2):
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
            f_px, c_px = normalized_intrinsics(size, self.resized_from_448)
            camera = CameraIntrinsics(
                matrix=np.array([[f_px, 0.0, c_px], [0.0, f_px, c_px], [0.0, 0.0, 1.0]]),
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
