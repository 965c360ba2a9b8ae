"""Fidelity of rendered eye patches: render at the original pose vs the normalization of the photo.

``python benchmarks/render_fidelity.py [--filament]`` prints, per single-face photo of
../shared/data/faces, the mean absolute difference (grey levels) of each eye and
the largest label difference (degrees); with ``--filament`` also the mean
absolute difference between the Filament and ray-casting renders over a set of poses.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)

from facemesh.camera import camera_for_image  # noqa: E402
from facemesh.io import load_image_rgb  # noqa: E402
from facemesh.landmarks.mediapipe import MediaPipeFaceMesh  # noqa: E402
from gazeaug.augment import face_asset, render_poses, sampled_placement, source_placement  # noqa: E402
from gazeaug.normalize import normalize_image  # noqa: E402
from gazeaug.pipeline import fit_face, mesh_for_fit  # noqa: E402
from gazeaug.render import create_renderer  # noqa: E402

PHOTOS = ("astronaut.png", "business-person.png", "sergey.png", "pexels/image00.jpg", "pexels/image01.jpg")
POSES = [(0, 0), (0, 30), (15, 20), (-20, 35), (10, -15), (-30, 10)]
TARGET = np.array([60.0, 90.0, -20.0])


def main() -> None:
    """Print the table."""
    ap = argparse.ArgumentParser(description=__doc__)
    add_data_option(ap)
    ap.add_argument("--filament", action="store_true")
    args = ap.parse_args()
    require_data(ap, args.data, *(f"faces/{p}" for p in PHOTOS))
    det = MediaPipeFaceMesh()
    print(
        "| photo | MAD left | MAD right | max label diff (deg) |"
        + (" Filament vs raycast MAD |" if args.filament else "")
    )
    print("|---|---|---|---|" + ("---|" if args.filament else ""))
    for name in PHOTOS:
        image = load_image_rgb(args.data / "faces" / name)
        h, w = image.shape[:2]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit = fit_face(image, camera_for_image(None, w, h, warn=False), det, source=name)
        asset = face_asset(mesh_for_fit(fit))
        ref = normalize_image(image, fit.camera, fit.pose, fit.model.vertices_mm, fit.keypoints, gaze_target_mm=TARGET)
        ray = create_renderer("raycast").scene(asset.render_mesh)
        out = render_poses(ray, asset, [source_placement(asset)], gaze_target_mm=TARGET)[0]
        mads = [np.abs(ref.eye(s).image.astype(float) - out.eye(s).image).mean() for s in ("left", "right")]
        dl = max(
            float(np.degrees(np.abs(getattr(ref.eye(s), k) - getattr(out.eye(s), k))).max())
            for s in ("left", "right")
            for k in ("gaze", "head_pose")
        )
        row = f"| {name} | {mads[0]:.2f} | {mads[1]:.2f} | {dl:.1e} |"
        if args.filament:
            fil = create_renderer("filament").scene(asset.render_mesh)
            places = [sampled_placement(asset, np.radians(y), np.radians(p)) for y, p in POSES]
            a = render_poses(ray, asset, places)
            b = render_poses(fil, asset, places, renderer_name="filament")
            d = [
                np.abs(x.eye(s).image.astype(float) - y.eye(s).image).mean()
                for x, y in zip(a, b)
                for s in ("left", "right")
            ]
            row += f" {np.mean(d):.2f} (max {np.max(d):.2f}) |"
        print(row, flush=True)


if __name__ == "__main__":
    main()
