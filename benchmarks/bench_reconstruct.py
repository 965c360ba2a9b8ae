"""Surfaces for landmark models without triangles: each method against MediaPipe's own triangulation.

``python benchmarks/bench_reconstruct.py [--figure docs/img/reconstruction.png]`` prints, for
MediaPipe's 468 points given without triangles, dlib's 68-point subset and ETH-XGaze's 50
points (:mod:`facemesh.face_models.layouts`), and for each method of
:data:`facemesh.reconstruct.SURFACE_METHODS`, over the single-face photos of ../shared/data/faces:

- coverage: the reconstructed surface seen from the front (rasterized at 0.25 mm) over the
  area of the dense mesh's (MediaPipe's triangulation, eyes and mouth closed), min and mean;
- outline: the surface over its own outline (the points' convex hull seen from the front), min:
  1.0 means no hole and no notch;
- holes: the boundary loops beyond the outer one (``bad``: the boundary is not a set of
  simple loops), worst photo;
- eye patches rendered at the original pose, yaw +-20, pitch +-20 and pitch 30 deg: the mean
  absolute grey difference against the same patches from the dense mesh (mean and worst
  patch), and the pixels no triangle covered (inpainted by the renderer; mean and worst patch);
- the time of one reconstruction (median, ms).

Only the surface differs: both meshes have the same vertices (the sparse ones are a subset of
the dense mesh's), the same texture coordinates and pose, and are rendered with the dense
mesh's normalized cameras. ``--figure`` draws one photo's surfaces turned frontal.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from people import TRAIN_PHOTOS  # noqa: E402  (benchmarks/people.py: the photos every benchmark uses)
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)

from facemesh.build import fit_face, mesh_for_fit  # noqa: E402
from facemesh.camera import camera_for_image  # noqa: E402
from facemesh.conventions import face_forward, frontal_coordinates  # noqa: E402
from facemesh.face_models.layouts import SPARSE_LAYOUTS  # noqa: E402
from facemesh.face_models.triangulation import boundary_loops  # noqa: E402
from facemesh.io import load_image_rgb  # noqa: E402
from facemesh.landmarks.mediapipe import MediaPipeFaceMesh  # noqa: E402
from facemesh.mesh import texture_uv  # noqa: E402
from facemesh.reconstruct import SURFACE_METHODS, Reconstruction, reconstruct_surface  # noqa: E402
from facemesh.types import FaceMesh  # noqa: E402

PHOTOS = TRAIN_PHOTOS  # the 9 single-face photos of ../shared/data/faces
#: (yaw, pitch) degrees of the rendered head poses; None: the photo's own pose.
POSES: tuple[tuple[float, float] | None, ...] = (None, (20, 0), (-20, 0), (0, 20), (0, -20), (0, 30))
LAYOUTS = {"468": np.arange(468)} | {k: np.asarray(v[0]) for k, v in SPARSE_LAYOUTS.items()}
RASTER_MM = 0.25


def surface_mesh(dense: FaceMesh, idx: np.ndarray, rec: Reconstruction) -> FaceMesh:
    """The dense mesh's vertices at ``idx`` (then any appended ones) with the reconstructed triangles."""
    v = np.asarray(dense.vertices_mm)[idx]
    uv = np.asarray(dense.uv)[idx]
    if len(rec.appended_vertices_mm):
        th, tw = dense.texture.shape[:2]
        v = np.concatenate([v, rec.appended_vertices_mm])
        uv = np.concatenate([uv, texture_uv(rec.appended_vertices_mm, dense.camera, dense.texture_origin_px, (tw, th))])
    return dataclasses.replace(
        dense, vertices_mm=v, triangles=rec.triangles, uv=uv, reconstruction=rec.as_metadata(), extras={}
    )


