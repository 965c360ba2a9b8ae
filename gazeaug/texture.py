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

For speed, the levels are also packed side by side into one uint8 atlas
(each level with a one-pixel replicated border), so a trilinear lookup is two
``cv2.remap`` calls (the lower and the upper level of every pixel) and one
blend, however many levels the pixels of a batch span. Both lookups and the
blend round to whole grey levels (OpenCV's 8-bit paths: bilinear weights in
1/32 pixel, results rounded): within one grey level of exact trilinear
filtering, and the same for test-time normalization and rendering. Positions are clamped
to level 0's pixel centres; on every level that lands within the level or on
its replicated border, which is what ``BORDER_REPLICATE`` gives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from facemesh.render import remap_bilinear

from .errors import GazeAugError

__all__ = [
    "MAX_LEVELS",
    "MipPyramid",
    "build_pyramid",
    "region_pyramid",
    "level_of_detail",
    "sample",
    "remap_bilinear",
]

#: Pyramid levels beyond the original (footprints up to 16 source pixels per output pixel).
MAX_LEVELS = 4


@dataclass(frozen=True)
class MipPyramid:
    """An image and its ``cv2.pyrDown`` levels.

    Attributes:
        levels: level 0 is the (h, w, 3) uint8 RGB image; level l is about (h / 2**l, w / 2**l, 3).
        atlas: (h + 2, sum(w_l + 2), 3) uint8: the levels side by side, each with a
            one-pixel replicated border; level l's pixel (x, y) is atlas pixel
            (x + offsets_x[l], y + 1).
        offsets_x: (L,) float32 atlas column of each level's pixel x = 0.
    """

    levels: tuple[NDArray[np.uint8], ...]
    atlas: NDArray[np.uint8]
    offsets_x: NDArray[np.float32]


