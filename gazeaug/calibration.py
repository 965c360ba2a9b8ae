"""Per-user calibration: a correction of the model's gaze fitted while the user looks at known points.

Every person differs from a person-independent model by an offset (kappa, the
angle between the eye's optical and visual axes, is 4-8 deg and differs per
person; eye shape; the model's own bias for that face). A few seconds of looking
at known points measure it. The correction acts on the model's output, gaze
(pitch, yaw) in radians in the face-centre normalized frame, so it holds as the
head moves:

- ``none``: the identity;
- ``bias``: ``g' = g + b`` (2 parameters);
- ``scale``: each angle its own gain and offset, ``A`` diagonal (4 parameters; 3 points or more);
- ``affine``: ``g' = A g + b`` (6 parameters; 4 points or more).

The samples of each point are reduced to their median (prediction and truth),
so blinks and the first frames after a saccade weigh little. Which correction is
kept is decided by leave-one-point-out: each kind is fitted without one point
and scored on it; starting from ``none``, a kind with more parameters replaces
the one kept so far only when its mean left-out error is at least
:data:`MIN_GAIN` (10 %) lower (a calibration that does not clearly help is not
applied), and each kind needs :data:`MIN_POINTS` points (the affine map 12).
The error before and after (on the points themselves and left out) is recorded.

A calibration file (JSON) names the model it was fitted for by the SHA-256 of
the model file, and :func:`load_calibration` refuses it for another model.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import GazeAugError

__all__ = [
    "Calibration",
    "fit_calibration",
    "calibrate",
    "load_calibration",
    "model_digest",
    "CALIBRATION_FORMAT",
    "KINDS",
]

CALIBRATION_FORMAT = "gazeaug-calibration"
#: The corrections, simplest first (a tie goes to the simpler).
KINDS = ("none", "bias", "scale", "affine")
#: Points each correction needs (it is fitted on one fewer when one is left out). The affine map
#: needs 12: on the 9 points of the calibration grid it passed leave-one-out (13.1 deg left out
#: against 16.6 uncorrected) and then made a simulated person's test sequence worse (median
#: 18.4 -> 20.3 deg; benchmarks/track_accuracy.py with the demo model of 2026-11-23).
MIN_POINTS = {"none": 2, "bias": 2, "scale": 3, "affine": 12}
#: A calibration file's bounds: a gain (matrix entry) up to this, an offset up to this many degrees.
MAX_GAIN = 5.0
MAX_OFFSET_DEG = 45.0
#: A correction with more parameters is kept over a simpler one only when its left-out error is at
#: least this share lower (fewer points than parameters' worth make the left-out errors noisy).
MIN_GAIN = 0.10


def model_digest(path: str | Path) -> str:
    """SHA-256 (hex) of a model file's bytes: what a calibration is tied to."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _errors_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    from facemesh.conventions import angular_error_deg, pitchyaw_to_vector

    return np.asarray(angular_error_deg(pitchyaw_to_vector(a), pitchyaw_to_vector(b)), dtype=np.float64)


