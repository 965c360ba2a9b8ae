"""Rendering by ray casting: one caster gives fragments, shaders turn fragments into colours.

The split follows pytorch3d's rasterizer -> fragments -> shader:

``camera_rays``
    The one pixel -> ray helper: a camera's pixel -> ray matrix (``K^-1``,
    ``R^T K^-1``, or a normalized camera's ``R^T S^-1 C_n^-1``) times the
    homogeneous pixel centres of :func:`facemesh.conventions.homogeneous_pixel_centres`
    (OpenCV: pixel (i, j) centred at (i, j)), packed as ``(origin, direction)``
    rays; ``supersample`` > 1 casts s x s rays per pixel.
:class:`RayCaster`
    One Open3D ``RaycastingScene`` (Embree) of several triangle meshes (a face;
    for the simulator also both eyeballs). ``trace(rays)`` gives
    :class:`Fragments`: per ray the mesh hit, its triangle, the barycentric
    coordinates of the hit and the distance along the ray. Rays hit triangles
    from either side, so windings do not matter here.
Shaders
    Callables ``shader(fragments, rays, mask) -> (..., 3)`` colours
    (:class:`Shader`) that colour the fragments where ``mask`` is True (their
    mesh's); :func:`shade` composites one shader per mesh over a background.
    Here: :class:`BilinearTextureShader` (``facemesh build --preview``,
    ``facemesh render``); in :mod:`gazeaug.render.shaders` the mip-mapped
    texture shader of the eye patches and the eyeball shader of the simulator.
    Textured shaders share one barycentric texture-coordinate table,
    :class:`TexelTable`.

:class:`RaycastScene` puts them together for one textured :class:`FaceMesh`.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .conventions import homogeneous_pixel_centres, uv_to_pixels
from .types import FaceMesh, InputError

__all__ = [
    "OPEN3D_INSTALL_HINT",
    "import_open3d",
    "rotate_about",
    "camera_rays",
    "pinhole_pixel_to_ray",
    "Fragments",
    "RayCaster",
    "TexelTable",
    "Shader",
    "BilinearTextureShader",
    "shade",
    "remap_bilinear",
    "RenderResult",
    "RaycastScene",
]

OPEN3D_INSTALL_HINT = (
    "rendering needs open3d: pip install open3d (on Debian it also needs the system "
    "libraries libusb-1.0-0, libgl1 and libegl1)"
)

# cv2.remap takes maps of at most SHRT_MAX rows.
_MAX_REMAP_ROWS = 32000


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


# --------------------------------------------------------------------------- rays


@functools.lru_cache(maxsize=8)
def _pixel_centres(size_wh: tuple[int, int], supersample: int) -> NDArray[np.float64]:
    """(H s * W s, 3) float64 :func:`homogeneous_pixel_centres`, cached per size (read-only)."""
    grid = homogeneous_pixel_centres(size_wh, supersample).reshape(-1, 3)
    grid.setflags(write=False)
    return grid


def pinhole_pixel_to_ray(camera_matrix: ArrayLike, rotation_camera: ArrayLike | None = None) -> NDArray[np.float64]:
    """(3, 3) float64 ``R^T K^-1``: pixel ``(x, y, 1)`` -> ray direction in the scene's frame.

    Args:
        camera_matrix: (3, 3) float ``K``, pixels.
        rotation_camera: (3, 3) float ``R``, rows = the camera's x, y, z axes in
            the scene's frame (None: the identity, the scene's own camera).
    """
    k_inv = np.linalg.inv(np.asarray(camera_matrix, dtype=np.float64))
    return k_inv if rotation_camera is None else np.asarray(rotation_camera, dtype=np.float64).T @ k_inv


def camera_rays(
    pixel_to_ray: ArrayLike, origin_mm: ArrayLike, size_wh: tuple[int, int], supersample: int = 1
) -> NDArray[np.float32]:
    """The rays of every pixel centre (or sub-pixel sample) of P cameras, packed for :meth:`RayCaster.trace`.

    The ray of homogeneous pixel ``q = (x, y, 1)`` (:func:`~facemesh.conventions.homogeneous_pixel_centres`)
    is ``origin + s M q`` for s >= 0. All rays come from one float32 product,
    ``q @ [[0 | M^T]] + (origin | 0)`` (the pixel's constant 1 carries the origin).

    Args:
        pixel_to_ray: (3, 3) or (P, 3, 3) float ``M``, pixel -> direction in
            the scene's frame (e.g. :func:`pinhole_pixel_to_ray`).
        origin_mm: (3,) or (P, 3) float, mm, scene frame: each camera's centre.
        size_wh: (W, H) image size, pixels (shared by the P cameras).
        supersample: rays per pixel side (1: one ray through the pixel centre).

    Returns:
        (H s, W s, 6) float32 for one camera, (P, H s, W s, 6) for P:
        ``(origin xyz, direction xyz)`` with the direction's length set by ``M``
        (the ray parameter of a hit is in those units).
    """
    m = np.asarray(pixel_to_ray, dtype=np.float64)
    o = np.asarray(origin_mm, dtype=np.float64)
    single = m.ndim == 2
    m = m.reshape(-1, 3, 3)
    o = np.broadcast_to(o.reshape(-1, 3), (len(m), 3))
    s = int(supersample)
    if s < 1:
        raise InputError(f"supersample: expected >= 1, got {supersample}")
    w, h = int(size_wh[0]), int(size_wh[1])
    packed = np.zeros((len(m), 3, 6), dtype=np.float64)
    packed[:, :, 3:] = m.transpose(0, 2, 1)
    packed[:, 2, :3] = o
    rays = np.matmul(_pixel_centres((w, h), s)[None], packed).astype(np.float32).reshape(len(m), h * s, w * s, 6)
    return rays[0] if single else rays


# --------------------------------------------------------------------------- caster


@dataclass(frozen=True)
class Fragments:
    """What :meth:`RayCaster.trace` gives for each ray (arrays of the rays' shape ``S``).

    Attributes:
        mesh_id: S int32, the index of the mesh the ray hit first (the order
            the meshes were added to the caster), -1 where it hit nothing.
        triangle_id: S int32, the hit triangle's row in that mesh's triangles, -1 where nothing was hit.
        barycentrics: S + (2,) float32 ``(b1, b2)``: the hit point is
            ``(1 - b1 - b2) v0 + b1 v1 + b2 v2`` of the triangle's corners
            ``(v0, v1, v2)`` (in the triangle's own corner order); 0 where nothing was hit.
        distance: S float32 ray parameter of the hit (hit = origin + distance x
            direction, so mm for unit directions); inf where nothing was hit.
    """

    mesh_id: NDArray[np.int32]
    triangle_id: NDArray[np.int32]
    barycentrics: NDArray[np.float32]
    distance: NDArray[np.float32]

    @property
    def shape(self) -> tuple[int, ...]:
        """S, the rays' shape."""
        return tuple(self.mesh_id.shape)

    @property
    def hit(self) -> NDArray[np.bool_]:
        """S bool: the ray hit a mesh."""
        return np.asarray(self.triangle_id >= 0)

    def of_mesh(self, mesh_id: int) -> NDArray[np.bool_]:
        """S bool: the ray hit mesh ``mesh_id`` first."""
        return np.asarray(self.mesh_id == mesh_id)

    def points(self, rays: NDArray[np.float32], mask: NDArray[np.bool_]) -> NDArray[np.float64]:
        """(K, 3) float64 hit points (scene frame) of the K rays where ``mask`` is True (rays: S + (6,))."""
        r = rays[mask].astype(np.float64)
        return r[:, :3] + r[:, 3:] * self.distance[mask, None].astype(np.float64)


class RayCaster:
    """Triangle meshes in one Embree scene; :meth:`trace` casts rays at them and gives :class:`Fragments`.

    Args:
        meshes: (vertices, triangles) pairs, each added with :meth:`add_mesh`
            (mesh ids 0, 1, ... in this order).

    Attributes:
        threads: Embree threads per cast (0: all cores). One per process is
            faster when several processes render.
    """

    def __init__(self, meshes: Sequence[tuple[ArrayLike, ArrayLike]] = (), threads: int = 0):
        o3d = import_open3d()
        self._o3d = o3d
        self._scene = o3d.t.geometry.RaycastingScene()
        self._triangle_counts: list[int] = []
        self.threads = int(threads)
        for vertices, triangles in meshes:
            self.add_mesh(vertices, triangles)

    @property
    def num_meshes(self) -> int:
        """How many meshes the scene holds."""
        return len(self._triangle_counts)

    def add_mesh(self, vertices_mm: ArrayLike, triangles: ArrayLike) -> int:
        """Add a mesh; returns its mesh id.

        Args:
            vertices_mm: (N, 3) float, mm, the scene's frame (cast to float32).
            triangles: (M, 3) int vertex indices, M >= 1 (any winding).

        Raises:
            InputError: no triangles, or NaN / infinite vertices.
        """
        v = np.ascontiguousarray(vertices_mm, dtype=np.float32)
        t = np.ascontiguousarray(triangles, dtype=np.uint32)
        if t.size == 0:
            raise InputError("cannot render a mesh without triangles")
        if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3:
            raise InputError(f"mesh: expected (N, 3) vertices and (M, 3) triangles, got {v.shape} and {t.shape}")
        if not np.isfinite(v).all():  # e.g. turned by a NaN angle: a blank picture otherwise
            raise InputError("cannot render a mesh whose vertices are NaN or infinite")
        mesh_id = int(self._scene.add_triangles(self._o3d.core.Tensor(v), self._o3d.core.Tensor(t)))
        if mesh_id != len(self._triangle_counts):  # pragma: no cover - Open3D numbers geometries 0, 1, ...
            raise RuntimeError(f"Open3D gave mesh id {mesh_id}, expected {len(self._triangle_counts)}")
        self._triangle_counts.append(len(t))
        return mesh_id

    def trace(self, rays: ArrayLike) -> Fragments:
        """Cast rays; the first hit of each.

        Args:
            rays: S + (6,) float ``(origin xyz, direction xyz)``, the scene's
                frame (directions of any non-zero length; cast to float32), e.g. from :func:`camera_rays`.

        Returns:
            :class:`Fragments` of shape S.
        """
        r = np.ascontiguousarray(rays, dtype=np.float32)
        if r.ndim < 1 or r.shape[-1] != 6:
            raise InputError(f"rays: expected (..., 6) origins and directions, got {r.shape}")
        if not self._triangle_counts:
            raise InputError("the ray caster holds no mesh")
        shape = r.shape[:-1]
        ans = self._scene.cast_rays(self._o3d.core.Tensor.from_numpy(r.reshape(-1, 6)), nthreads=self.threads)
        # Open3D marks misses with INVALID_ID = 2**32 - 1, which reads as -1 in int32
        return Fragments(
            mesh_id=ans["geometry_ids"].numpy().view(np.int32).reshape(shape),
            triangle_id=ans["primitive_ids"].numpy().view(np.int32).reshape(shape),
            barycentrics=ans["primitive_uvs"].numpy().reshape(shape + (2,)),
            distance=ans["t_hit"].numpy().reshape(shape),
        )


# --------------------------------------------------------------------------- shading


class TexelTable:
    """The barycentric texture-coordinate table of a textured mesh: hit -> texture pixel.

    Per triangle its first corner's texture pixel ``c0`` and the edges to the
    other two, ``e1 = c1 - c0`` and ``e2 = c2 - c0`` (float32, one (2, M) row
    per coordinate, so a lookup gathers contiguously); a hit at barycentrics
    ``(b1, b2)`` reads the texture at ``c0 + b1 e1 + b2 e2``.

    Args:
        uv: (N, 2) float glTF texture coordinates of the vertices.
        triangles: (M, 3) int vertex indices (the mesh's, as given to the caster).
        texture_size_wh: (w, h) of the texture, pixels.
    """

    def __init__(self, uv: ArrayLike, triangles: ArrayLike, texture_size_wh: tuple[int, int]):
        corners = uv_to_pixels(np.asarray(uv, dtype=np.float64), texture_size_wh)[np.asarray(triangles, dtype=np.int64)]
        self.c0 = np.ascontiguousarray(corners[:, 0].T, dtype=np.float32)
        self.e1 = np.ascontiguousarray((corners[:, 1] - corners[:, 0]).T, dtype=np.float32)
        self.e2 = np.ascontiguousarray((corners[:, 2] - corners[:, 0]).T, dtype=np.float32)

    def texture_px(self, fragments: Fragments, mask: NDArray[np.bool_] | None = None) -> NDArray[np.float32]:
        """Texture pixel positions of hits.

        Args:
            fragments: of shape S; their triangle ids index this table's triangles.
            mask: S bool, the fragments of this table's mesh (default: every hit).

        Returns:
            S + (2,) float32 (x, y) texture pixels (pixel centres at integers), (0, 0) outside ``mask``.
        """
        keep = fragments.hit if mask is None else mask
        idx = fragments.triangle_id.reshape(-1)
        bary = fragments.barycentrics.reshape(-1, 2)
        b1, b2 = bary[:, 0], bary[:, 1]
        px = np.empty((len(idx), 2), dtype=np.float32)
        for k in range(2):  # misses (-1) and other meshes' triangles are clipped into range, then zeroed
            px[:, k] = (
                np.take(self.c0[k], idx, mode="clip")
                + b1 * np.take(self.e1[k], idx, mode="clip")
                + b2 * np.take(self.e2[k], idx, mode="clip")
            )
        px[~keep.reshape(-1)] = 0.0
        return px.reshape(fragments.shape + (2,))


class Shader(Protocol):
    """Colours the fragments of one mesh.

    ``shader(fragments, rays, mask)``: fragments and rays (S + (6,) float32,
    as traced) of shape S, and the S bool ``mask`` of the fragments to colour.
    Returns S + (3,) RGB in [0, 255] (float32, or uint8), in the rays' own
    layout (a shader may use neighbouring rays, as a mip-mapped lookup does);
    values outside ``mask`` are 0. A new shader (lighting, glasses) is a class
    or function of this form.
    """

    def __call__(self, fragments: Fragments, rays: NDArray[np.float32], mask: NDArray[np.bool_]) -> NDArray[Any]:
        """S + (3,) RGB of the fragments where ``mask`` is True, 0 elsewhere."""
        ...


def remap_bilinear(
    image: NDArray[np.uint8],
    mx: NDArray[np.float32],
    my: NDArray[np.float32],
    dtype: type[np.floating] | type[np.uint8] = np.float32,
) -> NDArray[Any]:
    """``cv2.remap`` (bilinear, edges replicated) for maps of any number of rows (OpenCV takes < 32767).

    Args:
        image: (h, w, 3) uint8 source.
        mx: (R, C) float32 source x of each output pixel (pixel centres at integers).
        my: (R, C) float32 source y of each output pixel.
        dtype: of the result: float32 (OpenCV's rounded 8-bit values, as floats) or uint8.

    Returns:
        (R, C, 3) ``dtype``.
    """
    import cv2  # noqa: PLC0415

    mx = np.ascontiguousarray(mx, dtype=np.float32)
    my = np.ascontiguousarray(my, dtype=np.float32)
    rows = mx.shape[0]
    if rows <= _MAX_REMAP_ROWS and dtype == image.dtype:
        return np.asarray(cv2.remap(image, mx, my, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
    out = np.empty(mx.shape + (3,), dtype=dtype)
    for a in range(0, rows, _MAX_REMAP_ROWS):
        b = min(rows, a + _MAX_REMAP_ROWS)
        out[a:b] = cv2.remap(image, mx[a:b], my[a:b], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out


class BilinearTextureShader:
    """The texture read bilinearly at each hit (OpenCV ``remap``, edges replicated): no mip-mapping.

    Args:
        texture: (h, w, 3) uint8 RGB.
        table: the mesh's :class:`TexelTable` into ``texture``.
    """

    def __init__(self, texture: NDArray[np.uint8], table: TexelTable):
        self.texture = np.ascontiguousarray(texture)
        self.table = table

    def __call__(self, fragments: Fragments, rays: NDArray[np.float32], mask: NDArray[np.bool_]) -> NDArray[Any]:
        """S + (3,) float32 RGB (OpenCV's rounded 8-bit values), 0 outside ``mask``; see :class:`Shader`."""
        px = self.table.texture_px(fragments, mask)
        grid = px.reshape(-1, px.shape[-2], 2) if px.ndim >= 3 else px.reshape(-1, 1, 2)
        out = remap_bilinear(self.texture, grid[..., 0], grid[..., 1]).reshape(fragments.shape + (3,))
        out[~mask] = 0.0
        return out


def shade(
    fragments: Fragments,
    rays: NDArray[np.float32],
    shaders: Mapping[int, Shader],
    background: ArrayLike = (0.0, 0.0, 0.0),
) -> NDArray[np.float32]:
    """Composite: each fragment coloured by its mesh's shader, misses (and meshes without one) by the background.

    Args:
        fragments: of shape S.
        rays: S + (6,) float32, the rays traced.
        shaders: mesh id -> :class:`Shader`.
        background: (3,) RGB, or S + (3,) (e.g. a gradient), float.

    Returns:
        S + (3,) float32 RGB.
    """
    out = np.empty(fragments.shape + (3,), dtype=np.float32)
    out[...] = np.asarray(background, dtype=np.float32)
    for mesh_id, shader in shaders.items():
        mask = fragments.of_mesh(mesh_id)
        if mask.any():
            np.copyto(out, shader(fragments, rays, mask), where=mask[..., None])
    return out


# --------------------------------------------------------------------------- one textured face


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
    """A textured mesh in a :class:`RayCaster` with a :class:`BilinearTextureShader`; render it from many cameras.

    Args:
        vertices_mm: (N, 3) float, mm, OpenCV camera frame (of any camera).
        triangles: (M, 3) int vertex indices.
        uv: (N, 2) float glTF texture coordinates.
        texture: (h, w, 3) uint8 RGB.
    """

    def __init__(self, vertices_mm: ArrayLike, triangles: ArrayLike, uv: ArrayLike, texture: NDArray[np.uint8]):
        self.caster = RayCaster([(vertices_mm, triangles)])
        tex = np.ascontiguousarray(texture)
        self.shader = BilinearTextureShader(tex, TexelTable(uv, triangles, (tex.shape[1], tex.shape[0])))

    @classmethod
    def from_mesh(
        cls, mesh: FaceMesh, rotation: ArrayLike | None = None, centre_mm: ArrayLike | None = None
    ) -> RaycastScene:
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
        return self.shader.texture

    def trace(self, rays: ArrayLike) -> Fragments:
        """:meth:`RayCaster.trace` of the scene's one mesh (mesh id 0)."""
        return self.caster.trace(rays)

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
        """Render from a pinhole camera (no distortion), averaging s x s rays per pixel.

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
        pos = np.zeros(3) if position_mm is None else np.asarray(position_mm, dtype=np.float64)
        rays = camera_rays(pinhole_pixel_to_ray(camera_matrix, rotation_camera), pos, (w, h), s)
        frags = self.caster.trace(rays)
        hit = frags.hit
        img = shade(frags, rays, {0: self.shader}, background).astype(np.float64)
        img = img.reshape(h, s, w, s, 3).mean(axis=(1, 3))
        cov = hit.reshape(h, s, w, s).mean(axis=(1, 3)).astype(np.float32)
        return RenderResult(image=np.clip(np.round(img), 0, 255).astype(np.uint8), coverage=cov)
