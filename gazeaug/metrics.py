"""Metrics of a gaze model's predictions: does it read the eyes, or only guess well?

Every function takes predicted and true gaze as ``(N, 2)`` float arrays of
(pitch, yaw) in radians, both in the same frame: the face-centre normalized
frame the model predicts in (the *face frame*; :mod:`facemesh.conventions`
gives the angle convention), and, where needed, ``(N,)`` subject names.
Errors are angles between 3D unit gaze vectors, in degrees.

A mean error alone cannot tell a model that reads eyes from one that outputs
nearly the same direction for every image. So besides it:

- the **constant guess** (:func:`constant_guess_error_deg`): the mean error of
  predicting the test set's own mean gaze direction for every sample. The
  *mean gaze direction* (:func:`mean_gaze`) is the normalized mean of the 3D
  unit gaze vectors (``pitchyaw_to_vector``), converted back to (pitch, yaw)
  with ``vector_to_pitchyaw``. It is an oracle (it knows the test labels) and
  nearly the best constant: the normalized mean minimizes the mean squared
  chord distance ``2 - 2 cos(angle)``, not the mean angle, so another
  constant may do slightly better. A model whose error is not clearly below
  it (``ratio_to_constant`` near 1 or above) has learnt nothing usable from
  the eyes;
- **bias vs reading** (:func:`global_offset`, :func:`bias_removed_error_deg`):
  the model's global offset (mean predicted-minus-true pitch and yaw, the yaw
  difference wrapped into (-pi, pi]) is subtracted from every prediction
  before the error is taken. What is left is the part a per-setup calibration
  of one offset cannot remove: a model that reads the eyes but is shifted by
  a constant scores 0 here;
- **correlation** (:func:`pearson`): Pearson's r of predicted vs true pitch
  and of predicted vs true yaw (NaN where either is constant: a constant
  predictor has no correlation);
- **per-subject** mean errors (:func:`per_subject_errors_deg`);
- **per person: offset vs reading** (:func:`subject_offsets_removed_error_deg`,
  :func:`pearson_within_subjects`): the error after each subject's own offset
  is removed from that subject's predictions (what a one-offset calibration
  per person, :mod:`gazeaug.calibration`'s ``bias``, could reach at best), and
  Pearson's r within subjects (each subject's mean predicted and mean true
  angle removed before r is taken): whether the model follows a person's gaze
  from image to image, whatever offset it has for that person;
- a **bootstrap interval** of the relative error reduction between two models
  on the same samples (:func:`bootstrap_reduction`), resampling subjects (all
  of a subject's samples together: what generalizes to new people) or
  single samples (only the sampling noise of these images).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from facemesh.conventions import angular_error_deg, pitchyaw_to_vector, vector_to_pitchyaw

from .errors import GazeAugError

__all__ = [
    "angular_errors_deg",
    "mean_error_deg",
    "mean_gaze",
    "constant_guess_error_deg",
    "global_offset",
    "bias_removed_error_deg",
    "pearson",
    "per_subject_errors_deg",
    "subject_offsets_removed_error_deg",
    "pearson_within_subjects",
    "relative_reduction_percent",
    "bootstrap_reduction",
    "summarize",
    "RESAMPLE_UNITS",
]

#: What :func:`bootstrap_reduction` may resample.
RESAMPLE_UNITS = ("subjects", "samples")


def _pitchyaw(a: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise GazeAugError(f"{name}: expected (N, 2) (pitch, yaw) radians, got shape {arr.shape}")
    if len(arr) == 0:
        raise GazeAugError(f"{name}: no samples")
    if not np.all(np.isfinite(arr)):
        raise GazeAugError(f"{name}: expected finite angles, got NaN or infinity")
    return arr


def _pair(pred: ArrayLike, true: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    p, t = _pitchyaw(pred, "predicted gaze"), _pitchyaw(true, "true gaze")
    if p.shape != t.shape:
        raise GazeAugError(f"predicted and true gaze: expected the same shape, got {p.shape} and {t.shape}")
    return p, t


def _subjects(subjects: ArrayLike, n: int) -> NDArray[np.str_]:
    s = np.asarray(subjects).astype(str)
    if s.shape != (n,):
        raise GazeAugError(f"subjects: expected ({n},) names, one per sample, got shape {s.shape}")
    return s


def _errors(errors: ArrayLike, name: str) -> NDArray[np.float64]:
    e = np.asarray(errors, dtype=np.float64)
    if e.ndim != 1 or len(e) == 0:
        raise GazeAugError(f"{name}: expected (N,) errors in degrees, N >= 1, got shape {e.shape}")
    if not np.all(np.isfinite(e)) or np.any(e < 0):
        raise GazeAugError(f"{name}: expected finite errors >= 0 degrees")
    return e


def angular_errors_deg(pred: ArrayLike, true: ArrayLike) -> NDArray[np.float64]:
    """(N, 2) and (N, 2) radians (pitch, yaw), same frame -> (N,) float64 angles between the gaze vectors, degrees."""
    p, t = _pair(pred, true)
    return np.asarray(angular_error_deg(pitchyaw_to_vector(p), pitchyaw_to_vector(t)), dtype=np.float64)


def mean_error_deg(pred: ArrayLike, true: ArrayLike) -> float:
    """Mean angular error, degrees, of (N, 2) predicted vs (N, 2) true (pitch, yaw) radians."""
    return float(angular_errors_deg(pred, true).mean())


def mean_gaze(true: ArrayLike) -> NDArray[np.float64]:
    """(2,) float64 radians (pitch, yaw), same frame as ``true``: the normalized mean of the unit gaze vectors.

    Raises:
        GazeAugError: the vectors cancel out (their mean has length below 1e-9): no mean direction.
    """
    t = _pitchyaw(true, "true gaze")
    m = pitchyaw_to_vector(t).mean(axis=0)
    if float(np.linalg.norm(m)) < 1e-9:
        raise GazeAugError("true gaze: the gaze vectors cancel out; there is no mean direction")
    return np.asarray(vector_to_pitchyaw(m), dtype=np.float64)


def constant_guess_error_deg(true: ArrayLike) -> float:
    """Mean angular error, degrees, of predicting :func:`mean_gaze` of ``true`` (N, 2) for every sample."""
    t = _pitchyaw(true, "true gaze")
    return mean_error_deg(np.broadcast_to(mean_gaze(t), t.shape), t)


def _wrap(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angles into (-pi, pi]."""
    return np.asarray(np.pi - np.mod(np.pi - a, 2 * np.pi), dtype=np.float64)


