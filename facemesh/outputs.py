"""Output paths: checked before the work starts, locked while a run writes them, created with the user's umask.

Every command that writes checks each of its outputs first (:func:`check_output_file`,
:func:`check_output_folder`, :func:`check_picture_path`), so a read-only folder, a folder
where a file is expected, a parent path that is a file or an unknown extension is
refused in one line *before* any work is done, and nothing already there is touched.

Runs that write over minutes (``augment``, ``normalize-dataset``, ``train``, ``simulate``)
hold :func:`output_lock` for their whole duration: a second run on the same output is
told "another run is writing it" instead of taking the first run's in-progress file for
an interrupted one.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path

from .types import FaceMeshError

__all__ = [
    "OutputError",
    "OutputBusyError",
    "OutputExistsError",
    "check_output_file",
    "check_output_folder",
    "check_picture_path",
    "output_lock",
    "staged_folder",
    "lock_path",
    "umask_mode",
    "PICTURE_SUFFIXES",
]

#: Picture extensions every OpenCV build writes (checked against the installed build too).
PICTURE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


class OutputError(FaceMeshError):
    """An output path cannot be written: read-only folder, folder or file in the way, unknown extension."""


class OutputExistsError(OutputError):
    """A complete output is already there and would be replaced (``remedy="overwrite"``)."""


class OutputBusyError(OutputError):
    """Another run holds the lock of this output: it is writing it now."""


_UMASK_LOCK = threading.Lock()


def umask_mode(mode: int = 0o666) -> int:
    """``mode`` less the process's umask: the permissions a plain ``open(path, "w")`` would give."""
    with _UMASK_LOCK:  # os.umask can only be read by setting it
        mask = os.umask(0o22)
        os.umask(mask)
    return mode & ~mask


def _first_existing(path: Path) -> Path:
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _check_parent(path: Path, what: str) -> None:
    """The folder ``path`` goes into exists or can be created, and files can be made in it."""
    parent = path.parent
    base = _first_existing(parent)
    if not base.is_dir():
        raise OutputError(f"{path}: cannot write the {what}: {base} is a file, not a folder")
    try:  # a real probe: os.access says yes to root on read-only mounts and no to ACL-granted users
        with tempfile.TemporaryFile(dir=str(base)):
            pass
    except OSError as exc:
        # other errors (ENOENT from /proc, ENOSPC, EIO) say nothing of the folder by themselves: name it the problem
        reason = (
            "the folder is read-only"
            if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS)
            else f"files cannot be created there ({exc.strerror or exc})"
        )
        raise OutputError(f"{path}: cannot write the {what}: {base}: {reason}") from exc


def check_output_file(
    path: str | os.PathLike[str], suffixes: Iterable[str] | None = None, *, what: str = "output", exists_ok: bool = True
) -> Path:
    """Check that ``path`` can be written as a file, before any work is done.

    Args:
        path: the file to write.
        suffixes: accepted extensions (lower case, with the dot); None accepts any.
        what: what the file is, for messages (``"model"``, ``"preview picture"``).
        exists_ok: False refuses an existing file (it would be replaced).

    Returns:
        ``path`` as a Path.

    Raises:
        OutputError: wrong extension, ``path`` is a folder, exists (with ``exists_ok=False``),
            its parent is a file, or its folder is not writable.
    """
    p = Path(path)
    allowed = tuple(suffixes) if suffixes is not None else None
    if allowed is not None and p.suffix.lower() not in allowed:
        raise OutputError(f"{p}: the {what} must end in {' or '.join(allowed)}, got {p.suffix or 'no extension'!r}")
    if p.is_dir():
        raise OutputError(f"{p}: is a folder; the {what} must be a file path")
    if p.exists() and not exists_ok:
        raise OutputError(f"{p}: exists; choose another path or remove it")
    _check_parent(p, what)
    return p


