"""Turn MediaPipe's edge list into a clean, oriented, manifold triangulation.

The mediapipe wheel ships ``FACEMESH_TESSELATION`` as a set of edges only.
Its 3-cliques are the triangles, except for a few "spurious" cliques whose
three edges are all shared with two other cliques (a triangle spanned around a
vertex that already has its own fan). Removing those leaves an edge-manifold
surface with four holes: the outer face contour, both eye openings and the
mouth opening. We orient it consistently (right-hand normals out of the face,
:func:`facemesh.reconstruct.orient_triangles_toward`)
and close the eyes and the mouth by ear clipping, so the iris and sclera get
texture. Only the outer contour stays open.

Deterministic: apart from the ear clipper's choice of ear, every step is
integer logic over sorted containers; the ear clipper compares with explicit
tolerances and breaks ties by vertex index (:func:`ear_clip`), so rounding
noise in the vertices (another machine's BLAS or summation order) cannot
change a triangle.
"""

from __future__ import annotations

import itertools
from collections import Counter, defaultdict
from collections.abc import Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..reconstruct import orient_triangles_toward

__all__ = [
    "triangles_from_edges",
    "edge_use_counts",
    "boundary_edges",
    "boundary_loops",
    "ear_clip",
    "clean_triangulation_from_edges",
    "EAR_QUALITY_TIE_RAD",
    "COLLINEAR_REL_TOL",
]


def triangles_from_edges(edges: Iterable[tuple[int, int]]) -> list[tuple[int, int, int]]:
    """All 3-cliques of an undirected graph, each as a sorted vertex triple, sorted."""
    adj: dict[int, set[int]] = defaultdict(set)
    for a, b in edges:
        if a != b:
            adj[a].add(b)
            adj[b].add(a)
    tris: set[tuple[int, int, int]] = set()
    for a in adj:
        for b in adj[a]:
            if b <= a:
                continue
            for c in adj[a] & adj[b]:
                if c > b:
                    tris.add((a, b, c))
    return sorted(tris)


def edge_use_counts(triangles: ArrayLike) -> Counter[tuple[int, int]]:
    """How many triangles use each undirected edge (keys sorted pairs)."""
    cnt: Counter[tuple[int, int]] = Counter()
    for t in np.asarray(triangles, dtype=np.int64).reshape(-1, 3):
        for a, b in itertools.combinations(t.tolist(), 2):
            cnt[(min(a, b), max(a, b))] += 1
    return cnt


def boundary_edges(triangles: ArrayLike) -> list[tuple[int, int]]:
    """The edges used by one triangle only, directed as their triangle runs them, in triangle order."""
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    cnt = edge_use_counts(tri)
    return [
        (a, b)
        for t in tri.tolist()
        for a, b in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))
        if cnt[(min(a, b), max(a, b))] == 1
    ]


def boundary_loops(triangles: ArrayLike) -> list[list[int]]:
    """Closed loops of boundary edges (edges used by one triangle), ordered as the triangles run them.

    Each loop follows the directed boundary edges of the triangles, so for a
    consistently oriented mesh the loops run in one rotational sense.

    Raises:
        ValueError: the boundary is not a set of simple loops.
    """
    nxt: dict[int, int] = {}
    for a, b in boundary_edges(triangles):
        if a in nxt:
            raise ValueError(f"boundary vertex {a} is on more than one boundary edge leaving it")
        nxt[a] = b
    loops: list[list[int]] = []
    seen: set[int] = set()
    for start in sorted(nxt):
        if start in seen:
            continue
        loop = [start]
        seen.add(start)
        cur = nxt[start]
        while cur != start:
            if cur in seen or cur not in nxt:
                raise ValueError(f"boundary through vertex {cur} is not a simple loop")
            loop.append(cur)
            seen.add(cur)
            cur = nxt[cur]
        loops.append(loop)
    return loops


#: Ears whose quality (smallest angle, radians) lies within this of the best
#: ear's are tied; the tie is broken by vertex index (see :func:`ear_clip`).
#: Far above rounding noise (~1e-14 rad between machines) and far below the
#: gaps between genuinely different ears (>= 1e-2 rad on the shipped model).
EAR_QUALITY_TIE_RAD = 1e-9

#: Orientation tests treat a doubled signed triangle area within this fraction
#: of the polygon's squared size as zero (three points on a line).
COLLINEAR_REL_TOL = 1e-12


