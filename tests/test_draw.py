"""facemesh.draw.put_label: a label stays legible on white and on black."""

import numpy as np

from facemesh.draw import put_label


def _label_on(background: int, colour: tuple[int, int, int]) -> np.ndarray:
    img = np.full((40, 200, 3), background, np.uint8)
    put_label(img, "pitch +12.3", (5, 25), colour_bgr=colour)
    return img


def test_white_label_shows_on_white():
    img = _label_on(255, (255, 255, 255))
    # a bare white label would leave the picture all white; the outline darkens strokes' edges
    assert int(img.min()) < 60
    assert (img.max(axis=2) < 128).sum() > 50


def test_white_label_shows_on_black():
    img = _label_on(0, (255, 255, 255))
    assert (img.min(axis=2) > 200).sum() > 30


def test_label_left_of_origin_untouched():
    img = _label_on(128, (255, 255, 255))
    # the text starts at x = 5; the outline reaches at most a pixel or two to its left
    assert (img[:, :2] == 128).all()
    # nothing below the baseline's descent
    assert (img[34:] == 128).all()
