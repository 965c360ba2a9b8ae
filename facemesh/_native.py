"""Native libraries that write to the process's stderr: the one way to keep them quiet.

Some C and C++ libraries under facemesh write lines straight to file
descriptor 2, past Python's ``sys.stderr``: MediaPipe's TensorFlow Lite and
glog while its graph is built and first run, libpng inside ``cv2.imdecode``
("libpng warning: iCCP: known incorrect sRGB profile", "libpng error: ..."
for a damaged file), libjpeg ("Corrupt JPEG data: ..."). Every problem that
matters is reported by the Python code that called them (a typed error naming
the file), so their lines are noise on a command line that promises one
``error:`` line. :func:`native_stderr_silenced` points descriptor 2 to
``/dev/null`` around such a call.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager, suppress

__all__ = ["native_stderr_silenced"]

_FD2_LOCK = threading.RLock()


@contextmanager
def native_stderr_silenced(enabled: bool = True) -> Iterator[None]:
    """Point file descriptor 2 to ``/dev/null`` inside the block; always restore it.

    Python's ``sys.stderr`` is flushed first, so nothing written before the
    block is lost. One thread at a time (a re-entrant lock), so concurrent
    blocks cannot restore each other's ``/dev/null``. Where descriptor 2
    cannot be duplicated (closed, or no ``/dev/null``), the block runs with
    stderr untouched. Descriptor 2 is the process's: what another thread
    writes to it while a block runs (a progress bar's redraw) is lost too, so
    blocks are kept around the native call alone.
    """
    if not enabled:
        yield
        return
    with _FD2_LOCK:
        _flush_stderr()
        saved = -1
        try:
            saved = os.dup(2)
            devnull = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(devnull, 2)
            finally:
                os.close(devnull)
        except OSError:
            if saved >= 0:
                with suppress(OSError):
                    os.dup2(saved, 2)  # undo a partial redirection
                os.close(saved)
            saved = -1
        try:
            yield
        finally:
            if saved >= 0:
                _flush_stderr()
                try:
                    os.dup2(saved, 2)
                finally:
                    os.close(saved)


def _flush_stderr() -> None:
    try:
        sys.stderr.flush()
    except (AttributeError, OSError, ValueError):  # no stderr, or a closed one
        pass
