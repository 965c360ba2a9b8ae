"""Eye-patch renderers behind one interface: build a scene per face, render many views.

``raycast`` (default; Open3D ``RaycastingScene``, CPU), ``filament`` (Open3D's
offscreen Filament renderer; GPU or Mesa) and, for benchmarks only,
``pyrender`` (the paper's renderer; ``pip install gazeaug[bench]``).

The ray caster and its shaders: :mod:`facemesh.render` (caster, fragments,
bilinear texture shader) and :mod:`gazeaug.render.shaders` (mip-mapped texture,
eyeball).
"""

from __future__ import annotations

from typing import Any

from ..errors import GazeAugError
from .base import RenderedPatches, Renderer, RenderMesh, Scene, View, fill_misses, render_mesh, view_rays_packed
from .shaders import EyeballShader, MipTextureShader

__all__ = [
    "RENDERERS",
    "create_renderer",
    "RenderMesh",
    "RenderedPatches",
    "Renderer",
    "Scene",
    "View",
    "fill_misses",
    "render_mesh",
    "view_rays_packed",
    "MipTextureShader",
    "EyeballShader",
]

#: Names :func:`create_renderer` accepts.
RENDERERS = ("raycast", "filament", "pyrender")


def create_renderer(name: str = "raycast", **options: Any) -> Renderer:
    """A renderer by name (see :data:`RENDERERS`); options go to its constructor."""
    if name == "raycast":
        from .raycast import RaycastRenderer

        return RaycastRenderer(**options)
    if name == "filament":
        from .filament import FilamentRenderer

        return FilamentRenderer(**options)
    if name == "pyrender":
        from .pyrender_bench import PyrenderRenderer

        return PyrenderRenderer(**options)
    raise GazeAugError(f"renderer: expected one of {RENDERERS}, got {name!r}")
