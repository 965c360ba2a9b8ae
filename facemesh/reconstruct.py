"""Surface reconstruction for landmark models that have no triangulation.

dlib's 68 points, ETH-XGaze's 50-point face model or a user's own detector
give 3D points but no triangles. :func:`reconstruct_surface` makes a surface
of them with one of :data:`SURFACE_METHODS`:

``bpa+fill`` (the default)
    :func:`ball_pivoting` (the paper's method), then :func:`fill_to_outline`
    closes every hole and notch inside the face outline (the points' convex
    hull seen from the front) by ear clipping, without new vertices: the eye
    and mouth openings and whatever the balls left open.
``bpa``
    Ball-Pivoting alone (Bernardini et al. 1999) from Open3D or PyMeshLab.
    Its result keeps the holes the balls leave.
``poisson``
    Screened Poisson (Kazhdan and Hoppe 2013, PyMeshLab), cut to the
    outline's front sheet. Its vertices are new: they are *appended* after the
    landmark vertices (recorded in :attr:`Reconstruction.appended_vertices_mm`),
    and the landmark vertices themselves are not used by its triangles.
``delaunay``
    The Delaunay triangulation of the points seen from the front: covers the
    outline by construction; the planar fallback for models too sparse for a
    surface (MPIIFaceGaze's 6 points).

Which one is the default was measured (``benchmarks/bench_reconstruct.py``,
docs/face_model.md): projected coverage against MediaPipe's own triangulation
and eye patches rendered from each surface against those from the dense mesh.

Every method maps its triangles back onto the *input* point indices (vertex i
of the result is always landmark i: nothing is reordered, merged or removed),
cleans the triangle list (:func:`clean_triangles`) and orients every triangle
counter-clockwise seen from the camera (:func:`orient_triangles_toward`).

All points are in the OpenCV camera frame, millimetres (see
:mod:`facemesh.conventions`); the viewpoint is the camera centre, (0, 0, 0)
by default. "Seen from the front" means projected along ``forward``, the
direction the face looks (the head frame's -z axis in the camera frame, which
:func:`facemesh.mesh.build_face_mesh` passes from the head pose), so a turned
head is triangulated as it would be frontal.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .conventions import frontal_coordinates
from .types import InputError

__all__ = [
    "SURFACE_METHODS",
    "MIN_SURFACE_POINTS",
    "BallPivotingSettings",
    "PoissonSettings",
    "Reconstruction",
    "reconstruct_surface",
    "fill_to_outline",
    "insert_points",
    "ball_pivoting",
    "clean_triangles",
    "orient_triangles_toward",
    "median_spacing",
]

_BACKENDS = ("open3d", "pymeshlab")

#: The methods of :func:`reconstruct_surface`; the first is the default (the measured best).
SURFACE_METHODS = ("bpa+fill", "bpa", "poisson", "delaunay")

#: Ball-Pivoting and Poisson need a point cloud: with fewer points than this
#: they are refused (``delaunay`` is the planar fallback, taken by ``auto``).
MIN_SURFACE_POINTS = 20

#: A triangle whose doubled area is below this fraction of its longest edge
#: squared (about the sine of its largest angle's supplement) counts as zero-area.
_DEGENERATE_REL_AREA = 1e-9

#: An output vertex of a backend matches an input point when it lies within
#: this fraction of the point cloud's extent (covers float32 round-off).
_MATCH_REL_TOL = 1e-6


@dataclass(frozen=True)
class BallPivotingSettings:
    """How :func:`ball_pivoting` triangulates a point cloud.

    The defaults were tuned on MediaPipe's 468-point canonical face and
    ETH-XGaze's 50-point face model, frontal and turned up to 40 degrees, with
    and without 0.3 mm noise (see ``tests/test_reconstruct.py``). Ball-Pivoting's
    result changes abruptly with the radii, so several scaled copies of the
    radius schedule are tried and the best result kept.

    Attributes:
        backend: ``"open3d"`` or ``"pymeshlab"``.
        radius_factors: ball radii, as multiples of the median
            nearest-neighbour distance of the points, used in increasing
            order (each pass fills what the smaller balls left open).
        radius_scales: the whole schedule ``radius_factors`` is run once per
            scale (times each scale); the result with the largest visible area
            (triangle area projected across the line of sight, negative for
            triangles facing away, so folds do not count) wins, ties going to
            more vertices used, then to the earlier scale. ``(1.0,)`` runs once.
        normal_neighbours: number of nearest neighbours used to estimate each
            point's normal (PCA of the neighbourhood).
        min_component_fraction: after cleaning, edge-connected components with
            fewer triangles than this fraction of the largest component's are
            dropped (0 keeps all, 1 keeps only the largest and any as large).
        pymeshlab_clustering: PyMeshLab only: its ``clustering`` parameter, in
            percent of the ball radius (a point closer than this to a vertex
            already used is skipped, never moved). Ignored by Open3D.
        pymeshlab_crease_deg: PyMeshLab only: its ``creasethr`` parameter, the
            largest angle in degrees between neighbouring triangles the ball
            rolls over. MeshLab's default of 90 folds the lips over one another
            on the canonical face; 60 does not. Ignored by Open3D.
    """

    backend: str = "open3d"
    radius_factors: tuple[float, ...] = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)
    radius_scales: tuple[float, ...] = (1.0, 0.8, 1.25)
    normal_neighbours: int = 12
    min_component_fraction: float = 0.2
    pymeshlab_clustering: float = 5.0
    pymeshlab_crease_deg: float = 60.0

    def __post_init__(self) -> None:
        if self.backend not in _BACKENDS:
            raise InputError(f"backend: expected one of {_BACKENDS}, got {self.backend!r}")
        factors = tuple(float(f) for f in self.radius_factors)
        if not factors or not all(np.isfinite(f) and f > 0 for f in factors):
            raise InputError(f"radius_factors: expected one or more positive numbers, got {self.radius_factors}")
        object.__setattr__(self, "radius_factors", tuple(sorted(factors)))
        scales = tuple(float(f) for f in self.radius_scales)
        if not scales or not all(np.isfinite(f) and f > 0 for f in scales):
            raise InputError(f"radius_scales: expected one or more positive numbers, got {self.radius_scales}")
        object.__setattr__(self, "radius_scales", scales)
        if int(self.normal_neighbours) < 3:
            raise InputError(f"normal_neighbours: expected >= 3, got {self.normal_neighbours}")
        if not 0.0 <= float(self.min_component_fraction) <= 1.0:
            raise InputError(f"min_component_fraction: expected a value in [0, 1], got {self.min_component_fraction}")
        if not 0.0 <= float(self.pymeshlab_clustering) <= 100.0:
            raise InputError(f"pymeshlab_clustering: expected percent in [0, 100], got {self.pymeshlab_clustering}")
        if not 0.0 < float(self.pymeshlab_crease_deg) <= 180.0:
            raise InputError(f"pymeshlab_crease_deg: expected degrees in (0, 180], got {self.pymeshlab_crease_deg}")


@dataclass(frozen=True)
class PoissonSettings:
    """How ``reconstruct_surface(..., "poisson")`` runs PyMeshLab's screened Poisson reconstruction.

    Attributes:
        depth: octree depth (PyMeshLab's ``depth``; 8 resolves about 1/256 of
            the points' extent, well under a millimetre on a face).
        normal_neighbours: nearest neighbours for each point's normal (PCA),
            oriented toward the viewpoint.
    """

    depth: int = 8
    normal_neighbours: int = 12

    def __post_init__(self) -> None:
        if not 4 <= int(self.depth) <= 12:
            raise InputError(f"poisson depth: expected 4..12, got {self.depth}")
        if int(self.normal_neighbours) < 3:
            raise InputError(f"normal_neighbours: expected >= 3, got {self.normal_neighbours}")


@dataclass(frozen=True)
class Reconstruction:
    """The result of :func:`reconstruct_surface` (or :func:`ball_pivoting`).

    Attributes:
        triangles: (M, 3) int64 indices into the input points followed by
            :attr:`appended_vertices_mm` (vertex index == landmark index for
            the first N), counter-clockwise seen from the viewpoint. Read-only.
        radii_mm: the ball radii used, millimetres, increasing (``()`` for
            ``poisson`` and ``delaunay``).
        backend: ``"open3d"`` or ``"pymeshlab"`` (Ball-Pivoting, Poisson),
            ``"scipy"`` (Delaunay).
        spacing_mm: median nearest-neighbour distance of the points, mm.
        method: one of :data:`SURFACE_METHODS`.
        surface_triangles: how many of the first rows of ``triangles`` the
            method itself made; the rows after them were added by the
            completion (``bpa+fill``: :func:`fill_to_outline`, then
            :func:`insert_points`, which replaces a split triangle by new rows).
        filled_loops: holes and notches the fill closed.
        open_loops: holes or notches the fill could not close (a polygon that
            folds over itself seen from the front); 0 on every face measured.
        appended_vertices_mm: (K, 3) float64, mm, camera frame: vertices after
            the N landmark vertices (``poisson``); (0, 3) otherwise. Read-only.
        inserted_points: landmarks the surface spanned over, made vertices by
            :func:`insert_points` (``bpa+fill``).
        num_points: N, the number of input points (landmark vertices).
    """

    triangles: NDArray[np.int64]
    radii_mm: tuple[float, ...]
    backend: str
    spacing_mm: float = field(default=float("nan"))
    method: str = "bpa"
    surface_triangles: int = -1
    filled_loops: int = 0
    open_loops: int = 0
    appended_vertices_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    inserted_points: int = 0
    num_points: int = 0

    def __post_init__(self) -> None:
        t = np.array(self.triangles, dtype=np.int64, copy=True).reshape(-1, 3)
        t.setflags(write=False)
        object.__setattr__(self, "triangles", t)
        object.__setattr__(self, "radii_mm", tuple(float(r) for r in self.radii_mm))
        if self.surface_triangles < 0:
            object.__setattr__(self, "surface_triangles", len(t))
        v = np.array(self.appended_vertices_mm, dtype=np.float64, copy=True).reshape(-1, 3)
        v.setflags(write=False)
        object.__setattr__(self, "appended_vertices_mm", v)

    @property
    def num_triangles(self) -> int:
        """Number of triangles M."""
        return len(self.triangles)

    @property
    def filled_triangles(self) -> int:
        """Triangles added by the fill (the last rows of :attr:`triangles`)."""
        return len(self.triangles) - self.surface_triangles

    def as_metadata(self) -> dict[str, Any]:
        """JSON-serialisable description, for :attr:`facemesh.types.FaceMesh.reconstruction`.

        Returns:
            ``{"method", "backend", "num_triangles"}``; Ball-Pivoting adds
            ``"radii_mm"``; ``bpa+fill`` adds ``"filled"``:
            ``{"triangles": F, "first_row": M - F, "loops": L, "left_open": O,
            "inserted_points": I}`` (the completion's triangles are the last F rows); ``poisson`` adds
            ``"appended_vertices": {"count": K, "first_index": N}``.
        """
        meta: dict[str, Any] = {"method": self.method, "backend": self.backend, "num_triangles": len(self.triangles)}
        if self.radii_mm:
            meta["radii_mm"] = [float(r) for r in self.radii_mm]
        if self.method == "bpa+fill":
            meta["filled"] = {
                "triangles": self.filled_triangles,
                "first_row": self.surface_triangles,
                "loops": self.filled_loops,
                "left_open": self.open_loops,
                "inserted_points": self.inserted_points,
            }
        if len(self.appended_vertices_mm):
            meta["appended_vertices"] = {"count": len(self.appended_vertices_mm), "first_index": int(self.num_points)}
        return meta


# --------------------------------------------------------------------------- helpers


def _validate_points(points: ArrayLike, name: str = "points_mm") -> NDArray[np.float64]:
    try:
        arr = np.array(points, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: expected an (N, 3) float array, got {type(points).__name__}") from exc
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name}: expected shape (N, 3), got {arr.shape}")
    if len(arr) < 4:
        raise InputError(f"{name}: expected at least 4 points, got {len(arr)}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: expected finite values, got NaN or infinite values")
    return arr


def _validate_point3(value: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: expected 3 finite numbers, got {np.asarray(value).tolist()}")
    return arr


def _validate_triangles(triangles: ArrayLike, num_vertices: int) -> NDArray[np.int64]:
    t = np.asarray(triangles)
    if t.size == 0:
        return np.zeros((0, 3), dtype=np.int64)
    if t.ndim != 2 or t.shape[1] != 3:
        raise InputError(f"triangles: expected shape (M, 3), got {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        if not np.all(np.isfinite(t)) or np.any(t != np.round(t)):
            raise InputError("triangles: expected integer vertex indices")
    t = t.astype(np.int64)
    if t.min() < 0 or t.max() >= num_vertices:
        raise InputError(f"triangles: indices must lie in [0, {num_vertices - 1}], got [{t.min()}, {t.max()}]")
    return t


def median_spacing(points_mm: ArrayLike) -> float:
    """Median distance from each point to its nearest *distinct* neighbour.

    Args:
        points_mm: (N, 3) float, N >= 4, any frame, millimetres.

    Returns:
        The median nearest-neighbour distance, mm (> 0).

    Raises:
        InputError: on malformed points or fewer than 2 distinct points.
    """
    from scipy.spatial import cKDTree

    p = _validate_points(points_mm)
    unique = np.unique(p, axis=0)
    if len(unique) < 2:
        raise InputError("points_mm: all points coincide")
    d, _ = cKDTree(unique).query(unique, k=2)
    return float(np.median(d[:, 1]))


def _triangle_areas(points: NDArray[np.float64], tri: NDArray[np.int64]) -> NDArray[np.float64]:
    if len(tri) == 0:
        return np.zeros(0)
    a, b, c = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def _undirected_edges(tri: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(3M, 2) sorted vertex pairs of every triangle edge, and the triangle of each."""
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]], axis=0)
    e.sort(axis=1)
    owner = np.tile(np.arange(len(tri), dtype=np.int64), 3)
    return e, owner


