"""What the texture crop's margin costs the eye patches a .glb feeds (docs/face_model.md, "Texture margin").

``python benchmarks/bench_texture_margin.py [--margins 0.15 0.25 0.4 0.5 0.6]`` prints, per photo of
../shared/data/faces and margin: the texture's size, the ``.glb``'s size, the time to build the
mesh and write it (best of 3), and how far the eye patches of the ``.glb`` read back (as
``gazeaug render face.glb`` renders them) are from the same fit textured with the whole photo
(margin 2: past every edge): the worst pixel and the worst patch's mean, grey levels (OpenCV's
RGB -> grey), over yaw -40, -20, 0, 20, 40 x pitch -20, 0, 30 deg and both eyes. The last column
counts the patches :func:`gazeaug.augment.texture_shortfall` flags (the warning of ``gazeaug
render``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
PHOTOS = ("astronaut.png", "sergey.png", "business-person.png", "pexels/image00.jpg", "pexels/image01.jpg")
POSES_DEG = [(y, p) for y in (-40, -20, 0, 20, 40) for p in (-20, 0, 30)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--faces", type=Path, default=REPO.parent / "shared" / "data" / "faces")
    ap.add_argument("--margins", type=float, nargs="+", default=[0.15, 0.25, 0.4, 0.5, 0.6])
    args = ap.parse_args()
    if not args.faces.is_dir():
        sys.exit(f"bench_texture_margin: {args.faces}: no such folder (../shared/data/faces)")

    import cv2

    from facemesh.camera import camera_for_image
    from facemesh.gltf import load_glb, save_glb
    from facemesh.io import load_image_rgb
    from facemesh.mesh import BuildSettings
    from gazeaug.augment import face_asset, render_poses, sampled_placement, texture_shortfall
    from gazeaug.pipeline import default_landmark_model, fit_face, mesh_for_fit
    from gazeaug.render import create_renderer

    detector = default_landmark_model()
    renderer = create_renderer("raycast")

    def patches(asset, places) -> np.ndarray:
        """(P, 2, H, W) float grey eye patches (left, right) at the placements."""
        samples = render_poses(renderer.scene(asset.render_mesh), asset, places)
        return np.array(
            [[cv2.cvtColor(s.eye(e).image, cv2.COLOR_RGB2GRAY) for e in ("left", "right")] for s in samples],
            dtype=np.float64,
        )

    print("| photo | margin | texture px | .glb kB | build + write ms | grey vs whole photo: max px / worst patch mean "
          "| flagged patches |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in PHOTOS:
            image = load_image_rgb(args.faces / name)
            h, w = image.shape[:2]
            fit = fit_face(image, camera_for_image(None, w, h, warn=False), detector, source=name)
            whole = face_asset(mesh_for_fit(fit, BuildSettings(texture_margin=2.0)))
            places = [sampled_placement(whole, np.radians(y), np.radians(p)) for y, p in POSES_DEG]
            reference = patches(whole, places)
            for margin in args.margins:
                path = Path(tmp) / f"m{margin}.glb"
                times = []
                for _ in range(3):
                    t0 = time.perf_counter()
                    mesh = mesh_for_fit(fit, BuildSettings(texture_margin=margin))
                    save_glb(mesh, path)
                    times.append(time.perf_counter() - t0)
                asset = face_asset(load_glb(path))
                diff = np.abs(patches(asset, places) - reference)
                flagged = int((texture_shortfall(asset, places) > 0).sum())
                th, tw = mesh.texture.shape[:2]
                print(
                    f"| {name} | {margin:g} | {tw}x{th} | {path.stat().st_size / 1e3:.0f} | {1e3 * min(times):.0f} | "
                    f"{diff.max():.0f} / {diff.mean(axis=(2, 3)).max():.2f} | {flagged} of {diff.shape[0] * 2} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
