"""How far the iris moves in the normalized eye patch per degree of true gaze, on simulated eyes.

``python benchmarks/eye_signal.py [--face PHOTO] [--identities 4] [--focal 650]``

A controlled sweep: one photo's face (default the built-in astronaut), several
drawn identities, the head frontal 550 mm from a 640 x 480 camera (focal 600 px,
the ``screen`` rig's), the eyes looking at points 500 mm away along a grid of
(pitch, yaw) in the head frame: -30 to +10 deg by 10, -20 to +20 deg by 10. The
iris is painted pure blue (no relighting, no noise, no kappa), each image goes
through our own pipeline (MediaPipe, PnP, normalization at ``--focal``), and the
blue pixels of each normalized patch give the visible iris's centroid and area.

Prints one JSON line: per identity and eye, the least-squares slopes of the
centroid's x against the normalized gaze yaw and of its y against the pitch
(px per degree), and the visible iris area (px) at each pitch. The geometric
expectation for the iris centre on a sphere of radius R at distance d: ``f R pi /
180 / d`` px per degree (0.23 for R = 12 mm, f = 650 px, d = 600 mm); the visible
centroid moves less where the lids cut the iris (vertically most of all).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

PITCHES = (-30, -20, -10, 0, 10)
YAWS = (-20, -10, 0, 10, 20)


def dominant(img: np.ndarray, channel: int) -> np.ndarray:
    """(H, W) bool: the pixels of an RGB patch whose ``channel`` exceeds both others by over 60 grey levels.

    Channel 2 (blue) finds the painted iris; channel 1 (green) the painted sclera.
    """
    p = img.astype(np.float64)
    others = np.delete(p, channel, axis=-1)
    return np.asarray((p[..., channel] - others.max(axis=-1)) > 60)


def clean_setup() -> tuple[Any, np.ndarray, Any]:
    """Simulator settings without relighting, blur, noise, JPEG loss, brightness change or kappa, and the camera.

    Returns:
        (SimSettings, (3, 3) camera matrix, CameraIntrinsics): a 640 x 480 camera, focal 600 px
        (the ``screen`` rig's), principal point at the image centre, no distortion.
    """
    from facemesh.camera import CameraIntrinsics
    from gazeaug.simulate import SimSettings

    s = SimSettings(
        relight=False,
        kappa_deg=0.0,
        blur_sigma_px=(0.0, 0.0),
        noise_sigma=(0.0, 0.0),
        jpeg_quality=(95, 95),
        brightness=(1.0, 1.0),
    )
    w, h, f = 640, 480, 600.0
    k = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    return s, k, CameraIntrinsics(k, np.zeros(5), (w, h))


def main() -> None:
    """Run the sweep."""
    from facemesh.conventions import rotation_from_yaw_pitch
    from facemesh.io import load_image_rgb
    from gazeaug.normalize import NormalizationSettings, normalize_image
    from gazeaug.pipeline import default_landmark_model, fit_face
    from gazeaug.simulate import PhotoFace, SimSubject, draw_subject

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--face", type=Path, default=None, help="a face photo (default: the built-in astronaut)")
    ap.add_argument("--identities", type=int, default=4)
    ap.add_argument("--focal", type=float, default=650.0, help="the normalized camera's focal length, px")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    if args.face is None:
        from facemesh.build import sample_image

        image = sample_image()
    else:
        image = load_image_rgb(args.face)
    det = default_landmark_model()
    photo = PhotoFace.from_image(image, det, str(args.face or "astronaut"))
    s, k, cam = clean_setup()
    w, h = cam.image_size
    norm = NormalizationSettings(focal_px=args.focal)
    results = []
    for ident in range(args.identities):
        d = draw_subject(s, np.random.default_rng(100 + ident))
        d = dataclasses.replace(d, iris_rgb=(0.0, 0.0, 255.0), glasses=None, kappa_deg=(0.0, 0.0))
        subj = SimSubject(photo, f"s{ident}", s, d)
        r, t = np.eye(3), np.array([0.0, 0.0, 550.0])
        mid = (subj.eye_centre["left"] + subj.eye_centre["right"]) / 2
        rows: dict[str, list[tuple[float, float, float, float, float, int]]] = {"left": [], "right": []}
        for pitch in PITCHES:
            for yaw in YAWS:
                direction = rotation_from_yaw_pitch(math.radians(yaw), math.radians(pitch)) @ [0.0, 0.0, -1.0]
                target = r @ (mid + 500.0 * direction) + t
                frame = subj.render(r, t, target, k, (w, h), np.random.default_rng(1))
                try:
                    fit = fit_face(frame.image, cam, det)
                except Exception:  # noqa: BLE001 - a miss is left out of the fit
                    continue
                pts = fit.model.vertices_mm
                kp = fit.keypoints
                n = normalize_image(frame.image, cam, fit.pose, pts, kp, gaze_target_mm=target, settings=norm)
                for side in ("left", "right"):
                    eye = n.eye(side)
                    blue = dominant(eye.image, 2)
                    ys, xs = np.nonzero(blue)
                    if len(xs) > 8 and eye.gaze is not None:
                        gp, gy = np.degrees(eye.gaze)
                        rows[side].append((gp, gy, float(xs.mean()), float(ys.mean()), pitch, int(blue.sum())))
        for side, rr in rows.items():
            if len(rr) < 5:
                continue
            a = np.array(rr)
            design = np.column_stack([a[:, 1], a[:, 0], np.ones(len(a))])  # yaw, pitch, 1
            bx = np.linalg.lstsq(design, a[:, 2], rcond=None)[0]
            by = np.linalg.lstsq(design, a[:, 3], rcond=None)[0]
            results.append(
                {
                    "identity": ident,
                    "eye": side,
                    "dx_per_deg_yaw": round(float(bx[0]), 3),
                    "dy_per_deg_pitch": round(float(by[1]), 3),
                    "iris_area_px_by_pitch": {
                        str(p): round(float(a[a[:, 4] == p, 5].mean()), 1) for p in PITCHES if np.any(a[:, 4] == p)
                    },
                    "images": len(rr),
                }
            )
    expected = args.focal * 12.0 * math.pi / 180 / norm.distance_mm
    print(json.dumps({"focal_px": args.focal, "expected_iris_centre_px_per_deg": round(expected, 3), "eyes": results}))


if __name__ == "__main__":
    main()