def global_offset(pred: ArrayLike, true: ArrayLike) -> NDArray[np.float64]:
    """(2,) float64 radians: the mean of predicted minus true (pitch, yaw), the yaw difference wrapped to (-pi, pi]."""
    p, t = _pair(pred, true)
    d = p - t
    d[:, 1] = _wrap(d[:, 1])
    return np.asarray(d.mean(axis=0), dtype=np.float64)


def bias_removed_error_deg(pred: ArrayLike, true: ArrayLike) -> float:
    """Mean angular error, degrees, after :func:`global_offset` is subtracted from every prediction's angles."""
    p, t = _pair(pred, true)
    return mean_error_deg(p - global_offset(p, t), t)


def _r(x: NDArray[np.float64], y: NDArray[np.float64]) -> float:
    if len(x) < 2:  # before the means: an empty selection has none (and numpy would warn)
        return math.nan
    dx, dy = x - x.mean(), y - y.mean()
    sx, sy = float(np.sqrt((dx * dx).sum())), float(np.sqrt((dy * dy).sum()))
    # a spread at rounding level (a constant predictor's float noise) is no spread
    if sx <= 1e-12 * max(1.0, float(np.abs(x).max())) or sy <= 1e-12 * max(1.0, float(np.abs(y).max())):
        return math.nan
    return float(np.clip((dx * dy).sum() / (sx * sy), -1.0, 1.0))


def pearson(pred: ArrayLike, true: ArrayLike) -> NDArray[np.float64]:
    """(2,) float64: Pearson's r of predicted vs true pitch, and of predicted vs true yaw; NaN where undefined.

    Undefined (NaN): fewer than two samples, or the predicted or the true angle is constant.
    """
    p, t = _pair(pred, true)
    return np.array([_r(p[:, 0], t[:, 0]), _r(p[:, 1], t[:, 1])])


def per_subject_errors_deg(errors: ArrayLike, subjects: ArrayLike) -> dict[str, float]:
    """Mean error per subject: (N,) errors in degrees and (N,) subject names -> {subject: mean degrees}, sorted."""
    e = _errors(errors, "errors")
    s = _subjects(subjects, len(e))
    return {str(k): float(e[s == k].mean()) for k in sorted(set(s.tolist()))}


