"""Shaders of the eye-patch renderer and the simulator, over :class:`facemesh.render.Fragments`.

Each is a :class:`facemesh.render.Shader`: ``shader(fragments, rays, mask)``
gives the RGB of the fragments where ``mask`` is True, in the rays' layout;
:func:`facemesh.render.shade` composites one per mesh. The bilinear texture
shader (no mip-maps) is :class:`facemesh.render.BilinearTextureShader`.
A new shader (lighting, glasses) is one more small class here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from facemesh.render import Fragments, TexelTable

from ..texture import MipPyramid, sample

__all__ = ["MipTextureShader", "EyeballShader"]


class MipTextureShader:
    """The texture read by the trilinear mip-mapped sampler of :mod:`gazeaug.texture` (as normalization reads photos).

    The level of detail comes from neighbouring rays' texture positions, so
    the fragments must keep the images' layout: shape (P, H, W).

    Args:
        pyramid: the texture's :class:`~gazeaug.texture.MipPyramid`.
        table: the mesh's :class:`~facemesh.render.TexelTable` into the pyramid's level 0.
        antialias: False reads level 0 bilinearly (no mip-mapping).
        dtype: of the colours, uint8 (default) or float32 (the same values).
    """

    def __init__(
        self,
        pyramid: MipPyramid,
        table: TexelTable,
        *,
        antialias: bool = True,
        dtype: type[np.floating] | type[np.uint8] = np.uint8,
    ):
        self.pyramid = pyramid
        self.table = table
        self.antialias = antialias
        self.dtype = dtype

    def __call__(self, fragments: Fragments, rays: NDArray[np.float32], mask: NDArray[np.bool_]) -> NDArray[Any]:
        """(P, H, W, 3) ``dtype`` RGB, 0 outside ``mask``; see :class:`facemesh.render.Shader`."""
        coords = self.table.texture_px(fragments, mask)
        return sample(self.pyramid, coords, mask, antialias=self.antialias, dtype=self.dtype)


#: Sclera RGB lit head-on; it darkens to 55% where the eyeball is seen edge-on.
SCLERA_RGB = (232.0, 226.0, 220.0)
#: Pupil RGB.
PUPIL_RGB = (18.0, 16.0, 16.0)


@dataclass(frozen=True)
class EyeballShader:
    """A 3D eyeball: sclera shaded by the viewing angle, an iris darker toward its limbus, a pupil.

    The colour of a hit on the eyeball's mesh depends on the angle between the
    sphere's normal there and the optical axis: within ``asin(pupil / radius)``
    the pupil, within ``asin(iris / radius)`` the iris (``iris_rgb``, darkened
    by ``1 - 0.45 f^4`` with f the fraction of the iris angle), else the sclera
    (:data:`SCLERA_RGB` times ``0.55 + 0.45 cos`` of the angle between the
    normal and the ray back to the viewer).

    Attributes:
        centre_mm: (3,) float, mm, the scene's frame: the sphere's centre.
        optical_axis: (3,) float unit vector, the scene's frame.
        radius_mm: the sphere's radius.
        iris_radius_mm: the iris's radius on the sphere.
        pupil_radius_mm: the pupil's radius.
        iris_rgb: (3,) float RGB of the iris.
    """

    centre_mm: NDArray[np.float64]
    optical_axis: NDArray[np.float64]
    radius_mm: float
    iris_radius_mm: float
    pupil_radius_mm: float
    iris_rgb: NDArray[np.float64]

    def __call__(self, fragments: Fragments, rays: NDArray[np.float32], mask: NDArray[np.bool_]) -> NDArray[Any]:
        """S + (3,) float32 RGB, 0 outside ``mask``; see :class:`facemesh.render.Shader`."""
        out = np.zeros(fragments.shape + (3,), dtype=np.float32)
        p = fragments.points(rays, mask)
        d = rays[mask][:, 3:].astype(np.float64)
        n = (p - self.centre_mm) / self.radius_mm
        ang = np.degrees(np.arccos(np.clip(n @ self.optical_axis, -1.0, 1.0)))
        iris_ang = math.degrees(math.asin(self.iris_radius_mm / self.radius_mm))
        pupil_ang = math.degrees(math.asin(self.pupil_radius_mm / self.radius_mm))
        view = np.clip(-(n * d / np.linalg.norm(d, axis=1, keepdims=True)).sum(1), 0.0, 1.0)
        sclera = np.array(SCLERA_RGB) * (0.55 + 0.45 * view)[:, None]
        frac = np.clip(ang / iris_ang, 0.0, 1.0)[:, None]
        iris = np.asarray(self.iris_rgb) * (1.0 - 0.45 * frac**4)  # darker toward the limbus
        col = np.where((ang < iris_ang)[:, None], iris, sclera)
        out[mask] = np.where((ang < pupil_ang)[:, None], np.array(PUPIL_RGB), col)
        return out
