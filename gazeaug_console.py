"""The ``facemesh`` and ``gazeaug`` console scripts' first module.

It imports nothing of the two packages until its function runs, so that a Ctrl-C
while Python loads them (a third of a second: numpy, OpenCV, the command
line's modules) ends as any other Ctrl-C before work starts: one line,
exit 130, and no traceback. Then :func:`facemesh.cli.console_entry` takes
over (a Ctrl-C during a command is the command's to report).
"""

from __future__ import annotations

import importlib
import sys

__all__ = ["facemesh", "gazeaug"]


def _run(module: str, prog: str) -> None:
    try:
        entry = importlib.import_module(module).entry
    except KeyboardInterrupt:
        import signal  # here, not above: a Ctrl-C during that import would be a traceback

        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C does not turn this line into a traceback
        # the line facemesh.cli.console_entry prints for a Ctrl-C before main's own handling
        print(f"{prog}: interrupted before it started; nothing was written", file=sys.stderr)
        sys.exit(130)
    entry()


def facemesh() -> None:
    """The ``facemesh`` command (:func:`facemesh.cli.entry`)."""
    _run("facemesh.cli", "facemesh")


def gazeaug() -> None:
    """The ``gazeaug`` command (:func:`gazeaug.cli.entry`)."""
    _run("gazeaug.cli", "gazeaug")
