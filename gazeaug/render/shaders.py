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

__all__ = ["MipTextureShader", "EyeballShader", "Light", "LitShader", "FlatShader"]


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
class Light:
    """A directional light with an ambient term: ``ambient + (1 - ambient) max(0, n . direction)``, over a reference.

    Attributes:
        direction: (3,) float unit vector, the scene's frame: from the surface toward the light.
        ambient: the share of light that comes from everywhere, in [0, 1].
        reference: the factor is divided by ``ambient + (1 - ambient) reference`` (default 0.9), so a
            surface facing the light is about as bright as the unlit texture.
        specular: strength of the mirror highlight on wet surfaces (the cornea), in grey levels at its peak.
    """

    direction: NDArray[np.float64]
    ambient: float
    reference: float = 0.9
    specular: float = 0.0

    def factor(self, normals: NDArray[np.float64]) -> NDArray[np.float64]:
        """(K,) float64 brightness factors of K unit normals (K, 3), the scene's frame."""
        lam = np.clip(normals @ np.asarray(self.direction, dtype=np.float64), 0.0, 1.0)
        return (self.ambient + (1.0 - self.ambient) * lam) / (self.ambient + (1.0 - self.ambient) * self.reference)


@dataclass(frozen=True)
class LitShader:
    """Another shader's colours times a :class:`Light`'s factor at the normal interpolated over each hit triangle.

    Attributes:
        base: the shader that gives the unlit colours.
        normals: (N, 3) float unit vertex normals of the mesh, the scene's frame, pointing out of the
            surface toward the viewer's side.
        triangles: (M, 3) int, the mesh's triangles as given to the caster.
        light: the light.
    """

    base: Any
    normals: NDArray[np.float64]
    triangles: NDArray[Any]
    light: Light

    def __call__(self, fragments: Fragments, rays: NDArray[np.float32], mask: NDArray[np.bool_]) -> NDArray[Any]:
        """S + (3,) float32 RGB, 0 outside ``mask``; see :class:`facemesh.render.Shader`."""
        out = np.asarray(self.base(fragments, rays, mask), dtype=np.float32)
        tri = np.asarray(self.triangles)[fragments.triangle_id[mask]]
        b = fragments.barycentrics[mask].astype(np.float64)
        n = (
            (1.0 - b[:, :1] - b[:, 1:]) * self.normals[tri[:, 0]]
            + b[:, :1] * self.normals[tri[:, 1]]
            + b[:, 1:] * self.normals[tri[:, 2]]
        )
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        out[mask] *= self.light.factor(n)[:, None].astype(np.float32)
        return out


@dataclass(frozen=True)
class FlatShader:
    """One colour everywhere (glasses frames); wrap it in a :class:`LitShader` to light it.

    Attributes:
        rgb: (3,) float RGB.
    """

    rgb: tuple[float, float, float]

    def __call__(self, fragments: Fragments, rays: NDArray[np.float32], mask: NDArray[np.bool_]) -> NDArray[Any]:
        """S + (3,) float32 RGB, 0 outside ``mask``; see :class:`facemesh.render.Shader`."""
        out = np.zeros(fragments.shape + (3,), dtype=np.float32)
        out[mask] = np.asarray(self.rgb, dtype=np.float32)
        return out


