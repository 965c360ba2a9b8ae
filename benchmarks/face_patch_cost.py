"""What a normalized face patch costs: ms per ``normalize_image`` and per ``render_poses`` sample, with and without.

``python benchmarks/face_patch_cost.py [--data ../shared/data] [--repeat 12]`` fits two photos of
``DATA/faces`` (MediaPipe, PnP), then times, per photo and per face patch (none, 112 x 112 at
480 px, 224 x 224 at 960 px: the same field of view), test-time normalization of the photo and the
ray-cast render of 8 head poses (per sample). Medians after two warm-up calls; one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)

PHOTOS = ("sergey.png", "pexels/image00.jpg")
#: (face patch (width, height), face focal px): none, half resolution, ETH-XGaze's.
FACES: tuple[tuple[tuple[int, int] | None, float], ...] = (
    (None, 960.0),
    ((112, 112), 480.0),
    ((224, 224), 960.0),
)


def _median_ms(fn: Any, repeat: int) -> float:
    times = []
    for _ in range(repeat + 2):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return round(float(np.median(times[2:])) * 1000, 2)


def _time_photo(img: Any, fit: Any, asset: Any, places: list[Any], repeat: int) -> dict[str, Any]:
    """The figures of one fitted photo, per face patch of :data:`FACES`."""
    from gazeaug.augment import render_poses
    from gazeaug.normalize import NormalizationSettings, normalize_image
    from gazeaug.render import create_renderer

    rows = {}
    for size, focal in FACES:
        s = NormalizationSettings(face_patch_size_wh=size, face_focal_px=focal if size else 960.0)
        scene = create_renderer("raycast", settings=s).scene(asset.render_mesh)
        key = "none" if size is None else f"{size[0]}x{size[1]}@{focal:g}"

        def norm(s: Any = s) -> None:
            normalize_image(img, fit.camera, fit.pose, fit.model.vertices_mm, fit.keypoints, settings=s)

        def render(s: Any = s, scene: Any = scene) -> None:
            render_poses(scene, asset, places, settings=s)

        rows[key] = {
            "normalize_ms": _median_ms(norm, repeat),
            "render_ms_per_sample": round(_median_ms(render, repeat) / len(places), 2),
        }
    return rows


def main() -> None:
    """Fit, time, print one JSON line."""
    from facemesh.camera import camera_for_image
    from facemesh.io import load_image_rgb
    from facemesh.landmarks import MediaPipeFaceMesh
    from gazeaug.augment import face_asset, sampled_placement
    from gazeaug.pipeline import fit_face, mesh_for_fit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_data_option(ap)
    ap.add_argument("--repeat", type=int, default=12)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    require_data(ap, args.data, *(f"faces/{p}" for p in PHOTOS))
    det = MediaPipeFaceMesh(refine_landmarks=True)
    out: dict[str, Any] = {}
    for name in PHOTOS:
        img = load_image_rgb(args.data / "faces" / name)
        h, w = img.shape[:2]
        fit = fit_face(img, camera_for_image(None, w, h, warn=False), det)
        asset = face_asset(mesh_for_fit(fit))
        places = [sampled_placement(asset, np.radians(y), np.radians(30.0)) for y in np.linspace(-20, 20, 8)]
        rows = _time_photo(img, fit, asset, places, args.repeat)
        out[f"{name} ({w}x{h})"] = rows
    det.close()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
