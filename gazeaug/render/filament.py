"""Open3D's offscreen Filament renderer (``--renderer filament``): rasterization on a GPU (or Mesa on CPU).

The mesh is drawn unlit with its texture; each view sets Filament's camera
from the normalized camera's intrinsics (``f_n ||e|| / d_n``, principal point
``(w / 2, h / 2)``, moved to OpenGL's pixel centres by
:func:`facemesh.conventions.opencv_to_opengl_pixels`) and the extrinsics
``[R A | R b]`` (mesh frame -> normalized camera). Filament needs an EGL or
Vulkan driver (Debian: libegl1, libgl1, libvulkan1, mesa-vulkan-drivers).
Pixels the mesh does not cover are inpainted like the ray caster's; they are
found with a second, flat-coloured pass only when the first pass shows the
background colour.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from facemesh.conventions import gltf_uv_to_bottom_left_uv, opencv_to_opengl_pixels, pixels_to_uv, uv_to_pixels
from facemesh.render import import_open3d

from ..errors import GazeAugError
from ..normalize import NormalizationSettings
from ..texture import MAX_LEVELS, build_pyramid
from .base import RenderedPatches, RenderMesh, View, fill_misses

__all__ = ["FilamentRenderer", "FilamentFaceScene"]

_MARKER = (1.0, 0.0, 1.0)  # magenta: a background colour no face has


def _srgb_encode(x: np.ndarray) -> np.ndarray:
    """Linear [0, 1+] -> sRGB-encoded (the standard piecewise curve)."""
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0), 1 / 2.4) - 0.055)


_SRGB_ENCODE = np.round(_srgb_encode(np.arange(256) / 255.0) * 255.0).clip(0, 255).astype(np.uint8)


# Open3D cannot destroy an OffscreenRenderer and start another in one process (Filament
# aborts), so there is one per patch size for the life of the process, shared by all
# scenes; each scene puts its own face into it before drawing.
_RENDERERS: dict[tuple[int, int], Any] = {}
_CURRENT: dict[tuple[int, int], Any] = {}


def _offscreen_renderer(size: tuple[int, int]) -> Any:
    r = _RENDERERS.get(size)
    if r is None:
        o3d = import_open3d()
        try:
            r = o3d.visualization.rendering.OffscreenRenderer(*size)
        except Exception as exc:  # noqa: BLE001 - the driver's message is the useful part
            raise GazeAugError(
                f"Open3D's Filament renderer could not start ({exc}); it needs EGL or Vulkan "
                "(Debian: libegl1 libgl1 libvulkan1 mesa-vulkan-drivers). Use --renderer raycast."
            ) from exc
        _RENDERERS[size] = r
    return r


class FilamentFaceScene:
    """One face for Open3D's ``OffscreenRenderer`` of the patch size (one renderer per process, shared)."""

    def __init__(self, mesh: RenderMesh, size_wh: tuple[int, int], pixels_per_mm: float):
        o3d = import_open3d()
        rendering = o3d.visualization.rendering
        w, h = size_wh
        self._renderer = _offscreen_renderer((int(w), int(h)))
        self._size = (int(w), int(h))
        tm = o3d.geometry.TriangleMesh()
        tm.vertices = o3d.utility.Vector3dVector(np.asarray(mesh.vertices_mm, dtype=np.float64))
        tm.triangles = o3d.utility.Vector3iVector(np.asarray(mesh.triangles, dtype=np.int32))
        tri = np.asarray(mesh.triangles)
        # Filament samples one texture level, without mip-maps: upload the pyramid level that
        # matches the eyes' minification (what the ray caster's trilinear filter picks there).
        level = 0
        if pixels_per_mm > 0 and mesh.texels_per_mm > 0:
            level = int(np.clip(np.round(np.log2(mesh.texels_per_mm / pixels_per_mm)), 0, MAX_LEVELS))
        pyramid = build_pyramid(np.asarray(mesh.texture), max_levels=level).levels
        level = len(pyramid) - 1
        tex_l = pyramid[level]
        th, tw = mesh.texture.shape[:2]
        x_l = uv_to_pixels(np.asarray(mesh.uv, dtype=np.float64), (tw, th)) / 2.0**level  # level-l pixels
        uv_l = pixels_to_uv(x_l, (0, 0), (tex_l.shape[1], tex_l.shape[0]))[tri.ravel()]
        # Open3D textures: v up from the bottom row (glTF: v down)
        tm.triangle_uvs = o3d.utility.Vector2dVector(gltf_uv_to_bottom_left_uv(uv_l))
        tm.triangle_material_ids = o3d.utility.IntVector(np.zeros(len(tri), dtype=np.int32))
        # Filament decodes the albedo texture as sRGB and (post-processing off) writes linear
        # values at half intensity: upload sRGB-encoded values and a base colour of encode(2),
        # so that the output equals the texture's values.
        tex = o3d.geometry.Image(np.ascontiguousarray(_SRGB_ENCODE[tex_l]))
        tm.textures = [tex]
        mat = rendering.MaterialRecord()
        mat.shader = "defaultUnlit"
        mat.albedo_img = tex
        c = float(_srgb_encode(np.array(2.0)))
        mat.base_color = [c, c, c, 1.0]
        self._geometry = (tm, mat)
        self.texture_level = level
        self._show()

    def _show(self) -> None:
        """Make this face the one the shared renderer draws."""
        if _CURRENT.get(self._size) is self:
            return
        scene = self._renderer.scene
        scene.clear_geometry()
        scene.set_background([*_MARKER, 1.0])
        scene.add_geometry("face", *self._geometry)
        scene.view.set_post_processing(False)
        _CURRENT[self._size] = self

    def render(self, views: Sequence[View]) -> RenderedPatches:
        """Render each view; see :class:`~gazeaug.render.base.Scene`."""
        self._show()
        w, h = self._size
        images = np.empty((len(views), h, w, 3), dtype=np.float32)
        hit = np.ones((len(views), h, w), dtype=bool)
        for i, v in enumerate(views):
            if v.camera.size_wh != self._size:
                raise GazeAugError(f"view size {v.camera.size_wh} differs from the scene's {self._size}")
            k = v.camera.camera_matrix.copy()
            k[0, 0] = k[1, 1] = v.camera.focal_px / v.camera.scale
            k[:2, 2] = opencv_to_opengl_pixels(k[:2, 2])  # Filament: pixel centres at half integers
            ext = np.eye(4)
            ext[:3, :3] = v.camera.rotation @ v.rotation
            ext[:3, 3] = v.camera.rotation @ v.translation_mm
            self._renderer.setup_camera(k, ext, w, h)
            self._renderer.scene.camera.set_projection(k, 1.0, 10000.0, float(w), float(h))
            img = np.asarray(self._renderer.render_to_image())[..., :3]
            images[i] = img
            marker = np.all(img == (255, 0, 255), axis=-1)  # linear output: the marker stays (255, 0, 255)
            hit[i] = ~marker
        return RenderedPatches(images=fill_misses(images, hit), coverage=hit.reshape(len(views), -1).mean(axis=1))


class FilamentRenderer:
    """Factory of :class:`FilamentFaceScene` (``name = "filament"``)."""

    name = "filament"

    def __init__(self, settings: NormalizationSettings | None = None, **_: Any):
        self.settings = settings or NormalizationSettings()
        if self.settings.face_patch_size_wh is not None:  # one image size per scene: the eye patch's
            raise GazeAugError("the filament renderer renders eye patches only: a face patch needs --renderer raycast")

    def scene(self, mesh: RenderMesh) -> FilamentFaceScene:
        """Load one face (the renderer's image size is the patch size)."""
        s = self.settings
        return FilamentFaceScene(mesh, s.patch_size_wh, s.focal_px / s.distance_mm)
