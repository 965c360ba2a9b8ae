"""What every renderer shares: the mesh it draws (with a background ring), the views, and the fill of misses.

A renderer builds a :class:`Scene` once per face (``renderer.scene(mesh)``) and
renders many :class:`View` s from it. A view is a normalized camera
(:class:`gazeaug.camera.NormalizedCamera`, in the frame of the application's
camera) plus the rigid motion that takes the mesh from its source camera's
frame into the application camera's frame, so the scene never changes while
the head pose does.

Background: a face mesh ends at the face contour, so a turned head can leave
pixels that no triangle covers. :func:`render_mesh` adds rings of triangles
around the contour, pushed outward and backward in the head frame, textured
with whatever the photo shows around the face (hair, ears, background); any
pixel still uncovered is inpainted from its neighbours (:func:`fill_misses`).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from facemesh.face_models.triangulation import boundary_loops
from facemesh.mesh import texture_uv
from facemesh.reconstruct import orient_triangles_toward
from facemesh.render import camera_rays
from facemesh.types import FaceMesh

from ..camera import NormalizedCamera, pixel_to_ray_matrices
from ..errors import GazeAugError

__all__ = [
    "RenderMesh",
    "View",
    "RenderedPatches",
    "Scene",
    "Renderer",
    "render_mesh",
    "fill_misses",
    "view_rays_packed",
]

#: Background rings around the face contour: (outward growth of the contour
#: about its centre, in the head's x-y plane; how far back, mm). Reaches past
#: the eye patches' edges for heads turned 40 deg.
BACKGROUND_RINGS: tuple[tuple[float, float], ...] = ((0.15, 5.0), (0.5, 12.0), (1.2, 20.0))


@dataclass(frozen=True)
class RenderMesh:
    """A face mesh ready to draw.

    Attributes:
        vertices_mm: (V, 3) float64, mm, the source camera's frame. The first
            ``num_face_vertices`` are the face mesh's (landmark order); the rest
            are the background rings.
        triangles: (T, 3) int64, counter-clockwise seen from the source camera.
        uv: (V, 2) float64 glTF texture coordinates into ``texture``.
        texture: (h, w, 3) uint8 RGB.
        num_face_vertices: N, the face mesh's own vertex count.
        texels_per_mm: texture pixels per mm at the head's distance in the source
            photo (``f / ||t_head||``): how much detail the texture holds.
        ring_parent: (V - N,) int64: the face vertex (on the outer contour) each ring
            vertex was grown from; empty without rings.
    """

    vertices_mm: NDArray[np.float64]
    triangles: NDArray[np.int64]
    uv: NDArray[np.float64]
    texture: NDArray[np.uint8]
    num_face_vertices: int
    texels_per_mm: float = 0.0
    ring_parent: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


@dataclass(frozen=True)
class View:
    """One normalized camera looking at the mesh in a new pose.

    Attributes:
        camera: the normalized camera, in the application camera's frame.
        rotation: (3, 3) float64 ``A``, and
        translation_mm: (3,) float64 ``b``: a mesh point ``v`` (source camera
            frame) sits at ``A v + b`` in the application camera's frame.
    """

    camera: NormalizedCamera
    rotation: NDArray[np.float64]
    translation_mm: NDArray[np.float64]


@dataclass(frozen=True)
class RenderedPatches:
    """What a scene gives for a list of views.

    Attributes:
        images: (P, H, W, 3) uint8 RGB, one per view.
        coverage: (P,) float64, the fraction of each image's pixels covered by the mesh before filling.
    """

    images: NDArray[np.uint8]
    coverage: NDArray[np.float64]


class Scene(Protocol):
    """A face loaded into a renderer."""

    def render(self, views: Sequence[View]) -> RenderedPatches:
        """Render each view (all views share one patch size)."""
        ...


class Renderer(Protocol):
    """Builds scenes. ``name`` is recorded in outputs."""

    name: str

    def scene(self, mesh: RenderMesh) -> Scene:
        """Load one face."""
        ...


def view_rays_packed(views: Sequence[View], supersample: int = 1) -> NDArray[np.float32]:
    """Rays of every pixel of every view, in the mesh's (source camera) frame, as (P, H s, W s, 6) float32.

    Each ray is ``(origin xyz, direction xyz)`` (:func:`facemesh.render.camera_rays`):
    the mesh-frame ray of pixel ``(u, v, 1)`` is ``A^T R^T S^-1 C_n^-1 (u, v, 1)``
    from the camera centre ``A^T (0 - b)``. ``supersample`` s > 1 casts s x s rays per pixel
    (sub-pixel centres, :func:`facemesh.conventions.homogeneous_pixel_centres`).
    """
    if not views:
        raise GazeAugError("no views to render")
    sizes = {v.camera.size_wh for v in views}
    if len(sizes) != 1:
        raise GazeAugError(f"views to render together must share one patch size, got {sorted(sizes)}")
    a = np.stack([v.rotation for v in views])
    b = np.stack([v.translation_mm for v in views])
    m = np.einsum("pji,pjk->pik", a, pixel_to_ray_matrices([v.camera for v in views]))
    return camera_rays(m, -np.einsum("pji,pj->pi", a, b), sizes.pop(), supersample)  # origins A^T (0 - b)


def fill_misses(images: NDArray[Any], hit: NDArray[np.bool_]) -> NDArray[np.uint8]:
    """Round to uint8 and inpaint pixels no ray hit (Telea), per image; images without misses pass through.

    Args:
        images: (P, H, W, 3) float RGB, or uint8 (then filled in place).
        hit: (P, H, W) bool.
    """
    import cv2

    out = images if images.dtype == np.uint8 else np.clip(np.round(images), 0, 255).astype(np.uint8)
    for i in np.flatnonzero(~hit.reshape(len(hit), -1).all(axis=1)):
        if not hit[i].any():
            out[i] = 0
            continue
        mask = (~hit[i]).astype(np.uint8)
        out[i] = cv2.inpaint(out[i], mask, 3, cv2.INPAINT_TELEA)
    return out


@functools.lru_cache(maxsize=8)
def _boundary_loops(triangles_bytes: bytes) -> list[list[int]]:
    """Boundary loops of a triangulation (cached: every MediaPipe mesh shares one), [] if not simple loops."""
    tri = np.frombuffer(triangles_bytes, dtype=np.int64).reshape(-1, 3)
    try:
        return boundary_loops(tri)
    except ValueError:
        return []


def render_mesh(mesh: FaceMesh, rings: Sequence[tuple[float, float]] = BACKGROUND_RINGS) -> RenderMesh:
    """The face mesh plus background rings around its outer contour (see the module docstring).

    Meshes whose boundary is not a set of simple loops (some Ball-Pivoting
    results) and meshes with an atlas texture get no rings; their misses are inpainted.
    """
    v = np.asarray(mesh.vertices_mm, dtype=np.float64)
    tri = np.asarray(mesh.triangles, dtype=np.int64)
    uv = np.asarray(mesh.uv, dtype=np.float64)
    n = len(v)
    # an atlas texture (facemesh build --atlas) is no longer the photo: rings cannot be textured from it
    loops = [] if "atlas" in mesh.extras else _boundary_loops(tri.tobytes())
    texels = float(np.mean(mesh.camera.focal_px) / np.linalg.norm(mesh.pose.translation_mm))
    if not loops or not rings:
        return RenderMesh(v, tri, uv, np.asarray(mesh.texture), n, texels)
    # the outer contour: the loop with the largest extent
    outer = max(loops, key=lambda lp: float(np.ptp(v[lp], axis=0).sum()))
    r, t = mesh.pose.rotation, mesh.pose.translation_mm
    head = (v[outer] - t) @ r  # head frame
    centre = head[:, :2].mean(axis=0)
    new_vertices = []
    for grow, back in rings:
        ring = head.copy()
        ring[:, :2] = centre + (head[:, :2] - centre) * (1.0 + grow)
        ring[:, 2] += back
        new_vertices.append(ring @ r.T + t)
    ring_v = np.concatenate(new_vertices)
    # texture: where the ring points project in the source image
    th, tw = mesh.texture.shape[:2]
    ring_uv = texture_uv(ring_v, mesh.camera, mesh.texture_origin_px, (tw, th))
    # quads between consecutive rings
    m = len(outer)
    prev = np.asarray(outer, dtype=np.int64)
    new_tri = []
    for k in range(len(rings)):
        cur = n + k * m + np.arange(m)
        a, b = prev, np.roll(prev, -1)
        c, d = np.roll(cur, -1), cur
        new_tri.append(np.stack([a, b, c], axis=1))
        new_tri.append(np.stack([a, c, d], axis=1))
        prev = cur
    all_v = np.concatenate([v, ring_v])
    # orient the new triangles like the face: counter-clockwise seen from the source camera
    extra = orient_triangles_toward(all_v, np.concatenate(new_tri), np.zeros(3))
    return RenderMesh(
        all_v,
        np.concatenate([tri, extra]),
        np.concatenate([uv, ring_uv]),
        np.asarray(mesh.texture),
        n,
        texels,
        np.tile(np.asarray(outer, dtype=np.int64), len(rings)),  # ring k, vertex j grew from outer[j]
    )
