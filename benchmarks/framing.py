"""How far test-time normalization's framing moves an eye in its patch, on simulated people.

``python benchmarks/framing.py SIMULATED_DIR NORMALIZED.h5 [--focal 650]``

``SIMULATED_DIR`` is a ``gazeaug simulate`` output (its ``simulation.jsonl``
holds each image's true eyeball centres, mm, camera frame) and ``NORMALIZED.h5``
the same images through ``gazeaug normalize-dataset`` (one row per image, in
the simulation's order: ``source_index``), which placed each eye's normalized
camera from the landmarks MediaPipe detected and the head pose PnP found.
Redirected training eyes are framed from the rendered pose itself, exactly;
a test image's eye lands wherever detection puts it.

For every image and eye, the true eyeball centre is projected through the
row's normalizing rotation (``R_norm_left``/``R_norm_right``) onto the patch
plane at the normalized focal length ``--focal``: where the eye's centre sits
relative to the patch centre, px. The eyeball centre lies behind the eye
corners that normalization aims at, by an amount that is the subject's own, so
each subject's median is removed; what is left is the frame-to-frame
framing error (detection and PnP), to about a pixel (the same depth offset
seen from head poses a few degrees apart).

Prints one JSON line: percentiles of the distance (px) and the standard
deviation per axis (x right, y down, px), both eyes pooled, and each subject's
median offset (the part that the subject's median removes).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    from gazeaug.errors import GazeAugError
    from gazeaug.io_h5 import H5TrainingSet

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("simulated", type=Path, help="a gazeaug simulate output folder")
    ap.add_argument("normalized", type=Path, help="its images through gazeaug normalize-dataset (.h5)")
    ap.add_argument("--focal", type=float, default=650.0, help="the normalized focal length, px (default 650)")
    args = ap.parse_args()
    if not (args.simulated / "simulation.jsonl").is_file():
        print(f"{args.simulated}: no simulation.jsonl (expected a gazeaug simulate output folder)", file=sys.stderr)
        return 2
    records = [json.loads(line) for line in (args.simulated / "simulation.jsonl").read_text().splitlines() if line]
    try:
        ts = H5TrainingSet(args.normalized)
        d = ts.read(["R_norm_left", "R_norm_right", "source_index"])
    except GazeAugError as exc:
        print(exc, file=sys.stderr)
        return 2
    if len(d["source_index"]) and int(d["source_index"].max()) >= len(records):
        print(f"{args.normalized}: rows of other images than {args.simulated}'s {len(records)}", file=sys.stderr)
        return 2
    subjects = ts.subjects[ts.rows]
    offsets = []  # (N, 2 eyes, 2) px
    for i, k in enumerate(d["source_index"]):
        rec = records[int(k)]
        row = []
        for side in ("left", "right"):
            v = d[f"R_norm_{side}"][i] @ np.asarray(rec["eyeball_centres_mm"][side], dtype=np.float64)
            row.append(args.focal * v[:2] / v[2])
        offsets.append(row)
    off = np.asarray(offsets)
    medians = {s: np.median(off[subjects == s], axis=0) for s in np.unique(subjects)}
    dev = off - np.stack([medians[s] for s in subjects])
    dist = np.hypot(dev[..., 0], dev[..., 1]).ravel()
    pct = (50, 75, 90, 95, 100)
    print(
        json.dumps(
            {
                "images": len(off),
                "focal_px": args.focal,
                "distance_px_percentiles": {
                    str(p): round(float(v), 2) for p, v in zip(pct, np.percentile(dist, pct), strict=True)
                },
                "std_px_xy": [round(float(v), 2) for v in dev.reshape(-1, 2).std(axis=0)],
                "subject_median_px_xy": {
                    s: [[round(float(v), 1) for v in eye] for eye in m] for s, m in medians.items()
                },
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
