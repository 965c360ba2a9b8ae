"""Tests of :mod:`facemesh.reconstruct` (Ball-Pivoting for landmark sets without triangles).

Expected values come from the geometry of hand-made meshes or from
independent re-implementations of each property in this file (edge counts,
fans, components, projected coverage), never from the module's own output.

Real face points come from the shared data folder (``../shared/data`` or
``$GAZEAUG_SHARED_DATA``): MediaPipe's canonical face, or without that folder the
built-in face model's 468 points (the same landmarks, within 7 mm RMS of it); ETH-XGaze's
50 points, whose tests are skipped without it (and fail under CI, see conftest.py).
"""

from __future__ import annotations

import os
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest
from conftest import _missing_shared, shared_data_dir
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull

from facemesh.reconstruct import (
    BallPivotingSettings,
    Reconstruction,
    ball_pivoting,
    clean_triangles,
    fill_to_outline,
    insert_points,
    orient_triangles_toward,
    reconstruct_surface,
)
from facemesh.types import InputError

ORIGIN = np.zeros(3)
FACE_DEPTH_MM = 500.0
FOCAL_PX = 1000.0


# --------------------------------------------------------------------------- data


def _data_dir() -> Path:
    path = shared_data_dir()
    if path is None:
        _missing_shared("reconstruct")
    assert path is not None
    return path


def _require(path: Path) -> Path:
    if not path.is_file():
        pytest.skip(f"shared data file not found: {path} (set GAZEAUG_SHARED_DATA to the 'data' folder)")
    return path


def _canonical_points_camera_mm() -> NDArray[np.float64]:
    """MediaPipe's canonical face (cm, y up, z toward the viewer) as a face 500 mm in front of the camera.

    Without ../shared, the built-in face model's points (mm, already y down and z into the head).
    """
    if shared_data_dir() is None and not os.environ.get("CI"):
        from facemesh import builtin_face_model

        return builtin_face_model().vertices_mm + np.array([0.0, 0.0, FACE_DEPTH_MM])
    path = _require(_data_dir() / "reference" / "mediapipe_face_geometry" / "canonical_face_model.obj")
    verts = [[float(v) for v in line.split()[1:4]] for line in path.read_text().splitlines() if line.startswith("v ")]
    cm = np.array(verts)
    assert cm.shape == (468, 3)
    head_mm = cm * np.array([1.0, -1.0, -1.0]) * 10.0
    return head_mm + np.array([0.0, 0.0, FACE_DEPTH_MM])


def _eth_points_camera_mm() -> NDArray[np.float64]:
    """ETH-XGaze's 50-point face model (mm; x to the image right, y down, z into the head) at 500 mm."""
    path = _require(_data_dir() / "gaze" / "calibrations" / "eth_xgaze_face_model.txt")
    pts = np.loadtxt(path)
    assert pts.shape == (50, 3)
    # sanity of the frame assumed: chin (row 0) below the eyebrows, nose tip (row 14) nearest the camera
    assert pts[0, 1] > pts[1:11, 1].max()
    assert np.argmin(pts[:, 2]) == 14
    return pts + np.array([0.0, 0.0, FACE_DEPTH_MM])


# --------------------------------------------------------------------------- independent mesh checks


def _edge_counts(tri: NDArray[np.int64]) -> Counter[tuple[int, int]]:
    c: Counter[tuple[int, int]] = Counter()
    for a, b, d in tri.tolist():
        for u, v in ((a, b), (b, d), (d, a)):
            c[(min(u, v), max(u, v))] += 1
    return c


def _directed_edge_counts(tri: NDArray[np.int64]) -> Counter[tuple[int, int]]:
    c: Counter[tuple[int, int]] = Counter()
    for a, b, d in tri.tolist():
        for e in ((a, b), (b, d), (d, a)):
            c[e] += 1
    return c