def ear_clip(loop: list[int], points_2d: ArrayLike) -> list[tuple[int, int, int]]:
    """Triangulate a simple polygon by ear clipping, always cutting the best-shaped ear.

    Deterministic by construction: the choice of ear is a combinatorial
    decision on floating-point values, so it follows exact rules that do not
    depend on rounding noise, nor on where ``loop`` starts:

    * An ear is a convex corner ``(prev, apex, next)`` whose triangle holds no
      other polygon vertex. Orientation tests use a tolerance of
      :data:`COLLINEAR_REL_TOL` times the squared size of the polygon: a corner
      whose three points are (nearly) on a line is not an ear, and a vertex
      on (or within that tolerance of) an ear's edge blocks the ear.
    * An ear's quality is its smallest angle (fat triangles first). All ears
      within :data:`EAR_QUALITY_TIE_RAD` of the best quality are tied, and
      among them **the ear whose apex has the largest vertex index** is cut.

    Exact ties are not rare: a left-right symmetric polygon (the mouth of a
    symmetric face) offers mirror-image ears of equal quality, whose computed
    qualities differ only by rounding (~1e-14 rad) and so, before this rule,
    by machine. (Largest rather than smallest index: that is the choice the
    shipped model was built with, so it did not change.)

    Args:
        loop: vertex indices of the polygon, in order (either sense).
        points_2d: (N, 2) float positions indexed by vertex index (any unit).

    Returns:
        len(loop) - 2 triangles with the same rotational sense as ``loop``;
        each ear as ``(prev, apex, next)`` in the order cut, the last triangle
        as the three remaining vertices in loop order.

    Raises:
        InputError: the polygon is not simple (no ear left to cut).
    """
    from ..types import InputError

    p = np.asarray(points_2d, dtype=np.float64)
    idx = list(loop)
    signed = 0.5 * sum(
        p[idx[i], 0] * p[idx[(i + 1) % len(idx)], 1] - p[idx[(i + 1) % len(idx)], 0] * p[idx[i], 1]
        for i in range(len(idx))
    )
    sense = 1.0 if signed > 0 else -1.0
    pts = p[idx]
    size = float(np.max(pts.max(axis=0) - pts.min(axis=0))) if len(idx) else 0.0
    area_tol = COLLINEAR_REL_TOL * size * size
    out: list[tuple[int, int, int]] = []

    def cross(o: int, a: int, b: int) -> float:
        """Doubled signed area of (o, a, b), positive when they turn as the loop does."""
        return sense * float((p[a, 0] - p[o, 0]) * (p[b, 1] - p[o, 1]) - (p[a, 1] - p[o, 1]) * (p[b, 0] - p[o, 0]))

    def smallest_angle(a: int, b: int, c: int) -> float:
        tri_pts = p[[a, b, c]]
        angles = []
        for k in range(3):
            u = tri_pts[(k + 1) % 3] - tri_pts[k]
            w = tri_pts[(k + 2) % 3] - tri_pts[k]
            cosang = u @ w / (np.linalg.norm(u) * np.linalg.norm(w) + 1e-300)
            angles.append(float(np.arccos(np.clip(cosang, -1, 1))))
        return min(angles)

    while len(idx) > 3:
        n = len(idx)
        ears: list[tuple[float, int, int]] = []  # (quality, apex vertex, position in idx)
        for i in range(n):
            a, b, c = idx[i - 1], idx[i], idx[(i + 1) % n]
            if cross(a, b, c) <= area_tol:
                continue  # reflex or flat corner
            if any(
                cross(a, b, q) >= -area_tol and cross(b, c, q) >= -area_tol and cross(c, a, q) >= -area_tol
                for q in idx
                if q not in (a, b, c)
            ):
                continue  # another vertex inside or on the ear
            ears.append((smallest_angle(a, b, c), b, i))
        if not ears:
            raise InputError("ear clipping failed: the polygon is not simple")
        best_q = max(q for q, _, _ in ears)
        _, _, best = max((e for e in ears if e[0] >= best_q - EAR_QUALITY_TIE_RAD), key=lambda e: e[1])
        out.append((idx[best - 1], idx[best], idx[(best + 1) % n]))
        del idx[best]
    out.append((idx[0], idx[1], idx[2]))
    return out


def clean_triangulation_from_edges(
    edges: Iterable[tuple[int, int]], vertices_head_mm: ArrayLike, *, close_holes_smaller_than: int = 30
) -> NDArray[np.int64]:
    """MediaPipe-style edge list -> manifold, oriented triangles with the inner holes closed.

    Args:
        edges: undirected vertex index pairs.
        vertices_head_mm: (N, 3) float, head frame (faces look toward -z).
        close_holes_smaller_than: boundary loops with fewer vertices than this
            are closed (eyes: 16, mouth: 20); the outer contour (36) stays open.

    Returns:
        (M, 3) int64, right-hand normals pointing out of the face (toward -z of the head frame).
        The same on every machine: the holes are closed by :func:`ear_clip`,
        whose choices follow exact tie-breaking rules.
    """
    v = np.asarray(vertices_head_mm, dtype=np.float64)
    cliques = triangles_from_edges(edges)
    cnt = edge_use_counts(cliques)
    # Spurious cliques: all three edges over-used (three cliques share them).
    spurious = {t for t in cliques if all(cnt[(min(a, b), max(a, b))] > 2 for a, b in itertools.combinations(t, 2))}
    tris = [t for t in cliques if t not in spurious]
    cnt = edge_use_counts(tris)
    if max(cnt.values()) > 2:
        raise ValueError("the edge graph is not a surface: edges remain with more than two triangles")
    outward = np.array([0.0, 0.0, -1.0])
    tri = orient_triangles_toward(v, np.array(tris), direction=outward)
    added: list[tuple[int, int, int]] = []
    for loop in boundary_loops(tri):
        if len(loop) >= close_holes_smaller_than:
            continue
        # The loop runs as the triangles' boundary edges do; the patch closing
        # it must run each edge the other way, so clip the reversed loop.
        added.extend(ear_clip(loop[::-1], v[:, :2]))
    full = np.vstack([tri, np.array(added, dtype=np.int64).reshape(-1, 3)])
    return orient_triangles_toward(v, full, direction=outward)
