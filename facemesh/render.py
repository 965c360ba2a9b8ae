"""Exact, perspective-correct rendering of a textured mesh by ray casting (Open3D ``RaycastingScene``).

One ray per pixel through the pixel centre as OpenCV defines it (pixel (i, j)
centred at (i, j)); an ideal pinhole camera (no distortion). The hit
triangle's barycentric coordinates interpolate the vertices' uv, and the
texture is sampled bilinearly. ``supersample`` > 1 casts s x s rays per pixel
and averages them, so a texture seen smaller than it was taken does not alias.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .conventions import uv_to_pixels
from .types import FaceMesh, InputError

__all__ = ["RaycastScene", "OPEN3D_INSTALL_HINT", "import_open3d", "rotate_about"]

OPEN3D_INSTALL_HINT = (
    "rendering needs open3d: pip install open3d (on Debian it also needs the system "
    "libraries libusb-1.0-0, libgl1 and libegl1)"
)


def import_open3d() -> Any:
    """Import open3d or raise ImportError with an install hint."""
    try:
        import open3d  # noqa: PLC0415
    except ImportError as exc:
        raise ImportError(f"{OPEN3D_INSTALL_HINT} ({exc})") from exc
    return open3d


def rotate_about(points_mm: ArrayLike, rotation: ArrayLike, centre_mm: ArrayLike) -> NDArray[np.float64]:
    """``c + R (p - c)`` for each row p: turn points about a centre.

    Args:
        points_mm: (N, 3) float, mm, camera frame.
        rotation: (3, 3) float rotation, camera frame.
        centre_mm: (3,) float, mm, camera frame.
    """
    p = np.asarray(points_mm, dtype=np.float64)
    c = np.asarray(centre_mm, dtype=np.float64)
    return (p - c) @ np.asarray(rotation, dtype=np.float64).T + c


@dataclass(frozen=True)
class RenderResult:
    """What one render gives.

    Attributes:
        image: (H, W, 3) uint8 RGB.
        coverage: (H, W) float32 in [0, 1], the fraction of each pixel's rays that hit the mesh.
    """

    image: NDArray[np.uint8]
    coverage: NDArray[np.float32]


class RaycastScene:
    """A textured mesh loaded once into an Embree scene; render it from many cameras.

    Args:
        vertices_mm: (N, 3) float, mm, OpenCV camera frame (of any camera).
        triangles: (M, 3) int vertex indices.
        uv: (N, 2) float glTF texture coordinates.
        texture: (h, w, 3) uint8 RGB.
    """

    def __init__(self, vertices_mm: ArrayLike, triangles: ArrayLike, uv: ArrayLike, texture: NDArray[np.uint8]):
        o3d = import_open3d()
        self._vertices = np.asarray(vertices_mm, dtype=np.float32)
        self._triangles = np.asarray(triangles, dtype=np.uint32)
        self._uv = np.asarray(uv, dtype=np.float64)
        self._texture = np.ascontiguousarray(texture)
        th, tw = self._texture.shape[:2]
        # per triangle: first corner's texture pixel and the edges to the other two, gathered once per hit;
        # (2, M): x row and y row
        corners = uv_to_pixels(self._uv, (tw, th))[self._triangles.astype(np.int64)]
        self._c0 = np.ascontiguousarray(corners[:, 0].T, dtype=np.float32)
        self._e1 = np.ascontiguousarray((corners[:, 1] - corners[:, 0]).T, dtype=np.float32)
        self._e2 = np.ascontiguousarray((corners[:, 2] - corners[:, 0]).T, dtype=np.float32)
        if self._triangles.size == 0:
            raise InputError("cannot render a mesh without triangles")
        if not np.isfinite(self._vertices).all():  # e.g. turned by a NaN angle: a blank picture otherwise
            raise InputError("cannot render a mesh whose vertices are NaN or infinite")
        #: Embree threads per cast (0: all cores). One per process is faster when several processes render.
        self.threads = 0
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(self._vertices), o3d.core.Tensor(self._triangles))

    @classmethod
    def from_mesh(
        cls, mesh: FaceMesh, rotation: ArrayLike | None = None, centre_mm: ArrayLike | None = None
    ) -> "RaycastScene":
        """Scene of a :class:`FaceMesh`, optionally turned by ``rotation`` about ``centre_mm``.

        ``centre_mm`` defaults to the head pose's origin (the midpoint between the eyes).
        """
        v = mesh.vertices_mm
        if rotation is not None:
            c = mesh.pose.translation_mm if centre_mm is None else centre_mm
            v = rotate_about(v, rotation, c)
        return cls(v, mesh.triangles, mesh.uv, mesh.texture)

    @property
    def texture(self) -> NDArray[np.uint8]:
        """(h, w, 3) uint8 RGB, the texture this scene samples."""
        return self._texture

    def trace(
        self, origins_mm: ArrayLike, directions: ArrayLike
    ) -> tuple[NDArray[np.bool_], NDArray[np.float32], NDArray[np.float32]]:
        """Cast rays; give where each hits the texture.

        Args:
            origins_mm: (..., 3) float, mm, scene frame.
            directions: (..., 3) float, any length, scene frame.

        Returns:
            ``(hit, texture_px, distance)``: (...,) bool, whether the ray hit the
            mesh; (..., 2) float32 texture pixel coordinates (x, y; pixel centres
            at integers) of the first hit, (0, 0) where nothing was hit; (...,)
            float32 ray parameter of the hit (distance in units of the
            direction's length; inf where nothing was hit).
        """
        o = np.asarray(origins_mm, dtype=np.float32)
        d = np.asarray(directions, dtype=np.float32)
        shape = np.broadcast_shapes(o.shape, d.shape)
        if shape[-1] != 3:
            raise InputError(f"rays: expected (..., 3) origins and directions, got {o.shape} and {d.shape}")
        rays = np.empty(shape[:-1] + (6,), dtype=np.float32)
        rays[..., :3] = o
        rays[..., 3:] = d
        return self.trace_rays(rays)

    def trace_rays(self, rays: ArrayLike) -> tuple[NDArray[np.bool_], NDArray[np.float32], NDArray[np.float32]]:
        """:meth:`trace` for rays already packed as (..., 6) float32 ``(origin xyz, direction xyz)``."""
        o3d = import_open3d()
        r = np.asarray(rays, dtype=np.float32)
        if r.ndim < 1 or r.shape[-1] != 6:
            raise InputError(f"rays: expected (..., 6) origins and directions, got {r.shape}")
        shape = r.shape[:-1]
        ans = self._scene.cast_rays(
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(r).reshape(-1, 6)), nthreads=self.threads
        )
        prim = ans["primitive_ids"].numpy()
        bary = ans["primitive_uvs"].numpy()
        hit = prim != self._scene.INVALID_ID
        # texture position = corner 0 + b1 edge 1 + b2 edge 2 of the hit triangle (misses: clipped, then zeroed),
        # one coordinate at a time from (2, M) tables (contiguous gathers)
        idx = prim.astype(np.int64)
        b1, b2 = bary[:, 0], bary[:, 1]
        px = np.empty((len(idx), 2), dtype=np.float32)
        for k in range(2):
            px[:, k] = (
                np.take(self._c0[k], idx, mode="clip")
                + b1 * np.take(self._e1[k], idx, mode="clip")
                + b2 * np.take(self._e2[k], idx, mode="clip")
            )
        px[~hit] = 0.0
        t_hit = ans["t_hit"].numpy()
        return hit.reshape(shape), px.reshape(shape + (2,)), t_hit.reshape(shape)

    def render(
        self,
        camera_matrix: ArrayLike,
        size_wh: tuple[int, int],
        *,
        rotation_camera: ArrayLike | None = None,
        position_mm: ArrayLike | None = None,
        supersample: int = 1,
        background: tuple[int, int, int] = (0, 0, 0),
    ) -> RenderResult:
        """Render from a pinhole camera.

        Args:
            camera_matrix: (3, 3) float intrinsics, pixels.
            size_wh: (width, height) of the output in pixels.
            rotation_camera: (3, 3) float rows = the render camera's x, y, z
                axes in the scene's frame (identity: the scene's own camera).
            position_mm: (3,) float, the render camera's centre in the scene's frame (default origin).
            supersample: rays per pixel side (1 = one ray through the pixel centre).
            background: RGB of pixels no ray hits.
        """
        w, h = size_wh
        s = int(supersample)
        if s < 1:
            raise InputError(f"supersample: expected >= 1, got {supersample}")
        k = np.asarray(camera_matrix, dtype=np.float64)
        rot = np.eye(3) if rotation_camera is None else np.asarray(rotation_camera, dtype=np.float64)
        pos = np.zeros(3) if position_mm is None else np.asarray(position_mm, dtype=np.float64)
        # Sub-pixel sample offsets centred on the pixel centre.
        offs = (np.arange(s) + 0.5) / s - 0.5
        xs = (np.arange(w)[:, None] + offs[None, :]).ravel()
        ys = (np.arange(h)[:, None] + offs[None, :]).ravel()
        gx, gy = np.meshgrid(xs, ys)
        pix = np.stack([gx, gy, np.ones_like(gx)], axis=-1)
        dirs = (pix @ np.linalg.inv(k).T) @ rot  # camera axes -> scene frame (rows of rot are the axes)
        hit, px, _ = self.trace(np.broadcast_to(pos, dirs.shape), dirs)
        import cv2  # noqa: PLC0415

        samples = cv2.remap(
            self._texture, px[..., 0], px[..., 1], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        ).astype(np.float64)
        samples[~hit] = background
        img = samples.reshape(h, s, w, s, 3).mean(axis=(1, 3))
        cov = hit.reshape(h, s, w, s).mean(axis=(1, 3)).astype(np.float32)
        return RenderResult(image=np.clip(np.round(img), 0, 255).astype(np.uint8), coverage=cov)