def _num_components(tri: NDArray[np.int64]) -> int:
    """Edge-connected components of triangles."""
    by_edge: dict[tuple[int, int], list[int]] = defaultdict(list)
    for t, (a, b, d) in enumerate(tri.tolist()):
        for u, v in ((a, b), (b, d), (d, a)):
            by_edge[(min(u, v), max(u, v))].append(t)
    rows, cols = [], []
    for ts in by_edge.values():
        for t in ts[1:]:
            rows.append(ts[0])
            cols.append(t)
    m = len(tri)
    g = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(m, m))
    return int(connected_components(g, directed=False)[0])


def _non_manifold_vertices(tri: NDArray[np.int64]) -> list[int]:
    """Vertices whose incident triangles do not form one fan connected through edges at the vertex."""
    incident: dict[int, list[int]] = defaultdict(list)
    for t, row in enumerate(tri.tolist()):
        for v in row:
            incident[v].append(t)
    bad = []
    for v, ts in incident.items():
        others = {t: set(tri[t].tolist()) - {v} for t in ts}
        seen = {ts[0]}
        stack = [ts[0]]
        while stack:
            t = stack.pop()
            for u in ts:
                if u not in seen and others[t] & others[u]:
                    seen.add(u)
                    stack.append(u)
        if len(seen) != len(ts):
            bad.append(v)
    return bad


def _facing_fraction(points: NDArray[np.float64], tri: NDArray[np.int64], viewpoint: NDArray[np.float64]) -> float:
    a, b, c = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]
    normal = np.cross(b - a, c - a)
    return float(np.mean(np.sum(normal * (viewpoint - (a + b + c) / 3.0), axis=1) > 0))


def _projected_coverage(points: NDArray[np.float64], tri: NDArray[np.int64]) -> float:
    """Total area of the projected triangles over the area of the projected points' convex hull (f = 1000 px)."""
    uv = FOCAL_PX * points[:, :2] / points[:, 2:3]
    a, b, c = uv[tri[:, 0]], uv[tri[:, 1]], uv[tri[:, 2]]
    ab, ac = b - a, c - a
    area = 0.5 * np.abs(ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0]).sum()
    return float(area / ConvexHull(uv).volume)  # in 2D, ConvexHull.volume is the area


def _boundary_cycles(tri: NDArray[np.int64]) -> int:
    """Connected pieces of the boundary-edge graph (edges used by one triangle): 1 = only the outer contour."""
    edges = [e for e, n in _edge_counts(tri).items() if n == 1]
    if not edges:
        return 0
    verts = sorted({v for e in edges for v in e})
    pos = {v: i for i, v in enumerate(verts)}
    rows = [pos[a] for a, _ in edges]
    cols = [pos[b] for _, b in edges]
    g = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(verts), len(verts)))
    return int(connected_components(g, directed=False)[0])


def _check_surface(
    points: NDArray[np.float64],
    rec: Reconstruction,
    *,
    min_used: float,
    min_coverage: float,
    max_coverage: float,
) -> dict[str, float]:
    tri = np.asarray(rec.triangles)
    assert tri.dtype == np.int64 and tri.ndim == 2 and tri.shape[1] == 3 and len(tri) > 0
    assert tri.min() >= 0 and tri.max() < len(points)
    # indices really are input indices: a BPA triangle fits in a ball of the largest radius,
    # so no edge is longer than its diameter (scrambled indices would give face-wide edges);
    # the completion's triangles (the rows after rec.surface_triangles) may bridge wider gaps
    surface = tri[: rec.surface_triangles]
    edge_len = np.linalg.norm(points[surface] - points[np.roll(surface, 1, axis=1)], axis=2)
    assert edge_len.max() <= 2.0 * max(rec.radii_mm) + 1e-9
    assert len({tuple(sorted(t)) for t in tri.tolist()}) == len(tri), "duplicate triangles"
    assert np.all((tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2]))
    assert _num_components(tri) == 1
    counts = _edge_counts(tri)
    assert set(counts.values()) <= {1, 2}, "edge used by more than two triangles"
    assert _non_manifold_vertices(tri) == []
    directed = _directed_edge_counts(tri)
    assert max(directed.values()) == 1, "two triangles traverse an edge the same way: inconsistent winding"
    interior = [e for e, n in counts.items() if n == 2]
    assert all(directed[e] == 1 and directed[e[::-1]] == 1 for e in interior)
    facing = _facing_fraction(points, tri, ORIGIN)
    assert facing > 0.95
    used = len(np.unique(tri)) / len(points)
    assert used >= min_used
    coverage = _projected_coverage(points, tri)
    assert min_coverage <= coverage <= max_coverage
    return {"facing": facing, "used": used, "coverage": coverage, "boundary_cycles": _boundary_cycles(tri)}