@dataclass(frozen=True)
class EyeballShader:
    """A 3D eyeball: sclera shaded by the viewing angle, an iris darker toward its limbus, a pupil.

    The colour of a hit on the eyeball's mesh depends on the angle between the
    sphere's normal there and the optical axis: within ``asin(pupil / radius)``
    the pupil, within ``asin(iris / radius)`` the iris (``iris_rgb``, darkened
    by ``1 - 0.45 f^4`` with f the fraction of the iris angle), else the sclera
    (``sclera_rgb``, default :data:`SCLERA_RGB`, times ``0.55 + 0.45 cos`` of the
    angle between the normal and the ray back to the viewer).

    Options for realism (their defaults give the plain eyeball above):

    - ``limbus_soft_deg``: the iris blends into the sclera over this many degrees
      (a smoothstep centred on the limbus) instead of a hard edge.
    - ``iris_streaks``: amplitude (0..1) of radial streaks in the iris (a sum of
      three sines of the angle around the optical axis, phases from ``pattern_seed``).
    - ``up`` and ``lid_shadow``: the sclera and iris darken toward the upper lid
      (``up``, unit vector, the scene's frame, toward the top of the head) by up to
      ``lid_shadow`` (0..1), as lids and lashes shadow a real eye.
    - ``light``: a :class:`Light` multiplies the colour by its factor at the sphere's
      normal, and its ``specular`` adds a corneal highlight (the mirror reflection
      of the light in the cornea, a small bright spot).

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
    sclera_rgb: tuple[float, float, float] = SCLERA_RGB
    limbus_soft_deg: float = 0.0
    iris_streaks: float = 0.0
    pattern_seed: int = 0
    up: NDArray[np.float64] | None = None
    lid_shadow: float = 0.0
    light: Light | None = None

    def __call__(self, fragments: Fragments, rays: NDArray[np.float32], mask: NDArray[np.bool_]) -> NDArray[Any]:
        """S + (3,) float32 RGB, 0 outside ``mask``; see :class:`facemesh.render.Shader`."""
        out = np.zeros(fragments.shape + (3,), dtype=np.float32)
        p = fragments.points(rays, mask)
        d = rays[mask][:, 3:].astype(np.float64)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        axis = np.asarray(self.optical_axis, dtype=np.float64)
        n = (p - self.centre_mm) / self.radius_mm
        ang = np.degrees(np.arccos(np.clip(n @ axis, -1.0, 1.0)))
        iris_ang = math.degrees(math.asin(self.iris_radius_mm / self.radius_mm))
        pupil_ang = math.degrees(math.asin(self.pupil_radius_mm / self.radius_mm))
        view = np.clip(-(n * d).sum(1), 0.0, 1.0)
        sclera = np.array(self.sclera_rgb) * (0.55 + 0.45 * view)[:, None]
        frac = np.clip(ang / iris_ang, 0.0, 1.0)[:, None]
        iris = np.asarray(self.iris_rgb) * (1.0 - 0.45 * frac**4)  # darker toward the limbus
        if self.iris_streaks > 0:
            # angle around the optical axis, from a fixed reference perpendicular to it
            ref = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            e1 = np.cross(axis, ref)
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(axis, e1)
            theta = np.arctan2(n @ e2, n @ e1)
            ph = np.random.default_rng(self.pattern_seed).uniform(0, 2 * np.pi, 3)
            streak = np.sin(17 * theta + ph[0]) + 0.6 * np.sin(29 * theta + ph[1]) + 0.4 * np.sin(43 * theta + ph[2])
            iris = iris * (1.0 + self.iris_streaks * streak / 2.0)[:, None]
        if self.limbus_soft_deg > 0:
            x = np.clip((ang - (iris_ang - self.limbus_soft_deg / 2)) / self.limbus_soft_deg, 0.0, 1.0)
            w = (x * x * (3 - 2 * x))[:, None]  # 0 inside the iris, 1 on the sclera
            col = (1 - w) * iris + w * sclera
        else:
            col = np.where((ang < iris_ang)[:, None], iris, sclera)
        col = np.where((ang < pupil_ang)[:, None], np.array(PUPIL_RGB), col)
        if self.up is not None and self.lid_shadow > 0:
            height = np.clip(n @ np.asarray(self.up, dtype=np.float64), 0.0, 1.0)  # 0 at the equator, 1 at the top
            col = col * (1.0 - self.lid_shadow * np.clip(height / 0.6, 0.0, 1.0))[:, None]
        if self.light is not None:
            col = col * self.light.factor(n)[:, None]
            if self.light.specular > 0:
                h = np.asarray(self.light.direction, dtype=np.float64) - d
                h /= np.linalg.norm(h, axis=1, keepdims=True)
                spec = np.clip((n * h).sum(1), 0.0, 1.0) ** 400
                cornea = (ang < iris_ang + 2.0)[:, None]
                col = col + np.where(cornea, self.light.specular * spec[:, None], 0.0)
        out[mask] = col
        return out
