"""Evaluating a gaze model: on a normalized .h5, or on a raw dataset through test-time normalization.

Raw datasets (any reader of :mod:`gazeaug.datasets`): each image is
normalized as in Zhang et al. 2018 (MediaPipe landmarks, PnP, the model's own
normalization settings), the model predicts the gaze in the face-centre
normalized frame, and the prediction is denormalized (``R^T g``) into the
camera frame. The error is the angle between that 3D vector and the true one
(target - face centre, or the dataset's gaze vector), in degrees. Images
without a face are counted and listed, not fatal.

The face centre is the mean of the posed face model's eye and mouth corners
(:func:`gazeaug.normalize.reference_points`); the gaze origin of the labels is
the same point, so a perfect model has zero error.

Each row of the results (``rows``, also ``errors.csv``) keeps the prediction
and the label in the face-centre normalized frame the model predicts in:
``pred_pitch_rad``, ``pred_yaw_rad``, ``true_pitch_rad``, ``true_yaw_rad``
(radians, the convention of :mod:`facemesh.conventions`). The angle between
them is the row's ``error_deg`` (a rotation keeps angles, so the camera-frame
and face-frame errors agree). From them, ``metrics`` holds
:func:`gazeaug.metrics.summarize`: the constant-guess error, the error
without the model's global offset, the correlations and per-subject means.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from facemesh.conventions import angular_error_deg, pitchyaw_to_vector

from .datasets.base import DatasetError, DatasetReader, GazeSample
from .engine import Engine
from .errors import GazeAugError
from .io_h5 import H5TrainingSet
from .models import uses_face
from .normalize import NormalizationSettings, NormalizedSample, gaze_direction, normalize_image
from .train import angular_errors_deg, predict_arrays

if TYPE_CHECKING:
    from .estimator import GazeEstimator

__all__ = ["evaluate_h5", "evaluate_dataset", "predict_image", "write_report", "settings_from_meta"]


def settings_from_meta(meta: Mapping[str, Any]) -> NormalizationSettings:
    """The normalization a model's inputs need: its training data's (the defaults when unrecorded).

    A model that reads no face patch (``meta["uses_face"]`` False or absent) gets settings that
    make none, even when its training data carried face patches: test time samples what it reads.
    """
    settings = NormalizationSettings.from_dict(meta.get("normalization") or {})
    return settings if meta.get("uses_face") else settings.without_face()


def _is_estimator(model: Any) -> bool:
    from .estimator import GazeEstimator

    return isinstance(model, GazeEstimator)


def _reads_face(model: Any) -> bool:
    """Whether ``model`` (a PyTorch model or a :class:`gazeaug.estimator.GazeEstimator`) reads a face patch."""
    return bool(model.uses_face) if _is_estimator(model) else uses_face(model)


def _predict(
    model: Any,
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    head_pose: NDArray[np.floating[Any]],
    face: NDArray[np.uint8] | None,
) -> NDArray[np.float64]:
    """(N, 2) float64 radians (pitch, yaw), face-centre normalized frame, from a PyTorch model or an estimator.

    The inputs as :func:`gazeaug.train.predict_arrays` takes them: (N, H, W, 3) uint8 RGB patches,
    (N, 2) head pose in radians; ``face`` (N, Hf, Wf, 3) uint8 or None.
    """
    if _is_estimator(model):
        return model.predict(left, right, np.asarray(head_pose), face)  # type: ignore[no-any-return]
    return predict_arrays(model, left, right, head_pose, face=face)


def _model_settings(model: Any, meta: Mapping[str, Any]) -> NormalizationSettings:
    """The normalization ``model``'s inputs need: an estimator's own, else :func:`settings_from_meta`."""
    return model.normalization if _is_estimator(model) else settings_from_meta(meta)  # type: ignore[no-any-return]


def _metrics(rows: list[dict[str, Any]]) -> dict[str, Any] | None:
    """:func:`gazeaug.metrics.summarize` of the rows' face-frame predictions and labels.

    None without rows, or when a prediction is not finite (the errors then say so: NaN).
    """
    from .metrics import summarize

    if not rows:
        return None
    pred = np.array([[r["pred_pitch_rad"], r["pred_yaw_rad"]] for r in rows], dtype=np.float64)
    true = np.array([[r["true_pitch_rad"], r["true_yaw_rad"]] for r in rows], dtype=np.float64)
    if not (np.all(np.isfinite(pred)) and np.all(np.isfinite(true))):
        return None
    return summarize(pred, true, [str(r["subject"]) for r in rows])


def _face_frame(pred: NDArray[np.float64], true: NDArray[np.float64]) -> dict[str, float]:
    """A row's face-frame prediction and label: (2,) radians (pitch, yaw) each."""
    return {
        "pred_pitch_rad": float(pred[0]),
        "pred_yaw_rad": float(pred[1]),
        "true_pitch_rad": float(true[0]),
        "true_yaw_rad": float(true[1]),
    }