def _edge_ids(tri: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64], int]:
    """An integer id per undirected edge slot (3M,), the owning triangle (3M,), and the number of edges."""
    e, owner = _undirected_edges(tri)
    if len(e) == 0:
        return np.zeros(0, dtype=np.int64), owner, 0
    _, ids = np.unique(e, axis=0, return_inverse=True)
    ids = ids.reshape(-1)
    return ids, owner, int(ids.max()) + 1


def _triangle_components(tri: NDArray[np.int64]) -> NDArray[np.int64]:
    """Label of each triangle's edge-connected component (triangles sharing an edge are connected)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(tri)
    if m == 0:
        return np.zeros(0, dtype=np.int64)
    ids, owner, n_edges = _edge_ids(tri)
    # bipartite triangle <-> edge graph; triangles connected through an edge node
    rows = owner
    cols = m + ids
    g = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(m + n_edges, m + n_edges))
    _, labels = connected_components(g, directed=False)
    return labels[:m].astype(np.int64)


def _vertex_fans(tri: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Fan label of every corner (3M,) and the vertex of every corner (3M,).

    Two corners at the same vertex v belong to the same fan when their
    triangles share an edge that contains v. Assumes edges are manifold.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(tri)
    corner_vertex = tri.T.reshape(-1)  # corner c = k * m + t  <->  tri[t, k]
    nxt = np.roll(tri, -1, axis=1).T.reshape(-1)
    prv = np.roll(tri, 1, axis=1).T.reshape(-1)
    corners = np.arange(3 * m, dtype=np.int64)
    # each corner touches two edges (v, nxt) and (v, prv); key them by (v, other)
    keys = np.concatenate([np.stack([corner_vertex, nxt], 1), np.stack([corner_vertex, prv], 1)])
    who = np.concatenate([corners, corners])
    _, key_id = np.unique(keys, axis=0, return_inverse=True)
    key_id = key_id.reshape(-1)
    n_keys = int(key_id.max()) + 1 if len(key_id) else 0
    g = coo_matrix((np.ones(len(who)), (who, 3 * m + key_id)), shape=(3 * m + n_keys, 3 * m + n_keys))
    _, labels = connected_components(g, directed=False)
    return labels[: 3 * m].astype(np.int64), corner_vertex


# --------------------------------------------------------------------------- cleaning


def _drop_non_manifold_edges(tri: NDArray[np.int64], priority: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Keep-mask: accept triangles in increasing ``priority``; refuse one that would be an edge's third."""
    m = len(tri)
    keep = np.ones(m, dtype=bool)
    if m == 0:
        return keep
    ids, owner, n_edges = _edge_ids(tri)
    count = np.bincount(ids, minlength=n_edges)
    if count.max() <= 2:
        return keep
    # only triangles touching an over-used edge can be refused; visit them in priority order
    involved = np.unique(owner[count[ids] > 2])
    edge_of = ids.reshape(3, m).T  # (M, 3) edge ids of each triangle
    used = count.copy()
    for t in involved:
        used[edge_of[t]] -= 1  # start with every involved triangle out ...
    for t in involved[np.lexsort((involved, priority[involved]))]:
        e = edge_of[t]
        if np.all(used[e] < 2):  # ... and put back those that fit
            used[e] += 1
        else:
            keep[t] = False
    return keep


