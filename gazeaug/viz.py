"""Pictures for checking by eye: contact sheets of eye patches with gaze arrows, and pose/gaze distributions."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from facemesh.conventions import pitchyaw_to_vector

from .normalize import NormalizedSample

__all__ = ["draw_gaze", "contact_sheet", "plot_distributions"]


def draw_gaze(patch: NDArray[np.uint8], gaze_pitchyaw: NDArray[np.float64], scale: int = 3) -> NDArray[np.uint8]:
    """The patch enlarged ``scale`` times with the gaze drawn as an arrow from its centre.

    The arrow is the gaze vector's (x, y) in the normalized camera frame (x right,
    y down in the image): a gaze up and to the image's left points up and left.
    """
    import cv2

    big = np.asarray(cv2.resize(patch, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST), dtype=np.uint8)
    h, w = big.shape[:2]
    g = pitchyaw_to_vector(gaze_pitchyaw)
    length = 0.45 * w
    start = (w // 2, h // 2)
    end = (int(round(start[0] + length * g[0])), int(round(start[1] + length * g[1])))
    cv2.arrowedLine(big, start, end, (255, 220, 0), max(1, scale // 2), cv2.LINE_AA, tipLength=0.2)
    return big


def contact_sheet(samples: Sequence[NormalizedSample], columns: int = 4, scale: int = 3) -> NDArray[np.uint8]:
    """A grid of samples, each its right eye then its left eye (as they appear in the image), gaze drawn.

    Returns:
        (H, W, 3) uint8 RGB.
    """
    tiles = []
    for s in samples:
        pair = []
        for side in ("right", "left"):
            e = s.eye(side)
            if e.gaze is not None:
                pair.append(draw_gaze(e.image, e.gaze, scale))
            else:
                import cv2

                pair.append(np.asarray(cv2.resize(e.image, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)))
        tile = np.concatenate(pair, axis=1)
        tiles.append(np.pad(tile, ((2, 2), (2, 2), (0, 0)), constant_values=255))
    if not tiles:
        raise ValueError("no samples to show")
    th, tw = tiles[0].shape[:2]
    rows = -(-len(tiles) // columns)
    sheet = np.full((rows * th, columns * tw, 3), 255, dtype=np.uint8)
    for i, t in enumerate(tiles):
        r, c = divmod(i, columns)
        sheet[r * th : (r + 1) * th, c * tw : (c + 1) * tw] = t
    return sheet


def _angles(group: Sequence[NormalizedSample] | Mapping[str, NDArray[np.float64]], what: str) -> NDArray[np.float64]:
    """(M, 2) radians (pitch, yaw) of ``what`` (``head_pose`` or ``gaze``) for a group."""
    if isinstance(group, Mapping):
        return np.asarray(group[what], dtype=np.float64).reshape(-1, 2)
    vals = [getattr(s.eye(side), what) for s in group for side in ("left", "right")]
    vals = [v for v in vals if v is not None]
    return np.asarray(vals, dtype=np.float64).reshape(-1, 2)


def plot_distributions(
    groups: Mapping[str, Sequence[NormalizedSample] | Mapping[str, NDArray[np.float64]]],
    path: str | Path,
    title: str = "Head pose and gaze (normalized)",
) -> None:
    """Pitch/yaw scatter plots with marginal histograms, head pose and gaze side by side, per group.

    A group is a list of samples (both eyes' normalized-frame angles) or a
    mapping ``{"head_pose": (M, 2), "gaze": (M, 2)}`` of (pitch, yaw) radians.
    Plotted in degrees; written atomically to ``path`` (PNG).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facemesh.io import atomic_write

    fig = plt.figure(figsize=(11, 5.5))
    grid = fig.add_gridspec(2, 4, width_ratios=(4, 1, 4, 1), height_ratios=(1, 4), wspace=0.08, hspace=0.08)
    for k, what in enumerate(("head_pose", "gaze")):
        ax = fig.add_subplot(grid[1, 2 * k])
        top = fig.add_subplot(grid[0, 2 * k], sharex=ax)
        right = fig.add_subplot(grid[1, 2 * k + 1], sharey=ax)
        for name, group in groups.items():
            rad = _angles(group, what)
            if not len(rad):
                continue
            a = np.degrees(rad)
            if len(a) > 5000:  # keep the picture light: an even subsample
                a = a[np.linspace(0, len(a) - 1, 5000).astype(int)]
            ax.scatter(a[:, 1], a[:, 0], s=6, alpha=0.5, label=f"{name} ({len(rad)})")
            top.hist(a[:, 1], bins=30, alpha=0.5)
            right.hist(a[:, 0], bins=30, alpha=0.5, orientation="horizontal")
        ax.set_xlabel(f"{what.replace('_', ' ')} yaw (deg)")
        ax.set_ylabel(f"{what.replace('_', ' ')} pitch (deg)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
        top.axis("off")
        right.axis("off")
    fig.suptitle(title)
    with atomic_write(path) as fh:
        fig.savefig(fh, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
