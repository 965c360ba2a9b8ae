"""Derive the built-in MediaPipe-topology face model from inputs anyone can get with pip.

Run ``python -m facemesh.face_models.derive_mediapipe -o model.npz`` to derive it
again, and ``--write-packaged`` to replace
``facemesh/face_models/mediapipe468.npz``, the file the package loads. The inputs are face photos that
ship inside installed wheels and MediaPipe's own 3D landmark output on them:
the two public-domain portraits (scikit-image's ``astronaut`` and
matplotlib's ``sample_data/grace_hopper.jpg``) and the 100 face crops of
scikit-image's ``lfw_subset`` (25 x 25 grey crops from Labeled Faces in the
Wild, 100 different people). The triangulation comes from the
``FACEMESH_TESSELATION`` edge list inside the mediapipe wheel. MediaPipe's
canonical face model is *not* used (the tests compare against it).

Steps:
1. MediaPipe Face Mesh (with iris refinement) on each photo (the LFW crops
   enlarged 8x with bicubic interpolation and a 50 px replicated border, so the
   face detector finds them; 98 of 100 are found); each face's 478 points as
   (x_px, y_px, z * W): x right, y down, z away from the camera, which is the
   head frame's axis directions for a face looking at the camera.
2. Generalised Procrustes alignment (similarity), then the mean shape.
3. Left-right symmetry: mirror the mean (x -> -x), find each point's mirror
   partner by optimal assignment, refined by rigid alignment; the model is the
   average of the shape and its mirrored, re-indexed copy. The partner
   permutation is stored as ``mirror``.
4. Frame: origin at the midpoint of the eye centres (eye centre = mean of the
   eye's two corners); z normal to the plane that best fits the face's outer
   contour, into the head; x along the eye line (toward the subject's left),
   y toward the chin.
5. Metric scale: the distance between the two iris centres (landmarks 468 and
   473) is set to the mean adult interpupillary distance, 63 mm (Dodgson 2004,
   "Variation and extrema of human interpupillary distance").
6. Triangles: :func:`facemesh.face_models.triangulation.clean_triangulation_from_edges`
   (computed before step 4's final levelling, which needs the outer contour).

Reproducibility: the vertices are floating-point results and may differ
between machines by ~1e-13 mm (BLAS, summation order). The triangles and the
partner permutation are combinatorial and must not: the one decision that
sat on an exact tie, which of two mirror-image ears of the (symmetric) mouth
opening the ear clipper cuts first, is taken by an explicit rule (ears within
``EAR_QUALITY_TIE_RAD`` of the best are tied; the largest apex vertex index
wins), see :func:`facemesh.face_models.triangulation.ear_clip`. Before that
rule, rounding noise decided it and 4 of the 898 triangles (two flipped quad
diagonals at the mouth corners) changed from machine to machine.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from ..geometry import apply_similarity, similarity_transform
from . import _DATA_FILE
from .triangulation import clean_triangulation_from_edges

#: Mean adult interpupillary distance, millimetres (Dodgson 2004).
INTERPUPILLARY_DISTANCE_MM = 63.0
IRIS_CENTRES = (468, 473)
NUM_MESH_POINTS = 468


def wheel_photos() -> dict[str, NDArray[np.uint8]]:
    """The public-domain face photos that ship inside pip wheels, as RGB uint8."""
    import matplotlib
    import skimage.data

    from ..io import load_image_rgb

    return {
        "skimage.data.astronaut": np.asarray(skimage.data.astronaut()),
        "matplotlib/sample_data/grace_hopper.jpg": load_image_rgb(
            Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
        ),
    }


#: How the 25 x 25 LFW crops are enlarged before detection.
LFW_UPSCALE = 8
LFW_BORDER_PX = 50


def lfw_photos() -> dict[str, NDArray[np.uint8]]:
    """The 100 face crops of scikit-image's ``lfw_subset``, enlarged, as RGB uint8.

    ``skimage.data.lfw_subset()`` is (200, 25, 25) float in [0, 1]: 100 faces,
    then 100 non-faces. Each face is enlarged ``LFW_UPSCALE`` times (bicubic)
    and padded by ``LFW_BORDER_PX`` replicated pixels.
    """
    import cv2
    import skimage.data

    crops = np.asarray(skimage.data.lfw_subset())[:100]
    out = {}
    for i, crop in enumerate(crops):
        grey = np.clip(np.rint(crop * 255.0), 0, 255).astype(np.uint8)
        grey = cv2.resize(grey, None, fx=LFW_UPSCALE, fy=LFW_UPSCALE, interpolation=cv2.INTER_CUBIC)
        grey = cv2.copyMakeBorder(grey, *(LFW_BORDER_PX,) * 4, cv2.BORDER_REPLICATE)
        out[f"skimage.data.lfw_subset[{i}]"] = np.ascontiguousarray(np.repeat(grey[:, :, None], 3, axis=2))
    return out


def landmark_shapes(
    photos: dict[str, NDArray[np.uint8]], *, required: bool = True
) -> tuple[list[str], list[NDArray[np.float64]]]:
    """MediaPipe's (478, 3) 3D landmarks of the largest face in each photo.

    Returns the names of the photos used and their shapes. With
    ``required=False`` photos where no face is found are left out.
    """
    from ..landmarks import MediaPipeFaceMesh, select_face
    from ..types import NoFaceError

    names, shapes = [], []
    with MediaPipeFaceMesh(refine_landmarks=True) as det:
        for name, img in photos.items():
            try:
                face = select_face(det.detect(img), source=name)
            except NoFaceError:
                if required:
                    raise
                continue
            assert face.points_3d is not None
            names.append(name)
            shapes.append(np.asarray(face.points_3d))
    return names, shapes


def procrustes_mean(shapes: list[NDArray[np.float64]], iterations: int = 10) -> NDArray[np.float64]:
    """Generalised Procrustes mean shape (similarity), in the first shape's scale."""
    ref = shapes[0]
    for _ in range(iterations):
        aligned = [apply_similarity(s, *similarity_transform(s, ref)) for s in shapes]
        new = np.mean(aligned, axis=0)
        s, r, t = similarity_transform(new, shapes[0])
        ref = apply_similarity(new, s, r, t)
    return ref


