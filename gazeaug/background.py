"""Long runs' plumbing: reading ahead in a background thread, and Ctrl-C taken between steps.

:func:`read_ahead` is the one producer-thread pattern (training batches, video frames): the work
that fills the queue (HDF5 reading, video decoding) releases the GIL, so it overlaps the
consumer's own work. :func:`interrupt_between_steps` is the one way a long run (augment,
normalize-dataset, train, track) takes a Ctrl-C.
"""

from __future__ import annotations

import contextlib
import queue
import threading
from collections.abc import Callable, Generator, Iterator
from typing import Any, TypeVar

__all__ = ["read_ahead", "interrupt_between_steps"]

T = TypeVar("T")

_END = object()


class _Failed:
    """An exception the producer raised, to raise again in the consumer."""

    def __init__(self, exc: BaseException):
        self.exc = exc


def read_ahead(
    make: Callable[[], Iterator[T]], depth: int, name: str = "gazeaug-read-ahead"
) -> Generator[T, None, None]:
    """The items of ``make()``, produced up to ``depth`` ahead by a background thread, in order.

    ``make`` is called in that thread; the iterator it returns is closed there when it ends, fails
    or is abandoned. An error of the producer is raised here. Closing this generator (or leaving a
    ``for`` loop over it) stops the producer at its next item or within 0.05 s, and waits for it.
    """
    q: queue.Queue[Any] = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()

    def put(item: Any) -> bool:
        """Queue an item unless the consumer has stopped (it then no longer takes any)."""
        while not stop.is_set():
            try:
                q.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        it: Iterator[T] | None = None
        try:
            it = make()
            for item in it:
                if not put(item):
                    return
            put(_END)
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer, raised there
            put(_Failed(exc))
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                close()

    worker = threading.Thread(target=work, name=name, daemon=True)
    worker.start()
    try:
        while True:
            item = q.get()
            if item is _END:
                return
            if isinstance(item, _Failed):
                raise item.exc
            yield item
    finally:
        stop.set()
        worker.join()


@contextlib.contextmanager
def interrupt_between_steps() -> Iterator[Callable[[], bool]]:
    """Turn a first Ctrl-C into a flag the run checks between steps (a second one interrupts at once).

    Python delivers SIGINT as a KeyboardInterrupt wherever the main thread is, and
    drops it when that is a garbage-collection callback ("Exception ignored ..."): the
    run would then go on as if nothing was pressed, or hang, when the callback held a
    lock a reading thread waits for (h5py's: a training run hung so, once in a few
    dozen Ctrl-Cs). Checked between steps, the interruption is never lost and always
    leaves a consistent state. Outside the main thread (or when a handler other than
    Python's default is set), nothing changes.
    """
    import signal

    pressed: list[bool] = []
    if threading.current_thread() is not threading.main_thread() or (
        signal.getsignal(signal.SIGINT) is not signal.default_int_handler
    ):
        yield lambda: False
        return

    def handler(signum: int, frame: Any) -> None:
        if pressed:
            raise KeyboardInterrupt
        pressed.append(True)

    signal.signal(signal.SIGINT, handler)
    try:
        yield lambda: bool(pressed)
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
