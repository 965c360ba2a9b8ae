"""How the three vertex placements differ: fidelity of the original-view render and a picture.

Usage: python benchmarks/compare_placements.py [FACES_DIR] [-o placements.png]

(docs/img/placements.png is drawn by ``python docs/make_figures.py placements``.)

For each photo it builds the mesh with each placement and reports
  reproj  mean distance (px) between projected vertices and their landmarks;
  eyes    mean absolute grey-level difference between the photo and the mesh
          rendered from the photo's own camera, over the pixels inside both eye
          contours (what a gaze model sees);
  turned  the same face turned 30 deg yaw, for the picture.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from facemesh import BuildSettings, build_face_mesh, builtin_face_model, camera_for_image, load_image_rgb
from facemesh.conventions import rotation_from_yaw_pitch
from facemesh.io import save_image_rgb
from facemesh.landmarks import MediaPipeFaceMesh, select_face
from facemesh.pose import project_points
from facemesh.render import RaycastScene

PHOTOS = ["astronaut.png", "business-person.png", "sergey.png", "pexels/image00.jpg"]
EYE_RINGS = {
    "right": [33, 7, 163, 144, 145, 153, 154, 155, 133, 173, 157, 158, 159, 160, 161, 246],
    "left": [362, 382, 381, 380, 374, 373, 390, 249, 263, 466, 388, 387, 386, 385, 384, 398],
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "faces", nargs="?", type=Path, default=Path(__file__).resolve().parents[2] / "shared/data/faces"
    )
    parser.add_argument("-o", "--output", type=Path, default=Path("placements.png"), help="the picture")
    args = parser.parse_args()
    model = builtin_face_model()
    rows = []
    print(f"{'photo':<22} {'placement':<14} {'reproj px':>9} {'eyes grey':>9}")
    with MediaPipeFaceMesh() as det:
        for name in PHOTOS:
            img = load_image_rgb(args.faces / name)
            h, w = img.shape[:2]
            cam = camera_for_image(None, w, h, warn=False)
            face = select_face(det.detect(img))
            mask = np.zeros((h, w), np.uint8)
            for ring in EYE_RINGS.values():
                cv2.fillPoly(mask, [np.round(face.points_px[ring]).astype(np.int32)], 1)
            grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(float)
            tiles = []
            for placement in ("canonical", "backprojected", "landmarks3d"):
                mesh = build_face_mesh(img, face, model, cam, BuildSettings(vertex_placement=placement))
                reproj = np.linalg.norm(project_points(mesh.vertices_mm, cam) - face.points_px[:468], axis=1).mean()
                res = RaycastScene.from_mesh(mesh).render(cam.matrix, (w, h), supersample=1)
                rg = cv2.cvtColor(res.image, cv2.COLOR_RGB2GRAY).astype(float)
                sel = (mask > 0) & (res.coverage == 1)
                eyes = float(np.abs(rg - grey)[sel].mean())
                print(f"{name:<22} {placement:<14} {reproj:>9.2f} {eyes:>9.2f}")
                turned = RaycastScene.from_mesh(mesh, rotation=rotation_from_yaw_pitch(np.radians(30), 0)).render(
                    cam.matrix, (w, h), supersample=2, background=(128, 128, 128)
                )
                x0, y0, x1, y1 = (int(v) for v in face.bbox_px)
                pad = int(0.1 * (x1 - x0))
                crop = turned.image[max(0, y0 - pad) : y1 + pad, max(0, x0 - pad) : x1 + pad]
                tile = cv2.resize(crop, (220, int(220 * crop.shape[0] / crop.shape[1])))[:260]
                tile = cv2.copyMakeBorder(
                    tile, 0, 260 - tile.shape[0], 0, 0, cv2.BORDER_CONSTANT, value=(128, 128, 128)
                )
                cv2.putText(tile, f"{placement} {eyes:.1f}", (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 0), 1)
                tiles.append(tile)
            rows.append(np.concatenate(tiles, axis=1))
    save_image_rgb(args.output, np.concatenate(rows[:2], axis=0))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