def mirror_partners(points: NDArray[np.float64], iterations: int = 10) -> NDArray[np.int64]:
    """Permutation p with point p[i] the left-right mirror of point i (an involution)."""
    mirrored = points * np.array([-1.0, 1.0, 1.0])
    moved = mirrored + (points.mean(axis=0) - mirrored.mean(axis=0))
    perm = np.arange(len(points))
    for _ in range(iterations):
        cost = np.linalg.norm(points[:, None, :] - moved[None, :, :], axis=2)
        _, perm = linear_sum_assignment(cost)
        s, r, t = similarity_transform(mirrored[perm], points, with_scale=False)
        moved = apply_similarity(mirrored, s, r, t)
    if not np.array_equal(perm[perm], np.arange(len(points))):
        raise RuntimeError("mirror assignment is not an involution")
    return perm.astype(np.int64)


def symmetric_head_frame(shape: NDArray[np.float64], perm: NDArray[np.int64]) -> NDArray[np.float64]:
    """Symmetrise and express in the head frame (origin between the eyes, metric scale).

    ``shape`` holds the 468 mesh points followed by the two iris centres.
    """
    from . import EYE_CORNERS

    mirrored = shape * np.array([-1.0, 1.0, 1.0])
    s, r, t = similarity_transform(mirrored[perm], shape, with_scale=False)
    sym = 0.5 * (shape + apply_similarity(mirrored[perm], s, r, t))
    right = sym[list(EYE_CORNERS["right"])].mean(axis=0)
    left = sym[list(EYE_CORNERS["left"])].mean(axis=0)
    x = left - right  # image right = subject's left
    x /= np.linalg.norm(x)
    # Face normal: from the nose tip region into the head is +z; use the
    # plane through eye centres and mouth corners (61, 291).
    mouth = sym[[61, 291]].mean(axis=0)
    y = mouth - 0.5 * (left + right)
    y -= x * (y @ x)
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    rot = np.stack([x, y, z])  # rows: new axes in old coordinates
    head = (sym - 0.5 * (left + right)) @ rot.T
    ipd = np.linalg.norm(head[NUM_MESH_POINTS] - head[NUM_MESH_POINTS + 1])
    return head * (INTERPUPILLARY_DISTANCE_MM / ipd)


