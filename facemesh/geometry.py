"""Small geometric helpers shared by the stages (no conventions live here)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["similarity_transform", "apply_similarity", "nearest_rotation", "vertex_normals"]


def similarity_transform(
    source: ArrayLike, target: ArrayLike, *, with_scale: bool = True
) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares ``s, R, t`` with ``target ~ s * R @ source + t`` (Umeyama 1991).

    Args:
        source: (N, 3) float points.
        target: (N, 3) float points, same order.
        with_scale: estimate ``s``; otherwise ``s = 1`` (rigid).

    Returns:
        ``(s, R, t)``: float, (3, 3) float64 proper rotation, (3,) float64.
    """
    a = np.asarray(source, dtype=np.float64)
    b = np.asarray(target, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2 or a.shape[1] != 3 or len(a) < 3:
        raise ValueError(f"similarity_transform: expected two (N>=3, 3) arrays, got {a.shape} and {b.shape}")
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    a0, b0 = a - ma, b - mb
    cov = b0.T @ a0
    r = nearest_rotation(cov)  # Kabsch: the rotation nearest the cross-covariance
    s = (
        float(np.trace(r.T @ cov) / (a0**2).sum()) if with_scale else 1.0
    )  # trace(R^T C) = sum of signed singular values
    t = mb - s * r @ ma
    return s, r, t


def apply_similarity(points: ArrayLike, s: float, r: ArrayLike, t: ArrayLike) -> NDArray[np.float64]:
    """``s * R @ p + t`` for each row p of an (N, 3) array."""
    p = np.asarray(points, dtype=np.float64)
    return s * p @ np.asarray(r, dtype=np.float64).T + np.asarray(t, dtype=np.float64)


def nearest_rotation(matrix: ArrayLike) -> NDArray[np.float64]:
    """The proper rotation closest to a (3, 3) matrix in the Frobenius norm: ``U diag(1, 1, det(U V^T)) V^T``.

    For a rotation stored in float32 or printed rounded, whose rows are orthonormal only to the
    stored precision; a matrix that is no rotation at all comes back as *some* rotation, so check
    how far it was (``np.abs(m @ m.T - I).max()``) first where that matters.

    Args:
        matrix: (3, 3) float, finite.

    Returns:
        (3, 3) float64, ``R R^T = I``, ``det R = +1``.

    Raises:
        ValueError: not a finite (3, 3) matrix.
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (3, 3) or not np.isfinite(m).all():
        raise ValueError(f"nearest_rotation: expected a finite (3, 3) matrix, got shape {m.shape}")
    u, _, vt = np.linalg.svd(m)
    return u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0]) @ vt


def vertex_normals(
    positions: ArrayLike, triangles: ArrayLike, fallback: ArrayLike = (0.0, 0.0, 1.0)
) -> NDArray[np.float64]:
    """Area-weighted unit vertex normals: the sum of the right-hand normals of the triangles at each vertex.

    Args:
        positions: (N, 3) float, any frame and unit.
        triangles: (M, 3) int vertex indices; a triangle's normal is ``(v1 - v0) x (v2 - v0)``.
        fallback: (3,) unit vector given to vertices that no triangle (or only degenerate ones) touches.

    Returns:
        (N, 3) float64 unit vectors, the positions' frame.
    """
    pos = np.asarray(positions, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    acc = np.zeros_like(pos)
    if len(tri):
        a, b, c = (pos[tri[:, k]] for k in range(3))
        face = np.cross(b - a, c - a)  # length = 2 * area: area weighting
        for k in range(3):
            np.add.at(acc, tri[:, k], face)
    norm = np.linalg.norm(acc, axis=1)
    good = norm > 1e-12 * max(1.0, float(np.abs(pos).max(initial=0.0))) ** 2
    out = np.tile(np.asarray(fallback, dtype=np.float64), (len(pos), 1))
    out[good] = acc[good] / norm[good, None]
    return out