def subject_offsets_removed_error_deg(pred: ArrayLike, true: ArrayLike, subjects: ArrayLike) -> float:
    """Mean angular error, degrees, once each subject's own :func:`global_offset` leaves that subject's predictions.

    Only subjects with two samples or more count (one sample's own offset removes its whole error);
    NaN when no subject has two.

    Args:
        pred: (N, 2) float radians (pitch, yaw), face frame.
        true: (N, 2) float radians (pitch, yaw), the same frame.
        subjects: (N,) subject names.
    """
    p, t, groups = _repeated_subjects(pred, true, subjects)
    if not groups:
        return math.nan
    q = p.copy()
    for rows in groups:
        q[rows] -= global_offset(p[rows], t[rows])
    return mean_error_deg(q, t)


def _repeated_subjects(
    pred: ArrayLike, true: ArrayLike, subjects: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], list[NDArray[np.bool_]]]:
    """The samples of subjects with two samples or more: (K, 2) predicted, (K, 2) true, one row mask per subject."""
    p, t = _pair(pred, true)
    s = _subjects(subjects, len(p))
    names, counts = np.unique(s, return_counts=True)
    keep = np.isin(s, names[counts >= 2])
    p, t, s = p[keep], t[keep], s[keep]
    return p, t, [s == k for k in names[counts >= 2]]


def pearson_within_subjects(pred: ArrayLike, true: ArrayLike, subjects: ArrayLike) -> NDArray[np.float64]:
    """(2,) float64: Pearson's r of pitch and of yaw within subjects; NaN where undefined.

    Each subject's mean predicted and mean true angle are subtracted from that subject's
    predicted and true angles (yaws are not wrapped, as in :func:`pearson`), and r is taken over
    all samples pooled: a model that reads each person's gaze but with a different offset per
    person scores 1; one that outputs a constant per person has no correlation (NaN). Only
    subjects with two samples or more count (NaN when none has two).
    """
    p, t, groups = _repeated_subjects(pred, true, subjects)
    dp, dt = p.copy(), t.copy()
    for rows in groups:
        dp[rows] -= p[rows].mean(axis=0)
        dt[rows] -= t[rows].mean(axis=0)
    return np.array([_r(dp[:, 0], dt[:, 0]), _r(dp[:, 1], dt[:, 1])])


def relative_reduction_percent(errors_a: ArrayLike, errors_b: ArrayLike) -> float:
    """``100 (mean a - mean b) / mean a``: how much model b lowers model a's mean error on the same (N,) samples.

    NaN when model a's mean error is 0 (nothing to reduce).
    """
    a, b = _errors(errors_a, "errors of model a"), _errors(errors_b, "errors of model b")
    if a.shape != b.shape:
        raise GazeAugError(f"errors: expected both models on the same samples, got {a.shape} and {b.shape}")
    ma = float(a.mean())
    return math.nan if ma == 0 else 100.0 * (ma - float(b.mean())) / ma