def _drop_non_manifold_vertices(tri: NDArray[np.int64], areas: NDArray[np.float64] | None) -> NDArray[np.bool_]:
    """Keep-mask: at a vertex with several fans keep the fan with most triangles (then most area)."""
    m = len(tri)
    keep = np.ones(m, dtype=bool)
    if m == 0:
        return keep
    fan, vert = _vertex_fans(tri)
    owner = np.tile(np.arange(m, dtype=np.int64), 3)
    pairs = np.unique(np.stack([vert, fan], 1), axis=0)
    verts, n_fans = np.unique(pairs[:, 0], return_counts=True)
    bad = set(verts[n_fans > 1].tolist())
    if not bad:
        return keep
    w = np.ones(m) if areas is None else areas
    for v in sorted(bad):
        sel = np.flatnonzero(vert == v)
        labels = fan[sel]
        best, best_key = None, None
        for lab in np.unique(labels):
            tris = owner[sel[labels == lab]]
            key = (len(tris), float(w[tris].sum()), -int(lab))
            if best_key is None or key > best_key:
                best, best_key = lab, key
        keep[owner[sel[labels != best]]] = False
    return keep


def clean_triangles(
    triangles: ArrayLike,
    num_vertices: int,
    *,
    min_component_fraction: float = 0.2,
    points: ArrayLike | None = None,
) -> NDArray[np.int64]:
    """Make a triangle list a clean, manifold surface, touching only the index array.

    Vertices are never removed or renumbered; triangles are only dropped (their
    winding is kept; use :func:`orient_triangles_toward` afterwards). In order:

    1. Degenerate triangles: a repeated vertex index, or (when ``points`` is
       given) zero area (doubled area below 1e-9 times the longest edge squared).
    2. Duplicates: triangles on the same vertex set, in either winding; the
       first one is kept.
    3. Non-manifold edges (used by more than two triangles): triangles are
       accepted greedily in increasing order of area when ``points`` is given
       (ties, and without points: in increasing index order, i.e. earlier
       triangles first); a triangle that would become the third on any of its
       edges is dropped. Large triangles spanning across the surface, which
       Ball-Pivoting's bigger radii create, are thus the ones dropped. Only
       triangles touching an over-used edge can be dropped.
    4. Non-manifold vertices (whose triangles form more than one fan connected
       through edges at that vertex): the fan with most triangles (then most
       area) is kept, the triangles of the other fans dropped. Steps 3-4 repeat
       until nothing changes.
    5. Small components: edge-connected components with fewer triangles than
       ``min_component_fraction`` times the largest component's are dropped.

    Args:
        triangles: (M, 3) integer vertex indices.
        num_vertices: N, the number of vertices the indices refer to.
        min_component_fraction: in [0, 1]; 0 keeps every component.
        points: optional (N, 3) float vertex positions, enabling the area tests.

    Returns:
        (M', 3) int64, a subset of the input rows in their original order and winding.

    Raises:
        InputError: on malformed triangles, indices out of range, bad points.
    """
    n = int(num_vertices)
    tri = _validate_triangles(triangles, n)
    if not 0.0 <= float(min_component_fraction) <= 1.0:
        raise InputError(f"min_component_fraction: expected a value in [0, 1], got {min_component_fraction}")
    pts: NDArray[np.float64] | None = None
    if points is not None:
        pts = np.asarray(points, dtype=np.float64)
        if pts.shape != (n, 3) or not np.all(np.isfinite(pts)):
            raise InputError(f"points: expected finite shape ({n}, 3), got {pts.shape}")
    if len(tri) == 0:
        return tri

    # 1. degenerate
    ok = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 2] != tri[:, 0])
    if pts is not None:
        a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
        cross = np.linalg.norm(np.cross(b - a, c - a), axis=1)
        longest = np.max(np.stack([np.sum((b - a) ** 2, 1), np.sum((c - b) ** 2, 1), np.sum((a - c) ** 2, 1)]), 0)
        ok &= cross > _DEGENERATE_REL_AREA * longest
    tri = tri[ok]

    # 2. duplicates (same vertex set), first kept
    if len(tri):
        _, first = np.unique(np.sort(tri, axis=1), axis=0, return_index=True)
        tri = tri[np.sort(first)]

    # 3-4. non-manifold edges and vertices
    for _ in range(100):
        if len(tri) == 0:
            break
        areas = _triangle_areas(pts, tri) if pts is not None else None
        priority = areas if areas is not None else np.zeros(len(tri))
        keep = _drop_non_manifold_edges(tri, priority)
        tri = tri[keep]
        areas = areas[keep] if areas is not None else None
        keep = _drop_non_manifold_vertices(tri, areas)
        tri = tri[keep]
        if keep.all():
            break

    # 5. small components
    if len(tri) and min_component_fraction > 0:
        labels = _triangle_components(tri)
        sizes = np.bincount(labels)
        tri = tri[sizes[labels] >= float(min_component_fraction) * sizes.max()]
    return np.ascontiguousarray(tri, dtype=np.int64)


