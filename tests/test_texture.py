"""The trilinear mip sampler against a hand-written bilinear / trilinear formula."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import face_photo

from gazeaug.texture import build_pyramid, sample


def _bilinear_replicate(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup with pixel centres at integers and edges replicated, written out by hand."""
    h, w = img.shape[:2]
    x = np.clip(x, 0, w - 1)
    y = np.clip(y, 0, h - 1)
    x0 = np.floor(x).astype(int)
    y0 = np.floor(y).astype(int)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    f = img.astype(np.float64)
    top = f[y0, x0] * (1 - fx) + f[y0, x1] * fx
    bottom = f[y1, x0] * (1 - fx) + f[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def _patch_coords(scale: float, offset: tuple[float, float], size_wh=(60, 36)) -> np.ndarray:
    w, h = size_wh
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    return np.stack([offset[0] + scale * u, offset[1] + scale * v], axis=-1)


def test_trilinear_matches_the_formula_per_level():
    rng = np.random.default_rng(3)
    import cv2

    # texture with detail at every scale, smooth enough that remap's 1/32-pixel weights stay below 0.5 grey;
    # the 8-bit lookups and blend round to whole grey levels: within 1.5 of the exact value, 0.4 on average
    img = cv2.GaussianBlur(rng.integers(0, 256, (300, 420, 3), dtype=np.uint8), (0, 0), 1.5)
    img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX)
    pyr = build_pyramid(img)
    assert len(pyr.levels) == 5
    # footprints 1, 1.5, 2.8, 4, 6 and 40 source pixels: lod 0, 0.58, 1.49, 2, 2.58 and clipped to 4
    scales = (1.0, 1.5, 2.8, 4.0, 6.0, 40.0)
    coords = np.stack([_patch_coords(s, (3.3 + 7 * i, 5.7 + 3 * i)) for i, s in enumerate(scales)])
    valid = np.ones(coords.shape[:3], dtype=bool)
    got = sample(pyr, coords.astype(np.float32), valid)
    for i, s in enumerate(scales):
        lod = min(np.log2(s), len(pyr.levels) - 1)
        expected = np.zeros(coords.shape[1:3] + (3,))
        for level, lv in enumerate(pyr.levels):
            weight = max(0.0, 1.0 - abs(lod - level))
            if weight:
                f = 2.0**-level
                expected += weight * _bilinear_replicate(lv, coords[i, ..., 0] * f, coords[i, ..., 1] * f)
        # cv2.remap interpolates with 1/32-pixel fixed-point weights
        assert np.abs(got[i] - expected).max() < 1.5, (s, np.abs(got[i] - expected).max())
        assert np.abs(got[i] - expected).mean() < 0.4, (s, np.abs(got[i] - expected).mean())


def test_outside_positions_replicate_the_edge_and_invalid_pixels_are_zero():
    img = np.zeros((64, 64, 3), dtype=np.uint8)
    img[:, -1] = (10, 20, 30)  # right edge column
    pyr = build_pyramid(img)
    coords = np.full((1, 2, 2, 2), (500.0, 30.0), dtype=np.float32)
    coords[0, :, 1, 0] = 501.0  # footprint 1: level 0
    valid = np.array([[[True, True], [False, False]]])
    got = sample(pyr, coords, valid)
    np.testing.assert_allclose(got[0, 0], [[10, 20, 30], [10, 20, 30]], atol=0.01)
    assert not got[0, 1].any()


def test_constant_texture_gives_the_constant_at_every_level():
    img = np.full((128, 96, 3), (200, 100, 50), dtype=np.uint8)
    pyr = build_pyramid(img)
    coords = np.stack([_patch_coords(s, (2.0, 2.0), (8, 8)) for s in (1.0, 3.0, 9.0)]).astype(np.float32)
    got = sample(pyr, coords, np.ones(coords.shape[:3], dtype=bool))
    np.testing.assert_allclose(got, np.broadcast_to([200, 100, 50], got.shape), atol=0.01)


@pytest.mark.parametrize("name", ["astronaut.png", "business-person.png", "pexels/image00.jpg", "pexels/image01.jpg"])
def test_normalizing_from_the_eye_region_equals_the_whole_image(faces_dir, detector, name):
    from facemesh import builtin_face_model, camera_for_image, load_image_rgb, solve_head_pose
    from facemesh.face_models import KEYPOINTS
    from facemesh.landmarks import select_face
    from gazeaug.normalize import normalize_image

    img = load_image_rgb(face_photo(faces_dir, name))  # the astronaut runs without ../shared
    h, w = img.shape[:2]
    cam = camera_for_image(None, w, h, warn=False)
    face = select_face(detector.detect(img))
    model = builtin_face_model().vertices_mm
    pose = solve_head_pose(face.points_px[:468], model, cam)
    region = normalize_image(img, cam, pose, model, KEYPOINTS["mediapipe"])
    whole = normalize_image(img, cam, pose, model, KEYPOINTS["mediapipe"], pyramid=build_pyramid(img))
    for side in ("left", "right"):
        diff = np.abs(region.eye(side).image.astype(int) - whole.eye(side).image)
        # the same samples; positions relative to the region round differently in float32 now and then
        assert diff.max() <= 1 and (diff > 0).mean() < 0.002