def _summary(errors: NDArray[np.float64], subjects: NDArray[Any]) -> dict[str, Any]:
    per = {}
    for s in sorted(set(subjects.tolist())):
        e = errors[subjects == s]
        per[str(s)] = {"count": int(len(e)), "mean_deg": float(e.mean()), "median_deg": float(np.median(e))}
    return {
        "count": int(len(errors)),
        "mean_deg": float(errors.mean()) if len(errors) else None,
        "median_deg": float(np.median(errors)) if len(errors) else None,
        "std_deg": float(errors.std()) if len(errors) else None,
        "per_subject": per,
    }


def evaluate_h5(model: Any | GazeEstimator, path: str | Path) -> dict[str, Any]:
    """Errors on a normalized training-set file (angles between predicted and true gaze vectors).

    ``model``: a PyTorch model (:func:`gazeaug.train.load_model`) or a
    :class:`gazeaug.estimator.GazeEstimator` (a ``.pt`` or an ``.onnx`` export).
    """
    data = H5TrainingSet(path)
    if _is_estimator(model):  # a PyTorch model alone does not record its patch size
        face = _reads_face(model)
        pairs: list[tuple[str, tuple[int, int] | None, tuple[int, int] | None]] = [
            ("eye", data.patch_size_wh, model.normalization.patch_size_wh)
        ]
        if face:
            pairs.append(("face", data.face_patch_size_wh, model.normalization.face_patch_size_wh))
        for what, got, want in pairs:
            if got != want:
                shown = ["none" if v is None else f"{v[0]} x {v[1]} px" for v in (got, want)]
                raise GazeAugError(
                    f"{path}: its {what} patches are {shown[0]}, the model {model.path} reads {shown[1]} "
                    "(normalize the set with the model's settings)"
                )
    errs, subj, preds, trues = [], [], [], []
    keys = H5TrainingSet.batch_keys(_reads_face(model))
    for batch in data.batches(512, keys=keys):
        pred = _predict(model, batch["left_eye"], batch["right_eye"], batch["head_pose"], batch.get("face"))
        errs.append(angular_errors_deg(pred, batch["gaze"]))
        subj.append(batch["subject"])
        preds.append(pred)
        trues.append(np.asarray(batch["gaze"], dtype=np.float64))
    errors = np.concatenate(errs)
    out = _summary(errors, np.concatenate(subj))
    rows = [
        {"index": i, "subject": str(s), "error_deg": float(e), **_face_frame(p, t)}
        for i, (s, e, p, t) in enumerate(
            zip(np.concatenate(subj), errors, np.concatenate(preds), np.concatenate(trues))
        )
    ]
    out.update(source=str(path), kind="h5", skipped=0, skipped_samples=[], rows=rows, metrics=_metrics(rows))
    out["mirror_average"] = _mirror_average(model)
    return out


