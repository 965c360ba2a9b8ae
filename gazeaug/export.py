"""ONNX export of a trained model (inputs ``left_eye``, ``right_eye``, ``head_pose`` [, ``face``]; output ``gaze``).

A model that reads the normalized face patch (:func:`gazeaug.models.uses_face`) has the input ``face`` too,
float32 (N, 3, Hf, Wf) prepared as the eyes are.

Inputs are the *prepared* tensors of :func:`gazeaug.models.preprocess.prepare_inputs`
(float32, eyes (N, 3, H, W) in [-1, 1], head pose (N, 2) radians); the batch
dimension is dynamic. Uses PyTorch's TorchScript-based exporter, which needs
the ``onnx`` package (``pip install 'gazeaug[train]'``; below 1.18, as
mediapipe 0.10.21 needs protobuf < 5).

The file's ``metadata_props`` say how to feed it (strings; JSON where structured):
``gazeaug.input_mode`` (``rgb`` or ``grey_equalized``: pass it to ``prepare_inputs``),
``gazeaug.normalization`` (the normalized camera the training data used, as
:meth:`NormalizationSettings.as_dict` writes it), ``gazeaug.patch_size_wh``,
``gazeaug.mirror_average`` (``true`` when the exported module is
:func:`gazeaug.models.mirror.mirror_averaged`'s: the graph itself averages with the
mirrored eyes), ``gazeaug.shift_average_px`` (the translation, pixels, over which the
graph itself averages, :func:`gazeaug.models.shift.shift_averaged`; 0: none) and
``gazeaug.output`` (what ``gaze`` holds).
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

from .errors import GazeAugError
from .models import import_torch, uses_face
from .models.shift import shift_average_px_of
from .normalize import NormalizationSettings

__all__ = ["export_onnx"]


def export_onnx(model: Any, meta: dict[str, Any], output: str | Path, opset: int = 17) -> Path:
    """Write the model as ONNX (atomically); returns the path.

    Raises:
        GazeAugError: the output does not end in .onnx, ``meta["patch_size_wh"]`` is not two integers
            within :attr:`NormalizationSettings.PATCH_SIDE_RANGE`, or a weight is NaN or infinite.
    """
    import warnings

    from facemesh.io import atomic_write

    torch = import_torch()
    try:
        import onnx  # noqa: PLC0415
    except ImportError as exc:
        raise ImportError(f"ONNX export needs the onnx package: pip install 'onnx<1.18' ({exc})") from exc
    out = Path(output)
    if out.suffix != ".onnx":
        raise GazeAugError(f"{out}: the output must end in .onnx")
    try:  # load_model checked a file's; a caller's own meta is checked here (huge sizes exhaust memory)
        w, h = NormalizationSettings(patch_size_wh=meta.get("patch_size_wh", (60, 36))).patch_size_wh
    except GazeAugError as exc:
        raise GazeAugError(f"the model's patch_size_wh cannot be exported: {exc}") from exc
    model = model.cpu().eval()
    for name, tensor in model.state_dict().items():
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise GazeAugError(f"not a usable gazeaug model: non-finite weights in {name}; nothing exported")
    example: tuple[Any, ...] = (torch.zeros(1, 3, h, w), torch.zeros(1, 3, h, w), torch.zeros(1, 2))
    names = ["left_eye", "right_eye", "head_pose"]
    if uses_face(model):
        face_size = NormalizationSettings.from_dict(meta.get("normalization") or {}).face_patch_size_wh
        if face_size is None:
            raise GazeAugError("the model reads a face patch, and its normalization makes none: nothing exported")
        example = (*example, torch.zeros(1, 3, face_size[1], face_size[0]))
        names.append("face")
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            model,
            example,
            buf,
            input_names=names,
            output_names=["gaze"],
            dynamic_axes={k: {0: "batch"} for k in (*names, "gaze")},
            opset_version=opset,
            dynamo=False,
        )
    proto = onnx.load_from_string(buf.getvalue())
    norm = meta.get("normalization")
    props = {
        "gazeaug.input_mode": str(meta.get("input_mode", "rgb")),
        # the graph averages with the mirrored eyes itself when this is true (read from the module exported,
        # not from meta, so the file says what the graph does): feed it the plain eyes
        "gazeaug.mirror_average": json.dumps(bool(getattr(model, "mirror_average", False))),
        # likewise the translations it averages over (0: none)
        "gazeaug.shift_average_px": json.dumps(shift_average_px_of(model)),
        "gazeaug.normalization": json.dumps(norm if isinstance(norm, dict) else NormalizationSettings().as_dict()),
        "gazeaug.patch_size_wh": json.dumps([w, h]),
        "gazeaug.output": "gaze (N, 2) float32: (pitch, yaw) radians in the face-centre normalized frame",
    }
    for key, value in props.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    with atomic_write(out) as fh:
        fh.write(proto.SerializeToString())
    return out