def _backend_or_skip(name: str) -> None:
    pytest.importorskip(name, reason=f"{name} is not installed (or fails to import)")


# --------------------------------------------------------------------------- ball pivoting on real faces


@pytest.fixture(scope="module")
def canonical() -> NDArray[np.float64]:
    return _canonical_points_camera_mm()


@pytest.fixture(scope="module")
def eth() -> NDArray[np.float64]:
    return _eth_points_camera_mm()


@pytest.mark.parametrize("backend", ["open3d", "pymeshlab"])
def test_canonical_face_completed_has_no_hole_and_covers_the_face(backend: str, canonical: NDArray[np.float64]) -> None:
    """The default method (Ball-Pivoting, then its holes closed): one oriented manifold, every point used,
    one boundary cycle (the face contour: no hole inside it), and the projected coverage of the convex
    hull at least 0.99 (MediaPipe's own triangulation: 1.001, a few back-facing triangles at the sides)."""
    _backend_or_skip(backend)
    rec = reconstruct_surface(canonical, ball_pivoting_settings=BallPivotingSettings(backend=backend))
    assert rec.method == "bpa+fill" and rec.backend == backend and rec.open_loops == 0
    figures = _check_surface(canonical, rec, min_used=1.0, min_coverage=0.99, max_coverage=1.03)
    assert figures["boundary_cycles"] == 1
    meta = rec.as_metadata()
    assert meta["filled"]["first_row"] == rec.surface_triangles
    assert meta["filled"]["triangles"] == len(rec.triangles) - rec.surface_triangles > 0
    print(backend, "canonical bpa+fill", figures, meta["filled"])


@pytest.mark.parametrize("backend", ["open3d", "pymeshlab"])
def test_canonical_face_ball_pivoting_alone(
    backend: str, canonical: NDArray[np.float64], request: pytest.FixtureRequest
) -> None:
    """Ball-Pivoting alone (``bpa``) is a manifold too, but leaves holes: no coverage bound, reported."""
    _backend_or_skip(backend)
    if backend == "open3d" and shared_data_dir() is None:
        # A library defect this stand-in shows: Open3D's Ball-Pivoting on the built-in model's upper lip
        # makes a Moebius fold (triangles [73, 41, 38] and [41, 38, 82] both traverse 41 -> 38), which
        # orient_triangles_toward cannot orient. bpa+fill drops folds before it fills (test above).
        request.applymarker(
            pytest.mark.xfail(strict=True, reason="open3d BPA on the built-in model's points is non-orientable")
        )
    rec = ball_pivoting(canonical, (0.0, 0.0, 0.0), BallPivotingSettings(backend=backend))
    assert rec.backend == backend and rec.method == "bpa"
    figures = _check_surface(canonical, rec, min_used=0.90, min_coverage=0.0, max_coverage=1.03)
    print(backend, "canonical bpa", figures, "radii", [round(r, 2) for r in rec.radii_mm])


@pytest.mark.parametrize("backend", ["open3d", "pymeshlab"])
def test_eth_xgaze_sparse_face_completed_covers_its_outline(backend: str, eth: NDArray[np.float64]) -> None:
    """ETH-XGaze's 50 points have nothing between the eyes' outer corners and the chin: balls sized to the
    point spacing cannot bridge the cheeks (Ball-Pivoting alone covers about 0.63-0.68 of the hull); the
    completion covers the outline (the convex hull) whole, with no hole."""
    _backend_or_skip(backend)
    rec = reconstruct_surface(eth, ball_pivoting_settings=BallPivotingSettings(backend=backend))
    figures = _check_surface(eth, rec, min_used=1.0, min_coverage=0.99, max_coverage=1.03)
    assert figures["boundary_cycles"] == 1
    print(backend, "eth bpa+fill", figures)