def bootstrap_reduction(
    errors_a: ArrayLike,
    errors_b: ArrayLike,
    subjects: ArrayLike | None = None,
    *,
    resample: str = "subjects",
    n_boot: int = 2000,
    level: float = 0.95,
    seed: int = 0,
) -> dict[str, Any]:
    """A percentile bootstrap interval of :func:`relative_reduction_percent` (model b vs model a).

    Args:
        errors_a: (N,) float, degrees: model a's error on each sample.
        errors_b: (N,) float, degrees: model b's error on the same samples, in the same order.
        subjects: (N,) subject names; needed when ``resample`` is ``subjects``.
        resample: ``subjects``: each replicate draws as many subjects as there are, with
            replacement, and takes all their samples (a cluster bootstrap: the interval covers
            the variation between people; with one subject it has zero width). ``samples``:
            each replicate draws N samples with replacement (only the sampling noise of these
            images, as if every sample were independent).
        n_boot: replicates (>= 100).
        level: the interval's coverage, in (0, 1).
        seed: seeds the draws (``numpy.random.default_rng(seed)``).

    Returns:
        ``reduction_percent`` (on all samples), ``low`` and ``high`` (the ``(1 - level) / 2`` and
        ``(1 + level) / 2`` quantiles of the replicates, percent), ``level``, ``resample``,
        ``units`` (how many subjects or samples were resampled), ``n_boot``, ``seed``.
    """
    a, b = _errors(errors_a, "errors of model a"), _errors(errors_b, "errors of model b")
    if a.shape != b.shape:
        raise GazeAugError(f"errors: expected both models on the same samples, got {a.shape} and {b.shape}")
    if resample not in RESAMPLE_UNITS:
        raise GazeAugError(f"resample: expected one of {', '.join(RESAMPLE_UNITS)}, got {resample!r}")
    if not (isinstance(n_boot, int) and n_boot >= 100):
        raise GazeAugError(f"n_boot: expected an integer >= 100, got {n_boot!r}")
    if not (isinstance(level, float) and 0 < level < 1):
        raise GazeAugError(f"level: expected a number in (0, 1), got {level!r}")
    if resample == "subjects":
        if subjects is None:
            raise GazeAugError("subjects: needed to resample subjects")
        s = _subjects(subjects, len(a))
        names = sorted(set(s.tolist()))
        sum_a = np.array([a[s == k].sum() for k in names])
        sum_b = np.array([b[s == k].sum() for k in names])
    else:
        sum_a, sum_b = a, b
    k = len(sum_a)
    rng = np.random.default_rng(seed)
    ra, rb = np.empty(n_boot), np.empty(n_boot)
    for i in range(n_boot):  # each replicate: k units drawn with replacement; its total errors
        idx = rng.integers(0, k, size=k)
        ra[i], rb[i] = sum_a[idx].sum(), sum_b[idx].sum()  # the replicate's sample count cancels in the ratio
    with np.errstate(divide="ignore", invalid="ignore"):
        reps = np.where(ra > 0, 100.0 * (ra - rb) / ra, np.nan)
    reps = reps[np.isfinite(reps)]
    low, high = (
        (float(np.quantile(reps, (1 - level) / 2)), float(np.quantile(reps, (1 + level) / 2)))
        if len(reps)
        else (math.nan, math.nan)
    )
    return {
        "reduction_percent": relative_reduction_percent(a, b),
        "low": low,
        "high": high,
        "level": level,
        "resample": resample,
        "units": k,
        "n_boot": n_boot,
        "seed": seed,
    }


def summarize(pred: ArrayLike, true: ArrayLike, subjects: Sequence[str] | ArrayLike) -> dict[str, Any]:
    """Every metric of one model on one test set, as plain values (NaN written as None).

    Args:
        pred: (N, 2) float radians (pitch, yaw), face frame: the model's predictions.
        true: (N, 2) float radians (pitch, yaw), face frame: the labels.
        subjects: (N,) subject names.

    Returns:
        ``count``; ``mean_deg``, ``median_deg`` (angular error); ``constant_guess_deg``
        (:func:`constant_guess_error_deg`) and ``ratio_to_constant`` (``mean_deg`` over it);
        ``mean_gaze_deg`` ((pitch, yaw) of :func:`mean_gaze`, degrees); ``offset_deg`` ((pitch,
        yaw) of :func:`global_offset`, degrees); ``bias_removed_deg``; ``pearson_pitch``,
        ``pearson_yaw``; ``per_subject_deg`` ({subject: mean error}); ``subject_mean_deg``
        (the mean of the per-subject means: every person weighs the same);
        ``subject_offsets_removed_deg`` (:func:`subject_offsets_removed_error_deg`);
        ``pearson_within_pitch``, ``pearson_within_yaw`` (:func:`pearson_within_subjects`).
    """
    p, t = _pair(pred, true)
    names = _subjects(subjects, len(p))
    errors = angular_errors_deg(p, t)
    per = per_subject_errors_deg(errors, names)
    const = constant_guess_error_deg(t)
    r = pearson(p, t)
    within = pearson_within_subjects(p, t, names)
    mean = float(errors.mean())

    def plain(v: float) -> float | None:
        return None if not math.isfinite(v) else float(v)

    return {
        "count": int(len(p)),
        "mean_deg": mean,
        "median_deg": float(np.median(errors)),
        "constant_guess_deg": const,
        "ratio_to_constant": plain(mean / const) if const > 0 else None,
        "mean_gaze_deg": np.degrees(mean_gaze(t)).tolist(),
        "offset_deg": np.degrees(global_offset(p, t)).tolist(),
        "bias_removed_deg": bias_removed_error_deg(p, t),
        "pearson_pitch": plain(float(r[0])),
        "pearson_yaw": plain(float(r[1])),
        "per_subject_deg": per,
        "subject_mean_deg": float(np.mean(list(per.values()))),
        "subject_offsets_removed_deg": plain(subject_offsets_removed_error_deg(p, t, names)),
        "pearson_within_pitch": plain(float(within[0])),
        "pearson_within_yaw": plain(float(within[1])),
    }
