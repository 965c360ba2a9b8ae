"""A trained gaze model ready to predict, from a PyTorch model file (``.pt``) or its ONNX export (``.onnx``).

Both kinds take the same normalized eye patches and head pose and give the
same output: gaze (pitch, yaw) in radians in the face-centre normalized frame
(:mod:`facemesh.conventions`). A ``.pt`` file is read by
:func:`gazeaug.train.load_model` (the safe loader: no code in it runs); an
``.onnx`` file runs on ONNX Runtime and says how to feed it in its
``metadata_props`` (:mod:`gazeaug.export`): the input mode, the normalized
camera and the patch size. An ONNX file without them is refused.

>>> est = load_estimator("model.pt")            # doctest: +SKIP
>>> est.predict(left, right, head_pose)         # doctest: +SKIP
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import GazeAugError
from .normalize import NormalizationSettings

__all__ = ["GazeEstimator", "load_estimator", "ONNX_INSTALL_HINT"]

ONNX_INSTALL_HINT = "running an .onnx model needs ONNX Runtime: pip install onnxruntime"


@dataclass(frozen=True)
class GazeEstimator:
    """A loaded gaze model.

    Attributes:
        path: the file it came from.
        kind: ``pytorch`` or ``onnx``.
        normalization: the normalized camera its training data used (test images must be normalized so).
        input_mode: ``rgb`` or ``grey_equalized`` (:mod:`gazeaug.models.preprocess`).
        meta: the model file's metadata (``.pt``) or ``metadata_props`` (``.onnx``).
    """

    path: Path
    kind: str
    normalization: NormalizationSettings
    input_mode: str
    meta: dict[str, Any]
    _runner: Any

    def predict(
        self, left: NDArray[np.uint8], right: NDArray[np.uint8], head_pose: NDArray[np.floating[Any]]
    ) -> NDArray[np.float64]:
        """Gaze for normalized eyes.

        Args:
            left: (N, H, W, 3) uint8 RGB, the left eye patches (``normalization.patch_size_wh``).
            right: (N, H, W, 3) uint8 RGB, the right eye patches.
            head_pose: (N, 2) float, radians (pitch, yaw), face-centre normalized frame.

        Returns:
            (N, 2) float64 radians (pitch, yaw), face-centre normalized frame.
        """
        w, h = self.normalization.patch_size_wh
        for name, a in (("left", left), ("right", right)):
            if a.ndim != 4 or a.shape[1:] != (h, w, 3) or a.dtype != np.uint8:
                raise GazeAugError(f"{name} eye patches: expected (N, {h}, {w}, 3) uint8, got {a.shape} {a.dtype}")
        if self.kind == "pytorch":
            from .train import predict_arrays

            return predict_arrays(self._runner, left, right, np.asarray(head_pose), input_mode=self.input_mode)
        from .models.preprocess import prepare_inputs

        a, b, c = prepare_inputs(left, right, np.asarray(head_pose), self.input_mode)
        feed = {"left_eye": a.contiguous().numpy(), "right_eye": b.contiguous().numpy(), "head_pose": c.numpy()}
        (out,) = self._runner.run(["gaze"], feed)
        return np.asarray(out, dtype=np.float64)

    def warm_up(self) -> None:
        """Run the model once on blank input.

        The first call's one-time costs (imports, allocations) are then paid before a timed loop.
        """
        w, h = self.normalization.patch_size_wh
        blank = np.zeros((1, h, w, 3), np.uint8)
        self.predict(blank, blank, np.zeros((1, 2)))


def load_estimator(path: str | Path, device: str = "cpu") -> GazeEstimator:
    """Load a ``.pt`` model file or an ``.onnx`` export (module docstring).

    Raises:
        GazeAugError: a missing or unusable file, an ONNX file without gazeaug's metadata.
        ImportError: ``.onnx`` without ONNX Runtime installed (:data:`ONNX_INSTALL_HINT`).
    """
    p = Path(path)
    if p.suffix.lower() == ".onnx":
        return _load_onnx(p)
    from .train import load_model

    model, meta = load_model(p, device=device)
    norm = NormalizationSettings.from_dict(meta["normalization"])
    return GazeEstimator(p, "pytorch", norm, str(meta["input_mode"]), meta, model)


def _load_onnx(p: Path) -> GazeEstimator:
    from .models.preprocess import check_input_mode

    try:
        import onnxruntime as ort  # noqa: PLC0415
    except ImportError as exc:
        raise ImportError(ONNX_INSTALL_HINT) from exc
    if not p.is_file():
        raise GazeAugError(f"{p}: no such model file")
    try:
        opts = ort.SessionOptions()
        opts.log_severity_level = 3
        # one sample per call (a video's frames): one thread, no spinning, leaves the cores to the
        # landmark model and the decoder (with the default thread pool a call took 7 ms instead of 0.2)
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        session = ort.InferenceSession(str(p), sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # noqa: BLE001 - onnxruntime raises its own exception types
        raise GazeAugError(f"{p}: not a readable ONNX model ({str(exc).splitlines()[0][:200]})") from exc
    props = dict(session.get_modelmeta().custom_metadata_map)
    names = sorted(i.name for i in session.get_inputs())
    if names != ["head_pose", "left_eye", "right_eye"] or [o.name for o in session.get_outputs()] != ["gaze"]:
        raise GazeAugError(f"{p}: not a gazeaug ONNX model (inputs {names}; expected head_pose, left_eye, right_eye)")
    try:
        mode = check_input_mode(props["gazeaug.input_mode"])
        norm = NormalizationSettings.from_dict(json.loads(props["gazeaug.normalization"]))
        size = json.loads(props["gazeaug.patch_size_wh"])
        norm = NormalizationSettings.from_dict({**norm.as_dict(), "patch_size_wh": size})
    except KeyError as exc:
        raise GazeAugError(
            f"{p}: the ONNX file lacks gazeaug's metadata ({exc.args[0]}); export it again with `gazeaug export`"
        ) from exc
    except (ValueError, TypeError, GazeAugError) as exc:
        raise GazeAugError(f"{p}: unusable gazeaug metadata in the ONNX file ({exc})") from exc
    w, h = norm.patch_size_wh
    for inp in session.get_inputs():
        if inp.name in ("left_eye", "right_eye") and list(inp.shape[1:]) != [3, h, w]:
            raise GazeAugError(
                f"{p}: the model takes {inp.name} of shape {inp.shape[1:]}, its metadata names {w}x{h} patches "
                f"(expected [3, {h}, {w}])"
            )
    return GazeEstimator(p, "onnx", norm, mode, props, session)