def _mirror_average(model: Any) -> bool:
    """Whether ``model`` (an estimator or a PyTorch model) averages its answers with the mirrored eyes."""
    if _is_estimator(model):
        return bool(model.mirror_average)
    return bool(getattr(model, "mirror_average", False))  # the wrapper of gazeaug.models.mirror says so


def predict_image(
    model: Any, image: NDArray[np.uint8], fit: Any, settings: NormalizationSettings
) -> tuple[NDArray[np.float64], NormalizedSample]:
    """Gaze of one fitted face: (3,) unit vector, camera frame, from the face centre; and the normalized sample."""
    pred, sample = _predict_normalized(model, image, fit, settings)
    assert sample.face is not None
    return sample.face.camera.denormalize_vector(pitchyaw_to_vector(pred)), sample


def _predict_normalized(
    model: Any, image: NDArray[np.uint8], fit: Any, settings: NormalizationSettings
) -> tuple[NDArray[np.float64], NormalizedSample]:
    """(2,) float64 radians (pitch, yaw), face-centre normalized frame: the model's gaze; and the normalized sample."""
    sample = normalize_image(image, fit.camera, fit.pose, fit.model.vertices_mm, fit.keypoints, settings=settings)
    assert sample.face is not None
    face = None if sample.face.image is None else sample.face.image[None]
    pred = _predict(model, sample.left.image[None], sample.right.image[None], sample.face.head_pose[None], face)[0]
    return pred, sample


_EVAL_STATE: dict[str, Any] = {}


def _eval_setup(model: Any, settings: NormalizationSettings, threads: int = 0) -> None:
    """A worker's state: the model, the normalization and one landmark detector (``threads``: torch's; 0 keeps it).

    ``model``: a PyTorch model, an estimator, or the path of an ``.onnx`` file (an ONNX Runtime
    session does not pickle: each Ray actor loads its own).
    """
    from .pipeline import default_landmark_model

    if isinstance(model, (str, Path)):
        from .estimator import load_estimator

        model = load_estimator(model)
    if threads:
        import torch

        torch.set_num_threads(threads)
    _EVAL_STATE.update(model=model, settings=settings, detector=default_landmark_model())


def _evaluate_one(s: GazeSample) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """One sample's report row, or why it was skipped (with the worker's state, see :func:`_eval_setup`)."""
    from facemesh.pose import PoseError
    from facemesh.types import InputError, NoFaceError

    from .pipeline import fit_face

    try:
        image = s.load_image()
        fit = fit_face(image, s.camera, _EVAL_STATE["detector"], source=str(s.image_path))
        pred, sample = _predict_normalized(_EVAL_STATE["model"], image, fit, _EVAL_STATE["settings"])
    except (NoFaceError, PoseError, InputError, GazeAugError) as exc:
        return None, {"source_index": s.source_index, "image": str(s.image_path), "reason": str(exc)}
    assert sample.face is not None
    g = sample.face.camera.denormalize_vector(pitchyaw_to_vector(pred))
    truth = gaze_direction(sample.face.camera.reference_mm, s.gaze_target_mm, s.gaze_vector)
    assert truth is not None  # every GazeSample has a target or a vector
    row = {
        "index": s.source_index,
        "subject": s.subject,
        "image": str(s.image_path),
        "error_deg": float(angular_error_deg(g, truth)),
        "gaze_camera": np.round(g, 6).tolist(),
        **_face_frame(pred, sample.face.camera.gaze_pitchyaw(truth)),
    }
    return row, None


def _evaluate_block(samples: list[GazeSample]) -> list[tuple[dict[str, Any] | None, dict[str, Any] | None]]:
    """:func:`_evaluate_one` over a block (the unit a Ray actor processes); skips name the node."""
    from .engine import node_name

    node = node_name()
    out = []
    for s in samples:
        row, skip = _evaluate_one(s)
        out.append((row, None if skip is None else {**skip, "node": node}))
    return out