@pytest.mark.parametrize("method", ["delaunay", "poisson"])
def test_other_methods_on_the_canonical_face(method: str, canonical: NDArray[np.float64]) -> None:
    """Delaunay seen from the front covers the hull exactly; Poisson appends its own vertices."""
    if method == "poisson":
        _backend_or_skip("pymeshlab")
    rec = reconstruct_surface(canonical, method, forward=(0.0, 0.0, -1.0))
    tri = np.asarray(rec.triangles)
    n = len(canonical)
    assert rec.method == method and rec.num_points == n
    if method == "delaunay":
        assert len(rec.appended_vertices_mm) == 0 and len(np.unique(tri)) == n
        # planar triangulation of n points with h on the hull (seen from the front: orthographic x, y)
        h = len(ConvexHull(canonical[:, :2]).vertices)
        assert len(tri) == 2 * n - 2 - h
        assert _projected_coverage(canonical, tri) == pytest.approx(1.0, abs=0.01)
        assert _boundary_cycles(tri) == 1
    else:
        k = len(rec.appended_vertices_mm)
        assert k > n and tri.min() >= n and tri.max() == n + k - 1  # only appended vertices, all used
        assert rec.as_metadata()["appended_vertices"] == {"count": k, "first_index": n}
        pts = np.concatenate([canonical, rec.appended_vertices_mm])
        assert _facing_fraction(pts, tri, ORIGIN) > 0.95
        assert set(_edge_counts(tri).values()) <= {1, 2}


def test_too_few_points_for_a_surface_and_the_planar_fallback() -> None:
    """MPIIFaceGaze's 6 points (eye corners, mouth corners): Ball-Pivoting and Poisson refuse them with one
    clear message; Delaunay triangulates them seen from the front: 2n - 2 - h triangles over the hull."""
    six = np.array([[-45.0, -3, 0], [-15, 0, 3], [15, 0, 3], [45, -3, 0], [-25, 60, -2], [25, 60, -2]]) + np.array(
        [0.0, 0.0, 500.0]
    )
    for method in ("bpa", "bpa+fill", "poisson"):
        with pytest.raises(InputError, match=r"6 are too few for .*'delaunay'"):
            reconstruct_surface(six, method)
    rec = reconstruct_surface(six, "delaunay", forward=(0.0, 0.0, -1.0))
    h = len(ConvexHull(six[:, :2]).vertices)
    assert len(rec.triangles) == 2 * 6 - 2 - h
    assert _projected_coverage(six, np.asarray(rec.triangles)) == pytest.approx(1.0, abs=1e-9)
    assert _facing_fraction(six, np.asarray(rec.triangles), ORIGIN) == 1.0
    with pytest.raises(InputError, match="surface method"):
        reconstruct_surface(six, "magic")


# --------------------------------------------------------------------------- the completion, by hand


def _grid(k: int = 4) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """k x k points 10 mm apart at z = 500 (a face looking at the camera), 2 (k-1)^2 triangles."""
    pts = np.array([[10.0 * x, 10.0 * y, 500.0] for y in range(k) for x in range(k)])
    tri = []
    for y in range(k - 1):
        for x in range(k - 1):
            i = k * y + x
            tri += [[i, i + 1, i + k + 1], [i, i + k + 1, i + k]]
    return pts, orient_triangles_toward(pts, np.array(tri), (0.0, 0.0, 0.0))


FACING_CAMERA = (0.0, 0.0, -1.0)


