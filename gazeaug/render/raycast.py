"""The default renderer: Open3D ``RaycastingScene`` (Embree) ray casting with mip-mapped texture sampling.

One ray per pixel through the pixel centre (OpenCV's convention); the hit
triangle's barycentric coordinates interpolate the vertices' uv, and the
texture is read with the trilinear sampler of :mod:`gazeaug.texture`, the same
one test-time normalization uses, so minified texture does not alias. All
views of one call are cast in one batch.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from facemesh.render import RaycastScene

from ..normalize import NormalizationSettings
from ..texture import build_pyramid, sample
from .base import RenderedPatches, RenderMesh, View, fill_misses, view_rays_packed

__all__ = ["RaycastRenderer", "RaycastFaceScene"]


class RaycastFaceScene:
    """One face in an Embree scene, plus its texture pyramid."""

    def __init__(self, mesh: RenderMesh, antialias: bool = True, threads: int = 0):
        self._scene = RaycastScene(mesh.vertices_mm, mesh.triangles, mesh.uv, mesh.texture)
        self._scene.threads = threads
        self._pyramid = build_pyramid(np.asarray(mesh.texture))
        self._antialias = antialias

    def render(self, views: Sequence[View]) -> RenderedPatches:
        """Render each view; see :class:`~gazeaug.render.base.Scene`."""
        hit, coords, _ = self._scene.trace_rays(view_rays_packed(views))
        colours = sample(self._pyramid, coords, hit, antialias=self._antialias, dtype=np.uint8)
        coverage = hit.reshape(len(hit), -1).mean(axis=1)
        return RenderedPatches(images=fill_misses(colours, hit), coverage=coverage.astype(np.float64))


class RaycastRenderer:
    """Factory of :class:`RaycastFaceScene` (``name = "raycast"``).

    Args:
        antialias: trilinear mip-mapped sampling (default); False samples the full-resolution texture.
    """

    name = "raycast"

    def __init__(self, settings: NormalizationSettings | None = None, antialias: bool | None = None, threads: int = 0):
        self.antialias = (settings or NormalizationSettings()).antialias if antialias is None else antialias
        self.threads = int(threads)

    def scene(self, mesh: RenderMesh) -> RaycastFaceScene:
        """Load one face."""
        return RaycastFaceScene(mesh, self.antialias, self.threads)