def level_to_contour_plane(head: NDArray[np.float64], triangles: NDArray[np.int64]) -> NDArray[np.float64]:
    """Turn the model so that z is normal to the plane best fitting the face's outer contour.

    The outer contour (the mesh's one open boundary: forehead, temples, jaw)
    is a stable, expression-free reference; with it the frame lies within
    about 1 deg of MediaPipe's canonical one. x stays along the eye line
    (projected onto that plane), the origin between the eyes.
    """
    from . import EYE_CORNERS
    from .triangulation import boundary_loops

    contour = max(boundary_loops(triangles), key=len)
    pts = head[contour] - head[contour].mean(axis=0)
    _, vecs = np.linalg.eigh(pts.T @ pts)
    z = vecs[:, 0]
    if z[2] < 0:
        z = -z
    eye_line = head[list(EYE_CORNERS["left"])].mean(axis=0) - head[list(EYE_CORNERS["right"])].mean(axis=0)
    x = eye_line - z * (eye_line @ z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return head @ np.stack([x, y, z]).T


def derivation_inputs() -> tuple[list[str], list[NDArray[np.float64]], list[tuple[int, int]]]:
    """Everything the derivation reads from installed wheels (step 1 and the edge list).

    Returns:
        ``(names, shapes, edges)``: the names of the photos where MediaPipe
        found a face; their (478, 3) float64 landmarks as ``(x_px, y_px,
        z * W)`` (image frame x, y in pixels; z away from the camera in the
        same pixel units); and ``FACEMESH_TESSELATION`` as a sorted list of
        (i, j) vertex index pairs.
    """
    from ..landmarks.mediapipe import import_mediapipe_face_mesh

    names, shapes = landmark_shapes(wheel_photos())
    lfw_names, lfw_shapes = landmark_shapes(lfw_photos(), required=False)
    edges = sorted((int(a), int(b)) for a, b in import_mediapipe_face_mesh().FACEMESH_TESSELATION)
    return names + lfw_names, shapes + lfw_shapes, edges


def derive_from_landmarks(
    names: list[str], shapes: list[NDArray[np.float64]], edges: list[tuple[int, int]]
) -> dict[str, NDArray[np.generic]]:
    """Steps 2-6 on given landmarks; returns the arrays stored in ``mediapipe468.npz``.

    Args:
        names: one name per face (stored as ``sources``).
        shapes: per face, (478, 3) float64 MediaPipe landmarks as ``(x_px, y_px, z * W)``.
        edges: MediaPipe's tessellation edges, (i, j) vertex index pairs.

    Returns:
        ``vertices_mm`` (468, 3) float64, millimetres, head frame;
        ``triangles`` (898, 3) int64 vertex indices, right-hand normals out of
        the face; ``mirror`` (468,) int64, the left-right partner of each
        point; ``sources`` (F,) str, the photos used.

    The triangles and the partner permutation are combinatorial decisions
    taken by exact rules (see
    :func:`facemesh.face_models.triangulation.ear_clip` for the one tie the
    symmetric shape produces), so noise of the order of floating-point
    rounding in ``shapes`` (another machine's BLAS or summation order) moves
    the vertices by ~1e-13 mm and changes neither.
    """
    # The 468 mesh points and the two iris centres (the ring around each iris
    # is left out: it only follows the eye).
    keep = list(range(NUM_MESH_POINTS)) + list(IRIS_CENTRES)
    mean = procrustes_mean([np.asarray(s, dtype=np.float64)[keep] for s in shapes])
    perm468 = mirror_partners(mean[:NUM_MESH_POINTS])
    perm = np.concatenate([perm468, [NUM_MESH_POINTS + 1, NUM_MESH_POINTS]])
    head = symmetric_head_frame(mean, perm)
    triangles = clean_triangulation_from_edges(edges, head[:NUM_MESH_POINTS])
    head = level_to_contour_plane(head, triangles)
    return {
        "vertices_mm": head[:NUM_MESH_POINTS].astype(np.float64),
        "triangles": triangles.astype(np.int64),
        "mirror": perm468,
        "sources": np.array(names),
    }


def derive() -> dict[str, NDArray[np.generic]]:
    """Run all steps; returns the arrays stored in ``mediapipe468.npz`` (see :func:`derive_from_landmarks`)."""
    return derive_from_landmarks(*derivation_inputs())


#: The model file the package loads (:func:`facemesh.face_models.builtin_face_model`).
PACKAGED_MODEL = Path(__file__).with_name(_DATA_FILE)


def main(argv: list[str] | None = None) -> None:
    """Command-line entry: write the model file."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("-o", "--output", type=Path, help="write the model here (an .npz file)")
    where.add_argument(
        "--write-packaged",
        action="store_true",
        help=f"replace the model file the package loads ({PACKAGED_MODEL.name}, beside this module)",
    )
    args = parser.parse_args(argv)
    from ..io import atomic_write

    output = PACKAGED_MODEL if args.write_packaged else args.output
    arrays = derive()
    with atomic_write(output) as fh:
        np.savez_compressed(fh, **arrays)
    print(f"wrote {output}: {len(arrays['vertices_mm'])} points, {len(arrays['triangles'])} triangles")


if __name__ == "__main__":
    main()