def test_fill_closes_a_hole_and_a_notch_with_no_new_vertex() -> None:
    pts, tri = _grid(4)  # 9 squares, 18 triangles, area 900 mm^2
    centre = [t for t, row in enumerate(tri.tolist()) if set(row) <= {5, 6, 9, 10}]
    corner = [t for t, row in enumerate(tri.tolist()) if 0 in row]
    assert len(centre) == 2 and len(corner) == 2
    holed = np.delete(tri, centre + corner[:1], axis=0)  # a 4-edge hole and a notch at the corner
    surface, added, filled, left_open = fill_to_outline(pts, holed, FACING_CAMERA)
    assert len(surface) == 15 and (filled, left_open) == (2, 0)
    assert len(added) == 3  # 2 for the square hole, 1 for the notch
    full = np.concatenate([surface, added])
    assert _projected_coverage(pts, full) == pytest.approx(1.0)
    assert _boundary_cycles(full) == 1 and max(_directed_edge_counts(full).values()) == 1
    assert _facing_fraction(pts, full, ORIGIN) == 1.0


def test_fill_takes_unused_points_inside_a_hole() -> None:
    """The centre square of a 5 x 5 grid's middle 3 x 3 block removed (8 triangles around point 12):
    point 12 is unused inside the hole; the fill uses it (8 triangles), not a 6-triangle ear clipping."""
    pts, tri = _grid(5)
    block = {6, 7, 8, 11, 12, 13, 16, 17, 18}
    keep = np.array([not set(row) <= block for row in tri.tolist()])
    assert (~keep).sum() == 8
    surface, added, filled, left_open = fill_to_outline(pts, tri[keep], FACING_CAMERA)
    assert (filled, left_open) == (1, 0) and len(added) == 8 and 12 in added
    full = np.concatenate([surface, added])
    assert _projected_coverage(pts, full) == pytest.approx(1.0) and _boundary_cycles(full) == 1


def test_insert_points_splits_the_triangle_or_the_edge_a_point_lies_on() -> None:
    pts = np.array([[0.0, 0, 500], [30, 0, 500], [0, 30, 500], [30, 30, 500], [8, 8, 495], [15, 15, 495]])
    tri = orient_triangles_toward(pts, np.array([[0, 1, 2], [1, 3, 2]]), (0.0, 0.0, 0.0))
    # point 4 inside triangle (0, 1, 2): three triangles instead of one
    out, n = insert_points(pts, tri, FACING_CAMERA, [4])
    assert n == 1 and len(out) == 4 and sum(4 in t for t in out.tolist()) == 3
    # point 5 on the shared edge 1-2: both triangles split in two
    out, n = insert_points(pts, tri, FACING_CAMERA, [5])
    assert n == 1 and len(out) == 4 and sum(5 in t for t in out.tolist()) == 4
    assert max(_directed_edge_counts(out).values()) == 1 and _facing_fraction(pts, out, ORIGIN) == 1.0
    # a point outside every triangle is skipped
    far = np.vstack([pts, [[100.0, 100.0, 500.0]]])
    out, n = insert_points(far, tri, FACING_CAMERA, [6])
    assert n == 0 and out.tolist() == tri.tolist()


def test_fill_joins_an_island_inside_a_hole() -> None:
    """A 6 x 6 grid whose middle 3 x 3 squares are gone except the centre square: an island in a ring hole."""
    pts, tri = _grid(6)
    ring = {7, 8, 9, 10, 13, 16, 19, 22, 25, 26, 27, 28, 14, 15, 20, 21}
    inner = {14, 15, 20, 21}
    gone = np.array([set(row) <= ring and not set(row) <= inner for row in tri.tolist()])
    assert gone.sum() == 16
    surface, added, filled, left_open = fill_to_outline(pts, tri[~gone], FACING_CAMERA)
    assert left_open == 0
    full = np.concatenate([surface, added])
    assert _projected_coverage(pts, full) == pytest.approx(1.0)
    assert _boundary_cycles(full) == 1 and _num_components(full) == 1
    assert set(_edge_counts(full).values()) <= {1, 2} and max(_directed_edge_counts(full).values()) == 1


