"""Anti-aliased texture sampling: a Gaussian image pyramid and per-pixel trilinear (mip-mapped) lookups.

Both test-time normalization and training-time rendering turn each output
pixel into a source position (image pixels for normalization, texture pixels
for rendering) and sample it here, so that the two give the same patch for the
same geometry. Without filtering, a 60 x 36 eye patch taken from a photo where
the eye spans several times more pixels aliases; here each pixel reads the
pyramid level whose texel spacing matches the pixel's footprint, as a GPU's
trilinear filter does.

Level ``l`` is ``cv2.pyrDown`` applied ``l`` times; its pixel ``j`` is centred
on level-0 position ``2**l * j``. The footprint of an output pixel is the
larger of the lengths of the source position's steps to the neighbouring
output pixels (the GPU rule); ``lod = log2(footprint)``, clipped to the levels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .errors import GazeAugError

__all__ = ["MAX_LEVELS", "MipPyramid", "build_pyramid", "level_of_detail", "sample", "remap_bilinear"]

#: Pyramid levels beyond the original (footprints up to 16 source pixels per output pixel).
MAX_LEVELS = 4

# cv2.remap takes maps of at most SHRT_MAX rows.
_MAX_REMAP_ROWS = 32000


@dataclass(frozen=True)
class MipPyramid:
    """An image and its ``cv2.pyrDown`` levels.

    Attributes:
        levels: level 0 is the (h, w, 3) uint8 RGB image; level l is about (h / 2**l, w / 2**l, 3).
    """

    levels: tuple[NDArray[np.uint8], ...]


def build_pyramid(image_rgb: NDArray[np.uint8], max_levels: int = MAX_LEVELS) -> MipPyramid:
    """Gaussian pyramid of an RGB image (stops before a level would be smaller than 4 pixels)."""
    import cv2

    img = np.ascontiguousarray(image_rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise GazeAugError(f"texture: expected (H, W, 3) uint8, got {img.shape} {img.dtype}")
    levels: list[NDArray[np.uint8]] = [img]
    while len(levels) <= max_levels and min(levels[-1].shape[:2]) >= 8:
        levels.append(np.asarray(cv2.pyrDown(levels[-1]), dtype=np.uint8))
    return MipPyramid(levels=tuple(levels))


def level_of_detail(coords_px: NDArray[np.float32], valid: NDArray[np.bool_]) -> NDArray[np.float32]:
    """Per-pixel pyramid level from the source positions of neighbouring pixels.

    The footprint of a pixel is the longest step in source pixels to any of
    its four neighbours that is also valid (the GPU rule, made symmetric).

    Args:
        coords_px: (P, H, W, 2) float, source pixel positions (x, y) of P output images.
        valid: (P, H, W) bool, where the position is defined (rays that hit the mesh).

    Returns:
        (P, H, W) float32 ``log2`` of the footprint, >= 0 (0 for pixels without a valid neighbour).
    """
    c = np.asarray(coords_px, dtype=np.float32)
    foot = np.zeros(valid.shape, dtype=np.float32)
    for axis in (1, 2):
        d = np.diff(c, axis=axis)
        length = np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1])
        n = valid.shape[axis]
        both = np.take(valid, np.arange(1, n), axis=axis) & np.take(valid, np.arange(0, n - 1), axis=axis)
        length = np.where(both, length, np.float32(0.0))
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis] = slice(0, n - 1)
        hi[axis] = slice(1, n)
        np.maximum(foot[tuple(lo)], length, out=foot[tuple(lo)])
        np.maximum(foot[tuple(hi)], length, out=foot[tuple(hi)])
    return np.log2(np.maximum(foot, np.float32(1.0)))


def remap_bilinear(image: NDArray[np.uint8], mx: NDArray[np.float32], my: NDArray[np.float32]) -> NDArray[np.float32]:
    """``cv2.remap`` (bilinear, edges replicated) for maps of any number of rows (OpenCV takes < 32767).

    Args:
        image: (h, w, 3) uint8 source.
        mx: (R, C) float32 source x of each output pixel.
        my: (R, C) float32 source y of each output pixel.

    Returns:
        (R, C, 3) float32.
    """
    import cv2

    mx = np.ascontiguousarray(mx, dtype=np.float32)
    my = np.ascontiguousarray(my, dtype=np.float32)
    rows = mx.shape[0]
    out = np.empty(mx.shape + (3,), dtype=np.float32)
    for a in range(0, rows, _MAX_REMAP_ROWS):
        b = min(rows, a + _MAX_REMAP_ROWS)
        out[a:b] = cv2.remap(image, mx[a:b], my[a:b], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out


def sample(
    pyramid: MipPyramid,
    coords_px: NDArray[np.float32],
    valid: NDArray[np.bool_],
    *,
    antialias: bool = True,
) -> NDArray[np.float32]:
    """Sample the pyramid at source positions: bilinear within a level, linear between levels.

    Args:
        pyramid: the source image's pyramid.
        coords_px: (P, H, W, 2) float32 level-0 pixel positions (x, y; pixel centres at integers).
        valid: (P, H, W) bool; invalid pixels come out 0.
        antialias: False samples level 0 only (plain bilinear, like ``cv2.warpPerspective``).

    Returns:
        (P, H, W, 3) float32 RGB in [0, 255].
    """
    p, h, w = valid.shape
    mx = np.ascontiguousarray(coords_px[..., 0].reshape(p * h, w), dtype=np.float32)
    my = np.ascontiguousarray(coords_px[..., 1].reshape(p * h, w), dtype=np.float32)
    if not antialias or len(pyramid.levels) == 1:
        out = remap_bilinear(pyramid.levels[0], mx, my).reshape(p, h, w, 3)
    else:
        lod = np.minimum(level_of_detail(coords_px, valid), np.float32(len(pyramid.levels) - 1)).reshape(p * h, w)
        out_flat = np.zeros((p * h, w, 3), dtype=np.float32)
        low, high = int(np.floor(lod.min())), int(np.ceil(lod.max()))
        for level in range(low, high + 1):
            weight = np.maximum(np.float32(1.0) - np.abs(lod - np.float32(level)), np.float32(0.0))
            f = np.float32(2.0**-level)
            out_flat += weight[..., None] * remap_bilinear(pyramid.levels[level], mx * f, my * f)
        out = out_flat.reshape(p, h, w, 3)
    out[~valid] = 0.0
    return out
