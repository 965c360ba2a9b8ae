"""A trained gaze model ready to predict, from a PyTorch model file (``.pt``) or its ONNX export (``.onnx``).

Both kinds take the same normalized eye patches and head pose and give the
same output: gaze (pitch, yaw) in radians in the face-centre normalized frame
(:mod:`facemesh.conventions`). A ``.pt`` file is read by
:func:`gazeaug.train.load_model` (the safe loader: no code in it runs); an
``.onnx`` file runs on ONNX Runtime and says how to feed it in its
``metadata_props`` (:mod:`gazeaug.export`): the input mode, the normalized
camera and the patch size. An ONNX file without them is refused.

A model that reads the normalized face patch too (:attr:`GazeEstimator.uses_face`) takes it
as a fourth input; its ``normalization`` makes one.

>>> est = load_estimator("model.pt")            # doctest: +SKIP
>>> est.predict(left, right, head_pose)         # doctest: +SKIP
>>> est.predict(left, right, head_pose, face)   # doctest: +SKIP
"""

from __future__ import annotations

import hashlib
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

#: The inputs of every gazeaug ONNX model, sorted (a model that reads the face patch has ``face`` too).
_ONNX_INPUTS = ["head_pose", "left_eye", "right_eye"]


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
    _sha256: str

    @property
    def model_sha256(self) -> str:
        """SHA-256 (hex) of the model file's bytes as this estimator read them (what a calibration is tied to).

        The digest of the very bytes the model was built from, so a file replaced after loading
        cannot pass for the one loaded (:func:`gazeaug.calibration.model_digest` reads the file again).
        """
        return self._sha256

    @property
    def mirror_average(self) -> bool:
        """True when the model's answers are averaged with its answers on the mirrored eyes.

        A ``.pt`` model as loaded (its file's ``prediction`` entry, or ``load_estimator``'s
        choice); an ``.onnx`` export as exported (``gazeaug.mirror_average``: its graph does it).
        """
        if self.kind == "pytorch":
            return bool(self.meta.get("mirror_average", False))
        return bool(self.meta.get("gazeaug.mirror_average", "false") == "true")

    @property
    def uses_face(self) -> bool:
        """True when the model reads the normalized face patch too (give :meth:`predict` ``face``)."""
        if self.kind == "pytorch":
            from .models import uses_face

            return uses_face(self._runner)
        return "face" in {i.name for i in self._runner.get_inputs()}

    def predict(
        self,
        left: NDArray[np.uint8],
        right: NDArray[np.uint8],
        head_pose: NDArray[np.floating[Any]],
        face: NDArray[np.uint8] | None = None,
    ) -> NDArray[np.float64]:
        """Gaze for normalized eyes (and face).

        Args:
            left: (N, H, W, 3) uint8 RGB, the left eye patches (``normalization.patch_size_wh``).
            right: (N, H, W, 3) uint8 RGB, the right eye patches.
            head_pose: (N, 2) float, radians (pitch, yaw), face-centre normalized frame.
            face: (N, Hf, Wf, 3) uint8 RGB, the normalized face patches
                (``normalization.face_patch_size_wh``): needed when :attr:`uses_face`, else ignored.

        Returns:
            (N, 2) float64 radians (pitch, yaw), face-centre normalized frame.
        """
        from .train import check_model_inputs

        if not self.uses_face:
            face = None
        elif face is None:
            raise GazeAugError(f"{self.path}: the model reads a normalized face patch as well, and none was given")
        left, right, head_pose, face = check_model_inputs(
            left, right, head_pose, face, self.normalization.patch_size_wh, self.normalization.face_patch_size_wh
        )
        if self.kind == "pytorch":
            from .train import predict_arrays

            return predict_arrays(
                self._runner, left, right, np.asarray(head_pose), input_mode=self.input_mode, face=face
            )
        from .models.preprocess import prepare_inputs

        inputs = prepare_inputs(left, right, np.asarray(head_pose), self.input_mode, face=face)
        names = ("left_eye", "right_eye", "head_pose", "face")
        feed = {k: t.contiguous().numpy() for k, t in zip(names, inputs)}
        (out,) = self._runner.run(["gaze"], feed)
        return np.asarray(out, dtype=np.float64)

    def warm_up(self) -> None:
        """Run the model once on blank input.

        The first call's one-time costs (imports, allocations) are then paid before a timed loop.
        """
        w, h = self.normalization.patch_size_wh
        blank = np.zeros((1, h, w, 3), np.uint8)
        fw, fh = self.normalization.face_patch_size_wh or (w, h)
        self.predict(blank, blank, np.zeros((1, 2)), np.zeros((1, fh, fw, 3), np.uint8))


