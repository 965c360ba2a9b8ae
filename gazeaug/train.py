"""Training the gaze model on the HDF5 sets that ``augment`` and ``normalize-dataset`` write.

Batches are shuffled across the whole file (:meth:`H5TrainingSet.order`) and
come from the rows held on the training device, read once, when they fit, or
else are streamed from the file by a background thread in bounded memory: the
same batches either way (:mod:`gazeaug.train_data`). The patches reach the
device as uint8 and are augmented
(:mod:`gazeaug.train_augment`, the one place of training-time augmentation)
and converted to the model's input there (:func:`train_inputs`); CUDA steps run
in bfloat16 autocast, the model's forward and backward of full batches replayed as
CUDA graphs (:mod:`gazeaug.train_graphs`), the optimizer fused. The model predicts
the gaze (pitch, yaw) in the face-centre normalized frame; the loss is the
L1 distance of the angles, each axis weighed by the inverse of its spread over
the training labels (:func:`axis_weights`), the reported error the angle between 3D gaze
vectors (degrees). One checkpoint per epoch (``MODEL.ckpt.pt``) lets an
interrupted run resume; the final model (``MODEL.pt``) holds the weights, the
model's name and options, the preprocessing, the normalization settings of
its training data and the training log. The log is also written as CSV, with
a plot of the curves.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import math
import time
import warnings
from collections.abc import Collection, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import __version__
from .background import interrupt_between_steps
from .errors import GazeAugError, TracebackText
from .io_h5 import H5TrainingSet  # the schema's reader lives beside its writer; re-exported here
from .models import create_model, import_torch, uses_face
from .models.keypoints import KEYPOINT_SCALE_PX, attach_keypoint_head, keypoint_loss
from .models.preprocess import (
    check_input_mode,
    input_mode_from_record,
    input_mode_of,
    prepare_inputs,
    preprocessing_record,
    set_input_mode,
)
from .models.shift import MAX_SHIFT_AVERAGE_PX, shift_average_px_of
from .normalize import EYE_KEYPOINTS, NormalizationSettings
from .train_augment import TrainAugment, augment_generator
from .train_data import check_preload, epoch_batches, hold_rows, placeholder_batch, prefetch_batches, train_inputs
from .train_graphs import graph_model, quiet_stream_mismatch

__all__ = [
    "unfinished_checkpoint",
    "TrainSettings",
    "TrainAugment",
    "H5TrainingSet",
    "train",
    "load_model",
    "predict_arrays",
    "angular_errors_deg",
    "prefetch_batches",
    "train_inputs",
    "MODEL_FORMAT",
]

MODEL_FORMAT = "gazeaug-model"
_CKPT_KEYS = ("state_dict", "optimizer", "scheduler", "epoch", "settings", "data_selection", "log", "torch_rng")
#: The settings a checkpoint of an older gazeaug did not record, as that gazeaug trained.
_LEGACY_SETTINGS: dict[str, Any] = {
    "augment": asdict(TrainAugment(enabled=False)),
    "input_mode": "rgb",
    "auto_samples": 250_000,  # not used by a run whose epochs were given, as every older run's were
    "balance_axes": False,
    "keypoint_loss_weight": 0.0,
}
#: The augmentation fields an older gazeaug's checkpoint did not record, as that gazeaug augmented.
_LEGACY_AUGMENT: dict[str, Any] = {"mirror": 0.0, "head_pose_deg": 0.0, "scale": 0.0}
#: Augmentation defaults that changed, as (field, the default before): a checkpoint made under the
#: older default resumes with it where the run being resumed leaves the field at today's default,
#: so a run started before the change finishes as it began (``gazeaug train --resume`` has no
#: option for each strength). ``shift_px`` was 2 before 2026-11-24 (docs/model.md).
_OLDER_AUGMENT_DEFAULTS: tuple[tuple[str, Any], ...] = (("shift_px", 2),)
#: Training defaults that changed, as (field, the default before), handled like
#: :data:`_OLDER_AUGMENT_DEFAULTS`: a checkpoint begun under the older default resumes with it where
#: the resuming settings leave the field at today's default. Both changed 2026-11-25 (docs/model.md), with
#: ``auto_samples`` (250k before), which a resumed run left at today's default always takes from its
#: checkpoint (:func:`_train`), whatever the value.
_OLDER_DEFAULTS: tuple[tuple[str, Any], ...] = (("lr", 1e-3), ("balance_axes", False))
#: :func:`axis_weights` takes an axis's spread as at least this share of the other's.
MIN_SPREAD_RATIO = 0.25
#: The fewest epochs :meth:`TrainSettings.fitted` gives.
AUTO_MIN_EPOCHS = 10
#: The most epochs :meth:`TrainSettings.fitted` gives: a set of under 250 rows (500k / 2000) would
#: otherwise train for many thousands of one-step epochs, each writing a checkpoint that holds the
#: whole log (24 rows at 250k samples: 10417 epochs, 8.9 min on 2 cores), to memorise a set too small
#: to generalize.
AUTO_MAX_EPOCHS = 2000
#: The most samples ``auto_samples`` (``--samples``) may ask for: far beyond any run, and a number every
#: file that records it (the model, its checkpoint) can hold.
MAX_AUTO_SAMPLES = 10**12


@dataclass(frozen=True)
class TrainSettings:
    """Hyper-parameters (the same for original and augmented training, so differences come from the data).

    Attributes:
        model: registered model name (default ``mobilenet_gaze``).
        model_options: keyword options of the model factory.
        epochs: passes over the training set (default None: fitted to the data size by
            :meth:`fitted`, enough epochs to show the model ``auto_samples`` samples, at least
            :data:`AUTO_MIN_EPOCHS`, at most :data:`AUTO_MAX_EPOCHS`).
        batch_size: samples per step (default None: fitted to the data size by :meth:`fitted`,
            about ``rows / 128`` rounded to a power of two, from 32 to 256).
        auto_samples: how many samples a run with ``epochs`` None shows the model (default 500000,
            250000 before 2026-11-25: with today's training-time augmentation the model underfits
            at 250k; on issue 13's benchmark 500k gave 8.66 +- 0.22 deg over 3 seeds against
            9.38 +- 0.47; docs/model.md).
        lr: AdamW learning rate (default 3e-3; 1e-3 before 2026-11-25), decayed by cosine to 1% at
            the end; in (0, 10].
        weight_decay: Adam weight decay (default 1e-4); in [0, 10).
        seed: seeds weights, shuffling and everything random (default 0).
        device: ``auto`` (CUDA when present), ``cpu`` or ``cuda``.
        augment: training-time augmentation of the eye patches, on the device
            (:class:`gazeaug.train_augment.TrainAugment`; default on, ``TrainAugment(enabled=False)``
            turns it off).
        input_mode: the model's input normalization, ``rgb`` (default) or ``grey_equalized``
            (grey + histogram equalization, as MPIIGaze's patches); recorded in the model file and
            applied by every user of the model (see :mod:`gazeaug.models.preprocess`).
        mirror_average: the model's predictions average its answer on the eyes and on their mirror
            image (:func:`gazeaug.models.mirror.mirror_averaged`; default True: 12.0 -> 11.1 deg on
            new people in issue 13's protocol, 3 seeds). The training is the same either way; the
            model file records it (``prediction.mirror_average``) and :func:`load_model` applies it.
            The training log's errors are the plain network's.
        shift_average_px: the model's predictions average its answers on the eye patches translated
            by this many pixels along each axis and both diagonals and on the patches themselves
            (9 answers; :func:`gazeaug.models.shift.shift_averaged`); 0 turns it off; an integer
            from 0 to :data:`~gazeaug.models.shift.MAX_SHIFT_AVERAGE_PX`, smaller than the patch's
            sides. Default 3 (since 2026-11-28: on 10 models of issue 13's benchmark 0.34 deg
            lower error on average, 9.70 -> 9.37, at 9 x the network's rows; docs/model.md). Recorded like
            ``mirror_average`` (``prediction.shift_average_px``) and applied by :func:`load_model`;
            the training is the same either way and its log's errors are the plain network's.
        balance_axes: the L1 loss weighs each axis by the inverse of the training labels' standard
            deviation on it (:func:`axis_weights`; default True), so the narrower pitch counts as
            much as the wider yaw; False: the plain L1 loss on (pitch, yaw) radians, as before
            2026-11-25. With an lr of 3e-3, on issue 13's benchmark (3 seeds): 9.38 deg against
            9.93, pitch r 0.66 against 0.57 (docs/model.md). The model file records the weights
            (``loss_weights_pitch_yaw``).
        keypoint_loss_weight: weight of a keypoint loss (:mod:`gazeaug.models.keypoints`): a head on
            the eye encoder's stride-4 map learns where each eye's iris centre and opening centre
            lie (the training set's ``eye_keypoints``, written by ``augment --redirect-eyes``;
            rows without them, NaN, count for the gaze alone), its mean absolute error in units of
            10 px added to the gaze loss times this weight. The head is for training only: the
            model file holds the gaze network alone. Default 0 (off); a number in [0, 100].
            Measured in docs/model.md ("the keypoint head as a loss").
    """

    model: str = "mobilenet_gaze"
    model_options: dict[str, Any] = field(default_factory=dict)
    epochs: int | None = None
    batch_size: int | None = None
    auto_samples: int = 500_000
    lr: float = 3e-3
    weight_decay: float = 1e-4
    seed: int = 0
    device: str = "auto"
    augment: TrainAugment = field(default_factory=TrainAugment)
    input_mode: str = "rgb"
    mirror_average: bool = True
    shift_average_px: int = 3
    balance_axes: bool = True
    keypoint_loss_weight: float = 0.0

    def __post_init__(self) -> None:
        if not (self.epochs is None or (_is_integer(self.epochs) and self.epochs >= 1)):
            raise GazeAugError(f"epochs: expected an integer >= 1 (or None: fitted to the data), got {self.epochs!r}")
        if not (self.batch_size is None or (_is_integer(self.batch_size) and self.batch_size >= 1)):
            raise GazeAugError(
                f"batch size: expected an integer >= 1 (or None: fitted to the data), got {self.batch_size!r}"
            )
        if not (_is_integer(self.auto_samples) and 1 <= self.auto_samples <= MAX_AUTO_SAMPLES):
            raise GazeAugError(
                f"auto_samples: expected an integer from 1 to {MAX_AUTO_SAMPLES:.0e}, got {self.auto_samples!r}"
            )
        # plain Python numbers: the files record these, and the safe loader refuses numpy scalars
        for name in ("epochs", "batch_size", "auto_samples", "seed"):
            v = getattr(self, name)
            if v is not None and _is_integer(v):
                object.__setattr__(self, name, int(v))
        if not (_is_number(self.lr) and 0 < self.lr <= 10):  # beyond, every step overflows the weights
            raise GazeAugError(f"learning rate: expected a number in (0, 10], got {self.lr!r}")
        if not (_is_number(self.weight_decay) and 0 <= self.weight_decay < 10):
            raise GazeAugError(f"weight decay: expected a number in [0, 10), got {self.weight_decay!r}")
        if not (isinstance(self.seed, int) and not isinstance(self.seed, bool) and 0 <= self.seed < 2**63):
            raise GazeAugError(f"seed: expected an integer from 0 to 2**63 - 1, got {self.seed!r}")
        if not (isinstance(self.model_options, dict) and all(isinstance(k, str) for k in self.model_options)):
            raise GazeAugError(f"model options: expected a dict of named options, got {self.model_options!r}")
        if self.device not in ("auto", "cpu", "cuda"):
            raise GazeAugError(f"device: expected auto, cpu or cuda, got {self.device!r}")
        if not isinstance(self.augment, TrainAugment):
            raise GazeAugError(f"augment: expected a TrainAugment, got {self.augment!r}")
        check_input_mode(self.input_mode)
        if not isinstance(self.mirror_average, (bool, np.bool_)):
            raise GazeAugError(f"mirror_average: expected true or false, got {self.mirror_average!r}")
        object.__setattr__(self, "mirror_average", bool(self.mirror_average))
        if not (_is_integer(self.shift_average_px) and 0 <= self.shift_average_px <= MAX_SHIFT_AVERAGE_PX):
            raise GazeAugError(
                f"shift_average_px: expected an integer from 0 to {MAX_SHIFT_AVERAGE_PX} pixels, "
                f"got {self.shift_average_px!r}"
            )
        object.__setattr__(self, "shift_average_px", int(self.shift_average_px))
        if not isinstance(self.balance_axes, (bool, np.bool_)):
            raise GazeAugError(f"balance_axes: expected true or false, got {self.balance_axes!r}")
        object.__setattr__(self, "balance_axes", bool(self.balance_axes))
        if not (_is_number(self.keypoint_loss_weight) and 0 <= self.keypoint_loss_weight <= 100):
            raise GazeAugError(
                f"keypoint loss weight: expected a number in [0, 100], got {self.keypoint_loss_weight!r}"
            )
        object.__setattr__(self, "keypoint_loss_weight", float(self.keypoint_loss_weight))
        object.__setattr__(self, "lr", float(self.lr))
        object.__setattr__(self, "weight_decay", float(self.weight_decay))

    def fitted(self, rows: int) -> TrainSettings:
        """These settings with the epochs and batch size left at None fitted to a training set of ``rows`` samples.

        A small set needs many passes: a gaze model that sees a few thousand eye patches
        ten times underfits (measured in docs/model.md: on 1800 simulated images, 30 epochs
        left 10.3 deg of training error and 12.0 deg on new people, 150 epochs 5.9 and 8.6).
        The batch is about ``rows / 128`` as a power of two, from 32 to 256 (small sets take
        small batches, so many optimizer steps); the epochs are enough to show the model
        ``auto_samples`` samples, at least :data:`AUTO_MIN_EPOCHS` and at most :data:`AUTO_MAX_EPOCHS`.
        Values already set are kept.
        """
        if not (_is_integer(rows) and rows >= 1):
            raise GazeAugError(f"rows: expected an integer >= 1, got {rows!r}")
        batch = self.batch_size
        if batch is None:
            batch = int(min(256, max(32, 2 ** round(math.log2(rows / 128)))))
        epochs = self.epochs
        if epochs is None:
            epochs = min(AUTO_MAX_EPOCHS, max(AUTO_MIN_EPOCHS, math.ceil(self.auto_samples / rows)))
        return replace(self, epochs=int(epochs), batch_size=int(batch))


def _is_integer(v: Any) -> bool:
    """An integer (int or numpy integer), not a bool."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_number(v: Any) -> bool:
    """A finite real number (int, float or numpy scalar), not a bool."""
    return (
        isinstance(v, (int, float, np.integer, np.floating))
        and not isinstance(v, (bool, np.bool_))
        and math.isfinite(v)
    )


def angular_errors_deg(
    pred_pitchyaw: NDArray[np.floating[Any]], true_pitchyaw: NDArray[np.floating[Any]]
) -> NDArray[np.float64]:
    """(N, 2) and (N, 2) radians (pitch, yaw) -> (N,) angles between the 3D gaze vectors, degrees."""
    from facemesh.conventions import angular_error_deg, pitchyaw_to_vector

    return np.asarray(
        angular_error_deg(pitchyaw_to_vector(np.asarray(pred_pitchyaw)), pitchyaw_to_vector(np.asarray(true_pitchyaw))),
        dtype=np.float64,
    )


def axis_weights(gaze: NDArray[Any]) -> tuple[float, float]:
    """The L1 loss's weights of (pitch, yaw) for training labels ``gaze`` (N, 2) radians: ``mean(sd) / sd``.

    Each axis is weighed by the inverse of its standard deviation over the training rows, scaled
    so the two weights average to 1 where the spreads are alike (``(s_p + s_y) / 2 / s``): on issue
    13's augmented wheelchair set (sd 8.1 and 18.9 deg) 1.67 and 0.71. A spread is taken as at
    least :data:`MIN_SPREAD_RATIO` of the other (weights at most 2.5 and 0.625), so a set whose
    gaze barely moves on one axis does not ignore the other. (1, 1) when an axis has no spread
    (fewer than two rows, or one gaze for all).
    """
    g = np.asarray(gaze, dtype=np.float64).reshape(-1, 2)
    sd = g.std(axis=0) if len(g) > 1 else np.zeros(2)
    if not (np.isfinite(sd).all() and (sd > 1e-9).all()):
        return (1.0, 1.0)
    sd = np.maximum(sd, MIN_SPREAD_RATIO * sd.max())
    w = sd.mean() / sd
    return (float(w[0]), float(w[1]))


def _device(name: str) -> Any:
    torch = import_torch()
    if name == "cuda" or (name == "auto" and torch.cuda.is_available()):
        if not torch.cuda.is_available():
            raise GazeAugError("device cuda asked for, but no CUDA device is available")
        return torch.device("cuda")
    return torch.device("cpu")


def check_model_inputs(
    left: Any,
    right: Any,
    head_pose: Any,
    face: Any = None,
    patch_size_wh: tuple[int, int] | None = None,
    face_patch_size_wh: tuple[int, int] | None = None,
) -> tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.float64], NDArray[np.uint8] | None]:
    """The inputs of a gaze model checked: N eyes, N head poses (and N faces), of the model's sizes.

    Eye and face patches (N, H, W, 3) uint8 RGB, of the given sizes (W, H) where given; head poses
    (N, 2) finite radians (pitch, yaw), face-centre normalized frame. Returns the arrays (the head
    poses as float64). Raises :class:`GazeAugError` naming what is wrong, expected against got.
    """

    def patches(name: str, a: Any, size: tuple[int, int] | None) -> NDArray[np.uint8]:
        a = np.asarray(a)
        if a.ndim != 4 or a.shape[3] != 3 or a.dtype != np.uint8:
            raise GazeAugError(f"{name} patches: expected (N, H, W, 3) uint8 RGB, got {a.shape} {a.dtype}")
        if size is not None and a.shape[1:3] != (size[1], size[0]):
            raise GazeAugError(
                f"{name} patches: the model reads {size[0]} x {size[1]} px ones, got {a.shape[2]} x {a.shape[1]}"
            )
        return a

    lefts, rights = patches("left eye", left, patch_size_wh), patches("right eye", right, patch_size_wh)
    faces = None if face is None else patches("face", face, face_patch_size_wh)
    n = len(lefts)
    for name, a in (("right eye", rights), ("face", faces)):
        if a is not None and len(a) != n:
            raise GazeAugError(f"{name} patches: expected {n}, one per left eye patch, got {len(a)}")
    try:
        pose = np.asarray(head_pose, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise GazeAugError(f"head poses: expected ({n}, 2) numbers, radians, got {exc}") from exc
    if pose.shape != (n, 2):
        raise GazeAugError(f"head poses: expected ({n}, 2) radians (pitch, yaw), one per eye patch, got {pose.shape}")
    if not np.isfinite(pose).all():
        bad = int((~np.isfinite(pose)).any(axis=1).sum())
        raise GazeAugError(f"head poses: expected finite numbers, got {bad} row(s) with NaN or infinity")
    return lefts, rights, pose, faces


def predict_arrays(
    model: Any,
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    head_pose: NDArray[Any],
    batch_size: int = 512,
    input_mode: str | None = None,
    face: NDArray[np.uint8] | None = None,
) -> NDArray[np.float64]:
    """Gaze (N, 2) float64 radians (pitch, yaw), face frame, for eye patches and head poses.

    Args:
        model: a gaze model (from :func:`load_model`, or being trained).
        left: (N, H, W, 3) uint8 RGB, the left eye patches.
        right: (N, H, W, 3) uint8 RGB, the right eye patches.
        head_pose: (N, 2) radians (pitch, yaw), face frame.
        batch_size: samples per forward pass.
        input_mode: the model's input mode; default: the one :func:`load_model` attached to the model
            (``rgb`` for a model built otherwise).
        face: (N, Hf, Wf, 3) uint8 RGB face patches: needed by a model that reads them
            (:func:`gazeaug.models.uses_face`), ignored by one that does not.

    Raises:
        GazeAugError: a model that reads face patches given none; inputs of other shapes, types or
            lengths (:func:`check_model_inputs`; a loaded model's patch sizes are checked too); a batch
            size under 1.
    """
    torch = import_torch()
    mode = input_mode_of(model) if input_mode is None else check_input_mode(input_mode)
    if not (_is_integer(batch_size) and batch_size >= 1):
        raise GazeAugError(f"batch size: expected an integer >= 1, got {batch_size!r}")
    if not uses_face(model):
        face = None
    elif face is None:
        raise GazeAugError("the model reads a normalized face patch as well, and none was given")
    # a loaded model's sizes (see load_model); a model being trained checks shapes and types only
    left, right, head_pose, face = check_model_inputs(
        left,
        right,
        head_pose,
        face,
        getattr(model, "patch_size_wh", None),
        getattr(model, "face_patch_size_wh", None),
    )
    px = shift_average_px_of(model)
    if px and min(np.shape(left)[1:3]) <= px:
        raise GazeAugError(
            f"eye patches: the model averages over translations of {px} px, so their sides must exceed it, "
            f"got {np.shape(left)[2]} x {np.shape(left)[1]}"
        )
    device = next(model.parameters()).device
    out = []
    model.eval()
    with torch.no_grad():
        for i in range(0, len(left), batch_size):
            sl = slice(i, i + batch_size)
            inputs = prepare_inputs(
                left[sl], right[sl], head_pose[sl], mode, device=device, face=None if face is None else face[sl]
            )
            out.append(model(*inputs).float().cpu().numpy())
    return np.concatenate(out).astype(np.float64) if out else np.zeros((0, 2))


def _check_fits(model: Any, settings: TrainSettings, data: H5TrainingSet, device: Any) -> None:
    """Run ``model`` once on zeros shaped like ``data``'s patches, or say in one line why it cannot.

    A model's options can ask more of a patch than it has (``face_pool`` larger than the face
    patch, ``blocks`` striding a small eye patch to nothing): PyTorch's error would come from deep
    in the first training step. Two samples in eval mode, without gradients; nothing is kept.

    Raises:
        GazeAugError: the model cannot read patches of this size, or cannot be called as
            ``model(left, right, head_pose[, face])``.
    """
    torch = import_torch()
    w, h = data.patch_size_wh
    eye = torch.zeros((2, 3, h, w), dtype=torch.float32, device=device)
    face = None
    if uses_face(model) and data.face_patch_size_wh is not None:
        fw, fh = data.face_patch_size_wh
        face = torch.zeros((2, 3, fh, fw), dtype=torch.float32, device=device)
    head = torch.zeros((2, 2), dtype=torch.float32, device=device)
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            out = model(eye, eye, head, face) if face is not None else model(eye, eye, head)
    except (RuntimeError, TypeError) as exc:
        if _out_of_memory(exc) or "CUDA" in str(exc):
            raise  # the device's trouble, not the model's fit to the patches (train() phrases an out of memory)
        sizes = f"eye patches {w} x {h} px" + ("" if face is None else f", face patches {fw} x {fh} px")
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else exc.__class__.__name__
        raise GazeAugError(
            f"model {settings.model!r} with options {settings.model_options or {}} cannot read this set's "
            f"{sizes} ({first})"
        ) from exc
    finally:
        model.train(was_training)
    shape = tuple(getattr(out, "shape", ()))
    if shape != (2, 2):
        raise GazeAugError(
            f"model {settings.model!r}: expected (pitch, yaw) per sample, an output of shape (2, 2) for 2 samples, "
            f"got {shape or type(out).__name__}"
        )


def _capture(model: Any, data: H5TrainingSet, batch_size: int, face: bool, device: Any, s: TrainSettings) -> Any:
    """The CUDA graphs of ``model``'s full batches (:func:`gazeaug.train_graphs.graph_model`), or None.

    ``model`` is put in train mode and captured on a placeholder batch of ``data``'s shapes
    (:func:`gazeaug.train_data.placeholder_batch`) through the training's own input path; the
    placeholder's inputs are freed on return.
    """
    torch = import_torch()
    model.train()
    batch = placeholder_batch(data, batch_size, face=face)
    return graph_model(model, train_inputs(batch, device, s.augment, s.input_mode, torch.Generator(device)).model_args)


def _evaluate_set(model: Any, data: H5TrainingSet, batch_size: int) -> float:
    errs = []
    keys = H5TrainingSet.batch_keys(uses_face(model))
    for batch in data.batches(batch_size, keys=keys):
        pred = predict_arrays(
            model, batch["left_eye"], batch["right_eye"], batch["head_pose"], batch_size, face=batch.get("face")
        )
        errs.append(angular_errors_deg(pred, batch["gaze"]))
    return float(np.concatenate(errs).mean())


def _save(obj: dict[str, Any], path: Path) -> None:
    from facemesh.io import atomic_write

    torch = import_torch()
    buf = io.BytesIO()
    torch.save(obj, buf)
    with atomic_write(path) as fh:
        fh.write(buf.getvalue())


#: What a model or checkpoint file may contain: tensors and plain Python values (dict, list, tuple, str,
#: int, float, bool, None), nothing else. Files are read with PyTorch's restricted unpickler
#: (``weights_only=True``), which refuses any other object before building it, so no code a file
#: carries can run. See docs/model.md, "What a model file may contain".
LOADER = "torch.load(weights_only=True)"


#: The key under which :func:`_load_plain` and :func:`load_model`'s ``meta`` give the SHA-256 (hex)
#: of the file's bytes as read.
FILE_SHA256_KEY = "file_sha256"


#: Callables a PyTorch file of tensors and plain values names (torch's own rebuild functions and
#: storages, an ordered dict): any other in a file is a crafted pickle's.
_TORCH_PICKLE_NAMES = ("torch.", "collections.OrderedDict")
#: The largest pickle inside a ``.pt`` archive that :func:`_pickle_outline` inflates, bytes.
_MAX_PICKLE_BYTES = 64 * 2**20


def _pickle_outline(raw: bytes) -> tuple[int | None, list[str]]:
    """The pickle protocol and the callables (``"module.name"``) a ``.pt`` file's pickle names.

    Read with :mod:`pickletools`, which parses the opcodes and builds nothing. ``raw``: the
    file's bytes, torch's zip format (its ``*/data.pkl``) or a bare pickle. Returns
    ``(None, [])`` when no pickle can be read from it; the names read before a damaged opcode.
    """
    import pickletools
    import zipfile

    data = raw
    if raw[:4] == b"PK\x03\x04":
        try:
            with zipfile.ZipFile(io.BytesIO(raw)) as zf:
                member = next((n for n in zf.namelist() if n.endswith("data.pkl")), None)
                # the pickle of a model holds names and plain values (the tensors are other members):
                # a larger one is not read (a crafted archive could inflate to any size)
                if member is None or zf.getinfo(member).file_size > _MAX_PICKLE_BYTES:
                    return None, []
                data = zf.read(member)
        except (zipfile.BadZipFile, OSError, EOFError, ValueError, KeyError):
            return None, []
    protocol: int | None = None
    names: list[str] = []
    strings: list[str] = []  # the strings pushed so far: STACK_GLOBAL takes its module and name from them
    try:
        for op, arg, _ in pickletools.genops(data):
            if op.name == "PROTO" and isinstance(arg, int):
                protocol = arg
            elif op.name in ("GLOBAL", "INST"):
                names.append(str(arg))
            elif op.name == "STACK_GLOBAL" and len(strings) >= 2:
                names.append(f"{strings[-2]} {strings[-1]}")
            elif isinstance(arg, str):
                strings.append(arg)
            if op.name == "STOP":
                break
    except Exception:  # noqa: BLE001 - a damaged stream: what was read so far
        pass
    return protocol, [n.replace(" ", ".", 1) for n in names]


def _load_plain(path: Path, what: str) -> dict[str, Any]:
    """A ``.pt`` file's top-level dict, read so that no code in the file can run.

    The file is read once; the SHA-256 (hex) of the bytes read is returned under the key
    :data:`FILE_SHA256_KEY` (a key no file of ours holds): what a calibration is tied to, of the
    very bytes the model was built from.

    Raises:
        GazeAugError: missing or unreadable, truncated, not a PyTorch file, holds objects other than
            tensors and plain values (a crafted pickle: refused before anything in it is built), or
            not a dict.
    """
    import pickle

    torch = import_torch()
    try:
        if not path.is_file():
            raise GazeAugError(f"{path}: no such {what} file")
        with path.open("rb") as fh:
            raw = fh.read()
    except OSError as exc:  # permissions, a folder on the way we may not enter, an I/O error
        raise GazeAugError(f"{path}: cannot read the {what} file ({exc.strerror or exc.__class__.__name__})") from exc
    try:
        with warnings.catch_warnings():  # "Detected pickle protocol 4 ...": a foreign file, refused below in words
            warnings.filterwarnings("ignore", message="Detected pickle protocol")
            obj = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        lines = [ln.strip() for ln in str(exc).splitlines()]
        named = [ln for ln in lines if "GLOBAL" in ln or "Unsupported global" in ln]
        protocol = None
        if not named:  # torch's safe unpickler stops at opcodes it does not know (pickle protocols 4
            # and 5) before it names any callable: read the opcodes (pickletools only parses)
            protocol, names = _pickle_outline(raw)
            named = [n for n in names if not n.startswith(_TORCH_PICKLE_NAMES)]
        if named:  # the file names a Python callable: a crafted pickle, refused before it is built
            raise GazeAugError(
                f"{path}: not a {what}: it holds objects other than tensors and plain values "
                f"({named[0]}); refused without running them"
            ) from exc
        if protocol is not None and protocol > 2:
            raise GazeAugError(
                f"{path}: not a {what} the safe loader can read (pickle protocol {protocol}; "
                "save it with torch.save's default protocol)"
            ) from exc
        raise GazeAugError(f"{path}: not a {what} (truncated, damaged or not a PyTorch file)") from exc
    except Exception as exc:  # noqa: BLE001 - torch raises many kinds for damaged files
        raise GazeAugError(
            f"{path}: not a {what} (truncated, damaged or not a PyTorch file: {exc.__class__.__name__})"
        ) from exc
    if not isinstance(obj, dict):
        raise GazeAugError(f"{path}: not a {what} (expected a dict, got {type(obj).__name__})")
    obj[FILE_SHA256_KEY] = hashlib.sha256(raw).hexdigest()
    return obj


def _state_dict(obj: dict[str, Any], path: Path, what: str) -> dict[str, Any]:
    torch = import_torch()
    sd = obj.get("state_dict")
    if not isinstance(sd, dict) or not all(isinstance(k, str) and torch.is_tensor(v) for k, v in sd.items()):
        raise GazeAugError(f"{path}: not a {what} (no 'state_dict' of named tensors)")
    return sd


def _load_weights(model: Any, state: dict[str, Any], path: Path, what: str) -> None:
    """Load ``state`` into ``model``, or say in one line how they disagree (names and shapes)."""
    want = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    got = {k: tuple(v.shape) for k, v in state.items()}
    missing, extra = sorted(set(want) - set(got)), sorted(set(got) - set(want))
    shapes = sorted(k for k in set(want) & set(got) if want[k] != got[k])
    problems = []
    if missing:
        problems.append(f"{len(missing)} tensors missing (first {missing[0]!r})")
    if extra:
        problems.append(f"{len(extra)} unexpected (first {extra[0]!r})")
    if shapes:
        k = shapes[0]
        problems.append(f"{len(shapes)} of other shapes (first {k!r}: expected {want[k]}, got {got[k]})")
    if problems:
        raise GazeAugError(f"{path}: the weights do not fit the {what}'s model: {'; '.join(problems)}")
    model.load_state_dict(state)


def load_model(
    path: str | Path, device: str = "cpu", *, mirror_average: bool | None = None
) -> tuple[Any, dict[str, Any]]:
    """A model saved by :func:`train` and its metadata (name, options, preprocessing, normalization, log).

    The file is read with PyTorch's restricted unpickler (tensors and plain values only): a file
    that carries code is refused and nothing in it runs.

    The model's input mode (``preprocessing["input"]``; ``rgb`` when absent) is attached to the
    model, so :func:`predict_arrays` prepares its inputs the same way, and given as
    ``meta["input_mode"]``.

    A model whose file says ``prediction.mirror_average`` (every model :func:`train` makes with
    the default settings) is returned wrapped by :func:`gazeaug.models.mirror.mirror_averaged`;
    ``meta["mirror_average"]`` says which. A file without the entry (made before it) predicts
    as it always did, unwrapped. Likewise ``prediction.shift_average_px`` (0 when absent, as in
    every file made before 2026-11-28): the network is wrapped by
    :func:`gazeaug.models.shift.shift_averaged` inside the mirror averaging;
    ``meta["shift_average_px"]`` says by how much.

    ``mirror_average`` (default None: as the file says) overrides the file's mirror averaging:
    False reads the network plainly (a model trained on the very people it reads is better so:
    docs/model.md), True averages a file that does not. ``meta["mirror_average"]`` says what is
    applied; ``meta["prediction"]`` stays the file's own entry.

    The metadata are checked: the weights must be finite, ``normalization`` a dict that
    :meth:`NormalizationSettings.from_dict` accepts (an absent key takes its default; ``meta``
    holds it in full) and ``patch_size_wh`` two integers within the settings' bounds.

    Raises:
        GazeAugError: missing, unreadable, truncated, crafted or not a gazeaug model; an unknown
            input preprocessing; non-finite weights; unusable ``normalization`` or ``patch_size_wh``;
            a ``prediction`` entry that is not ``{"mirror_average": bool, "shift_average_px": int}``
            (a translation not smaller than the patch's sides included); a model that reads a face
            patch whose normalization makes none; a ``mirror_average`` that is not None, True or False.
    """
    p = Path(path)
    mirror_average = check_mirror_average(mirror_average)
    obj = _load_plain(p, "gazeaug model")
    if obj.get("format") != MODEL_FORMAT:
        raise GazeAugError(f"{p}: not a gazeaug model (no '{MODEL_FORMAT}' format mark)")
    try:  # version 1 without an 'input' key: every model made before input modes, RGB
        input_mode = input_mode_from_record(obj.get("preprocessing"))
    except GazeAugError as exc:
        raise GazeAugError(f"{p}: {exc}") from exc
    name, options = obj.get("model"), obj.get("model_options", {})
    if not isinstance(name, str) or not isinstance(options, dict) or not all(isinstance(k, str) for k in options):
        raise GazeAugError(f"{p}: not a gazeaug model (bad 'model' or 'model_options' entries)")
    state = _state_dict(obj, p, "gazeaug model")
    _check_finite(state, p)
    normalization = _normalization(obj.get("normalization", {}), p, "model")
    patch = _patch_size(obj.get("patch_size_wh", list(NormalizationSettings().patch_size_wh)), p)
    try:
        model = create_model(name, **options)
    except TypeError as exc:
        raise GazeAugError(f"{p}: model {name!r} does not take the options {options} ({exc})") from exc
    except GazeAugError as exc:  # an unknown name, or an option's value refused
        raise GazeAugError(f"{p}: {exc}") from exc
    _load_weights(model, state, p, f"gazeaug model ({name})")
    if uses_face(model):
        if normalization.face_patch_size_wh is None:
            raise GazeAugError(
                f"{p}: the model reads a face patch, and its normalization makes none (face_patch_size_wh)"
            )
    file_mirror, shift = _prediction(obj.get("prediction", {}), p, patch)
    mirror = file_mirror if mirror_average is None else mirror_average
    if shift:
        from .models.shift import shift_averaged

        model = shift_averaged(model, shift)
    if mirror:
        from .models.mirror import mirror_averaged

        model = mirror_averaged(model)
    if uses_face(model):
        model.face_patch_size_wh = normalization.face_patch_size_wh  # predict_arrays checks what it is given
    if tuple(patch) == normalization.patch_size_wh:  # likewise the eye patches' size (files from before
        model.patch_size_wh = tuple(patch)  # the training checked the two agree may differ: not checked)
    model.to(_device(device)).eval()
    set_input_mode(model, input_mode)  # predict_arrays (evaluate, predict) reads it
    meta = {k: v for k, v in obj.items() if k != "state_dict"}
    meta["input_mode"] = input_mode
    meta["uses_face"] = uses_face(model)
    meta["mirror_average"] = mirror
    meta["shift_average_px"] = shift
    meta["normalization"] = normalization.as_dict()  # checked, in full (absent keys: the defaults)
    meta["patch_size_wh"] = patch
    return model, meta  # meta[FILE_SHA256_KEY]: the digest of the bytes read (_load_plain)


def check_mirror_average(value: Any) -> bool | None:
    """A mirror-averaging choice when loading a model: None (as the file says), True or False.

    Raises:
        GazeAugError: anything else (a string such as ``"off"`` included).
    """
    if value is None:
        return None
    if not isinstance(value, (bool, np.bool_)):
        raise GazeAugError(f"mirror_average: expected None, True or False, got {value!r:.80}")
    return bool(value)


def _prediction(value: Any, path: Path, patch_wh: Sequence[int]) -> tuple[bool, int]:
    """A model file's ``prediction`` entry: ``(mirror_average, shift_average_px)``.

    A dict whose ``mirror_average`` (False when absent) is a bool and whose ``shift_average_px``
    (0 when absent) an integer from 0 to :data:`MAX_SHIFT_AVERAGE_PX`, smaller than the patch's
    sides ``patch_wh`` (width, height).
    """
    expected = "expected {'mirror_average': true or false, 'shift_average_px': 0 to 8}"
    if not isinstance(value, dict):
        raise GazeAugError(f"{path}: not a usable gazeaug model: 'prediction': {expected}, got {value!r:.80}")
    flag, px = value.get("mirror_average", False), value.get("shift_average_px", 0)
    if not isinstance(flag, bool) or not (_is_integer(px) and 0 <= px <= MAX_SHIFT_AVERAGE_PX):
        raise GazeAugError(f"{path}: not a usable gazeaug model: 'prediction': {expected}, got {value!r:.80}")
    if px >= min(patch_wh):
        raise GazeAugError(
            f"{path}: not a usable gazeaug model: 'prediction': shift_average_px {px} must be smaller than "
            f"the patch's sides {list(patch_wh)}"
        )
    return flag, int(px)


def _check_finite(state: dict[str, Any], path: Path) -> None:
    """Refuse weights (or buffers) holding NaN or infinity: every prediction would be NaN."""
    torch = import_torch()
    for k, v in state.items():
        if v.is_floating_point() or v.is_complex():
            if not bool(torch.isfinite(v).all()):
                bad = int((~torch.isfinite(v)).sum())
                raise GazeAugError(
                    f"{path}: not a usable gazeaug model: non-finite weights in {k} "
                    f"({bad} of {v.numel()} values are NaN or infinite)"
                )


def _normalization(value: Any, path: Path, what: str) -> NormalizationSettings:
    """A recorded ``normalization`` entry as settings, or a GazeAugError naming the file."""
    try:
        return NormalizationSettings.from_dict(value)
    except GazeAugError as exc:
        raise GazeAugError(f"{path}: the {what}'s normalization settings are not usable: {exc}") from exc


def _patch_size(value: Any, path: Path) -> list[int]:
    """A model's ``patch_size_wh``: two integers within :attr:`NormalizationSettings.PATCH_SIDE_RANGE`."""
    try:
        return list(NormalizationSettings(patch_size_wh=value).patch_size_wh)
    except GazeAugError as exc:
        raise GazeAugError(f"{path}: not a usable gazeaug model: 'patch_size_wh': {exc}") from exc


def _data_selection(
    train_path: str | Path,
    val_path: str | Path | None,
    val_subjects: Sequence[str] | None,
    data: H5TrainingSet,
    val: H5TrainingSet | None,
) -> dict[str, Any]:
    """What a run trains and validates on (a resumed run must use exactly the same).

    The paths, and the fingerprints of the training and validation rows
    (:attr:`H5TrainingSet.fingerprint`: row count and a SHA-1 of the rows' labels and subjects;
    :attr:`H5TrainingSet.patch_fingerprint`: a SHA-1 of a sample of their patches), so another
    file put in the same place, or the same labels with images made anew, is told apart.
    """
    return {
        "train_path": str(Path(train_path).resolve()),
        "val_path": None if val_path is None else str(Path(val_path).resolve()),
        "val_subjects": sorted(set(val_subjects or [])),
        "train_fingerprint": data.fingerprint,
        "val_fingerprint": None if val is None else val.fingerprint,
        "train_patches": data.patch_fingerprint,
        "val_patches": None if val is None else val.patch_fingerprint,
    }


#: Data-selection keys a checkpoint of an older gazeaug may lack (not compared when it does).
_LATER_SELECTION_KEYS = ("train_patches", "val_patches")


def _recorded_settings(then: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint's settings with what an older gazeaug did not record filled in as it trained."""
    out = {**_LEGACY_SETTINGS, **then}
    if isinstance(out.get("augment"), dict):  # an augment record from before a field existed
        out["augment"] = {**_LEGACY_AUGMENT, **out["augment"]}
    return out


def _with_older_defaults(s: TrainSettings, recorded: dict[str, Any], given: Collection[str] = ()) -> TrainSettings:
    """``s`` resuming a run begun under an older default (:data:`_OLDER_DEFAULTS`, :data:`_OLDER_AUGMENT_DEFAULTS`).

    Where the run recorded the older default and ``s`` leaves the field at today's, the run goes on
    with its own value (``gazeaug train --resume`` cannot tell a default from a value given), except
    for the fields named in ``given``.
    """
    default = TrainSettings()
    older = {
        k: v
        for k, v in _OLDER_DEFAULTS
        if k not in given and recorded.get(k) == v and getattr(s, k) == getattr(default, k)
    }
    then_aug = recorded.get("augment")
    if isinstance(then_aug, dict):
        aug = {
            k: v
            for k, v in _OLDER_AUGMENT_DEFAULTS
            if then_aug.get(k) == v and getattr(s.augment, k) == getattr(default.augment, k)
        }
        if aug:
            older["augment"] = replace(s.augment, **aug)
    return replace(s, **older)


def _resumed_sizes(s: TrainSettings, then: dict[str, Any]) -> TrainSettings:
    """``s`` with the epochs and batch size it leaves to None taken from ``then``, a checkpoint's settings.

    A run left to :meth:`TrainSettings.fitted` resumes with what it was fitted to (and a checkpoint of
    an older gazeaug, whose defaults were 10 epochs at batch 256, with those); values ``then`` lacks
    stay None (the settings check then names the difference).
    """

    def taken(mine: int | None, theirs: Any) -> int | None:
        if mine is not None or not (_is_integer(theirs) and theirs >= 1):
            return mine
        return int(theirs)

    epochs, batch = taken(s.epochs, then.get("epochs")), taken(s.batch_size, then.get("batch_size"))
    return replace(s, epochs=epochs, batch_size=batch)


def _differences(then: dict[str, Any], now: dict[str, Any]) -> list[str]:
    return [
        f"{k}: {then.get(k)!r} then, {now.get(k)!r} now"
        for k in sorted(set(then) | set(now))
        if then.get(k) != now.get(k)
    ]


def train(
    train_path: str | Path,
    output: str | Path,
    settings: TrainSettings | None = None,
    *,
    val_path: str | Path | None = None,
    val_subjects: Sequence[str] | None = None,
    resume: bool = False,
    progress: bool = True,
    given: Collection[str] = (),
    preload: str = "auto",
    keep_unfinished: bool = False,
    cuda_graphs: bool = True,
) -> list[dict[str, Any]]:
    """Train a model and save it to ``output`` (``.pt``); returns the per-epoch log.

    Args:
        train_path: training set (.h5).
        output: the model file; ``.ckpt.pt``, ``.log.csv`` and ``.curves.png`` go beside it.
        settings: hyper-parameters.
        val_path: a validation set (.h5), read after each epoch in batches of the training's batch size.
        val_subjects: instead, hold these subjects of the training set out for validation.
        resume: continue from ``output``'s checkpoint.
        progress: show a progress bar.
        given: names of ``settings`` fields chosen on purpose (``gazeaug train --lr``). A resumed run
            begun under an older default (:data:`_OLDER_DEFAULTS`) goes on with its own value where
            ``settings`` holds today's default, since a default cannot be told from a value given;
            a field named here is kept as given, so a difference from the run is refused.
        preload: where the batches come from (:mod:`gazeaug.train_data`): ``auto`` (default) holds
            the training rows on the device, read once, when they fit in half the memory free
            there (on the host, at most 16 GiB), else streams them from the file each epoch;
            ``yes`` holds them whatever their size, ``no`` streams them. The batches, and so the
            model, are the same either way: only the speed and the memory differ.
        keep_unfinished: without ``resume``, refuse to start over where a run that did not finish
            left its checkpoint (:func:`unfinished_checkpoint`), rather than replace it at the first
            epoch (``gazeaug train`` sets it: the epochs done are not lost to a forgotten ``--resume``).
        cuda_graphs: on CUDA, replay the model's forward and backward of full batches as CUDA graphs
            (:mod:`gazeaug.train_graphs`; 2.5-3.1 x the samples per second of the default model at
            batch 256 on an H200); False calls the model eagerly. The same training either way;
            ignored on the CPU.

    Raises:
        GazeAugError: bad files or settings; an unfinished run's checkpoint with ``keep_unfinished``
            (``remedy="resume"``); the GPU or the host out of memory (``remedy="memory"``: what needs
            less said, and the checkpoint of the epochs finished before it named).
    """
    from facemesh.outputs import output_lock

    s = settings or TrainSettings()
    out = Path(output)
    if out.suffix != ".pt":
        raise GazeAugError(f"{out}: the model file must end in .pt")
    if val_path is not None and val_subjects:
        raise GazeAugError("give a validation set or validation subjects, not both")
    check_preload(preload)  # before any work
    if val_subjects is not None:
        if isinstance(val_subjects, (str, bytes)):
            raise GazeAugError(f"validation subjects: expected a list of names, got the string {val_subjects!r}")
        # plain str (numpy strings would land in the files as numpy scalars, which the safe loader refuses)
        val_subjects = [v.decode() if isinstance(v, bytes) else str(v) for v in val_subjects]
    with output_lock(out):  # held for the whole run: a second run on the same model is refused
        if keep_unfinished and not resume:
            _refuse_unfinished(out)
        try:
            return _train(
                train_path, out, s, val_path, val_subjects, resume, progress, frozenset(given), preload, cuda_graphs
            )
        except (RuntimeError, MemoryError) as exc:  # torch.OutOfMemoryError is a RuntimeError
            if not _out_of_memory(exc):
                raise
            first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else exc.__class__.__name__
            where = TracebackText(exc)  # the traceback as text: no frames held
        # raised here, outside the handler: the failed run's frames (model, held rows, graphs) are freed now
        ckpt = unfinished_checkpoint(out)
        kept = f"; the finished epochs are kept in {ckpt} (resumable with the same settings)" if ckpt else ""
        raise GazeAugError(
            f"out of memory while training ({first}): a smaller batch size, the rows streamed rather than "
            f"held, or a smaller model needs less{kept}",
            remedy="memory",
        ) from where


#: Phrases of the out-of-memory errors PyTorch raises as plain RuntimeErrors (the host's allocator,
#: cuBLAS's and cuDNN's workspaces, a pinned-memory allocation); torch.OutOfMemoryError is matched by type.
_OOM_PHRASES = ("out of memory", "can't allocate memory", "CUBLAS_STATUS_ALLOC_FAILED", "CUDNN_STATUS_ALLOC_FAILED")


def _out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` says the device or the host ran out of memory."""
    torch = import_torch()
    oom = getattr(torch, "OutOfMemoryError", None) or torch.cuda.OutOfMemoryError
    return isinstance(exc, (oom, MemoryError)) or any(p in str(exc) for p in _OOM_PHRASES)


def unfinished_checkpoint(output: str | Path) -> Path | None:
    """``output``'s checkpoint (``MODEL.ckpt.pt``) when a run that did not finish left it, else None.

    Read, not dated (a copy or ``touch`` changes a date): a checkpoint whose epoch is short of the
    epochs its settings record is unfinished, and so is a checkpoint of every epoch with no model
    file beside it (the run stopped, or failed, while writing the model: ``--resume`` writes it).
    None when there is no checkpoint, or one that cannot be read as a gazeaug checkpoint (nothing
    could resume from it).
    """
    ckpt = Path(output).with_suffix(".ckpt.pt")
    if not ckpt.is_file():
        return None
    try:
        ck = _load_plain(ckpt, "gazeaug checkpoint")
    except GazeAugError:
        return None
    epoch: Any = ck.get("epoch")
    settings: Any = ck.get("settings")
    epochs: Any = settings.get("epochs") if isinstance(settings, dict) else None
    if _is_integer(epoch) and _is_integer(epochs) and 0 <= epoch <= epochs:
        if epoch < epochs or not Path(output).exists():
            return ckpt
    return None


def _refuse_unfinished(out: Path) -> None:
    """Raise when ``out``'s checkpoint was left by a run that did not finish (called under the output's lock)."""
    ckpt = unfinished_checkpoint(out)
    if ckpt is not None:
        raise GazeAugError(
            f"{ckpt}: a run that did not finish left it (no run is writing it now); starting over would replace it",
            remedy="resume",
        )


def _train(
    train_path: str | Path,
    out: Path,
    s: TrainSettings,
    val_path: str | Path | None,
    val_subjects: Sequence[str] | None,
    resume: bool,
    progress: bool,
    given: frozenset[str] = frozenset(),
    preload: str = "auto",
    cuda_graphs: bool = True,
) -> list[dict[str, Any]]:
    torch = import_torch()
    ckpt_path = out.with_suffix(".ckpt.pt")
    data = H5TrainingSet(train_path, exclude_subjects=val_subjects or None)
    ck: dict[str, Any] = {}
    if resume:  # read once: its settings decide the sizes left to None, the rest is checked below
        if not ckpt_path.is_file():
            raise GazeAugError(f"{ckpt_path}: no checkpoint to resume from")
        ck = _load_plain(ckpt_path, "gazeaug checkpoint")
        if isinstance(ck.get("settings"), dict):
            then_samples: Any = _recorded_settings(ck["settings"]).get("auto_samples")
            left_out = "auto_samples" not in given and s.auto_samples == TrainSettings.auto_samples
            if (
                (s.epochs is not None or left_out)
                and _is_integer(then_samples)
                and 1 <= then_samples <= MAX_AUTO_SAMPLES
            ):
                # epochs given: auto_samples decides nothing in this run, so it is not compared (the
                # recorded epochs are); left out: the run's own, as the epochs and batch size left out
                s = replace(s, auto_samples=int(then_samples))
            s = _resumed_sizes(s, ck["settings"])  # left to None: the run being resumed decided them
            s = _with_older_defaults(s, _recorded_settings(ck["settings"]), given)
    s = s.fitted(len(data))  # epochs and batch size left to the data size: fixed now, recorded in the files
    n_epochs, batch_size = int(s.epochs or 0), int(s.batch_size or 0)
    # recorded in the model and used by predict and evaluate: checked now, not after the training
    normalization = _normalization(data.settings.get("normalization", {}), data.path, "training set")
    if normalization.patch_size_wh != tuple(data.patch_size_wh):
        if "normalization" in data.settings:
            raise GazeAugError(
                f"{data.path}: its eye patches are {data.patch_size_wh[0]} x {data.patch_size_wh[1]} px, its recorded "
                f"normalization makes {normalization.patch_size_wh[0]} x {normalization.patch_size_wh[1]} px ones"
            )
        # a set that records no normalization: the defaults, at the size of its patches
        normalization = NormalizationSettings.from_dict(
            {**normalization.as_dict(), "patch_size_wh": data.patch_size_wh}
        )
    if s.shift_average_px >= min(data.patch_size_wh):
        raise GazeAugError(
            f"shift_average_px: {s.shift_average_px} px must be smaller than the eye patches' sides "
            f"({data.patch_size_wh[0]} x {data.patch_size_wh[1]} in {data.path})"
        )
    val = None
    if val_path is not None:
        val = H5TrainingSet(val_path)
    elif val_subjects:
        val = H5TrainingSet(train_path, subjects=val_subjects)
    torch.manual_seed(s.seed)
    device = _device(s.device)
    model = create_model(s.model, **s.model_options).to(device)
    face = uses_face(model)
    if face:  # the face patches come from the training set, made as test time makes them
        for what in (data, val):
            if what is None:
                continue
            if what.face_patch_size_wh is None:
                raise GazeAugError(
                    f"{what.path}: the model reads a normalized face patch, and this set has none "
                    "(make it with --face-patch W H)"
                )
            made = _normalization(what.settings.get("normalization", {}), what.path, "training set")
            if (made.face_patch_size_wh, made.face_distance_mm, made.face_focal_px) != (
                normalization.face_patch_size_wh,
                normalization.face_distance_mm,
                normalization.face_focal_px,
            ) or made.face_patch_size_wh != what.face_patch_size_wh:
                raise GazeAugError(
                    f"{what.path}: its face patches ({what.face_patch_size_wh}, recorded as made by "
                    f"{made.face_patch_size_wh} px at {made.face_distance_mm:g} mm with {made.face_focal_px:g} px) "
                    f"differ from the training set's ({normalization.face_patch_size_wh} px at "
                    f"{normalization.face_distance_mm:g} mm with {normalization.face_focal_px:g} px)"
                )
    _check_fits(model, s, data, device)
    weights = axis_weights(data.gaze) if s.balance_axes else (1.0, 1.0)
    loss_weights = torch.tensor(weights, dtype=torch.float32, device=device)
    keypoints = s.keypoint_loss_weight > 0
    kp_head: Any = None
    kp_hook: Any = None
    params = list(model.parameters())
    if keypoints:
        if not data.has_eye_keypoints:
            raise GazeAugError(
                f"{data.path}: a keypoint loss needs the eye keypoints of the rows, this set has none "
                "(make it with augment --redirect-eyes, whose eyes are drawn)"
            )
        if not np.isfinite(data.eye_keypoints()).any():
            raise GazeAugError(f"{data.path}: a keypoint loss needs eye keypoints, every row's are unknown (NaN)")
        kp_head, kp_hook = attach_keypoint_head(model, data.patch_size_wh, len(EYE_KEYPOINTS))
        params += list(kp_head.parameters())  # after the model's: a checkpoint's optimizer state lines up
    # one fused kernel per step on CUDA (the same update; the host's launching bounds a small model's step)
    opt = torch.optim.AdamW(params, lr=s.lr, weight_decay=s.weight_decay, fused=device.type == "cuda")
    steps_per_epoch = math.ceil(len(data) / batch_size)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(
        opt, T_max=max(1, n_epochs * steps_per_epoch), eta_min=s.lr / 100
    )
    log: list[dict[str, Any]] = []
    start_epoch = 0
    selection = _data_selection(train_path, val_path, val_subjects, data, val)
    if resume:
        missing = [k for k in _CKPT_KEYS if k not in ck]
        if missing == ["data_selection"]:
            raise GazeAugError(
                f"{ckpt_path}: made by an older gazeaug that did not record its data selection; start over"
            )
        if missing:
            raise GazeAugError(f"{ckpt_path}: not a gazeaug checkpoint (missing {missing})")
        then_settings = ck.get("settings")
        if not isinstance(then_settings, dict):
            raise GazeAugError(f"{ckpt_path}: a damaged gazeaug checkpoint (its 'settings' are not a dict)")
        then_all = _recorded_settings(then_settings)
        # a checkpoint from before mirror averaging trained as every run does (it changes only the
        # prediction): it resumes with either setting; a recorded one must match, like every setting
        then_all.setdefault("mirror_average", s.mirror_average)
        then_all.setdefault("shift_average_px", s.shift_average_px)  # likewise, from before 2026-11-28
        changed = _differences(then_all, asdict(s))
        if changed:
            hint = ""
            if any(k not in then_settings for k in ("augment", "input_mode")):
                hint = (
                    "; made by an older gazeaug, without training-time augmentation and with RGB input: "
                    "resume it with --no-augment --input rgb (TrainAugment(enabled=False), input_mode='rgb') "
                    "or start over"
                )
            raise GazeAugError(f"{ckpt_path}: the checkpoint was made with other settings ({'; '.join(changed)}{hint})")
        then = ck.get("data_selection")
        if not isinstance(then, dict) or "train_fingerprint" not in then:
            raise GazeAugError(
                f"{ckpt_path}: made by an older gazeaug that did not record its training data's fingerprint; start over"
            )
        # a checkpoint from before the patches' fingerprint: its labels' fingerprint alone is compared
        compared = {k: v for k, v in selection.items() if k in then or k not in _LATER_SELECTION_KEYS}
        changed = _differences(then, compared)
        if changed:
            raise GazeAugError(
                f"{ckpt_path}: the checkpoint was made with another data selection ({'; '.join(changed)})"
            )
        _load_weights(model, _state_dict(ck, ckpt_path, "gazeaug checkpoint"), ckpt_path, "gazeaug checkpoint")
        if kp_head is not None:
            head_state = ck.get("keypoint_head")
            if not isinstance(head_state, dict):
                raise GazeAugError(f"{ckpt_path}: a damaged gazeaug checkpoint (no keypoint head's weights)")
            _load_weights(kp_head, head_state, ckpt_path, "gazeaug checkpoint")
        try:
            saved_opt = ck["optimizer"]
            groups = saved_opt.get("param_groups") if isinstance(saved_opt, dict) else None
            for g in groups if isinstance(groups, list) else []:  # the kernel: this device's, not the checkpoint's
                if isinstance(g, dict):
                    g["fused"], g["foreach"] = device.type == "cuda", None
            opt.load_state_dict(saved_opt)
            sched.load_state_dict(ck["scheduler"])
            log = [dict(r) for r in ck["log"]]
            start_epoch = int(ck["epoch"])
            torch.set_rng_state(ck["torch_rng"])
        except (RuntimeError, KeyError, ValueError, TypeError) as exc:
            raise GazeAugError(f"{ckpt_path}: a damaged gazeaug checkpoint ({exc.__class__.__name__}: {exc})") from exc
        if not 0 <= start_epoch <= n_epochs or len(log) != start_epoch:
            raise GazeAugError(f"{ckpt_path}: a damaged gazeaug checkpoint (epoch {start_epoch}, {len(log)} log rows)")
    cuda = device.type == "cuda"
    graphed: Any = None  # full batches' forward and backward as CUDA graphs (train_graphs)
    # the same batches either way (train_data): held on the device, read once, or streamed each epoch
    resident = hold_rows(data, device, face, preload, keypoints)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(
            total=n_epochs * len(data), initial=start_epoch * len(data), unit="sample", desc="train", dynamic_ncols=True
        )
    set_input_mode(model, s.input_mode)  # the validation's predict_arrays prepares inputs as training does
    with interrupt_between_steps() as interrupted:  # Ctrl-C taken between steps, never lost in a callback
        # a keypoint loss reads the encoder's map through a hook: not with a captured graph
        if cuda and cuda_graphs and not keypoints and start_epoch < n_epochs and len(data) >= batch_size:
            graphed = _capture(model, data, batch_size, face, device, s)  # before any epoch's reading thread runs
        for epoch in range(start_epoch, n_epochs):
            rng = np.random.default_rng([s.seed, epoch])
            gen = augment_generator(s.seed, epoch, device)
            model.train()
            t0 = time.perf_counter()
            losses, preds, gazes, sizes, kp_losses = [], [], [], [], []
            batches_cm = epoch_batches(data, resident, batch_size, rng, pin=cuda, face=face, keypoints=keypoints)
            with contextlib.closing(batches_cm) as batches:
                for step, tensors in enumerate(batches):
                    n = len(tensors["gaze"])
                    t = train_inputs(tensors, device, s.augment, s.input_mode, gen)
                    y = t.gaze
                    call = graphed if graphed is not None and n == batch_size else model
                    with torch.autocast("cuda", dtype=torch.bfloat16, enabled=cuda, cache_enabled=False):
                        pred = call(*t.model_args)
                        found = kp_head() if kp_head is not None else None  # (2B, K, 2): lefts, then rights
                    if call is graphed:
                        pred = pred.clone()  # the graph's output memory is overwritten by the next step
                    loss = ((pred.float() - y).abs() * loss_weights).mean()
                    if found is not None:
                        found = torch.stack([found[:n], found[n:]], dim=1)  # (B, 2, K, 2), as the targets
                        kp_term = keypoint_loss(found.float(), t.eye_keypoints)
                        loss = loss + s.keypoint_loss_weight * kp_term
                        kp_losses.append(kp_term.detach())
                        kp_head.feature_map = None  # the map goes with the step
                    opt.zero_grad(set_to_none=True)
                    with quiet_stream_mismatch(graphed is not None):
                        loss.backward()
                    opt.step()
                    sched.step()
                    losses.append(loss.detach())  # no synchronisation with the device inside the epoch
                    preds.append(pred.detach().float())
                    gazes.append(y.detach())  # the labels the model was given (a mirrored sample's yaw is negated)
                    sizes.append(n)
                    if bar is not None:
                        bar.update(n)
                        if step % 20 == 0:
                            bar.set_postfix(loss=f"{loss.item():.4f}")
                    if interrupted():
                        raise KeyboardInterrupt
            seen = sum(sizes)
            step_losses = torch.stack(losses).double().cpu().numpy()
            train_errors = angular_errors_deg(torch.cat(preds).cpu().numpy(), torch.cat(gazes).double().cpu().numpy())
            seconds = time.perf_counter() - t0
            row = {
                "epoch": epoch + 1,
                "train_loss": float(np.dot(step_losses, sizes) / seen),
                "train_error_deg": float(train_errors.mean()),
                # the training's own batch size: --batch-size is the one remedy an out of memory names
                "val_error_deg": _evaluate_set(model, val, batch_size) if val is not None else None,
                "seconds": round(seconds, 3),
                "samples_per_second": round(seen / seconds, 1),
            }
            if kp_losses:  # the keypoint term's mean absolute error, px (train_loss includes W times it / 10)
                steps_kp = torch.stack(kp_losses).double().cpu().numpy() * KEYPOINT_SCALE_PX
                row["keypoint_error_px"] = float(np.dot(steps_kp, sizes) / seen)
            log.append(row)
            if bar is not None:
                bar.write(json.dumps(row))
            _save(
                {
                    "state_dict": model.state_dict(),
                    "optimizer": opt.state_dict(),
                    "scheduler": sched.state_dict(),
                    "epoch": epoch + 1,
                    "settings": asdict(s),
                    "data_selection": selection,
                    "log": log,
                    "torch_rng": torch.get_rng_state(),
                    **({"keypoint_head": kp_head.state_dict()} if kp_head is not None else {}),
                },
                ckpt_path,
            )
    if kp_hook is not None:  # the model file holds the gaze network alone
        kp_hook.remove()
        kp_head.feature_map = None
    if graphed is not None:  # the graphs and their memory go now, not at a later garbage collection
        vars(graphed).pop("forward", None)  # PyTorch's replayed forward closes over the wrapper: a cycle
    if bar is not None:
        bar.close()
    _save(
        {
            "format": MODEL_FORMAT,
            "gazeaug_version": __version__,
            "model": s.model,
            "model_options": dict(s.model_options),
            "state_dict": {k: v.cpu() for k, v in model.state_dict().items()},
            "preprocessing": preprocessing_record(s.input_mode),
            "prediction": {"mirror_average": s.mirror_average, "shift_average_px": s.shift_average_px},
            "normalization": normalization.as_dict(),
            "patch_size_wh": list(data.patch_size_wh),
            "train_settings": asdict(s),
            "loss_weights_pitch_yaw": list(weights),
            "train_data": str(train_path),
            "val_subjects": list(val_subjects or []),
            "log": log,
        },
        out,
    )
    _write_log(out, log)
    return log


def _write_log(out: Path, log: list[dict[str, Any]]) -> None:
    from facemesh.io import atomic_write

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(log[0]), lineterminator="\n")
    w.writeheader()
    w.writerows(log)
    with atomic_write(out.with_suffix(".log.csv")) as fh:
        fh.write(buf.getvalue().encode("utf-8"))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    ep = [r["epoch"] for r in log]
    ax.plot(ep, [r["train_error_deg"] for r in log], "o-", label="train")
    if any(r["val_error_deg"] is not None for r in log):
        ax.plot(ep, [r["val_error_deg"] for r in log], "s-", label="validation")
    ax.set_xlabel("epoch")
    ax.set_ylabel("angular error (deg)")
    ax.grid(alpha=0.3)
    ax.legend()
    with atomic_write(out.with_suffix(".curves.png")) as fh:
        fig.savefig(fh, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