def evaluate_dataset(
    model: Any | GazeEstimator,
    meta: Mapping[str, Any],
    reader: DatasetReader,
    *,
    limit: int | None = None,
    progress: bool = True,
    engine: Engine | None = None,
) -> dict[str, Any]:
    """Errors on a raw dataset through test-time normalization and denormalization (see the module docstring).

    ``model``: a PyTorch model (with ``meta``, :func:`gazeaug.train.load_model`'s) or a
    :class:`gazeaug.estimator.GazeEstimator` (a ``.pt`` or an ``.onnx`` export; ``meta`` is then
    its ``meta`` and the normalization its own). ``engine``: where the samples are processed
    (default this machine; on Ray, blocks of ``engine.block_size`` samples, each actor with its
    own copy of the model).
    """
    if limit is not None and not (isinstance(limit, int) and limit >= 1):
        raise GazeAugError(f"limit: expected an integer >= 1, got {limit!r}")
    total = len(reader) if limit is None else min(len(reader), limit)
    if total == 0:
        raise DatasetError(f"{getattr(reader, 'root', reader.name)}: the dataset has no samples")
    settings = _model_settings(model, meta)
    rows, skipped = [], []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, unit="image", desc="evaluate", dynamic_ncols=True)

    def take(_b: int, results: list[tuple[dict[str, Any] | None, dict[str, Any] | None]]) -> None:
        for row, skip in results:
            if row is not None:
                rows.append(row)
            if skip is not None:
                skipped.append(skip)
        if bar is not None:
            bar.update(len(results))

    samples = (s for s in reader if s.source_index < total)
    try:
        if engine is not None and engine.kind == "ray":
            from .background import interrupt_between_steps
            from .engine import chunks, map_blocks

            blocks = enumerate(chunks(samples, engine.block_size))
            with interrupt_between_steps() as interrupted:
                map_blocks(
                    engine,
                    blocks,
                    _evaluate_block,
                    _eval_setup,
                    (model.path if _is_estimator(model) and model.kind == "onnx" else model, settings, 1),
                    on_result=take,
                    interrupted=interrupted,
                )
        else:
            from .models import one_torch_thread

            _eval_setup(model, settings)
            with one_torch_thread():  # as each Ray actor runs it: the same floats, and faster on one sample
                for s in samples:
                    row, skip = _evaluate_one(s)
                    take(0, [(row, skip)])
    finally:
        if bar is not None:
            bar.close()
    out = _summary(np.asarray([r["error_deg"] for r in rows]), np.asarray([r["subject"] for r in rows]))
    out.update(
        source=str(getattr(reader, "root", "")),
        kind=reader.name,
        skipped=len(skipped),
        skipped_samples=skipped,
        rows=rows,
        metrics=_metrics(rows),
        mirror_average=_mirror_average(model),
    )
    return out


def write_report(result: Mapping[str, Any], out_dir: str | Path) -> dict[str, Path]:
    """``errors.json`` (everything), ``errors.csv`` (one row per sample) and ``errors_hist.png`` in ``out_dir``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facemesh.io import atomic_write

    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    paths = {"json": d / "errors.json", "csv": d / "errors.csv", "plot": d / "errors_hist.png"}
    with atomic_write(paths["json"]) as fh:
        fh.write(json.dumps(result, indent=1, default=float).encode("utf-8"))
    rows = list(result.get("rows") or [])
    buf = io.StringIO()
    if rows:
        w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    with atomic_write(paths["csv"]) as fh:
        fh.write(buf.getvalue().encode("utf-8"))
    fig, ax = plt.subplots(figsize=(6, 4))
    errs = [r["error_deg"] for r in rows]
    if errs:
        ax.hist(errs, bins=30)
    ax.set_xlabel("angular error (deg)")
    ax.set_ylabel("samples")
    mean = result.get("mean_deg")
    ax.set_title(f"mean {mean:.2f} deg over {len(errs)} samples" if mean is not None else "no samples")
    with atomic_write(paths["plot"]) as fh:
        fig.savefig(fh, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return paths
