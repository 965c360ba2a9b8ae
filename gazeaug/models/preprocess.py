"""Input preprocessing, in one place for training and inference.

- Eye patches: RGB uint8 (N, H, W, 3) -> float32 (N, 3, H, W), scaled to [-1, 1]
  (``x / 127.5 - 1``). Colour is kept. **Neither eye is mirrored**: the left
  patch is the subject's left eye as the normalized camera sees it, and the
  model has one stream per eye (sharing weights).
- Head pose: (pitch, yaw) radians in the face-centre normalized frame, float32 (N, 2), as is.
- Target: gaze (pitch, yaw) radians in the face-centre normalized frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["prepare_inputs", "PREPROCESSING"]

#: Recorded in every checkpoint so a model is never fed differently prepared inputs.
PREPROCESSING = {"eyes": "rgb, x/127.5-1, NCHW, no mirroring", "head_pose": "pitch,yaw rad, face frame", "version": 1}


def prepare_inputs(
    left_eye: NDArray[np.uint8], right_eye: NDArray[np.uint8], head_pose: NDArray[np.floating[Any]]
) -> tuple[Any, Any, Any]:
    """Numpy arrays -> the three float32 torch tensors a model takes (on the CPU).

    Args:
        left_eye: (N, H, W, 3) uint8 RGB.
        right_eye: (N, H, W, 3) uint8 RGB.
        head_pose: (N, 2) float, radians.
    """
    from . import import_torch

    torch = import_torch()

    def eyes(a: NDArray[np.uint8]) -> Any:
        t = torch.from_numpy(np.ascontiguousarray(a)).permute(0, 3, 1, 2).float()
        return t.div_(127.5).sub_(1.0)

    return eyes(left_eye), eyes(right_eye), torch.from_numpy(np.asarray(head_pose, dtype=np.float32))
