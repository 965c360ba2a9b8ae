"""Input preprocessing, in one place for training and inference.

- Eye patches: RGB uint8 (N, H, W, 3) -> float32 (N, 3, H, W), scaled to [-1, 1]
  (``x / 127.5 - 1``). **Neither eye is mirrored**: the left patch is the
  subject's left eye as the normalized camera sees it, and the model has one
  stream per eye (sharing weights). The *input mode* says what happens before
  the scaling:

  - ``"rgb"`` (the default, and every model made before input modes existed):
    colour is kept.
  - ``"grey_equalized"``: as MPIIGaze's patches: grey (ITU-R BT.601 luma, in
    OpenCV's fixed point, rounded to integer grey levels), then histogram
    equalization per image and per eye (OpenCV's ``equalizeHist``: the
    cumulative histogram as a look-up table; an image of one grey level is kept
    as is), replicated to 3 channels so the architecture stays the same.
    Equal to ``cv2.equalizeHist(cv2.cvtColor(x, cv2.COLOR_RGB2GRAY))`` on uint8
    patches (a test checks it).

- Head pose: (pitch, yaw) radians in the face-centre normalized frame, float32 (N, 2), as is.
- Target: gaze (pitch, yaw) radians in the face-centre normalized frame.

The input mode is an option of the *model*, not of the data: it is recorded in
every model file's ``preprocessing`` dict (key ``input``; absent: ``"rgb"``),
:func:`gazeaug.train.load_model` attaches it to the model it builds
(:func:`set_input_mode`), and :func:`gazeaug.train.predict_arrays` (hence
``evaluate`` and ``predict``) reads it back (:func:`input_mode_of`). Training
applies the same :func:`scale_eyes` on the device after its augmentation.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import GazeAugError

__all__ = [
    "prepare_inputs",
    "scale_eyes",
    "equalize_grey",
    "eyes_to_float",
    "preprocessing_record",
    "input_mode_from_record",
    "set_input_mode",
    "input_mode_of",
    "check_input_mode",
    "PREPROCESSING",
    "INPUT_MODES",
]

#: The model input modes (see the module docstring).
INPUT_MODES = ("rgb", "grey_equalized")

#: Recorded in every checkpoint so a model is never fed differently prepared inputs (the ``rgb`` mode's
#: record; :func:`preprocessing_record` gives every mode's). Version 1: a reader that knows only this
#: version uses ``rgb``; grey-equalized models are written as version 2, which such a reader refuses
#: instead of feeding them colour.
PREPROCESSING = {
    "eyes": "rgb, x/127.5-1, NCHW, no mirroring",
    "head_pose": "pitch,yaw rad, face frame",
    "version": 1,
    "input": "rgb",
}

_RECORDS = {
    "rgb": PREPROCESSING,
    "grey_equalized": {
        "eyes": "grey (BT.601, rounded) + histogram equalization per image (cv2.equalizeHist), "
        "replicated to 3 channels, x/127.5-1, NCHW, no mirroring",
        "head_pose": "pitch,yaw rad, face frame",
        "version": 2,
        "input": "grey_equalized",
    },
}

#: The attribute of a model (``torch.nn.Module``) that holds its input mode.
_ATTR = "gazeaug_input_mode"
#: OpenCV's RGB -> grey weights for 8-bit images, in 15-bit fixed point: (0.299, 0.587, 0.114) * 2**15.
_GREY_WEIGHTS = (9798.0, 19235.0, 3735.0)


def check_input_mode(mode: Any) -> str:
    """``mode`` if it is one of :data:`INPUT_MODES`; else a GazeAugError."""
    if not (isinstance(mode, str) and mode in INPUT_MODES):
        raise GazeAugError(f"input mode: expected one of {', '.join(INPUT_MODES)}, got {mode!r}")
    return mode


def preprocessing_record(input_mode: str = "rgb") -> dict[str, Any]:
    """The ``preprocessing`` dict a model file records for ``input_mode`` (a copy)."""
    return dict(_RECORDS[check_input_mode(input_mode)])


def input_mode_from_record(record: Any) -> str:
    """The input mode a model file's ``preprocessing`` dict states.

    Version 1 without an ``input`` key (every model made before input modes) is ``rgb``.

    Raises:
        GazeAugError: not a dict, an unknown version, or a version and ``input`` that disagree.
    """
    if not isinstance(record, dict) or record.get("version") not in (1, 2):
        raise GazeAugError(f"made with another input preprocessing ({record})")
    mode = record.get("input", "rgb")
    if mode not in INPUT_MODES or record["version"] != _RECORDS[mode]["version"]:
        raise GazeAugError(f"made with another input preprocessing ({record})")
    return str(mode)


def set_input_mode(model: Any, input_mode: str) -> Any:
    """Attach ``input_mode`` to ``model`` (for :func:`input_mode_of`); returns the model."""
    setattr(model, _ATTR, check_input_mode(input_mode))
    return model


def input_mode_of(model: Any) -> str:
    """The input mode attached to ``model`` by :func:`set_input_mode`; ``rgb`` when none is."""
    return str(getattr(model, _ATTR, "rgb"))


def eyes_to_float(eyes: Any) -> Any:
    """uint8 torch tensor (N, H, W, 3) RGB, any device -> float32 (N, 3, H, W) in [0, 255] grey levels, same device.

    The result keeps the patches' memory order (channels last), on which the model runs fastest
    (about 1.5 x faster training on the CPU than on contiguous NCHW).
    """
    return eyes.permute(0, 3, 1, 2).float()


def equalize_grey(grey: Any) -> Any:
    """Histogram equalization per image, as OpenCV's ``equalizeHist``.

    Args:
        grey: float32 torch tensor (N, H, W) of integer grey levels 0..255, any device.

    Returns:
        float32 (N, H, W), integer grey levels 0..255, same device: level ``v`` of an image
        becomes ``round((cdf(v) - cdf(vmin)) * 255 / (H*W - cdf(vmin)))``, with ``cdf`` the image's
        cumulative histogram and ``vmin`` its darkest level (rounded half to even); an image of
        one level is returned as is.
    """
    from . import import_torch

    torch = import_torch()
    n = grey.shape[0]
    q = grey.reshape(n, -1).long()
    total = q.shape[1]
    offsets = torch.arange(n, device=q.device).mul_(256).unsqueeze(1)
    flat = (q + offsets).reshape(-1)
    if flat.device.type == "cpu":  # bincount is the fastest there; on a GPU it waits to size its output
        hist = torch.bincount(flat, minlength=n * 256).view(n, 256)
    else:
        hist = torch.zeros(n * 256, dtype=torch.int64, device=flat.device)
        hist = hist.index_add_(0, flat, torch.ones_like(flat)).view(n, 256)
    cdf = hist.cumsum(1)
    hmin = hist.gather(1, q.amin(1, keepdim=True))  # (N, 1): pixels at the darkest level
    denom = total - hmin
    scale = 255.0 / denom.clamp(min=1).float()  # float32, as OpenCV's
    lut = torch.round((cdf - hmin).float() * scale).clamp_(0, 255)
    out = lut.gather(1, q)
    out = torch.where(denom == 0, q.float(), out)  # one grey level: kept
    return out.view(grey.shape)


def scale_eyes(eyes: Any, input_mode: str = "rgb") -> Any:
    """Eye patches -> model input, on their device.

    Args:
        eyes: float32 torch tensor (N, 3, H, W), RGB, in [0, 255] grey levels (not necessarily
            integers: training scales augmented patches), any device.
        input_mode: ``rgb`` or ``grey_equalized`` (see the module docstring).

    Returns:
        float32 (N, 3, H, W) in [-1, 1], same device (``rgb``: ``eyes`` itself, scaled in place;
        ``grey_equalized``: in channels-last memory order).
    """
    mode = check_input_mode(input_mode)
    if mode == "grey_equalized":
        from . import import_torch

        torch = import_torch()
        r, g, b = _GREY_WEIGHTS
        luma = eyes[:, 0] * r + eyes[:, 1] * g + eyes[:, 2] * b
        grey = luma.div_(32768.0).add_(0.5).floor_().clamp_(0, 255)  # OpenCV: (sum + 2**14) >> 15
        eyes = equalize_grey(grey).unsqueeze(1).expand(-1, 3, -1, -1)
        eyes = eyes.contiguous(memory_format=torch.channels_last)  # as rgb's: the model runs fastest on it
    return eyes.div_(127.5).sub_(1.0)


def prepare_inputs(
    left_eye: NDArray[np.uint8],
    right_eye: NDArray[np.uint8],
    head_pose: NDArray[np.floating[Any]],
    input_mode: str = "rgb",
    device: Any = None,
    face: NDArray[np.uint8] | None = None,
) -> tuple[Any, ...]:
    """Numpy arrays -> the float32 torch tensors a model takes (three, or four with a face patch).

    Args:
        left_eye: (N, H, W, 3) uint8 RGB.
        right_eye: (N, H, W, 3) uint8 RGB.
        head_pose: (N, 2) float, radians.
        input_mode: the model's input mode (:func:`input_mode_of`; ``rgb`` for every model made
            before input modes).
        device: where the tensors go (default: the CPU); the patches travel as uint8 and are
            converted there.
        face: (N, Hf, Wf, 3) uint8 RGB normalized face patches, for a model that reads them
            (:func:`gazeaug.models.uses_face`); prepared as the eyes are (the same input mode).

    Returns:
        left, right: float32 (N, 3, H, W) in [-1, 1]; head pose: float32 (N, 2) radians; and, when
        ``face`` is given, the face: float32 (N, 3, Hf, Wf) in [-1, 1].
    """
    from . import import_torch

    torch = import_torch()

    def eyes(a: NDArray[np.uint8]) -> Any:
        t = torch.from_numpy(np.ascontiguousarray(a))
        return scale_eyes(eyes_to_float(t if device is None else t.to(device)), input_mode)

    head = torch.from_numpy(np.asarray(head_pose, dtype=np.float32))
    out = (eyes(left_eye), eyes(right_eye), head if device is None else head.to(device))
    return out if face is None else (*out, eyes(face))