def orient_triangles_toward(
    points: ArrayLike,
    triangles: ArrayLike,
    viewpoint: ArrayLike | None = None,
    *,
    direction: ArrayLike | None = None,
) -> NDArray[np.int64]:
    """Orient triangles consistently, counter-clockwise seen from ``viewpoint`` (or from far along ``direction``).

    The one place windings are decided: Ball-Pivoting output (toward the
    camera centre), the face model's triangulation (right-hand normals out of
    the face: ``direction`` -z of the head frame) and the background rings of
    :func:`gazeaug.render.render_mesh` (toward the source camera) all call it.

    Within each edge-connected component the winding is propagated across
    shared edges, walking the component from its first triangle: a neighbour
    that traverses the shared edge in the same direction as the triangle it
    is reached from is flipped, so that every interior edge ends up used once
    in each direction. Then the whole component is flipped if more of its
    triangles have their normal ``(b - a) x (c - a)`` pointing away from
    ``viewpoint`` (seen from their centroid) than toward it; a tie goes by the
    sum of ``normal . (viewpoint - centroid)``. With ``direction`` instead of a
    viewpoint (a viewpoint infinitely far along it) the same votes use
    ``normal . direction``. A non-orientable component (impossible for
    Ball-Pivoting output on a face) keeps the walk's result.

    Args:
        points: (N, 3) float vertex positions.
        triangles: (M, 3) integer vertex indices; edges should be manifold.
        viewpoint: (3,) float, same frame as ``points`` (the camera centre).
        direction: (3,) float, same frame: where right-hand normals should
            point (give this or ``viewpoint``, not both).

    Returns:
        (M, 3) int64, the same triangles in the same order, some with two
        indices swapped.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
        raise InputError(f"points: expected a finite (N, 3) array, got {pts.shape}")
    tri = _validate_triangles(triangles, len(pts)).copy()
    if viewpoint is not None and direction is None:
        view = _validate_point3(viewpoint, "viewpoint")
    elif direction is not None and viewpoint is None:
        view = _validate_point3(direction, "direction")
    else:
        raise InputError("orient_triangles_toward: give a viewpoint or a direction, not both or neither")
    m = len(tri)
    if m == 0:
        return tri

    # adjacency through undirected edges
    ids, owner, n_edges = _edge_ids(tri)
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order]
    starts = np.searchsorted(sorted_ids, np.arange(n_edges))
    ends = np.searchsorted(sorted_ids, np.arange(n_edges), side="right")
    edge_of = ids.reshape(3, m).T

    def directed(t: int, k: int) -> tuple[int, int]:
        # edge slot k of triangle t runs tri[t, k] -> tri[t, k + 1], the order _undirected_edges uses
        return int(tri[t, k]), int(tri[t, (k + 1) % 3])

    visited = np.zeros(m, dtype=bool)
    labels = np.full(m, -1, dtype=np.int64)
    n_comp = 0
    for seed in range(m):
        if visited[seed]:
            continue
        visited[seed] = True
        labels[seed] = n_comp
        stack = [seed]
        while stack:
            t = stack.pop()
            for k in range(3):
                e = edge_of[t, k]
                a, b = directed(t, k)
                for slot in order[starts[e] : ends[e]]:
                    u = int(owner[slot])
                    if u == t or visited[u]:
                        continue
                    ku = int(slot // m)
                    ua, ub = directed(u, ku)
                    if (ua, ub) == (a, b):  # same direction: flip u (swap two indices)
                        tri[u, [1, 2]] = tri[u, [2, 1]]
                        # (a, b, c) -> (a, c, b): edges [ab, bc, ca] -> [ac, cb, ba] = old [2, 1, 0]
                        edge_of[u] = edge_of[u][[2, 1, 0]]
                    visited[u] = True
                    labels[u] = n_comp
                    stack.append(u)
        n_comp += 1

    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    normal = np.cross(b - a, c - a)
    facing = normal @ view if direction is not None else np.sum(normal * (view - (a + b + c) / 3.0), axis=1)
    for comp in range(n_comp):
        sel = labels == comp
        votes = np.sign(facing[sel]).sum()
        if votes < 0 or (votes == 0 and facing[sel].sum() < 0):
            rows = np.flatnonzero(sel)[:, None]
            tri[rows, [1, 2]] = tri[rows, [2, 1]]
    return tri


# --------------------------------------------------------------------------- backends


def _import_pymeshlab(purpose: str) -> Any:
    try:
        import pymeshlab
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(f"{purpose} needs PyMeshLab: pip install pymeshlab. Import failed with: {exc}") from exc
    return pymeshlab


def _bpa_open3d(
    points: NDArray[np.float64],
    viewpoint: NDArray[np.float64],
    schedules: list[tuple[float, ...]],
    settings: BallPivotingSettings,
) -> list[tuple[NDArray[np.float64], NDArray[np.int64]]]:
    from .render import import_open3d

    o3d = import_open3d()
    k = min(int(settings.normal_neighbours), len(points))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=k))
    pcd.orient_normals_towards_camera_location(viewpoint)
    # Flipping every normal toward the camera on its own gets the far side of
    # a turned head wrong (its true normals face away from the camera), and
    # Open3D's BPA then refuses to triangulate it. So propagate one
    # orientation over the surface, then flip all normals together if most
    # of them face away from the camera.
    # (Open3D builds a Delaunay graph with Qhull for this, which fails on
    # coplanar or collinear points: those keep the per-point orientation.)
    try:
        pcd.orient_normals_consistent_tangent_plane(k)
    except RuntimeError:
        pcd.orient_normals_towards_camera_location(viewpoint)
    n = np.asarray(pcd.normals)
    if np.count_nonzero(np.sum(n * (viewpoint - points), axis=1) > 0) * 2 < len(n):
        pcd.normals = o3d.utility.Vector3dVector(-n)
    out = []
    for radii in schedules:
        mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(
            pcd, o3d.utility.DoubleVector(list(radii))
        )
        out.append((np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.triangles, dtype=np.int64)))
    return out


def _bpa_pymeshlab(
    points: NDArray[np.float64],
    viewpoint: NDArray[np.float64],
    schedules: list[tuple[float, ...]],
    settings: BallPivotingSettings,
) -> list[tuple[NDArray[np.float64], NDArray[np.int64]]]:
    pymeshlab = _import_pymeshlab("Ball-Pivoting with backend='pymeshlab'")
    k = min(int(settings.normal_neighbours), len(points))
    # PyMeshLab 2023+ calls an absolute parameter value PureValue; older ones AbsoluteValue
    absolute = getattr(pymeshlab, "PureValue", None) or pymeshlab.AbsoluteValue
    out = []
    for radii in schedules:
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points))
        ms.compute_normal_for_point_clouds(k=k, smoothiter=0, flipflag=True, viewpos=viewpoint)
        # One radius per call, increasing: with deletefaces=False each pass
        # starts from the faces of the previous one (MeshLab's documented way
        # of running the filter with growing radii).
        for r in radii:
            ms.generate_surface_reconstruction_ball_pivoting(
                ballradius=absolute(float(r)),
                clustering=float(settings.pymeshlab_clustering),
                creasethr=float(settings.pymeshlab_crease_deg),
                deletefaces=False,
            )
        m = ms.current_mesh()
        out.append((np.asarray(m.vertex_matrix(), dtype=np.float64), np.asarray(m.face_matrix(), dtype=np.int64)))
    return out


def _visible_area(points: NDArray[np.float64], tri: NDArray[np.int64], viewpoint: NDArray[np.float64]) -> float:
    """Sum over triangles of their area projected across the line of sight (negative when facing away), mm^2.

    Folds cancel (front + back + front counts once), so the more of the
    surface a triangulation covers without folding, the larger this is.
    """
    if len(tri) == 0:
        return 0.0
    a, b, c = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]
    area_vec = 0.5 * np.cross(b - a, c - a)
    sight = viewpoint - (a + b + c) / 3.0
    sight /= np.maximum(np.linalg.norm(sight, axis=1, keepdims=True), 1e-300)
    return float(np.sum(area_vec * sight))


def _map_to_input(
    points: NDArray[np.float64], out_vertices: NDArray[np.float64], out_triangles: NDArray[np.int64]
) -> NDArray[np.int64]:
    """Re-index a backend's triangles onto the input points by exact coordinate match."""
    from scipy.spatial import cKDTree

    if len(out_triangles) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    extent = float(np.max(np.abs(points))) if len(points) else 1.0
    tol = _MATCH_REL_TOL * max(extent, 1e-12)
    used = np.unique(out_triangles)
    if used.min() < 0 or used.max() >= len(out_vertices):
        raise RuntimeError("ball pivoting backend returned triangle indices outside its vertex list")
    d, idx = cKDTree(points).query(out_vertices[used], k=1)
    if np.any(d > tol):
        worst = int(np.argmax(d))
        raise RuntimeError(
            f"ball pivoting backend returned a vertex {out_vertices[used][worst].tolist()} that matches no "
            f"input point (nearest {d[worst]:.3g} mm away, tolerance {tol:.3g} mm)"
        )
    lut = np.full(len(out_vertices), -1, dtype=np.int64)
    lut[used] = idx
    return lut[out_triangles]


