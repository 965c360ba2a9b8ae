"""The default renderer: ray casting (Open3D ``RaycastingScene``, Embree) with mip-mapped texture sampling.

One ray per pixel through the pixel centre (OpenCV's convention,
:func:`facemesh.render.camera_rays`); the caster's fragments (triangle and
barycentric coordinates of each hit) give texture positions through the
mesh's :class:`~facemesh.render.TexelTable`, read by the trilinear sampler of
:mod:`gazeaug.texture` (:class:`~gazeaug.render.shaders.MipTextureShader`),
the same one test-time normalization uses, so minified texture does not
alias. All views of one call are cast in one batch.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from facemesh.render import RayCaster, TexelTable

from ..normalize import NormalizationSettings
from ..texture import build_pyramid
from .base import RenderedPatches, RenderMesh, View, fill_misses, view_rays_packed
from .shaders import MipTextureShader

__all__ = ["RaycastRenderer", "RaycastFaceScene"]


class RaycastFaceScene:
    """One face in a :class:`~facemesh.render.RayCaster`, coloured by a :class:`.shaders.MipTextureShader`."""

    def __init__(self, mesh: RenderMesh, antialias: bool = True, threads: int = 0):
        texture = np.asarray(mesh.texture)
        self.caster = RayCaster([(mesh.vertices_mm, mesh.triangles)], threads=threads)
        table = TexelTable(mesh.uv, mesh.triangles, (texture.shape[1], texture.shape[0]))
        self.shader = MipTextureShader(build_pyramid(texture), table, antialias=antialias, dtype=np.uint8)

    def render(self, views: Sequence[View]) -> RenderedPatches:
        """Render each view; see :class:`~gazeaug.render.base.Scene`."""
        rays = view_rays_packed(views)
        fragments = self.caster.trace(rays)
        hit = fragments.hit
        colours = self.shader(fragments, rays, hit)
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