def frontal_mask(
    vertices: np.ndarray, triangles: np.ndarray, forward: np.ndarray, lo: np.ndarray, size: tuple
) -> np.ndarray:
    """Pixels (RASTER_MM each) the triangles cover seen from the front."""
    import cv2

    q = np.round((frontal_coordinates(vertices, forward) - lo) / RASTER_MM * 16).astype(np.int32)
    mask = np.zeros(size, np.uint8)
    cv2.fillPoly(mask, [q[t] for t in np.asarray(triangles)], 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


def holes(triangles: np.ndarray) -> int | str:
    try:
        return max(len(boundary_loops(triangles)) - 1, 0)
    except ValueError:
        return "bad"


def eye_patches(asset, mesh: FaceMesh) -> tuple[np.ndarray, np.ndarray]:
    """(P, 2, H, W) grey patches and (P, 2) uncovered pixel counts of ``mesh`` at POSES, with ``asset``'s cameras."""
    import cv2

    from gazeaug.augment import render_poses, sampled_placement, source_placement
    from gazeaug.render import create_renderer
    from gazeaug.render.base import render_mesh

    places = [
        source_placement(asset) if p is None else sampled_placement(asset, np.radians(p[0]), np.radians(p[1]))
        for p in POSES
    ]
    scene = create_renderer("raycast").scene(render_mesh(mesh))
    out = render_poses(scene, asset, places)
    grey = np.array([[cv2.cvtColor(s.eye(e).image, cv2.COLOR_RGB2GRAY) for e in ("left", "right")] for s in out])
    h, w = grey.shape[2:]
    miss = np.array([[round((1.0 - s.eye(e).coverage) * h * w) for e in ("left", "right")] for s in out])
    return grey.astype(np.float64), miss


def main() -> None:
    """Print the table (and draw the figure)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_data_option(ap)
    ap.add_argument("--photos", type=int, default=len(PHOTOS), help="how many of the photos (default all 9)")
    ap.add_argument("--methods", nargs="+", default=list(SURFACE_METHODS), choices=SURFACE_METHODS)
    ap.add_argument("--figure", type=Path, help="also draw the first photo's surfaces turned frontal here")
    args = ap.parse_args()
    require_data(ap, args.data, *(f"faces/{p}" for p in PHOTOS[: args.photos]))

    from gazeaug.augment import face_asset

    det = MediaPipeFaceMesh()
    rows: dict[tuple[str, str], dict[str, list]] = {}
    figure_meshes: dict[tuple[str, str], FaceMesh] = {}
    for k, name in enumerate(PHOTOS[: args.photos]):
        image = load_image_rgb(args.data / "faces" / name)
        h, w = image.shape[:2]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit = fit_face(image, camera_for_image(None, w, h, warn=False), det, source=name)
        dense = mesh_for_fit(fit)
        asset = face_asset(dense)
        forward = face_forward(dense.pose.rotation)
        v_dense = np.asarray(dense.vertices_mm)
        q = frontal_coordinates(v_dense, forward)
        lo = q.min(axis=0) - 5.0
        size = tuple(int(x) for x in np.ceil((q.max(axis=0) + 5.0 - lo) / RASTER_MM)[::-1])
        dense_mask = frontal_mask(v_dense, dense.triangles, forward, lo, size)
        ref_grey, _ = eye_patches(asset, dense)
        if k == 0:
            figure_meshes[("468", "dense")] = dense
        for layout, idx in LAYOUTS.items():
            pts = v_dense[idx]
            for method in args.methods:
                t0 = time.perf_counter()
                rec = reconstruct_surface(pts, method, forward=forward)
                dt = time.perf_counter() - t0
                mesh = surface_mesh(dense, idx, rec)
                mask = frontal_mask(mesh.vertices_mm, mesh.triangles, forward, lo, size)
                hull = frontal_mask(pts, _hull_triangles(pts, forward), forward, lo, size)
                grey, miss = eye_patches(asset, mesh)
                r = rows.setdefault((layout, method), {k: [] for k in ("cov", "outline", "holes", "mad", "miss", "ms")})
                r["cov"].append((mask & dense_mask).sum() / dense_mask.sum())
                r["outline"].append((mask & hull).sum() / hull.sum())
                r["holes"].append(holes(rec.triangles))
                r["mad"].extend(np.abs(grey - ref_grey).mean(axis=(2, 3)).ravel().tolist())
                r["miss"].extend(miss.ravel().tolist())
                r["ms"].append(1000 * dt)
                if k == 0:
                    figure_meshes[(layout, method)] = mesh
        print(f"done {name}", file=sys.stderr, flush=True)

    print(
        "| points | method | coverage vs dense (min / mean) | outline covered (min) | holes (worst) "
        "| eye MAD grey (mean / worst) | uncovered px per patch (mean / worst) | ms |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for (layout, method), r in rows.items():
        worst_holes = "bad" if "bad" in r["holes"] else max(r["holes"])
        print(
            f"| {layout} | {method} | {min(r['cov']):.4f} / {np.mean(r['cov']):.4f} | {min(r['outline']):.4f} "
            f"| {worst_holes} | {np.mean(r['mad']):.2f} / {max(r['mad']):.2f} "
            f"| {np.mean(r['miss']):.1f} / {max(r['miss'])} | {np.median(r['ms']):.0f} |"
        )
    if args.figure:
        draw_figure(figure_meshes, args.figure)


def _hull_triangles(pts: np.ndarray, forward: np.ndarray) -> np.ndarray:
    from scipy.spatial import ConvexHull

    hull = ConvexHull(frontal_coordinates(pts, forward)).vertices
    return np.array([[hull[0], hull[i], hull[i + 1]] for i in range(1, len(hull) - 1)])


def draw_figure(meshes: dict[tuple[str, str], FaceMesh], path: Path) -> None:
    """Each surface turned frontal (textured, edges drawn), a row per layout, the dense mesh first."""
    import cv2

    from facemesh.io import save_image_rgb
    from facemesh.render import RaycastScene

    size = 240
    tiles: dict[tuple[str, str], np.ndarray] = {}
    for key, mesh in meshes.items():
        r, t = np.asarray(mesh.pose.rotation), np.asarray(mesh.pose.translation_mm)
        d = float(np.linalg.norm(t))
        v = (np.asarray(mesh.vertices_mm) - t) @ r + np.array([0.0, 0.0, d])  # frontal, same distance
        f = size * d / 190.0
        k = np.array([[f, 0, size / 2], [0, f, size * 0.42], [0, 0, 1]])
        img = RaycastScene(v, mesh.triangles, mesh.uv, mesh.texture).render(k, (size, size), supersample=2).image
        if key[1] != "poisson":  # its thousands of small triangles would hide the face
            px = (v[:, :2] / v[:, 2:3]) * f + k[:2, 2]
            tri = np.asarray(mesh.triangles)
            edges = img.copy()
            polys = [np.round(px[t] * 16).astype(np.int32) for t in tri]
            cv2.polylines(edges, polys, True, (255, 220, 0), 1, cv2.LINE_AA, 4)
            img = cv2.addWeighted(img, 0.6, edges, 0.4, 0)
        label = "dense (MediaPipe's triangles)" if key[1] == "dense" else f"{key[0]} points, {key[1]}"
        cv2.putText(img, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        tiles[key] = img
    layouts = list(dict.fromkeys(k[0] for k in tiles if k[1] != "dense"))
    methods = list(dict.fromkeys(k[1] for k in tiles if k[1] != "dense"))
    blank = np.zeros((size, size, 3), np.uint8)
    grid = []
    for layout in layouts:
        row = [tiles[("468", "dense")] if layout == "468" else blank]
        row += [tiles.get((layout, m), blank) for m in methods]
        grid.append(np.concatenate(row, axis=1))
    save_image_rgb(path, np.concatenate(grid, axis=0))
    print(f"wrote {path}", file=sys.stderr)


if __name__ == "__main__":
    main()