def test_radii_follow_point_spacing_and_metadata(canonical: NDArray[np.float64]) -> None:
    _backend_or_skip("open3d")
    settings = BallPivotingSettings(radius_factors=(1.0, 2.0), radius_scales=(1.0,))
    rec = ball_pivoting(canonical, settings=settings)
    # median nearest-neighbour distance, by brute force
    d = np.linalg.norm(canonical[:, None, :] - canonical[None, :, :], axis=2)
    np.fill_diagonal(d, np.inf)
    spacing = float(np.median(d.min(axis=1)))
    assert rec.radii_mm == pytest.approx((spacing, 2.0 * spacing))
    # twice as large a face: twice the radii, same triangles (BPA is scale-free)
    rec2 = ball_pivoting(canonical * 2.0, settings=settings)
    assert rec2.radii_mm == pytest.approx((2.0 * spacing, 4.0 * spacing))
    meta = rec.as_metadata()
    assert meta == {
        "method": "bpa",
        "backend": "open3d",
        "radii_mm": list(rec.radii_mm),
        "num_triangles": len(rec.triangles),
    }
    assert not rec.triangles.flags.writeable


def test_viewpoint_behind_the_points_flips_the_winding() -> None:
    """A bumpy 6 x 6 sheet at z = 500: seen from the origin the triangles wind one way,
    seen from z = 1000 (behind the sheet) the other way."""
    _backend_or_skip("open3d")
    xs, ys = np.meshgrid(np.arange(6) * 10.0, np.arange(6) * 10.0)
    zs = 500.0 + 2.0 * np.sin(xs / 13.0) * np.cos(ys / 17.0)
    pts = np.stack([xs.ravel(), ys.ravel(), zs.ravel()], axis=1)
    front = ball_pivoting(pts, (0.0, 0.0, 0.0))
    back = ball_pivoting(pts, (0.0, 0.0, 1000.0))
    assert _facing_fraction(pts, front.triangles, np.zeros(3)) == 1.0
    assert _facing_fraction(pts, back.triangles, np.array([0.0, 0.0, 1000.0])) == 1.0
    # a regular 6 x 6 grid: 25 squares, 50 triangles when fully covered
    assert len(front.triangles) == 50


# --------------------------------------------------------------------------- clean_triangles


# a unit square 0-1-2-3 (counter-clockwise seen from -z) plus spare points
_SQUARE = np.array(
    [
        [0.0, 0.0, 0.0],  # 0
        [1.0, 0.0, 0.0],  # 1
        [1.0, 1.0, 0.0],  # 2
        [0.0, 1.0, 0.0],  # 3
        [0.5, 0.0, 0.0],  # 4: on edge 0-1 (collinear with 0 and 1)
        [0.5, -0.5, 3.0],  # 5: off the plane, far: a big fin on edge 0-1
        [0.5, -0.5, 0.0],  # 6: below edge 0-1, in the plane
    ]
)


def test_clean_removes_repeated_index_and_zero_area_triangles() -> None:
    tri = np.array([[0, 1, 2], [0, 0, 1], [0, 2, 3], [0, 4, 1]])
    # without points only the repeated index is detectable
    assert clean_triangles(tri, 7, min_component_fraction=0.0).tolist() == [[0, 1, 2], [0, 2, 3], [0, 4, 1]]
    # with points, 0-4-1 is collinear: zero area
    out = clean_triangles(tri, 7, min_component_fraction=0.0, points=_SQUARE)
    assert out.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert out.dtype == np.int64


def test_clean_removes_duplicates_in_either_winding() -> None:
    tri = np.array([[0, 1, 2], [2, 1, 0], [1, 2, 0], [0, 2, 3]])
    out = clean_triangles(tri, 4, min_component_fraction=0.0)
    assert out.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_clean_resolves_a_fin_to_two_triangles_per_edge() -> None:
    # edge 0-1 shared by the square's triangle, a flat triangle below and a big fin out of the plane
    tri = np.array([[0, 1, 2], [0, 2, 3], [1, 0, 6], [0, 1, 5]])
    assert _edge_counts(tri)[(0, 1)] == 3
    out = clean_triangles(tri, 7, min_component_fraction=0.0, points=_SQUARE)
    assert max(_edge_counts(out).values()) <= 2
    # the rule: smaller triangles win, so the fin (area ~1.52 vs 0.25 and 0.5) goes
    assert sorted(map(sorted, out.tolist())) == [[0, 1, 2], [0, 1, 6], [0, 2, 3]]
    # without points: earlier triangles win, so the last one on the edge goes
    tri2 = np.array([[0, 1, 5], [0, 1, 2], [0, 2, 3], [1, 0, 6]])
    out2 = clean_triangles(tri2, 7, min_component_fraction=0.0)
    assert max(_edge_counts(out2).values()) <= 2
    assert out2.tolist() == [[0, 1, 5], [0, 1, 2], [0, 2, 3]]