def ball_pivoting(
    points_mm: ArrayLike,
    viewpoint_mm: ArrayLike = (0.0, 0.0, 0.0),
    settings: BallPivotingSettings = BallPivotingSettings(),
) -> Reconstruction:
    """Triangulate landmark points with the Ball-Pivoting Algorithm.

    Steps:

    1. Normals: PCA over each point's ``settings.normal_neighbours`` nearest
       neighbours, oriented toward ``viewpoint_mm``. Open3D: ``estimate_normals``
       + ``orient_normals_towards_camera_location``, then
       ``orient_normals_consistent_tangent_plane`` and one global flip so that
       most normals face the camera (so the far cheek of a turned head keeps its
       outward normals). PyMeshLab: ``compute_normal_for_point_clouds`` with
       ``flipflag``/``viewpos`` (its ball pivoting filter did not depend on
       them in PyMeshLab 2025.7).
    2. Radii: ``settings.radius_factors`` times the median nearest-neighbour
       distance, times each of ``settings.radius_scales`` (one run per scale).
    3. The backend's triangles are mapped back onto the input indices by exact
       coordinate match (a KD-tree query with a tolerance of 1e-6 of the largest
       coordinate); a vertex that matches no input point is an error. (Both
       backends returned the input points unchanged, in order, in the
       installed versions; the check guards against other versions.)
    4. :func:`clean_triangles` (with the points, so area-based rules apply),
       then :func:`orient_triangles_toward` the viewpoint.
    5. Of the runs, the one with the largest visible area is returned (see
       :class:`BallPivotingSettings`).

    Args:
        points_mm: (N, 3) float, N >= 4, millimetres, OpenCV camera frame.
        viewpoint_mm: (3,) float, camera frame mm: where the surface is seen
            from (the camera centre).
        settings: backend, radii and cleaning parameters.

    Returns:
        A :class:`Reconstruction` whose triangles index ``points_mm`` directly.

    Raises:
        InputError: malformed points (not (N, 3), N < 4, NaN/inf, all coincident).
        ImportError: the backend library is missing (with an install hint).
        RuntimeError: the backend returned a vertex that is not an input point.
    """
    pts = _validate_points(points_mm)
    view = _validate_point3(viewpoint_mm, "viewpoint_mm")
    spacing = median_spacing(pts)
    schedules = [
        tuple(float(f) * float(sc) * spacing for f in settings.radius_factors) for sc in settings.radius_scales
    ]
    run = _bpa_open3d if settings.backend == "open3d" else _bpa_pymeshlab
    best: tuple[float, int, int] | None = None
    chosen: tuple[NDArray[np.int64], tuple[float, ...]] | None = None
    for attempt, ((out_v, out_t), radii) in enumerate(zip(run(pts, view, schedules, settings), schedules)):
        tri = _map_to_input(pts, out_v, out_t)
        tri = clean_triangles(tri, len(pts), min_component_fraction=settings.min_component_fraction, points=pts)
        tri = orient_triangles_toward(pts, tri, view)
        key = (_visible_area(pts, tri, view), len(np.unique(tri)), -attempt)
        if best is None or key > best:
            best, chosen = key, (tri, radii)
    assert chosen is not None
    return Reconstruction(
        triangles=chosen[0], radii_mm=chosen[1], backend=settings.backend, spacing_mm=spacing, num_points=len(pts)
    )


# --------------------------------------------------------------------------- completion, other methods


