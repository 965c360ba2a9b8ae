"""What `facemesh build --atlas` costs and saves, on the single-face photos of ../shared/data/faces.

``python benchmarks/bench_atlas.py`` prints, per photo: the crop texture and the atlas
(sizes), the atlas's pixels as a fraction of the crop's, the seam copies appended after the
N landmark vertices, and the mean absolute difference (grey levels, 0-255, over the face's
pixels) between renders of the two meshes at the photo's own view (`facemesh render
--yaw 0 --pitch 0`). The figures quoted in docs/index.md ("--atlas") come from it.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
PHOTOS = ("astronaut.png", "business-person.png", "sergey.png", "pexels/image00.jpg", "pexels/image01.jpg")


def _render(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) uint8 render at the photo's view and (H, W) bool: pixels the face covers."""
    from facemesh.render import RaycastScene

    scene = RaycastScene.from_mesh(mesh, rotation=np.eye(3))
    w, h = mesh.camera.image_size
    out = scene.render(mesh.camera.matrix, (w, h), background=(128, 128, 128))
    return out.image, out.coverage >= 0.999


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--faces", type=Path, default=REPO.parent / "shared" / "data" / "faces")
    args = ap.parse_args()
    if not args.faces.is_dir():
        sys.exit(f"bench_atlas: {args.faces}: no such folder (../shared/data/faces)")

    from facemesh import build_mesh, camera_for_image, load_image_rgb
    from facemesh.atlas import atlas_mesh
    from facemesh.landmarks import MediaPipeFaceMesh

    print(f"{'photo':<22}{'crop':>11}{'atlas':>11}{'pixels':>8}{'seam copies':>13}{'render MAD':>12}{'atlas ms':>10}")
    ratios, copies, mads = [], [], []
    warnings.filterwarnings("ignore", message="no camera calibration")  # the default camera, as the CLI's
    with MediaPipeFaceMesh() as detector:
        for name in PHOTOS:
            image = load_image_rgb(args.faces / name)
            camera = camera_for_image(None, image.shape[1], image.shape[0])
            mesh = build_mesh(image, camera, detector, source=name)
            t0 = time.perf_counter()
            packed = atlas_mesh(mesh)
            ms = (time.perf_counter() - t0) * 1e3
            th, tw = mesh.texture.shape[:2]
            ah, aw = packed.texture.shape[:2]
            ratio = (aw * ah) / (tw * th)
            n_copies = packed.num_vertices - mesh.num_vertices
            a, mask_a = _render(mesh)
            b, mask_b = _render(packed)
            both = mask_a & mask_b
            mad = float(np.abs(a.astype(float) - b.astype(float))[both].mean())
            ratios.append(ratio)
            copies.append(n_copies)
            mads.append(mad)
            print(f"{name:<22}{tw:>5}x{th:<5}{aw:>5}x{ah:<5}{ratio:>8.2f}{n_copies:>13}{mad:>12.2f}{ms:>10.0f}")
    print(
        f"range: pixels {min(ratios):.2f}-{max(ratios):.2f} of the crop's, seam copies {min(copies)}-{max(copies)}, "
        f"render MAD {min(mads):.2f}-{max(mads):.2f} (mean {np.mean(mads):.2f}) grey levels"
    )


if __name__ == "__main__":
    main()
