"""Text on pictures that stays legible on any background (previews, video overlays)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["put_label"]


def put_label(
    image: NDArray[np.uint8],
    text: str,
    origin_px: tuple[int, int],
    scale: float = 0.5,
    colour_bgr: tuple[int, int, int] = (255, 255, 255),
    thickness: int = 1,
) -> None:
    """Write ``text`` on ``image`` in place, in ``colour_bgr`` over a dark outline.

    A bare white (or pale) label vanishes on a white background and a dark one
    on a dark background; the outline, two pixels wider than the strokes,
    keeps it legible on either.

    Args:
        image: (H, W, 3) uint8 BGR picture, written in place.
        text: the label (OpenCV's Hershey font: ASCII).
        origin_px: (x, y) integer pixels of the text's bottom-left corner, image frame
            (x right, y down, the top-left pixel's centre at (0, 0), as OpenCV).
        scale: OpenCV font scale (0.5 is about 10 px high).
        colour_bgr: the strokes' colour, BGR 0-255.
        thickness: the strokes' width, pixels.
    """
    import cv2

    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(image, text, origin_px, font, scale, (0, 0, 0), thickness + 2, cv2.LINE_AA)
    cv2.putText(image, text, origin_px, font, scale, colour_bgr, thickness, cv2.LINE_AA)
