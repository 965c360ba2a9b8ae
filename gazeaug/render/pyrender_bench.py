"""pyrender (the paper's renderer), for benchmarks only: ``pip install -e '.[bench]'`` from a clone.

OpenGL rasterization through EGL (``PYOPENGL_PLATFORM=egl`` is set unless the
user chose another platform); unlit (flat) shading of the textured mesh.
Misses are inpainted like the other renderers'. Kept to compare speed in
``gazeaug bench render``; it is not offered by ``gazeaug augment``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from facemesh.conventions import gltf_uv_to_bottom_left_uv, opencv_to_opengl_camera_pose, opencv_to_opengl_pixels

from ..errors import GazeAugError
from ..normalize import NormalizationSettings
from .base import RenderedPatches, RenderMesh, View, fill_misses

__all__ = ["PyrenderRenderer", "PyrenderFaceScene"]

_HINT = "the pyrender benchmark needs pyrender and EGL: pip install 'gazeaug[bench]' (Debian: libegl1 libgl1)"


def _import_pyrender() -> Any:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    try:
        import pyrender  # noqa: PLC0415
    except ImportError as exc:
        raise ImportError(f"{_HINT} ({exc})") from exc
    return pyrender


class PyrenderFaceScene:
    """One face in a pyrender scene with an offscreen renderer of the patch size."""

    def __init__(self, mesh: RenderMesh, size_wh: tuple[int, int]):
        pyrender = _import_pyrender()
        import trimesh
        from PIL import Image

        w, h = size_wh
        uv = gltf_uv_to_bottom_left_uv(mesh.uv)  # trimesh/OpenGL: v up
        visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(np.asarray(mesh.texture)))
        tm = trimesh.Trimesh(np.asarray(mesh.vertices_mm), np.asarray(mesh.triangles), visual=visual, process=False)
        self._scene = pyrender.Scene(bg_color=[1.0, 0.0, 1.0, 1.0], ambient_light=[1.0, 1.0, 1.0])
        self._scene.add(pyrender.Mesh.from_trimesh(tm, smooth=False))
        self._camera_node = None
        try:
            self._renderer = pyrender.OffscreenRenderer(int(w), int(h))
        except Exception as exc:  # noqa: BLE001 - the driver's message is the useful part
            raise GazeAugError(f"pyrender could not start ({exc}); {_HINT}") from exc
        self._pyrender = pyrender
        self._size = (int(w), int(h))

    def render(self, views: Sequence[View]) -> RenderedPatches:
        """Render each view; see :class:`~gazeaug.render.base.Scene`."""
        pr = self._pyrender
        w, h = self._size
        images = np.empty((len(views), h, w, 3), dtype=np.float32)
        hit = np.ones((len(views), h, w), dtype=bool)
        for i, v in enumerate(views):
            cx, cy = opencv_to_opengl_pixels(v.camera.camera_matrix[:2, 2])  # pixel centres at half integers
            f = v.camera.focal_px / v.camera.scale
            cam = pr.IntrinsicsCamera(f, f, cx, cy, znear=1.0, zfar=10000.0)
            # mesh frame -> normalized camera: [R A | R b]; pyrender wants the camera's pose in OpenGL axes
            pose = opencv_to_opengl_camera_pose(v.camera.rotation @ v.rotation, v.camera.rotation @ v.translation_mm)
            if self._camera_node is not None:
                self._scene.remove_node(self._camera_node)
            self._camera_node = self._scene.add(cam, pose=pose)
            color, _ = self._renderer.render(self._scene, flags=pr.RenderFlags.FLAT)
            images[i] = color[..., :3]
            hit[i] = ~np.all(color[..., :3] == (255, 0, 255), axis=-1)
        return RenderedPatches(images=fill_misses(images, hit), coverage=hit.reshape(len(views), -1).mean(axis=1))

    def close(self) -> None:
        """Free the OpenGL context."""
        self._renderer.delete()


class PyrenderRenderer:
    """Factory of :class:`PyrenderFaceScene` (``name = "pyrender"``), benchmark only."""

    name = "pyrender"

    def __init__(self, settings: NormalizationSettings | None = None, **_: Any):
        self.settings = settings or NormalizationSettings()

    def scene(self, mesh: RenderMesh) -> PyrenderFaceScene:
        """Load one face."""
        return PyrenderFaceScene(mesh, self.settings.patch_size_wh)
