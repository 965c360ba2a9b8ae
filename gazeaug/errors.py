"""The errors gazeaug raises for bad input (subclasses of facemesh's, so one ``except`` catches both)."""

from __future__ import annotations

from facemesh.types import FaceMeshError

__all__ = ["GazeAugError"]


class GazeAugError(FaceMeshError):
    """Bad input or settings for a gazeaug stage (message names the problem, expected vs. got)."""
