"""Mesh building time against the landmark detector's own time, per photo.

Usage: python benchmarks/bench_build.py [FACES_DIR] [--repeat N]

For each photo (default: ../shared/data/faces), with the MediaPipe graph loaded
once beforehand, it times (median of N runs):
  detect  MediaPipe Face Mesh alone on the decoded image;
  build   detect + PnP + vertices + texture crop + UVs (``build_mesh``);
  +glb    build + encoding the .glb in memory (PNG texture).
and prints build/detect (the target is <= 1.3).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from facemesh import build_mesh, camera_for_image, load_image_rgb
from facemesh.gltf import gltf_bytes
from facemesh.landmarks import MediaPipeFaceMesh

PHOTOS = [
    "astronaut.png",
    "business-person.png",
    "sergey.png",
    "two_children.jpeg",
    "pexels/image00.jpg",
    "pexels/image01.jpg",
]


def _median_ms(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1000)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[2] / "shared" / "data" / "faces"
    parser.add_argument("faces", nargs="?", type=Path, default=default)
    parser.add_argument("--repeat", type=int, default=15)
    args = parser.parse_args()
    if not args.faces.is_dir():
        sys.exit(f"no photos at {args.faces}")
    print(f"{'photo':<22} {'size':>10} {'detect ms':>10} {'build ms':>9} {'ratio':>6} {'+glb ms':>8}")
    ratios = []
    with MediaPipeFaceMesh() as det:
        det.detect(np.zeros((64, 64, 3), np.uint8))  # load the graph
        for name in PHOTOS:
            img = load_image_rgb(args.faces / name)
            h, w = img.shape[:2]
            cam = camera_for_image(None, w, h, warn=False)
            build_mesh(img, cam, det)  # warm-up
            t_det = _median_ms(lambda img=img: det.detect(img), args.repeat)
            t_build = _median_ms(lambda img=img, cam=cam: build_mesh(img, cam, det), args.repeat)
            t_glb = _median_ms(lambda img=img, cam=cam: gltf_bytes(build_mesh(img, cam, det)), args.repeat)
            ratios.append(t_build / t_det)
            print(f"{name:<22} {w:>4}x{h:<5} {t_det:>10.1f} {t_build:>9.1f} {t_build / t_det:>6.2f} {t_glb:>8.1f}")
    print(f"median build/detect ratio: {statistics.median(ratios):.2f} (target <= 1.3)")


if __name__ == "__main__":
    main()