def test_clean_splits_a_bowtie_vertex_keeping_the_bigger_fan() -> None:
    # vertex 0 joins fan {0-1-2, 0-2-3} and a lone triangle 0-7-8 sharing no edge with them
    pts = np.vstack([_SQUARE, [[-1.0, 0.0, 0.0], [-1.0, -1.0, 0.0]]])
    tri = np.array([[0, 7, 8], [0, 1, 2], [0, 2, 3]])
    assert _non_manifold_vertices(tri) == [0]
    out = clean_triangles(tri, 9, min_component_fraction=0.0, points=pts)
    assert out.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert _non_manifold_vertices(out) == []


def test_clean_drops_tiny_components() -> None:
    # a 3 x 3 grid of 8 triangles, plus one separate triangle far away
    grid_pts = np.array([[x, y, 0.0] for y in range(3) for x in range(3)])
    pts = np.vstack([grid_pts, [[10.0, 10.0, 0.0], [11.0, 10.0, 0.0], [10.0, 11.0, 0.0]]])
    grid = []
    for y in range(2):
        for x in range(2):
            i = 3 * y + x
            grid += [[i, i + 1, i + 4], [i, i + 4, i + 3]]
    tri = np.array(grid + [[9, 10, 11]])
    out = clean_triangles(tri, 12, min_component_fraction=0.2, points=pts)  # 1 < 0.2 * 8
    assert out.tolist() == grid
    assert clean_triangles(tri, 12, min_component_fraction=0.1, points=pts).tolist() == tri.tolist()  # 1 >= 0.8
    assert clean_triangles(tri, 12, min_component_fraction=0.0).tolist() == tri.tolist()


def test_clean_never_touches_vertices_and_rejects_bad_indices() -> None:
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    assert clean_triangles(tri, 100, min_component_fraction=0.5).tolist() == tri.tolist()
    assert clean_triangles(np.zeros((0, 3), dtype=np.int64), 4).shape == (0, 3)
    with pytest.raises(InputError):
        clean_triangles(np.array([[0, 1, 4]]), 4)
    with pytest.raises(InputError):
        clean_triangles(np.array([[0, 1]]), 4)


# --------------------------------------------------------------------------- orient_triangles_toward


def _quad_grid() -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """2 x 2 squares (3 x 3 vertices) in the plane z = 500, 8 triangles."""
    pts = np.array([[10.0 * x, 10.0 * y, 500.0] for y in range(3) for x in range(3)])
    tri = []
    for y in range(2):
        for x in range(2):
            i = 3 * y + x
            tri += [[i, i + 1, i + 4], [i, i + 4, i + 3]]
    return pts, np.array(tri, dtype=np.int64)


@pytest.mark.parametrize("seed", range(5))
def test_orient_makes_a_randomly_flipped_grid_ccw_from_the_viewpoint(seed: int) -> None:
    pts, tri = _quad_grid()
    rng = np.random.default_rng(seed)
    flipped = tri.copy()
    flip = rng.random(len(tri)) < 0.5
    flip[rng.integers(len(tri))] = True  # at least one flipped
    flipped[flip] = flipped[flip][:, ::-1]
    for view, sign in (((0.0, 0.0, 0.0), -1.0), ((10.0, 10.0, 1000.0), 1.0)):
        out = orient_triangles_toward(pts, flipped, view)
        assert [sorted(t) for t in out.tolist()] == [sorted(t) for t in tri.tolist()]  # same triangles, same order
        # CCW seen from the viewpoint: (b - a) x (c - a) points toward it, i.e. along -z from
        # the origin (in front) and +z from z = 1000 (behind); the plane is z = 500
        a, b, c = pts[out[:, 0]], pts[out[:, 1]], pts[out[:, 2]]
        nz = np.cross(b - a, c - a)[:, 2]
        assert np.all(np.sign(nz) == sign)
        assert max(_directed_edge_counts(out).values()) == 1