def _fit(
    kind: str, pred: NDArray[np.float64], true: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(A (2, 2), b (2,)) of one kind fitted to point pairs (P, 2) radians."""
    if kind == "none":
        return np.eye(2), np.zeros(2)
    if kind == "bias":
        return np.eye(2), (true - pred).mean(axis=0)
    if kind == "scale":  # per angle: true = a pred + b, least squares (a = 1 when the predictions do not vary)
        a, b = np.ones(2), np.zeros(2)
        for k in range(2):
            p, t = pred[:, k], true[:, k]
            var = float(np.var(p))
            a[k] = float(np.mean((p - p.mean()) * (t - t.mean()))) / var if var > 1e-12 else 1.0
            b[k] = float(t.mean() - a[k] * p.mean())
        return np.diag(a), b
    x = np.column_stack([pred, np.ones(len(pred))])
    sol, *_ = np.linalg.lstsq(x, true, rcond=None)  # (3, 2): true = pred @ A.T + b
    return sol[:2].T, sol[2]


@dataclass(frozen=True)
class Calibration:
    """A fitted correction (module docstring).

    Attributes:
        kind: ``none``, ``bias``, ``scale`` or ``affine``.
        matrix: ``A``, 2 x 2 (rows: pitch, yaw), applied to (pitch, yaw) radians.
        offset: ``b``, (pitch, yaw) radians.
        model_sha256: the model file it was fitted for (:func:`model_digest`).
        points: how many points it was fitted on.
        error_deg: mean angular error over the points per kind, ``{"none": ..., "bias": ..., ...}``
            for the fit on all points (``fitted``) and left out (``left_out``).
        mirror_average: how the model was read when the correction was fitted: True averaged with
            the mirrored eyes, False plainly (``--mirror-average``); None in files written before
            2026-12-01, which did not record it (the model file's own choice was used then).
    """

    kind: str
    matrix: tuple[tuple[float, float], tuple[float, float]]
    offset: tuple[float, float]
    model_sha256: str
    points: int
    error_deg: dict[str, dict[str, float]]
    mirror_average: bool | None = None

    def apply(self, pitchyaw: ArrayLike) -> NDArray[np.float64]:
        """(N, 2) or (2,) radians (pitch, yaw), face-centre normalized frame -> corrected, same shape."""
        g = np.asarray(pitchyaw, dtype=np.float64)
        return g @ np.asarray(self.matrix).T + np.asarray(self.offset)

    def check_for(self, model_sha256: str | None = None, mirror_average: bool | None = None) -> None:
        """Refuse a model this correction was not fitted for.

        Args:
            model_sha256: the model's :func:`model_digest`; None: not checked.
            mirror_average: how the model is read now; None, or a file that does not record it
                (before 2026-12-01): not checked.

        Raises:
            GazeAugError: fitted for another model file, or for the model read the other way (a
                correction of the averaged answers is not one of the plain answers).
        """
        if model_sha256 is not None and self.model_sha256 != model_sha256:
            raise GazeAugError(
                f"this calibration was fitted for another model (sha256 {self.model_sha256[:12]}...) than the one "
                f"given ({model_sha256[:12]}...): calibrate again with this model"
            )
        if mirror_average is not None and self.mirror_average is not None and self.mirror_average != mirror_average:
            fitted, now = ("on" if v else "off" for v in (self.mirror_average, mirror_average))
            raise GazeAugError(
                f"this calibration was fitted with the model's mirror averaging {fitted}, and the model is read "
                f"now with it {now}: give --mirror-average {fitted}, or calibrate again"
            )

    def as_dict(self) -> dict[str, Any]:
        """The file's content."""
        return {"format": CALIBRATION_FORMAT, "version": 1, **asdict(self)}

    def save(self, path: str | Path) -> Path:
        """Write the JSON file atomically."""
        from facemesh.io import atomic_write

        p = Path(path)
        with atomic_write(p) as fh:
            fh.write(json.dumps(self.as_dict(), indent=1).encode("utf-8"))
        return p


def fit_calibration(
    pred: ArrayLike,
    true: ArrayLike,
    point: ArrayLike,
    model_sha256: str,
    *,
    mirror_average: bool | None = None,
) -> Calibration:
    """Fit the per-user correction (module docstring).

    Args:
        pred: (N, 2) radians, the model's (pitch, yaw), face-centre normalized frame.
        true: (N, 2) radians, the true gaze in the same frames.
        point: (N,) which point each sample belongs to (any hashable labels).
        model_sha256: the model's :func:`model_digest`.
        mirror_average: how the model that gave ``pred`` was read (:attr:`Calibration.mirror_average`).

    Raises:
        GazeAugError: fewer than 2 points, or mismatched shapes.
    """
    p, t = np.asarray(pred, dtype=np.float64), np.asarray(true, dtype=np.float64)
    ids = np.asarray(point)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape != t.shape or len(ids) != len(p):
        raise GazeAugError(
            f"calibration: expected pred and true (N, 2) and point (N,), got {p.shape}, {t.shape}, {ids.shape}"
        )
    labels = list(dict.fromkeys(ids.tolist()))
    if len(labels) < 2:
        raise GazeAugError(
            f"calibration: the user looked at {len(labels)} point(s) with a gaze measured; at least 2 are needed"
        )
    pp = np.array([np.median(p[ids == k], axis=0) for k in labels])
    tp = np.array([np.median(t[ids == k], axis=0) for k in labels])
    kinds = [k for k in KINDS if len(labels) >= MIN_POINTS[k]]
    fitted, left_out = {}, {}
    for kind in kinds:
        a, b = _fit(kind, pp, tp)
        fitted[kind] = float(_errors_deg(pp @ a.T + b, tp).mean())
        errs = []
        for i in range(len(labels)):
            keep = np.arange(len(labels)) != i
            a_i, b_i = _fit(kind, pp[keep], tp[keep])
            errs.append(float(_errors_deg((pp[i] @ a_i.T + b_i)[None], tp[i][None])[0]))
        left_out[kind] = float(np.mean(errs))
    best = kinds[0]
    for kind in kinds[1:]:
        if left_out[kind] < (1.0 - MIN_GAIN) * left_out[best]:
            best = kind
    a, b = _fit(best, pp, tp)
    return Calibration(
        kind=best,
        matrix=((float(a[0, 0]), float(a[0, 1])), (float(a[1, 0]), float(a[1, 1]))),
        offset=(float(b[0]), float(b[1])),
        model_sha256=model_sha256,
        points=len(labels),
        error_deg={"fitted": fitted, "left_out": left_out},
        mirror_average=mirror_average,
    )


def load_calibration(
    path: str | Path, model_sha256: str | None = None, *, mirror_average: bool | None = None
) -> Calibration:
    """Read a calibration file; with ``model_sha256``, refuse one fitted for another model.

    With ``mirror_average`` (how the model is read now), refuse a file fitted on the model read the
    other way (a correction of the averaged answers is not one of the plain answers); a file that
    does not record it (written before 2026-12-01) is taken as it is.

    Raises:
        GazeAugError: unreadable, not a calibration, bad values, for another model, or for the
            model read the other way.
    """
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise GazeAugError(f"{p}: no such calibration file") from exc
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise GazeAugError(f"{p}: not a readable calibration file ({exc.__class__.__name__})") from exc
    if not isinstance(data, dict) or data.get("format") != CALIBRATION_FORMAT:
        raise GazeAugError(f"{p}: not a gazeaug calibration file (no '{CALIBRATION_FORMAT}' format mark)")
    try:
        cal = _from_record(data)
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise GazeAugError(f"{p}: bad calibration values ({exc})") from exc
    try:
        cal.check_for(model_sha256, mirror_average)
    except GazeAugError as exc:
        raise GazeAugError(f"{p}: {exc}") from None
    return cal


def _numbers(value: Any, shape: tuple[int, ...], what: str) -> NDArray[np.float64]:
    """Finite real numbers (no bools, no text) of one shape."""
    flat = np.asarray(value, dtype=object).ravel().tolist() if isinstance(value, list) else [value]
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in flat):
        raise ValueError(f"{what}: expected numbers, got {value!r}")
    a = np.asarray(value, dtype=np.float64)
    if a.shape != shape or not np.isfinite(a).all():
        raise ValueError(f"{what}: expected {' x '.join(map(str, shape))} finite numbers, got {value!r}")
    return a


def _from_record(data: dict[str, Any]) -> Calibration:
    """A :class:`Calibration` from a file's record, checked: the version, the kind's form, the bounds."""
    if data.get("version") != 1:
        raise ValueError(f"version: expected 1, got {data.get('version')!r}")
    digest = data["model_sha256"]
    if not (isinstance(digest, str) and len(digest) == 64 and all(c in "0123456789abcdef" for c in digest)):
        raise ValueError(f"model_sha256: expected 64 hexadecimal digits, got {digest!r}")
    kind = data["kind"]
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    a = _numbers(data["matrix"], (2, 2), "matrix")
    b = _numbers(data["offset"], (2,), "offset")
    form = {
        "none": np.allclose(a, np.eye(2)) and not b.any(),
        "bias": np.allclose(a, np.eye(2)),
        "scale": a[0, 1] == 0 and a[1, 0] == 0,
        "affine": True,
    }[kind]
    if not form:
        raise ValueError(f"a {kind!r} correction cannot have the matrix {a.tolist()} and offset {b.tolist()}")
    if not (np.abs(a).max() <= MAX_GAIN and math.degrees(float(np.abs(b).max())) <= MAX_OFFSET_DEG):
        raise ValueError(f"expected gains up to {MAX_GAIN:g} and offsets up to {MAX_OFFSET_DEG:g} deg")
    points = data.get("points", 0)
    return Calibration(
        kind=kind,
        matrix=((float(a[0, 0]), float(a[0, 1])), (float(a[1, 0]), float(a[1, 1]))),
        offset=(float(b[0]), float(b[1])),
        model_sha256=digest,
        points=int(points) if isinstance(points, int) and not isinstance(points, bool) else 0,
        error_deg=dict(data.get("error_deg") or {}) if isinstance(data.get("error_deg"), dict) else {},
        mirror_average=_mirror_record(data.get("mirror_average")),
    )


def _mirror_record(value: Any) -> bool | None:
    """A file's ``mirror_average``: true, false, or absent / null (files before 2026-12-01)."""
    if value is None or isinstance(value, bool):
        return value
    raise ValueError(f"mirror_average: expected true, false or null, got {value!r}")


def _targets_csv(path: Path, rig: Any) -> list[tuple[float, float, NDArray[np.float64]]]:
    """(start_s, end_s, point rig frame mm) per row of a TARGETS.csv.

    Columns ``start_s,end_s,target`` (a rig target's name) or ``start_s,end_s,x_mm,y_mm,z_mm``.
    """
    import csv

    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except FileNotFoundError as exc:
        raise GazeAugError(f"{path}: no such targets file") from exc
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise GazeAugError(f"{path}: not a readable CSV file ({exc.__class__.__name__})") from exc
    by_name = {t.name: t for t in (rig.targets if rig is not None else ())}
    out = []
    for i, r in enumerate(rows, start=2):
        try:
            a, b = float(r["start_s"]), float(r["end_s"])
            if r.get("target"):
                if r["target"] not in by_name:
                    raise ValueError(f"target {r['target']!r} is not in the rig (it has {sorted(by_name)})")
                p = by_name[r["target"]].centre
            else:
                p = np.array([float(r["x_mm"]), float(r["y_mm"]), float(r["z_mm"])])
            if not (math.isfinite(a) and math.isfinite(b) and a < b and np.isfinite(p).all()):
                raise ValueError("expected finite start_s < end_s and a finite point")
            if np.abs(p).max() > 1e5 or np.linalg.norm(p) < 1.0:
                raise ValueError("expected a point within 100 m of the eyes and not at them")
        except (KeyError, TypeError, ValueError) as exc:
            raise GazeAugError(
                f"{path}, line {i}: expected start_s,end_s and target (a rig target's name) or x_mm,y_mm,z_mm ({exc})"
            ) from exc
        out.append((a, b, np.asarray(p, dtype=np.float64)))
    if not out:
        raise GazeAugError(f"{path}: no targets (expected rows of start_s,end_s,target)")
    return out


def _place(point_mm: NDArray[np.float64]) -> str:
    """A point's label: its coordinates to 0.1 mm (looks at one place are one calibration point)."""
    return ",".join(f"{v:.1f}" for v in point_mm)


def calibrate(
    source: str | Path,
    estimator: Any,
    *,
    rig: Any = None,
    targets: str | Path | None = None,
    camera: Any = None,
    settle_s: float = 0.3,
    tracking: bool = True,
    progress: bool = True,
) -> tuple[Calibration, dict[str, Any]]:
    """Fit a user's calibration from a video (or image folder) of them looking at known points.

    Args:
        source: what ``gazeaug track`` reads.
        estimator: the model (:func:`gazeaug.estimator.load_estimator`) the calibration is for.
        rig: the rig (its camera places the targets in the camera frame; its targets are named in
            ``targets``).
        targets: a CSV of when the user looked where: ``start_s,end_s,target`` (a rig target's
            name) or ``start_s,end_s,x_mm,y_mm,z_mm`` (a point, rig frame). Without it, ``source``
            must be a simulated sequence (``gazeaug simulate --sequence``), whose ``truth.csv`` says.
        camera: the source's intrinsics (as for ``track``).
        settle_s: the first seconds of each look are left out (the saccade and its settling).
        tracking: MediaPipe's video mode.
        progress: a progress bar.

    Returns:
        The calibration and a report (points, samples, errors per kind fitted and left out, the kind chosen).

    Raises:
        GazeAugError: no truth, fewer than 2 points with a gaze, a bad targets file.
    """
    import tempfile

    from facemesh.conventions import rig_to_camera_points

    from .sequence import read_truth
    from .track import TrackSettings, track

    if not (isinstance(settle_s, (int, float)) and math.isfinite(settle_s) and 0 <= settle_s < 60):
        raise GazeAugError(f"settle: expected seconds from 0 to below 60, got {settle_s!r}")
    looks: list[tuple[float, float, NDArray[np.float64]]] = []  # (start, end, point rig frame mm)
    truth = None
    if targets is not None:
        if rig is None:
            raise GazeAugError("--targets needs the rig that places them (--rig)")
        looks = [(a + settle_s, b, p) for a, b, p in _targets_csv(Path(targets), rig)]
    else:
        if not Path(str(source)).exists():
            raise GazeAugError(f"{source}: no such folder (a simulated sequence) or video")
        truth = read_truth(source) if Path(str(source)).is_dir() else None
        if truth is None:
            raise GazeAugError(
                f"{source}: give --targets TARGETS.csv (when the user looked where), or a simulated sequence folder "
                "(gazeaug simulate --sequence) whose truth.csv says"
            )
    samples: list[tuple[str, NDArray[np.float64], NDArray[np.float64]]] = []  # (point, pred, true)
    run_of: dict[int, tuple[str, float]] = {}
    if truth is not None:  # runs of fixations and glances: the point (by place) and the run's start time
        prev = None
        for r in truth:
            key = (r["phase"], r["point_x_mm"], r["point_y_mm"], r["point_z_mm"])
            if key != prev:
                prev, start = key, r["time_s"]
            run_of[r["frame"]] = (_place(np.array(key[1:])), start)  # looks again at one place: one point
        by_frame = {r["frame"]: r for r in truth}
    r_rig = rig.camera_rotation() if rig is not None else None

    def take(row: dict[str, Any]) -> None:
        if row.get("status") != "ok" or "_model_pitchyaw" not in row:
            return
        t, ncam = float(row["time_s"]), row["_normalized_camera"]
        if truth is not None:
            tr = by_frame.get(int(row["frame"]))
            if tr is None or tr["phase"] == "saccade" or tr["blink"] > 0:
                return
            pid, start = run_of[int(row["frame"])]
            if t - start < settle_s:
                return
            point_cam = np.array([tr["target_x"], tr["target_y"], tr["target_z"]])
        else:
            hit = [i for i, (a, b, _) in enumerate(looks) if a <= t <= b]
            if not hit:
                return
            point = looks[hit[0]][2]
            pid = _place(point)  # looks again at one place: one point
            assert r_rig is not None
            point_cam = rig_to_camera_points(point, r_rig, rig.camera_position_mm)
        true = ncam.gaze_pitchyaw(point_cam - ncam.reference_mm)
        samples.append((pid, np.asarray(row["_model_pitchyaw"], dtype=np.float64), np.asarray(true)))

    settings = TrackSettings(smoothing=None, tracking=tracking, video=False)
    with tempfile.TemporaryDirectory(prefix="gazeaug-calibrate-") as tmp:
        summary = track(
            source, tmp, estimator, camera=camera, rig=rig, settings=settings, progress=progress, on_row=take
        )
    if not samples:
        raise GazeAugError(f"{source}: no frame with a gaze while the user looked at a known point")
    ids = np.array([s[0] for s in samples])
    pred = np.stack([s[1] for s in samples])
    true = np.stack([s[2] for s in samples])
    cal = fit_calibration(pred, true, ids, estimator.model_sha256, mirror_average=estimator.mirror_average)
    after = _errors_deg(cal.apply(pred), true)
    before = _errors_deg(pred, true)
    report = {
        "kind": cal.kind,
        "points": cal.points,
        "samples": len(samples),
        "frames": summary["frames"],
        "error_deg": cal.error_deg,
        "samples_error_deg": {"before": round(float(before.mean()), 3), "after": round(float(after.mean()), 3)},
        "mirror_average": cal.mirror_average,
    }
    return cal, report