def _unit_forward(
    forward: ArrayLike | None,
    points: NDArray[np.float64] | None = None,
    viewpoint: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """``forward`` checked (InputError) and made unit; when ``None``, from the points' centroid toward the viewpoint."""
    if forward is None:
        assert points is not None and viewpoint is not None
        f = viewpoint - points.mean(axis=0)
        problem = "the points' centroid is the viewpoint"
    else:
        f = _validate_point3(forward, "forward")
        problem = "got (0, 0, 0)"
    norm = float(np.linalg.norm(f))
    if not norm > 0:
        raise InputError(f"forward: expected a non-zero direction ({problem})")
    return f / norm


def _frontal(points: NDArray[np.float64], forward: ArrayLike) -> NDArray[np.float64]:
    """:func:`~facemesh.conventions.frontal_coordinates`, ``forward`` checked as the other inputs are (InputError)."""
    return frontal_coordinates(points, _unit_forward(forward))


def _region_loops(q: NDArray[np.float64], boundary: list[tuple[int, int]], hull: list[int]) -> list[list[int]]:
    """Loops around the uncovered region inside the outline, counter-clockwise in ``q``.

    The region's edges are the surface's boundary edges reversed (the surface
    lies on their right) and the outline's edges (counter-clockwise); an edge
    present in both directions bounds nothing and cancels. At a vertex with
    several ways on, the walk takes the sharpest left turn, so loops that
    touch at a vertex come out as separate simple loops.
    """
    from collections import Counter

    edges: Counter[tuple[int, int]] = Counter((b, a) for a, b in boundary)
    edges.update((hull[i], hull[(i + 1) % len(hull)]) for i in range(len(hull)))
    for (u, v), n in list(edges.items()):
        back = edges.get((v, u), 0)
        if n and back:
            k = min(n, back)
            edges[(u, v)] -= k
            edges[(v, u)] -= k
    out: dict[int, list[int]] = {}
    for (u, v), n in sorted(edges.items()):
        out.setdefault(u, []).extend([v] * n)
    loops: list[list[int]] = []
    budget = sum(len(ws) for ws in out.values())
    while True:
        starts = sorted(u for u, ws in out.items() if ws)
        if not starts:
            return loops
        u0 = starts[0]
        prev, cur = u0, out[u0].pop(0)
        loop = [u0]
        while cur != u0 and budget > 0:
            budget -= 1
            loop.append(cur)
            ways = out.get(cur) or []
            if not ways:
                break  # not closed: cannot happen for a region bounded by loops
            back = np.arctan2(*(q[prev] - q[cur])[::-1])
            turn = [((back - np.arctan2(*(q[w] - q[cur])[::-1])) % (2 * np.pi) or 2 * np.pi, w) for w in ways]
            nxt = min(turn)[1]
            ways.remove(nxt)
            prev, cur = cur, nxt
        loops.append(loop)


def _doubled_areas(q: NDArray[np.float64], tri: NDArray[np.int64]) -> NDArray[np.float64]:
    """(M,) twice the signed area of each triangle in 2D, positive when counter-clockwise."""
    a, b, c = q[tri[:, 0]], q[tri[:, 1]], q[tri[:, 2]]
    return np.asarray((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])


def _signed_area(xy: NDArray[np.float64]) -> float:
    return 0.5 * float(np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]))


def _inside(polygon_xy: NDArray[np.float64], points_xy: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Even-odd rule: which points lie inside the polygon (points on its edges: either)."""
    x, y = points_xy[:, 0:1], points_xy[:, 1:2]
    x0, y0 = polygon_xy[:, 0], polygon_xy[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        at = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return np.asarray(np.sum(crosses & (x < at), axis=1) % 2 == 1)


def _planar_subset(q: NDArray[np.float64], tri: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Keep-mask of triangles whose interiors do not overlap seen from the front, smaller triangles first.

    Overlap is tested by separating axes (the six edge normals of the two
    triangles); triangles that only share an edge or a corner do not overlap.
    A triangle facing backward (clockwise) is never kept.
    """
    m = len(tri)
    keep = np.zeros(m, dtype=bool)
    if m == 0:
        return keep
    xy = q[tri]  # (M, 3 corners, 2)
    e = np.roll(xy, -1, axis=1) - xy
    area2 = _doubled_areas(q, tri)
    normals = np.stack([e[..., 1], -e[..., 0]], axis=-1)  # (M, 3 axes, 2)
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-300)
    lo, hi = xy.min(axis=1), xy.max(axis=1)
    eps = 1e-9 * max(float(np.ptp(q, axis=0).max()), 1e-12)
    accepted: list[int] = []
    for t in np.argsort(area2, kind="stable"):
        if area2[t] <= 0:
            continue
        acc = np.asarray(accepted, dtype=np.int64)
        near = acc[np.all(lo[acc] < hi[t] - eps, axis=1) & np.all(hi[acc] > lo[t] + eps, axis=1)]
        if len(near):
            # project both triangles on t's three axes and on each near triangle's three axes
            on_t = [np.einsum("kd,njd->nkj", normals[t], xy[near]), np.einsum("kd,jd->kj", normals[t], xy[t])[None]]
            on_o = [np.einsum("nkd,njd->nkj", normals[near], xy[near]), np.einsum("nkd,jd->nkj", normals[near], xy[t])]
            separated = np.zeros(len(near), dtype=bool)
            for other, this in (on_t, on_o):
                gap = (other.max(axis=2) <= this.min(axis=2) + eps) | (other.min(axis=2) >= this.max(axis=2) - eps)
                separated |= gap.any(axis=1)
            if not separated.all():
                continue
        accepted.append(int(t))
        keep[t] = True
    return keep