def build_pyramid(image_rgb: NDArray[np.uint8], max_levels: int = MAX_LEVELS) -> MipPyramid:
    """Gaussian pyramid of an RGB image (stops before a level would be smaller than 4 pixels)."""
    import cv2

    img = np.ascontiguousarray(image_rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise GazeAugError(f"texture: expected (H, W, 3) uint8, got {img.shape} {img.dtype}")
    levels: list[NDArray[np.uint8]] = [img]
    while len(levels) <= max_levels and min(levels[-1].shape[:2]) >= 8:
        levels.append(np.asarray(cv2.pyrDown(levels[-1]), dtype=np.uint8))
    h0 = img.shape[0]
    atlas = np.zeros((h0 + 2, sum(lv.shape[1] + 2 for lv in levels), 3), dtype=np.uint8)
    offsets, x = [], 0
    for lv in levels:
        h, w = lv.shape[:2]
        atlas[: h + 2, x : x + w + 2] = cv2.copyMakeBorder(lv, 1, 1, 1, 1, cv2.BORDER_REPLICATE)
        offsets.append(x + 1)
        x += w + 2
    return MipPyramid(
        levels=tuple(levels),
        atlas=atlas,
        offsets_x=np.asarray(offsets, dtype=np.float32),
    )


#: Region crops start on multiples of this (so the crop's pyramid levels line up with the whole image's).
REGION_ALIGN = 2**MAX_LEVELS

#: Pixels kept around the sampled positions: pyrDown's 5-tap kernel, repeated over the levels, and the
#: bilinear taps of the coarsest level, stay inside it.
REGION_MARGIN_PX = 8 * 2**MAX_LEVELS


def region_pyramid(image_rgb: NDArray[np.uint8], coords_px: NDArray[np.float32]) -> tuple[MipPyramid, tuple[int, int]]:
    """The pyramid of just the part of an image that positions will sample (plus a margin).

    Building the pyramid of a 1920 x 1280 photo to read two 60 x 36 patches
    costs milliseconds; the region around the eyes costs a tenth of that.
    Sampling the region's pyramid at ``coords_px - origin`` gives what
    sampling the whole image's pyramid at ``coords_px`` gives: the region
    starts on a multiple of :data:`REGION_ALIGN` and keeps
    :data:`REGION_MARGIN_PX` around the positions (clipped to the image, whose
    edges the sampler replicates either way).

    Args:
        image_rgb: (H, W, 3) uint8 RGB.
        coords_px: (..., 2) float pixel positions (x, y) in the image.

    Returns:
        ``(pyramid, (x0, y0))``: the region's pyramid and its top-left pixel in the image.
    """
    h, w = image_rgb.shape[:2]
    c = np.asarray(coords_px, dtype=np.float64).reshape(-1, 2)
    c = c[np.isfinite(c).all(axis=1)]
    if len(c) == 0:
        return build_pyramid(image_rgb), (0, 0)
    lo = np.clip(np.floor(c.min(axis=0)), 0, [w - 1, h - 1]) - REGION_MARGIN_PX
    hi = np.clip(np.ceil(c.max(axis=0)), 0, [w - 1, h - 1]) + REGION_MARGIN_PX
    x0 = max(0, int(lo[0]) // REGION_ALIGN * REGION_ALIGN)
    y0 = max(0, int(lo[1]) // REGION_ALIGN * REGION_ALIGN)
    x1, y1 = min(w, int(hi[0]) + 1), min(h, int(hi[1]) + 1)
    return build_pyramid(np.ascontiguousarray(image_rgb[y0:y1, x0:x1])), (x0, y0)


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
    foot2 = np.zeros(valid.shape, dtype=np.float32)  # squared footprint
    # steps to the next pixel along x (axis 2) and along y (axis 1); each step counts for both its pixels
    for lo, hi in (
        ((slice(None), slice(None), slice(0, -1)), (slice(None), slice(None), slice(1, None))),
        ((slice(None), slice(0, -1), slice(None)), (slice(None), slice(1, None), slice(None))),
    ):
        d = c[hi] - c[lo]
        length2 = d[..., 0] * d[..., 0]
        length2 += d[..., 1] * d[..., 1]
        length2[~(valid[hi] & valid[lo])] = 0.0
        np.maximum(foot2[lo], length2, out=foot2[lo])
        np.maximum(foot2[hi], length2, out=foot2[hi])
    np.maximum(foot2, np.float32(1.0), out=foot2)
    lod = np.log2(foot2)
    lod *= np.float32(0.5)
    return lod


def sample(
    pyramid: MipPyramid,
    coords_px: NDArray[np.float32],
    valid: NDArray[np.bool_],
    *,
    antialias: bool = True,
    dtype: type[np.floating] | type[np.uint8] = np.float32,
) -> NDArray[Any]:
    """Sample the pyramid at source positions: bilinear within a level, linear between levels.

    Args:
        pyramid: the source image's pyramid.
        coords_px: (P, H, W, 2) float32 level-0 pixel positions (x, y; pixel centres at integers).
        valid: (P, H, W) bool; invalid pixels come out 0.
        antialias: False samples level 0 only (plain bilinear, like ``cv2.warpPerspective``).
        dtype: float32 (default) or uint8 (the same values: OpenCV's 8-bit lookups and blend round them).

    Returns:
        (P, H, W, 3) ``dtype`` RGB in [0, 255].
    """
    p, h, w = valid.shape
    mx = np.ascontiguousarray(coords_px[..., 0].reshape(p * h, w), dtype=np.float32)
    my = np.ascontiguousarray(coords_px[..., 1].reshape(p * h, w), dtype=np.float32)
    if not antialias or len(pyramid.levels) == 1:
        out = remap_bilinear(pyramid.levels[0], mx, my, dtype).reshape(p, h, w, 3)
    else:
        import cv2

        lod = np.minimum(level_of_detail(coords_px, valid), np.float32(len(pyramid.levels) - 1)).reshape(p * h, w)
        lower = lod.astype(np.intp)  # floor: lod >= 0
        frac: NDArray[np.float32] = np.asarray(lod - lower.astype(np.float32), dtype=np.float32)
        upper = np.minimum(lower + 1, len(pyramid.levels) - 1)
        # clamping to level 0's pixel centres keeps every level's position within one pixel of that
        # level (w_l = ceil(w_0 / 2**l) > (w_0 - 1) / 2**l), where the atlas border replicates the edge
        h0, w0 = pyramid.levels[0].shape[:2]
        mx = np.clip(mx, np.float32(0.0), np.float32(w0 - 1))
        my = np.clip(my, np.float32(0.0), np.float32(h0 - 1))
        scales = np.float32(2.0) ** -np.arange(len(pyramid.levels), dtype=np.float32)
        taps = []
        for level in (lower, upper):
            f = np.take(scales, level)
            ax = mx * f
            ax += np.take(pyramid.offsets_x, level)
            ay = my * f
            ay += np.float32(1.0)
            taps.append(remap_bilinear(pyramid.atlas, ax, ay, np.uint8))
        blended = cv2.blendLinear(taps[0], taps[1], np.asarray(1.0 - frac, dtype=np.float32), frac)
        out = np.asarray(blended, dtype=dtype).reshape(p, h, w, 3)
    out[~valid] = 0
    return out
