"""What corrections after the model could buy on a test set: per-person shifts and a linear map.

    python benchmarks/post_hoc.py EVAL/errors.csv [--rig-set TRAIN_AUGMENTED.h5]

``EVAL`` is a ``gazeaug evaluate`` report folder. Prints one JSON line, mean angular errors in
degrees over the rows of ``errors.csv``:

- ``plain``: the model's answers as they are;
- ``person_shift_to_rig_mean`` (needs ``--rig-set``, no test label is used): each person's answers
  shifted so that their mean is the rig's mean gaze, read as the mean (pitch, yaw) label of the
  set's augmented rows (those drawn for the rig: finite ``sampled_yaw_pitch``). An unlabeled
  self-calibration: a person who looks about the rig's targets for a while has that mean gaze;
  ``person_pitch_shift_to_rig_mean``: the same for the pitch alone (the yaw as the model gave it);
- ``person_shift_to_test_mean``: the same to the test set's pooled mean label (uses the labels,
  pooled over every person);
- ``person_offsets_removed`` (an oracle, :func:`gazeaug.metrics.subject_offsets_removed_error_deg`):
  each person's own mean error taken out, what a perfect per-person calibration would leave;
- ``linear_oracle``: pitch and yaw each mapped by the least-squares line fitted on these very rows
  (the best a global stretch and offset could do).

Angles are the report's (pitch, yaw) in radians, the normalized face frame (docs/conventions.md).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gazeaug.metrics import mean_error_deg, subject_offsets_removed_error_deg  # noqa: E402


def read_errors_csv(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pred, true, subjects) of a ``gazeaug evaluate`` ``errors.csv``: (N, 2) float64 radians
    (pitch, yaw) twice, (N,) str."""
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    pred = np.array([[float(r["pred_pitch_rad"]), float(r["pred_yaw_rad"])] for r in rows]).reshape(-1, 2)
    true = np.array([[float(r["true_pitch_rad"]), float(r["true_yaw_rad"])] for r in rows]).reshape(-1, 2)
    return pred, true, np.array([r["subject"] for r in rows], dtype=str)


def shift_each_person(pred: np.ndarray, subjects: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(N, 2): each subject's answers moved by one (pitch, yaw) offset so that their mean is ``target`` (2,)."""
    out = pred.astype(np.float64).copy()
    for s in np.unique(subjects):
        rows = subjects == s
        out[rows] += target - pred[rows].mean(axis=0)
    return out


def linear_oracle(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """(N, 2): each axis of ``pred`` mapped by the least-squares line to ``true`` fitted on these rows."""
    out = np.empty_like(pred, dtype=np.float64)
    for a in range(2):
        design = np.c_[pred[:, a], np.ones(len(pred))]
        out[:, a] = design @ np.linalg.lstsq(design, true[:, a], rcond=None)[0]
    return out


def rig_mean_gaze(h5: Path) -> np.ndarray:
    """(2,) float64 radians: the mean (pitch, yaw) label of an augmented set's rows drawn for its rig."""
    import h5py

    with h5py.File(h5, "r") as f:
        gaze = f["gaze"][()]
        drawn = np.isfinite(f["sampled_yaw_pitch"][()]).all(axis=1)
    if not drawn.any():
        raise ValueError("no row drawn for a rig (every sampled_yaw_pitch is NaN)")
    return gaze[drawn].mean(axis=0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("errors_csv", type=Path, help="a gazeaug evaluate report's errors.csv")
    ap.add_argument("--rig-set", type=Path, help="an augmented training set (.h5) whose drawn rows give the rig's mean")
    args = ap.parse_args()
    try:
        pred, true, subjects = read_errors_csv(args.errors_csv)
    except (OSError, KeyError, ValueError, csv.Error) as exc:
        ap.exit(2, f"{ap.prog}: {args.errors_csv}: not a gazeaug evaluate errors.csv ({exc})\n")
    if len(pred) == 0:
        ap.exit(2, f"{ap.prog}: {args.errors_csv}: no rows\n")
    out = {
        "rows": len(pred),
        "people": len(np.unique(subjects)),
        "plain": mean_error_deg(pred, true),
        "person_shift_to_test_mean": mean_error_deg(shift_each_person(pred, subjects, true.mean(axis=0)), true),
        "person_offsets_removed": subject_offsets_removed_error_deg(pred, true, subjects),
        "linear_oracle": mean_error_deg(linear_oracle(pred, true), true),
    }
    if args.rig_set is not None:
        try:
            rig = rig_mean_gaze(args.rig_set)
        except (OSError, KeyError, ValueError) as exc:
            ap.exit(2, f"{ap.prog}: {args.rig_set}: not an augmented set with drawn rows ({exc})\n")
        out["rig_mean_gaze_deg"] = [round(float(v), 2) for v in np.degrees(rig)]
        shifted = shift_each_person(pred, subjects, rig)
        out["person_shift_to_rig_mean"] = mean_error_deg(shifted, true)
        shifted[:, 1] = pred[:, 1]
        out["person_pitch_shift_to_rig_mean"] = mean_error_deg(shifted, true)
    print(json.dumps({k: round(v, 2) if isinstance(v, float) else v for k, v in out.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