def _constrained_fill(
    outer: list[int], islands: list[list[int]], interior: list[int], q: NDArray[np.float64]
) -> list[tuple[int, int, int]] | None:
    """Delaunay of a loop's vertices, its islands' and the unused points inside it, kept inside the region.

    The result is accepted only when it is the region exactly: every loop
    edge is a triangle edge and the triangles' area is the region's (a
    constrained triangulation that happened to need no flip); else ``None``.
    """
    from scipy.spatial import Delaunay, QhullError

    verts = np.array(sorted(set(outer).union(*islands, interior)), dtype=np.int64)
    try:
        simplices = verts[np.asarray(Delaunay(q[verts]).simplices, dtype=np.int64)]
    except QhullError:
        return None
    centroid = q[simplices].mean(axis=1)
    keep = _inside(q[outer], centroid)
    for isl in islands:
        keep &= ~_inside(q[isl], centroid)
    tri = simplices[keep]
    area2 = _doubled_areas(q, tri)
    tri[area2 < 0] = tri[area2 < 0][:, [0, 2, 1]]  # counter-clockwise, as the region's outer loop
    region = _signed_area(q[outer]) - sum(abs(_signed_area(q[isl])) for isl in islands)
    if abs(0.5 * float(np.abs(area2).sum()) - region) > 1e-9 * max(region, 1.0):
        return None
    have = {(min(u, v), max(u, v)) for t in tri.tolist() for u, v in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    for lp in [outer, *islands]:
        if any((min(u, v), max(u, v)) not in have for u, v in zip(lp, lp[1:] + lp[:1])):
            return None
    return [(int(x), int(y), int(z)) for x, y, z in tri]


def _outline(q: NDArray[np.float64]) -> list[int]:
    """The convex hull of 2D points, counter-clockwise, through every point on its edges (not only its corners)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        corners = [int(i) for i in ConvexHull(q).vertices]  # counter-clockwise in 2D
    except QhullError as exc:
        raise InputError("points: all on one line seen from the front; no outline to fill") from exc
    tol = 1e-9 * max(float(np.ptp(q, axis=0).max()), 1e-12)
    hull: list[int] = []
    for a, b in zip(corners, corners[1:] + corners[:1]):
        d = q[b] - q[a]
        length2 = float(d @ d)
        t = (q - q[a]) @ d / length2
        off = np.abs((q - q[a]) @ np.array([-d[1], d[0]])) / np.sqrt(length2)
        on = np.flatnonzero((off <= tol) & (t > 0) & (t < 1))
        hull += [a] + [int(i) for i in on[np.argsort(t[on], kind="stable")]]
    return hull


def fill_to_outline(
    points_mm: ArrayLike, triangles: ArrayLike, forward: ArrayLike
) -> tuple[NDArray[np.int64], NDArray[np.int64], int, int]:
    """Triangles that close every hole and notch of a surface inside its outline, with no new vertex.

    The outline is the convex hull of all the points seen from the front
    (:func:`facemesh.conventions.frontal_coordinates`). The uncovered region inside it is bounded
    by the surface's boundary edges and the hull's edges (:func:`_region_loops`).
    Each counter-clockwise loop is one piece of the region:

    * with no unused point and no island of surface inside it, it is
      triangulated by :func:`facemesh.face_models.triangulation.ear_clip`
      (best-shaped ear first, the one ear clipper of the project);
    * otherwise by the Delaunay triangulation of its vertices, its islands'
      and the unused points inside it, kept inside the region, when that is
      exactly the region (every loop edge present);
    * else the islands' triangles are removed and the whole piece, the
      islands' points included, is triangulated the same way; else by ear
      clipping (the inner points stay unused).

    A clockwise loop that no piece contains is a pocket of overlap left by a
    fold: it is closed in its own sense, so the surface has no hole there.
    The new triangles run every boundary edge the other way, so the result is
    consistently oriented.

    Args:
        points_mm: (N, 3) float, mm, camera frame.
        triangles: (M, 3) int, a consistently oriented edge-manifold surface,
            counter-clockwise seen from the front, with no triangle facing
            backward seen from the front.
        forward: (3,) float: where the face looks.

    Returns:
        ``(surface, added, filled, left_open)``: the input triangles (M', 3)
        int64 in their order, less those of islands that were re-triangulated;
        (F, 3) int64 triangles to append; the number of loops closed; the
        number left open.
    """
    from .face_models.triangulation import boundary_edges, ear_clip

    pts = np.asarray(points_mm, dtype=np.float64)
    tri = _validate_triangles(triangles, len(pts))
    q = _frontal(pts, forward)
    loops = [lp for lp in _region_loops(q, boundary_edges(tri), _outline(q)) if len(lp) >= 3]
    pieces = [lp for lp in loops if _signed_area(q[lp]) > 0]
    inner = [lp for lp in loops if _signed_area(q[lp]) <= 0]
    on_loops = {v for lp in loops for v in lp}
    unused = np.array(sorted(set(range(len(pts))) - set(tri.ravel().tolist()) - on_loops), dtype=np.int64)
    added: list[tuple[int, int, int]] = []
    filled = left_open = 0
    claimed: set[int] = set()
    for piece in pieces:
        poly = q[piece]
        islands = []
        for k, isl in enumerate(inner):
            probe = [v for v in isl if v not in piece]
            if k not in claimed and probe and _inside(poly, q[probe[:1]])[0]:
                islands.append(isl)
                claimed.add(k)
        interior = unused[_inside(poly, q[unused])] if len(unused) else unused
        for isl in islands:
            interior = interior[~_inside(q[isl], q[interior])] if len(interior) else interior
        patch = None
        if islands or len(interior):
            patch = _constrained_fill(piece, islands, interior.tolist(), q)
        if patch is None and islands:
            # drop the islands' triangles and triangulate the piece with their points inside it
            isl_verts = {v for isl in islands for v in isl}
            labels = _triangle_components(tri)
            gone = np.isin(labels, np.unique(labels[np.isin(tri, list(isl_verts)).any(axis=1)]))
            inside_piece = _inside(poly, q[np.unique(tri[gone])]) | np.isin(np.unique(tri[gone]), piece)
            if inside_piece.all():
                points_in = set(np.unique(tri[gone]).tolist()) - set(piece)
                tri = tri[~gone]
                islands = []
                interior = np.array(sorted(set(interior.tolist()) | points_in), dtype=np.int64)
                patch = _constrained_fill(piece, [], interior.tolist(), q)
        if patch is None and not islands:
            try:
                patch = ear_clip(piece, q)
            except InputError:
                patch = None
        if patch is None:
            left_open += 1
            continue
        added.extend(patch)
        filled += 1
    for k, isl in enumerate(inner):
        if k in claimed:
            continue
        try:
            added.extend(ear_clip(isl, q))  # a fold's pocket: closed in its own (clockwise) sense
            filled += 1
        except InputError:
            left_open += 1
    return tri, np.array(added, dtype=np.int64).reshape(-1, 3), filled, left_open


#: A point whose smallest barycentric coordinate in a triangle (seen from the
#: front) is below this lies on the triangle's edge: the edge is split.
_ON_EDGE_BARY = 1e-3


def insert_points(
    points_mm: ArrayLike, triangles: ArrayLike, forward: ArrayLike, indices: ArrayLike
) -> tuple[NDArray[np.int64], int]:
    """Make unused points vertices of the triangle (or edge) they lie on, seen from the front.

    Ball-Pivoting can span a triangle over a landmark (the eye corners, on the
    faces measured): the surface then misses that point's depth. Each point of
    ``indices`` that lies inside a triangle seen from the front
    (:func:`facemesh.conventions.frontal_coordinates`) splits it into three; one on an edge (its
    smallest barycentric coordinate below 1e-3) splits the edge's triangles in
    two each. Windings are kept, so nothing folds.

    Args:
        points_mm: (N, 3) float, mm.
        triangles: (M, 3) int, counter-clockwise seen from the front.
        forward: (3,) float: where the face looks.
        indices: (K,) int, the points to insert (in this order).

    Returns:
        ``(triangles, inserted)``: (M + 2 x inserted, 3) int64, the rows not
        split in their order then the new ones; how many points were inserted
        (points outside every triangle are skipped).
    """
    pts = np.asarray(points_mm, dtype=np.float64)
    tri = [tuple(int(v) for v in t) for t in _validate_triangles(triangles, len(pts)).tolist()]
    q = _frontal(pts, forward)
    inserted = 0
    for p in np.asarray(indices, dtype=np.int64).reshape(-1).tolist():
        arr = np.array(tri, dtype=np.int64).reshape(-1, 3)
        if not len(arr):
            break
        a, b, c = q[arr[:, 0]], q[arr[:, 1]], q[arr[:, 2]]
        den = _doubled_areas(q, arr)
        with np.errstate(divide="ignore", invalid="ignore"):
            wb = ((q[p] - a)[:, 0] * (c - a)[:, 1] - (q[p] - a)[:, 1] * (c - a)[:, 0]) / den
            wc = ((b - a)[:, 0] * (q[p] - a)[:, 1] - (b - a)[:, 1] * (q[p] - a)[:, 0]) / den
        bary = np.stack([1.0 - wb - wc, wb, wc], axis=1)
        ok = np.isfinite(bary).all(axis=1) & (den > 0) & (bary.min(axis=1) >= -_ON_EDGE_BARY) & ~(arr == p).any(axis=1)
        if not ok.any():
            continue
        t = int(np.flatnonzero(ok)[np.argmax(bary[ok].min(axis=1))])
        x, y, z = tri[t]
        k = int(np.argmin(bary[t]))
        if bary[t, k] >= _ON_EDGE_BARY:
            tri[t : t + 1] = []
            tri += [(x, y, p), (y, z, p), (z, x, p)]
        else:
            # on the edge opposite corner k: split it in this triangle and in its neighbour
            u, v = (x, y, z)[(k + 1) % 3], (x, y, z)[(k + 2) % 3]
            w = (x, y, z)[k]
            tri[t : t + 1] = []
            tri += [(u, p, w), (p, v, w)]
            for j, other in enumerate(tri[:-2]):
                if (v, u) in ((other[0], other[1]), (other[1], other[2]), (other[2], other[0])):
                    o = next(vv for vv in other if vv not in (u, v))
                    tri[j : j + 1] = []
                    tri += [(v, p, o), (p, u, o)]
                    break
        inserted += 1
    return np.array(tri, dtype=np.int64).reshape(-1, 3), inserted


def _delaunay(points: NDArray[np.float64], forward: NDArray[np.float64]) -> NDArray[np.int64]:
    from scipy.spatial import Delaunay, QhullError

    q = frontal_coordinates(points, forward)
    try:
        tri = np.asarray(Delaunay(q).simplices, dtype=np.int64)
    except QhullError as exc:
        raise InputError("points: all on one line seen from the front; no surface to triangulate") from exc
    cw = _doubled_areas(q, tri) < 0
    tri[cw] = tri[cw][:, [0, 2, 1]]  # counter-clockwise seen from the front
    return tri


def _poisson(
    points: NDArray[np.float64],
    viewpoint: NDArray[np.float64],
    forward: NDArray[np.float64],
    settings: PoissonSettings,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Screened Poisson, cut to its front sheet inside the outline: (K, 3) new vertices, (M, 3) triangles into them."""
    from scipy.spatial import Delaunay

    pymeshlab = _import_pymeshlab("Poisson reconstruction (method 'poisson')")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points))
    k = min(int(settings.normal_neighbours), len(points))
    ms.compute_normal_for_point_clouds(k=k, smoothiter=0, flipflag=True, viewpos=viewpoint)
    ms.generate_surface_reconstruction_screened_poisson(depth=int(settings.depth), preclean=True)
    m = ms.current_mesh()
    v = np.asarray(m.vertex_matrix(), dtype=np.float64)
    f = np.asarray(m.face_matrix(), dtype=np.int64)
    if len(f) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    # keep triangles inside the outline, facing the front, on the sheet nearest the viewer
    outline = Delaunay(frontal_coordinates(points, forward))
    inside = outline.find_simplex(frontal_coordinates(v, forward)) >= 0
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    facing = np.cross(b - a, c - a) @ forward
    f = f[inside[f].all(axis=1) & (facing > 0)]
    f = clean_triangles(f, len(v), min_component_fraction=1.0, points=v)  # the largest sheet
    used = np.unique(f)
    lut = np.full(len(v), -1, dtype=np.int64)
    lut[used] = np.arange(len(used))
    return v[used], lut[f]


