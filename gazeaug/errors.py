"""The errors gazeaug raises for bad input (subclasses of facemesh's, so one ``except`` catches both)."""

from __future__ import annotations

from facemesh.types import FaceMeshError

__all__ = ["GazeAugError", "TracebackText"]


class GazeAugError(FaceMeshError):
    """Bad input or settings for a gazeaug stage (message names the problem, expected vs. got)."""


class TracebackText(Exception):
    """A traceback kept as text, set as the ``__cause__`` of an error raised after its handler.

    Some errors are raised once the handler of the error behind them has ended, so that the
    failed work's frames (a model, the rows it held) are freed first: an out of memory while
    training is one. The traceback of the error behind it is kept as text (which holds no
    frames) in this exception, so a traceback of the new error still shows where the first
    was raised (the pattern of ``concurrent.futures``' remote tracebacks).
    """

    def __init__(self, exc: BaseException | str):
        """Keep ``exc``'s traceback, its causes included, as text (a str is taken as that text)."""
        import traceback

        self.text = exc if isinstance(exc, str) else "".join(traceback.format_exception(exc)).rstrip()
        super().__init__(self.text)  # args (text,): pickled and copied from the text

    def __str__(self) -> str:
        return "\n\n" + self.text