def test_orient_flips_each_component_on_its_own() -> None:
    pts, tri = _quad_grid()
    far = pts + np.array([100.0, 0.0, 0.0])
    all_pts = np.vstack([pts, far])
    both = np.vstack([tri, tri[:, ::-1] + len(pts)])  # second copy wound the other way
    out = orient_triangles_toward(all_pts, both, (0.0, 0.0, 0.0))
    a, b, c = all_pts[out[:, 0]], all_pts[out[:, 1]], all_pts[out[:, 2]]
    assert np.all(np.cross(b - a, c - a)[:, 2] < 0)


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "points, expected",
    [
        (np.zeros((10, 2)), r"expected shape \(N, 3\), got \(10, 2\)"),
        (np.zeros((10,)), r"expected shape \(N, 3\), got \(10,\)"),
        (np.array([[0.0, 0.0, 500.0], [1.0, 0.0, 500.0], [0.0, 1.0, 500.0]]), r"at least 4 points, got 3"),
        (np.array([[0.0, 0.0, 500.0], [1.0, np.nan, 500.0], [0.0, 1.0, 500.0], [1.0, 1.0, 500.0]]), r"finite"),
        (np.array([[0.0, 0.0, 500.0], [1.0, np.inf, 500.0], [0.0, 1.0, 500.0], [1.0, 1.0, 500.0]]), r"finite"),
        (np.full((5, 3), 7.0), r"coincide"),
    ],
)
def test_bad_points_raise_input_error(points: NDArray[np.float64], expected: str) -> None:
    with pytest.raises(InputError, match=expected):
        ball_pivoting(points)


def test_bad_settings_raise_input_error() -> None:
    with pytest.raises(InputError, match="backend"):
        BallPivotingSettings(backend="poisson")
    with pytest.raises(InputError, match="radius_factors"):
        BallPivotingSettings(radius_factors=(1.0, -2.0))
    with pytest.raises(InputError, match="min_component_fraction"):
        BallPivotingSettings(min_component_fraction=1.5)


def test_unmatched_backend_vertex_is_an_error() -> None:
    from facemesh.reconstruct import _map_to_input

    pts = np.array([[0.0, 0.0, 500.0], [10.0, 0.0, 500.0], [0.0, 10.0, 500.0], [10.0, 10.0, 500.0]])
    # a backend that reorders vertices is fine ...
    order = np.array([2, 0, 3, 1])
    out = _map_to_input(pts, pts[order], np.array([[0, 1, 2]]))
    assert out.tolist() == [[2, 0, 3]]
    # ... one that moves a vertex is not
    moved = pts[order].copy()
    moved[1, 0] += 0.01
    with pytest.raises(RuntimeError, match="matches no input point"):
        _map_to_input(pts, moved, np.array([[0, 1, 2]]))


@pytest.mark.parametrize("method", ["bpa+fill", "bpa", "poisson", "delaunay"])
def test_points_on_one_line_seen_from_the_front_are_refused(method: str) -> None:
    """A 'face' whose points line up seen from the front (a vertical sheet seen edge-on) has no surface:
    every method says so in one InputError (poisson used to fail inside Qhull)."""
    xs, zs = np.meshgrid(np.arange(5) * 10.0, 500.0 + np.arange(5) * 10.0)
    edge_on = np.stack([xs.ravel(), np.zeros(xs.size), zs.ravel()], axis=1)  # the plane y = 0
    with pytest.raises(InputError, match="on one line seen from the front"):
        reconstruct_surface(edge_on, method, forward=(0.0, 0.0, -1.0))
