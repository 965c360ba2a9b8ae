"""Eye-patch renderers behind one interface: build a scene per face, render many views.

``raycast`` (default; Open3D ``RaycastingScene``, CPU), ``filament`` (Open3D's
offscreen Filament renderer; GPU or Mesa) and, for benchmarks only,
``pyrender`` (the paper's renderer; ``pip install -e '.[bench]'`` from a clone).

Renderers are registered by name in :data:`RENDERERS` (a
:class:`gazeaug.registry.Registry`, the style models and dataset readers share);
a name maps to ``"package.module:Class"``, imported when first created, so
listing the names imports no Open3D. ``register_renderer(name, target,
benchmark_only=True)`` keeps a renderer out of production use (the command
line offers it to ``bench`` only).

The ray caster and its shaders: :mod:`facemesh.render` (caster, fragments,
bilinear texture shader) and :mod:`gazeaug.render.shaders` (mip-mapped texture,
eyeball).
"""

from __future__ import annotations

from typing import Any

from ..errors import GazeAugError
from ..registry import Registry, Target
from .base import RenderedPatches, Renderer, RenderMesh, Scene, View, fill_misses, render_mesh, view_rays_packed
from .shaders import EyeballShader, MipTextureShader

__all__ = [
    "RENDERERS",
    "register_renderer",
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

#: name -> renderer class (``Renderer``), constructed with the options :func:`create_renderer` gets.
RENDERERS = Registry("renderer", GazeAugError)


def register_renderer(name: str, target: Target | None = None, *, benchmark_only: bool = False) -> Any:
    """Make a renderer available to :func:`create_renderer` under ``name``.

    Use as a decorator on the class, or give ``target``: the class (or factory) or
    ``"package.module:Class"``, imported when first created.

    Args:
        name: the renderer's name.
        target: see above.
        benchmark_only: for comparisons only, not for making training sets
            (``RENDERERS.names(benchmark_only=False)`` leaves it out).
    """
    return RENDERERS.register(name, target, benchmark_only=benchmark_only)


register_renderer("raycast", "gazeaug.render.raycast:RaycastRenderer")
register_renderer("filament", "gazeaug.render.filament:FilamentRenderer")
register_renderer("pyrender", "gazeaug.render.pyrender_bench:PyrenderRenderer", benchmark_only=True)


def create_renderer(name: str = "raycast", **options: Any) -> Renderer:
    """A renderer by name (see :data:`RENDERERS`); options go to its constructor.

    Raises:
        GazeAugError: an unknown name (the message lists the registered ones).
    """
    renderer: Renderer = RENDERERS.create(name, **options)
    return renderer
