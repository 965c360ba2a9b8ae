"""Checks of the simulator's labels through our own pipeline.

``python benchmarks/check_simulator.py [--per-face 20]`` simulates both rigs from the
wheel photos and the single-face photos of ../shared/data/faces, then runs
MediaPipe + PnP + normalization on every image and prints one JSON line per
rig: the face detection rate, the head-pose difference between our pipeline
and the simulator (degrees, median and 95th percentile), and the normalized
gaze of the same images re-labelled to look into the camera (must be (0, 0)).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)

from facemesh.io import load_image_rgb  # noqa: E402
from gazeaug.datasets import open_dataset  # noqa: E402
from gazeaug.experiment import _wheel_faces  # noqa: E402
from gazeaug.normalize import normalize_image  # noqa: E402
from gazeaug.pipeline import default_landmark_model, fit_face  # noqa: E402
from gazeaug.sampling import BUILTIN_RIGS  # noqa: E402
from gazeaug.simulate import simulate  # noqa: E402


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation a^T b, degrees."""
    c = (np.trace(a.T @ b) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


def main() -> None:
    """Run the checks."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--per-face", type=int, default=20)
    add_data_option(ap)
    args = ap.parse_args()
    require_data(ap, args.data, "faces/sergey.png", "faces/business-person.png")
    warnings.simplefilter("ignore")
    faces = [*_wheel_faces()] + [str(args.data / "faces" / n) for n in ("sergey.png", "business-person.png")]
    det = default_landmark_model()
    with tempfile.TemporaryDirectory() as tmp:
        for rig in ("screen", "wheelchair"):
            out = Path(tmp) / rig
            simulate(faces, BUILTIN_RIGS[rig], out, per_face=args.per_face, progress=False)
            truth = [json.loads(line) for line in (out / "simulation.jsonl").read_text().splitlines()]
            found, pose_err, gaze0 = 0, [], []
            for s, t in zip(open_dataset(out), truth):
                try:
                    fit = fit_face(load_image_rgb(s.image_path), s.camera, det)
                except Exception:  # noqa: BLE001 - counted as not found
                    continue
                found += 1
                pose_err.append(rotation_angle_deg(fit.pose.rotation, np.array(t["head_rotation"])))
                n = normalize_image(
                    fit.image, s.camera, fit.pose, fit.model.vertices_mm, fit.keypoints, gaze_target_mm=[0.0, 0.0, 0.0]
                )
                gaze0.append(np.degrees(np.abs(n.left.gaze)).max())
            print(
                json.dumps(
                    {
                        "rig": rig,
                        "images": len(truth),
                        "faces_found": found,
                        "detection_rate": round(found / len(truth), 3),
                        "head_pose_diff_deg_median": round(float(np.median(pose_err)), 2),
                        "head_pose_diff_deg_p95": round(float(np.percentile(pose_err, 95)), 2),
                        "gaze_into_camera_max_deg": float(np.max(gaze0)),
                    }
                ),
                flush=True,
            )


if __name__ == "__main__":
    main()