def check_output_folder(path: str | os.PathLike[str], *, what: str = "output folder") -> Path:
    """Check that ``path`` can be a folder of outputs (created if missing), before any work is done.

    Raises:
        OutputError: ``path`` is a file, or neither it nor the folder it goes into is writable.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputError(f"{p}: is a file; the {what} must be a folder")
    if p.is_dir():
        _check_parent(p / "probe", what)
    else:
        _check_parent(p, what)
    return p


def check_picture_path(path: str | os.PathLike[str], *, what: str = "picture") -> Path:
    """:func:`check_output_file` for pictures: an extension the installed OpenCV can encode.

    Raises:
        OutputError: unknown picture extension, or the path is not writable.
    """
    import cv2

    p = Path(path)
    ok = p.suffix.lower() in PICTURE_SUFFIXES and bool(cv2.haveImageWriter("x" + p.suffix.lower()))
    if not ok:
        known = ", ".join(s for s in PICTURE_SUFFIXES if cv2.haveImageWriter("x" + s))
        raise OutputError(f"{p}: unknown picture extension {p.suffix or '(none)'!r}; use one of {known}")
    return check_output_file(p, None, what=what)


def lock_path(path: str | os.PathLike[str]) -> Path:
    """The lock file of an output: ``OUT.lock`` beside it (``OUT.h5`` -> ``OUT.h5.lock``)."""
    p = Path(path)
    return p.with_name(p.name + ".lock")


@contextlib.contextmanager
def output_lock(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Hold an exclusive lock on ``path``'s lock file for the block (POSIX ``flock``).

    The lock is released by the kernel when the process dies, so a killed run never
    leaves a stale lock: a ``.part`` file without a live lock holder is an interrupted
    run, one with a holder is a run in progress. The lock file is removed on exit.

    Raises:
        OutputBusyError: another process holds the lock (names its pid when known).
    """
    import fcntl

    lp = lock_path(path)
    lp.parent.mkdir(parents=True, exist_ok=True)
    while True:
        fd = os.open(str(lp), os.O_RDWR | os.O_CREAT, umask_mode())
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            pid = ""
            with contextlib.suppress(OSError, ValueError):
                pid = f" (pid {int(lp.read_text().strip())})"
            raise OutputBusyError(f"{path}: another run is writing it now{pid}; wait for it to end or stop it") from exc
        # the previous holder may have removed the file between our open and our lock: retry on the new one
        try:
            same = os.fstat(fd).st_ino == os.stat(lp).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield lp
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lp)
        os.close(fd)


@contextlib.contextmanager
def staged_folder(
    path: str | os.PathLike[str], *, overwrite: bool = False, marker: str | None = None
) -> Iterator[Path]:
    """Write a folder of outputs beside its place (``OUT.part/``) and swap it in only when the block succeeds.

    The lock of ``path`` (:func:`output_lock`) is held throughout. On any exception
    (Ctrl-C included) the ``.part`` folder is removed and ``path`` is untouched; a
    ``.part`` folder left by a killed run is removed first.

    Args:
        path: the folder to create or replace.
        overwrite: replace a non-empty ``path`` (otherwise :class:`OutputExistsError`).
        marker: a file that must be in a non-empty ``path`` for it to be replaced (so that
            ``overwrite`` never deletes a folder this program did not write).

    Yields:
        The ``.part`` folder to write into.

    Raises:
        OutputError: ``path`` is a file, is not empty (without ``overwrite``) or lacks ``marker``.
        OutputBusyError: another run is writing ``path``.
    """
    p = Path(path)
    if not p.name:  # "" or ".": staged beside itself under its real name
        p = p.resolve()
    check_output_folder(p)
    with output_lock(p):
        if p.is_dir() and any(p.iterdir()):
            if not overwrite:
                raise OutputExistsError(f"{p}: the folder exists and is not empty", remedy="overwrite")
            if marker is not None and not (p / marker).is_file():
                raise OutputError(f"{p}: not a folder this command wrote (no {marker}); refusing to replace it")
        part = p.with_name(p.name + ".part")
        if part.exists():
            shutil.rmtree(part)
        part.mkdir(parents=True)
        try:
            yield part
        except BaseException:
            shutil.rmtree(part, ignore_errors=True)
            raise
        old = None
        if p.exists():
            old = p.with_name(f".{p.name}.replaced-{os.getpid()}")
            os.replace(p, old)
        os.replace(part, p)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
