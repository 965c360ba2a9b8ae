"""Point of gaze, selection and calibration on simulated people with exact ground truth.

``python benchmarks/track_accuracy.py --model M.pt [--people 4] [--seconds 20] [-o /tmp/track_acc] [--card]``

For each of the first ``--people`` test people of ``benchmarks/people.py`` (none
of them among any training photos), with the ``wheelchair_objects`` rig:

1. simulates a **calibration sequence** (``--pattern calibration``: a 3 x 3 grid,
   15 s) and a **test sequence** (the rig's objects with glances between,
   ``--seconds``) of the same simulated person (same identity seed, other seeds);
   (kept in ``-o`` and reused by a later run; ``--fresh`` simulates them again);
2. fits the person's calibration on the first (``gazeaug calibrate``);
3. tracks the test sequence without and with it (``gazeaug track``) and scores it
   against the truth (:func:`gazeaug.sequence.sequence_accuracy`).

Prints one JSON line per person and one with the medians over people: gaze error
(deg, mm), selection accuracy, false selections per minute, before and after
calibration, and the correction kept; ``--card`` also records the medians in the model's
card (``M.json``, under ``measured.track_accuracy``; ``benchmarks/card.py``).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)

RIG = ROOT / "data_samples" / "rigs" / "wheelchair_objects.yaml"


def main() -> None:
    """Run it."""
    import numpy as np
    from people import PEOPLE_FILES, other_people  # benchmarks/people.py

    from gazeaug.calibration import calibrate
    from gazeaug.errors import GazeAugError
    from gazeaug.estimator import load_estimator
    from gazeaug.sampling import load_rig
    from gazeaug.sequence import SequenceSettings, simulate_sequence
    from gazeaug.track import TrackSettings, track

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--people", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=20.0)
    add_data_option(ap)
    ap.add_argument("-o", "--output", type=Path, default=Path("/tmp/track_acc"))
    ap.add_argument(
        "--fresh", action="store_true", help="simulate the sequences again even if OUT has them (OUT/personNN only)"
    )
    ap.add_argument("--card", action="store_true", help="record the medians in the model's card (M.json)")
    args = ap.parse_args()
    require_data(ap, args.data, *PEOPLE_FILES)
    warnings.simplefilter("ignore")
    rig = load_rig(RIG)
    try:
        est = load_estimator(args.model)
    except GazeAugError as exc:
        ap.exit(2, f"{ap.prog}: {exc}\n")
    people = list(other_people(args.data))[: args.people]
    rows = []
    for k, person in enumerate(people):
        d = args.output / f"person{k:02d}"
        if args.fresh:  # only what this script writes: OUT/personNN, simulated again
            import shutil

            shutil.rmtree(d, ignore_errors=True)
        calib_seq = SequenceSettings(seconds=15.0, pattern="calibration")
        test_seq = SequenceSettings(seconds=args.seconds)
        for name, seq, seed in (("calib", calib_seq, 100 + k), ("test", test_seq, 200 + k)):
            if not (d / name / "sequence.json").is_file():  # simulated once per output folder (--fresh: again)
                simulate_sequence(
                    person, rig, d / name, sequence=seq, seed=seed, identity_seed=k, overwrite=True, progress=False
                )
        cal, report = calibrate(d / "calib", est, rig=rig, progress=False)
        s = TrackSettings(video=False)
        before = track(d / "test", d / "t0", est, rig=rig, settings=s, progress=False)["accuracy"]
        after = track(d / "test", d / "t1", est, rig=rig, settings=s, progress=False, calibration=cal)["accuracy"]
        row = {
            "person": person.name,
            "calibration": report["kind"],
            "calibration_points": report["points"],
            "before": before,
            "after": after,
        }
        rows.append(row)
        print(json.dumps(row), flush=True)

    def med(key: str, sub: str | None, when: str) -> float | None:
        vals = [r[when][key][sub] if sub else r[when][key] for r in rows]
        vals = [v for v in vals if v is not None]
        return round(float(np.median(vals)), 2) if vals else None

    summary = {
        "people": len(rows),
        "model": str(args.model),
        **{
            f"{when}_{name}": med(key, sub, when)
            for when in ("before", "after")
            for name, key, sub in (
                ("median_gaze_error_deg", "gaze_error_deg", "median"),
                ("median_gaze_error_mm", "gaze_error_mm", "median"),
                ("selection_accuracy", "selection_accuracy", None),
                ("false_per_minute", "false_per_minute", None),
            )
        },
    }
    print(json.dumps(summary))
    if args.card:
        from card import record_or_exit, shown  # benchmarks/card.py

        figures = {k: v for k, v in summary.items() if k != "model"}
        seconds = "" if args.seconds == 20.0 else f" --seconds {args.seconds:g}"
        command = (
            f"python benchmarks/track_accuracy.py --model {shown(args.model)} --people {args.people}{seconds} --card"
        )
        record_or_exit(args.model, "track_accuracy", figures, command)


if __name__ == "__main__":
    main()