def load_estimator(path: str | Path, device: str = "cpu", *, mirror_average: bool | None = None) -> GazeEstimator:
    """Load a ``.pt`` model file or an ``.onnx`` export (module docstring).

    Args:
        path: the model file.
        device: ``cpu`` or ``cuda`` (``.pt`` only; an ``.onnx`` file runs on the CPU).
        mirror_average: None (default): as the file says; False: the network read plainly, without
            averaging with the mirrored eyes; True: averaged (:func:`gazeaug.train.load_model`). An
            ``.onnx`` export has the averaging in its graph or not: asking it otherwise is an error.

    Raises:
        GazeAugError: a missing or unusable file, an ONNX file without gazeaug's metadata; a
            ``mirror_average`` an ONNX graph does not do.
        ImportError: ``.onnx`` without ONNX Runtime installed (:data:`ONNX_INSTALL_HINT`).
    """
    from .train import FILE_SHA256_KEY, check_mirror_average, load_model

    p = Path(path)
    mirror_average = check_mirror_average(mirror_average)
    if p.suffix.lower() == ".onnx":
        est = _load_onnx(p)
        if mirror_average is not None and mirror_average != est.mirror_average:
            raise GazeAugError(
                f"{p}: the ONNX graph {'averages' if est.mirror_average else 'does not average'} with the "
                f"mirrored eyes (it was exported so); mirror averaging {'on' if mirror_average else 'off'} "
                "needs the .pt model"
            )
        return est
    from .evaluate import settings_from_meta

    model, meta = load_model(p, device=device, mirror_average=mirror_average)
    norm = settings_from_meta(meta)  # without a face patch unless the model reads one: test time samples that
    return GazeEstimator(p, "pytorch", norm, str(meta["input_mode"]), meta, model, str(meta[FILE_SHA256_KEY]))


#: The bytes of a TensorProto's external_data entry keyed "location" (field 1, length 8), which
#: every tensor stored outside the .onnx file has: the mark of external data, found without
#: parsing the model (only a tensor or value named exactly "location" encodes the same bytes).
_EXTERNAL_DATA_KEY = b"\n\x08location"


def _load_onnx(p: Path) -> GazeEstimator:
    from .models.preprocess import check_input_mode

    try:
        import onnxruntime as ort  # noqa: PLC0415
    except ImportError as exc:
        raise ImportError(ONNX_INSTALL_HINT) from exc
    if not p.is_file():
        raise GazeAugError(f"{p}: no such model file")
    try:  # read once: the session is built from the very bytes the digest is of
        raw = p.read_bytes()
    except OSError as exc:
        raise GazeAugError(f"{p}: cannot read the model file ({exc.strerror or exc.__class__.__name__})") from exc
    if _EXTERNAL_DATA_KEY in raw:
        # weights in other files: a session built from bytes would look for them in the working
        # directory, not beside the model, and the digest would not cover them
        raise GazeAugError(
            f"{p}: an ONNX model whose weights lie in other files (external data) is not supported: "
            "give a single-file model (gazeaug export writes one)"
        )
    try:
        opts = ort.SessionOptions()
        opts.log_severity_level = 3
        # one sample per call (a video's frames): one thread, no spinning, leaves the cores to the
        # landmark model and the decoder (with the default thread pool a call took 7 ms instead of 0.2)
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        session = ort.InferenceSession(raw, sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # noqa: BLE001 - onnxruntime raises its own exception types
        raise GazeAugError(f"{p}: not a readable ONNX model ({str(exc).splitlines()[0][:200]})") from exc
    props = dict(session.get_modelmeta().custom_metadata_map)
    names = sorted(i.name for i in session.get_inputs())
    if names not in (_ONNX_INPUTS, sorted([*_ONNX_INPUTS, "face"])) or [o.name for o in session.get_outputs()] != [
        "gaze"
    ]:
        raise GazeAugError(
            f"{p}: not a gazeaug ONNX model (inputs {names}; expected head_pose, left_eye, right_eye and maybe face)"
        )
    try:
        mode = check_input_mode(props["gazeaug.input_mode"])
        norm = NormalizationSettings.from_dict(json.loads(props["gazeaug.normalization"]))
        size = json.loads(props["gazeaug.patch_size_wh"])
        norm = NormalizationSettings.from_dict({**norm.as_dict(), "patch_size_wh": size})
    except KeyError as exc:
        raise GazeAugError(
            f"{p}: the ONNX file lacks gazeaug's metadata ({exc.args[0]}); export it again with `gazeaug export`"
        ) from exc
    except (ValueError, TypeError, OverflowError, RecursionError, GazeAugError) as exc:
        raise GazeAugError(f"{p}: unusable gazeaug metadata in the ONNX file ({exc})") from exc
    w, h = norm.patch_size_wh
    if "face" in names and norm.face_patch_size_wh is None:
        raise GazeAugError(f"{p}: the model reads a face patch, and its metadata's normalization makes none")
    fw, fh = norm.face_patch_size_wh or (0, 0)
    for inp in session.get_inputs():
        want = {"left_eye": [3, h, w], "right_eye": [3, h, w], "face": [3, fh, fw]}.get(inp.name)
        if want is not None and list(inp.shape[1:]) != want:
            raise GazeAugError(
                f"{p}: the model takes {inp.name} of shape {inp.shape[1:]}, its metadata name "
                f"{want[2]}x{want[1]} patches (expected {want})"
            )
    return GazeEstimator(p, "onnx", norm, mode, props, session, hashlib.sha256(raw).hexdigest())