def reconstruct_surface(
    points_mm: ArrayLike,
    method: str = SURFACE_METHODS[0],
    *,
    viewpoint_mm: ArrayLike = (0.0, 0.0, 0.0),
    forward: ArrayLike | None = None,
    ball_pivoting_settings: BallPivotingSettings = BallPivotingSettings(),
    poisson_settings: PoissonSettings = PoissonSettings(),
) -> Reconstruction:
    """A surface through landmark points that have no triangulation (see the module docstring for the methods).

    Args:
        points_mm: (N, 3) float, N >= 4 (>= :data:`MIN_SURFACE_POINTS` for
            ``bpa``, ``bpa+fill`` and ``poisson``), mm, OpenCV camera frame.
        method: one of :data:`SURFACE_METHODS`.
        viewpoint_mm: (3,) float, camera frame mm: where the surface is seen
            from (the camera centre); triangles come counter-clockwise seen from it.
        forward: (3,) float, camera frame: where the face looks (the head
            frame's -z axis), for the frontal view that ``bpa+fill`` and
            ``delaunay`` triangulate in. Default: from the points' centroid
            toward the viewpoint.
        ball_pivoting_settings: for ``bpa`` and ``bpa+fill``.
        poisson_settings: for ``poisson``.

    Returns:
        A :class:`Reconstruction`; its triangles index ``points_mm`` (then,
        for ``poisson``, its appended vertices).

    Raises:
        InputError: malformed points, an unknown method, or too few points for the method.
        ImportError: the backend library is missing (with an install hint).
    """
    if method not in SURFACE_METHODS:
        raise InputError(f"surface method: expected one of {SURFACE_METHODS}, got {method!r}")
    pts = _validate_points(points_mm)
    view = _validate_point3(viewpoint_mm, "viewpoint_mm")
    fwd = _unit_forward(forward, pts, view)
    if method != "delaunay" and len(pts) < MIN_SURFACE_POINTS:
        raise InputError(
            f"points: {len(pts)} are too few for {method} (it needs a point cloud of at least "
            f"{MIN_SURFACE_POINTS}); 'delaunay' triangulates them as seen from the front (a planar fallback)"
        )
    spacing = median_spacing(pts)
    q = frontal_coordinates(pts, fwd)
    extent = np.linalg.svd(q - q.mean(axis=0), compute_uv=False)  # (2,) spreads along the frontal axes
    if not extent[-1] > 1e-9 * extent[0]:
        raise InputError("points: all on one line seen from the front; no surface to make of them")
    if method in ("bpa", "bpa+fill"):
        rec = ball_pivoting(pts, view, ball_pivoting_settings)
        if method == "bpa":
            return rec
        surface = np.asarray(rec.triangles)
        # Seen from the front a face is a height field: triangles facing backward or overlapping
        # others are folds (Ball-Pivoting across the chin or the lips), which would cover part of
        # the face twice. Keep a subset that covers it once, smaller triangles first.
        surface = surface[_planar_subset(q, surface)]
        surface = clean_triangles(surface, len(pts), min_component_fraction=0.0)
        surface, added, filled, left_open = fill_to_outline(pts, surface, fwd)
        tri = np.concatenate([surface, added])
        unused = np.setdiff1d(np.arange(len(pts)), tri)
        tri, inserted = insert_points(pts, tri, fwd, unused)
        # earlier rows win where an edge would be over-used, so the surface's own triangles are kept
        tri = clean_triangles(tri, len(pts), min_component_fraction=0.0)
        kept_surface = int(np.sum(np.isin(_row_keys(tri, len(pts)), _row_keys(surface, len(pts)))))
        tri = orient_triangles_toward(pts, tri, view)
        return Reconstruction(
            triangles=tri,
            radii_mm=rec.radii_mm,
            backend=rec.backend,
            spacing_mm=spacing,
            method=method,
            surface_triangles=kept_surface,
            filled_loops=filled,
            open_loops=left_open,
            inserted_points=inserted,
            num_points=len(pts),
        )
    if method == "delaunay":
        tri = clean_triangles(_delaunay(pts, fwd), len(pts), min_component_fraction=0.0, points=pts)
        tri = orient_triangles_toward(pts, tri, view)
        return Reconstruction(tri, (), "scipy", spacing, method="delaunay", num_points=len(pts))
    new_v, new_t = _poisson(pts, view, fwd, poisson_settings)
    if len(new_t) == 0:
        raise InputError("poisson: the reconstruction left no surface in front of the points")
    all_v = np.concatenate([pts, new_v])
    tri = orient_triangles_toward(all_v, new_t + len(pts), view)
    return Reconstruction(
        tri, (), "pymeshlab", spacing, method="poisson", appended_vertices_mm=new_v, num_points=len(pts)
    )


def _row_keys(tri: NDArray[np.int64], n: int) -> NDArray[np.int64]:
    """One integer per triangle of indices below ``n``, the same for any order of its three indices."""
    s = np.sort(np.asarray(tri, dtype=np.int64).reshape(-1, 3), axis=1)
    return (s[:, 0] * n + s[:, 1]) * n + s[:, 2]
