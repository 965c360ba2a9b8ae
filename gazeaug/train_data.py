"""The training data path: from an HDF5 training set to the model's inputs on the training device.

Two sources give the same batches in the same order (:meth:`gazeaug.io_h5.H5TrainingSet.order`),
so a run's model does not depend on which one fed it:

- **resident** (:class:`ResidentSet`): the rows in use are read once and held on the training
  device, uint8 patches and float32 labels; a batch is one gather there. No reading,
  decompression or host-to-device copy per step: the data path of a GPU, where a background
  thread's HDF5 gzip decompression (about 20,000 rows/s, one core) would otherwise starve it.
- **streamed** (:func:`prefetch_batches`): a background thread reads the next batches from the
  file; memory stays bounded whatever the file's size.

``train(..., preload="auto")`` (:func:`should_preload`) holds a set resident when it fits in
:data:`PRELOAD_SHARE` of the memory free on the device (and, on the host, at most
:data:`PRELOAD_MAX_HOST_BYTES`), and streams it otherwise. :func:`train_inputs` then mirrors,
augments and scales a batch on the device, whichever fed it.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Generator, Iterator
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from .errors import GazeAugError
from .io_h5 import H5TrainingSet
from .models import import_torch
from .models.preprocess import scale_eyes
from .train_augment import TrainAugment, augment_eyes, augment_eyes_and_points, jitter_head_pose, mirror_samples

__all__ = [
    "PRELOAD_CHOICES",
    "PRELOAD_SHARE",
    "PRELOAD_MAX_HOST_BYTES",
    "ResidentSet",
    "ResidentSetTooLarge",
    "hold_rows",
    "epoch_batches",
    "placeholder_batch",
    "memory_available",
    "resident_bytes",
    "byte_size",
    "check_preload",
    "should_preload",
    "prefetch_batches",
    "train_inputs",
    "TrainInputs",
]

#: ``preload``: ``auto`` (resident when it fits, :func:`should_preload`), ``yes`` (resident, whatever
#: its size), ``no`` (streamed).
PRELOAD_CHOICES = ("auto", "yes", "no")
#: ``auto`` holds a set resident when it takes at most this share of the memory free on the device.
PRELOAD_SHARE = 0.5
#: ... and, in host memory, at most this many bytes (16 GiB: 1.2 million rows of two 60 x 36 eyes).
PRELOAD_MAX_HOST_BYTES = 16 << 30
#: Batches read ahead by the background thread of the streamed path.
PREFETCH = 3
#: Rows read at once while loading a resident set (file order).
_LOAD_ROWS = 4096


def byte_size(n: int) -> str:
    """``n`` bytes in words: ``"512 bytes"``, ``"3.4 MiB"``, ``"1.5 GiB"`` (the largest unit under which it is >= 1)."""
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{int(n)} bytes"


def resident_bytes(data: H5TrainingSet, face: bool, keypoints: bool = False) -> int:
    """Bytes a :class:`ResidentSet` of ``data`` takes.

    Per row: two eye patches (uint8), the face patch when ``face`` and the set has one, head pose
    and gaze (float32 (2,) each), the eye keypoints (float32 (2, 2, 2)) with ``keypoints``, and
    an int64 index.
    """
    w, h = data.patch_size_wh
    per_row = 2 * w * h * 3 + 2 * 2 * 4 + 8 + (2 * 2 * 2 * 4 if keypoints else 0)
    if face and data.face_patch_size_wh is not None:
        fw, fh = data.face_patch_size_wh
        per_row += fw * fh * 3
    return len(data) * per_row


def memory_available(device: Any) -> int | None:
    """Bytes free on ``device`` (a ``torch.device``); None when unknown.

    CUDA's free memory (with what PyTorch's caching allocator holds unused), or the host's
    available memory (``MemAvailable`` of ``/proc/meminfo``; elsewhere the free physical pages).
    """
    torch = import_torch()
    if device.type == "cuda":  # what PyTorch's caching allocator holds unused is free to it too
        free, _ = torch.cuda.mem_get_info(device)
        return int(free) + int(torch.cuda.memory_reserved(device)) - int(torch.cuda.memory_allocated(device))
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    with contextlib.suppress(AttributeError, OSError, ValueError):
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    return None


def check_preload(preload: Any) -> None:
    """Raise :class:`GazeAugError` unless ``preload`` is one of :data:`PRELOAD_CHOICES`."""
    if preload not in PRELOAD_CHOICES:
        raise GazeAugError(f"preload: expected one of {', '.join(PRELOAD_CHOICES)}, got {preload!r}")


def should_preload(preload: str, data: H5TrainingSet, face: bool, device: Any, keypoints: bool = False) -> bool:
    """Whether training holds ``data`` resident on ``device`` (:data:`PRELOAD_CHOICES`).

    ``auto``: when :func:`resident_bytes` is at most :data:`PRELOAD_SHARE` of
    :func:`memory_available` (unknown: not resident) and, on the host, at most
    :data:`PRELOAD_MAX_HOST_BYTES`.

    Raises:
        GazeAugError: ``preload`` is not one of :data:`PRELOAD_CHOICES`.
    """
    check_preload(preload)
    if preload != "auto":
        return preload == "yes"
    need = resident_bytes(data, face, keypoints)
    free = memory_available(device)
    if free is None or need > PRELOAD_SHARE * free:
        return False
    return device.type == "cuda" or need <= PRELOAD_MAX_HOST_BYTES


class ResidentSetTooLarge(GazeAugError):
    """The device cannot hold a training set's rows (:class:`ResidentSet`); ``remedy="stream"``: ``preload="no"``."""


def hold_rows(
    data: H5TrainingSet, device: Any, face: bool, preload: str, keypoints: bool = False
) -> ResidentSet | None:
    """The :class:`ResidentSet` training uses, or None to stream (:func:`should_preload`).

    ``auto`` streams, with a warning, a set whose allocation fails although it looked as if it
    fitted; ``yes`` raises :class:`ResidentSetTooLarge` then.
    """
    if not should_preload(preload, data, face, device, keypoints):
        return None
    try:
        return ResidentSet(data, device, face, keypoints)
    except ResidentSetTooLarge as exc:
        if preload == "yes":
            raise
        import warnings

        warnings.warn(f"{exc}: streaming them from the file instead", RuntimeWarning, stacklevel=2)
        return None


class ResidentSet:
    """The rows in use of a training set, held as tensors on the training device (read once).

    Args:
        data: the training set.
        device: the ``torch.device`` to hold the rows on.
        face: hold the face patches too (a model that reads them).
        keypoints: hold the eye keypoints too (a training with a keypoint loss).

    Attributes:
        data: the training set.
        face: whether the face patches are held.
        left, right: uint8 (K, H, W, 3) RGB eye patches, the rows in use in file order.
        head_pose, gaze: float32 (K, 2) radians (pitch, yaw), face-centre normalized frame.
        face_patches: uint8 (K, Hf, Wf, 3) RGB, or None.
        eye_keypoints: float32 (K, 2, 2, 2) px (the schema's ``eye_keypoints``), or None.

    Raises:
        ResidentSetTooLarge: the device cannot hold the rows (the message gives their size): on
            the host, more than the memory available (an allocation there succeeds whatever its
            size and fails page by page as it is filled); on a GPU, when allocating them fails.
    """

    def __init__(self, data: H5TrainingSet, device: Any, face: bool = False, keypoints: bool = False):
        torch = import_torch()
        self.data = data
        self.face = bool(face and data.face_patch_size_wh is not None)
        self._device = device
        w, h = data.patch_size_wh
        k = len(data)
        need = resident_bytes(data, self.face, keypoints)
        too_large = ResidentSetTooLarge(
            f"{data.path}: its {k} rows ({byte_size(need)}) do not fit on {device}", remedy="stream"
        )
        if device.type != "cuda":
            free = memory_available(device)
            if free is not None and need > free:
                raise too_large
        try:
            self.left = torch.empty((k, h, w, 3), dtype=torch.uint8, device=device)
            self.right = torch.empty((k, h, w, 3), dtype=torch.uint8, device=device)
            self.face_patches = None
            if self.face:
                fw, fh = data.face_patch_size_wh  # type: ignore[misc]
                self.face_patches = torch.empty((k, fh, fw, 3), dtype=torch.uint8, device=device)
        except (RuntimeError, MemoryError) as exc:  # torch.cuda.OutOfMemoryError is a RuntimeError
            raise too_large from exc
        keys = H5TrainingSet.batch_keys(self.face)
        lo = 0
        with contextlib.closing(data.batches(_LOAD_ROWS, None, keys)) as it:  # type: ignore[type-var]
            for batch in it:  # file order: row lo + i of the rows in use
                n = len(batch["gaze"])
                self.left[lo : lo + n].copy_(torch.from_numpy(np.ascontiguousarray(batch["left_eye"])))
                self.right[lo : lo + n].copy_(torch.from_numpy(np.ascontiguousarray(batch["right_eye"])))
                if self.face_patches is not None:
                    self.face_patches[lo : lo + n].copy_(torch.from_numpy(np.ascontiguousarray(batch["face"])))
                lo += n
        self.head_pose = torch.from_numpy(np.ascontiguousarray(data.head_pose, dtype=np.float32)).to(device)
        self.gaze = torch.from_numpy(np.ascontiguousarray(data.gaze, dtype=np.float32)).to(device)
        self.eye_keypoints = torch.from_numpy(data.eye_keypoints()).to(device) if keypoints else None

    def __len__(self) -> int:
        return len(self.data)

    def positions(self, rng: np.random.Generator | None) -> NDArray[np.int64]:
        """(K,) int64: the resident rows in the order :meth:`H5TrainingSet.batches` gives ``rng``."""
        order = self.data.order(rng, face=self.face)  # file rows
        return np.searchsorted(self.data.rows, order).astype(np.int64)

    def batches(self, batch_size: int, rng: np.random.Generator | None) -> Generator[dict[str, Any], None, None]:
        """The batches of :func:`prefetch_batches` (its ``tensors``), gathered on the device.

        Yields:
            ``eyes`` uint8 (2B, H, W, 3), the left eyes then the right eyes, RGB; ``head_pose`` and
            ``gaze`` float32 (B, 2) radians (pitch, yaw); ``face`` uint8 (B, Hf, Wf, 3) RGB when
            held; ``eye_keypoints`` float32 (B, 2, 2, 2) px when held. B rows (the last batch may
            have fewer), all on the device.
        """
        torch = import_torch()
        index = torch.from_numpy(self.positions(rng)).to(self._device)
        for lo in range(0, len(index), batch_size):
            i = index[lo : lo + batch_size]
            out = {
                "eyes": torch.cat([self.left.index_select(0, i), self.right.index_select(0, i)]),
                "head_pose": self.head_pose.index_select(0, i),
                "gaze": self.gaze.index_select(0, i),
            }
            if self.face_patches is not None:
                out["face"] = self.face_patches.index_select(0, i)
            if self.eye_keypoints is not None:
                out["eye_keypoints"] = self.eye_keypoints.index_select(0, i)
            yield out


def prefetch_batches(
    data: H5TrainingSet,
    batch_size: int,
    rng: np.random.Generator | None,
    *,
    depth: int = PREFETCH,
    pin: bool = False,
    face: bool = False,
    keypoints: bool = False,
) -> Generator[tuple[dict[str, NDArray[Any]], dict[str, Any]], None, None]:
    """:meth:`H5TrainingSet.batches`, read ``depth`` batches ahead by a background thread.

    The order is exactly that of ``data.batches(batch_size, rng)`` (one thread draws from ``rng``),
    so training stays deterministic. Close the iterator (``contextlib.closing``) to stop the thread
    early; an error of the reading thread is raised here. ``depth`` 0: no thread, the batches are
    read when asked for (the same batches).

    Yields:
        ``(batch, tensors)``: ``batch`` as :meth:`H5TrainingSet.batches` yields it (numpy, B rows);
        ``tensors`` the CPU torch tensors the training moves to its device: ``eyes`` uint8
        (2B, H, W, 3), the left eyes then the right eyes, RGB; ``head_pose`` and ``gaze`` float32
        (B, 2) radians (pitch, yaw); with ``face``, ``face`` uint8 (B, Hf, Wf, 3) RGB as well (the
        batch then holds it too); with ``keypoints``, ``eye_keypoints`` float32 (B, 2, 2, 2) px. In
        pinned memory with ``pin`` (for CUDA's asynchronous copies).
    """
    torch = import_torch()

    def tensor(a: NDArray[Any]) -> Any:
        t = torch.from_numpy(np.ascontiguousarray(a))
        return t.pin_memory() if pin else t

    def tensors(batch: dict[str, NDArray[Any]]) -> dict[str, Any]:
        out = {
            "eyes": tensor(np.concatenate([batch["left_eye"], batch["right_eye"]])),
            "head_pose": tensor(batch["head_pose"].astype(np.float32, copy=False)),
            "gaze": tensor(batch["gaze"].astype(np.float32, copy=False)),
        }
        if face:
            out["face"] = tensor(batch["face"])
        if keypoints:
            out["eye_keypoints"] = tensor(batch["eye_keypoints"].astype(np.float32, copy=False))
        return out

    keys = H5TrainingSet.batch_keys(face, keypoints)
    if depth <= 0:
        with contextlib.closing(data.batches(batch_size, rng, keys)) as it:  # type: ignore[type-var]
            for batch in it:
                yield batch, tensors(batch)
        return
    from .background import read_ahead

    def produce() -> Iterator[tuple[dict[str, NDArray[Any]], dict[str, Any]]]:
        with contextlib.closing(data.batches(batch_size, rng, keys)) as it:  # type: ignore[type-var]
            for batch in it:
                yield batch, tensors(batch)

    yield from read_ahead(produce, depth, "gazeaug-prefetch")


def epoch_batches(
    data: H5TrainingSet,
    resident: ResidentSet | None,
    batch_size: int,
    rng: np.random.Generator,
    *,
    pin: bool = False,
    face: bool = False,
    keypoints: bool = False,
) -> Generator[dict[str, Any], None, None]:
    """One epoch's batches as tensors (those of :meth:`ResidentSet.batches`).

    From ``resident`` when given, else streamed from ``data`` (:func:`prefetch_batches`): the same
    batches either way. Close it to stop early (the streamed path's thread ends).
    """
    if resident is not None:
        yield from resident.batches(batch_size, rng)
        return
    with contextlib.closing(prefetch_batches(data, batch_size, rng, pin=pin, face=face, keypoints=keypoints)) as it:
        for _, tensors in it:
            yield tensors


def placeholder_batch(data: H5TrainingSet, batch_size: int, *, face: bool = False) -> dict[str, Any]:
    """A full batch of zeros shaped as :func:`epoch_batches` gives ``data``'s (no row is read).

    What a CUDA graph capture needs before an epoch starts (:func:`gazeaug.train_graphs.graph_model`
    copies only shapes, dtypes and layouts; the values merely warm it up): capturing then, rather
    than at the epoch's first batch, keeps the capture clear of the streamed path's reading thread,
    whose pinned-memory allocations are CUDA calls a capture in progress may refuse.

    Returns:
        ``{"eyes": uint8 (2B, H, W, 3), "head_pose": float32 (B, 2), "gaze": float32 (B, 2)}`` on
        the CPU, contiguous, and with ``face`` ``"face": uint8 (B, Hf, Wf, 3)``; B = ``batch_size``,
        (W, H) = ``data.patch_size_wh``, (Wf, Hf) = ``data.face_patch_size_wh``.

    Raises:
        GazeAugError: ``face`` asked of a set without face patches.
    """
    torch = import_torch()
    w, h = data.patch_size_wh
    out = {
        "eyes": torch.zeros((2 * batch_size, h, w, 3), dtype=torch.uint8),
        "head_pose": torch.zeros((batch_size, 2), dtype=torch.float32),
        "gaze": torch.zeros((batch_size, 2), dtype=torch.float32),
    }
    if face:
        if data.face_patch_size_wh is None:
            raise GazeAugError(f"{data.path}: expected face patches for a face model's batch, the set has none")
        fw, fh = data.face_patch_size_wh
        out["face"] = torch.zeros((batch_size, fh, fw, 3), dtype=torch.uint8)
    return out


class TrainInputs(NamedTuple):
    """A batch ready for the model (:func:`train_inputs`), on the training device.

    Attributes:
        left, right: float32 (B, 3, H, W) in [-1, 1].
        head_pose, gaze: float32 (B, 2) radians (pitch, yaw), face-centre normalized frame.
        face: float32 (B, 3, Hf, Wf) in [-1, 1], or None.
        eye_keypoints: float32 (B, 2, 2, 2) px, moved with the patches (mirror, zoom, translation),
            NaN where unknown; None when the batch has none.
    """

    left: Any
    right: Any
    head_pose: Any
    gaze: Any
    face: Any
    eye_keypoints: Any

    @property
    def model_args(self) -> tuple[Any, ...]:
        """The model's inputs: ``(left, right, head_pose)``, and ``face`` when the batch has one."""
        return (
            (self.left, self.right, self.head_pose)
            if self.face is None
            else (self.left, self.right, self.head_pose, self.face)
        )


def train_inputs(
    tensors: dict[str, Any], device: Any, augment: TrainAugment, input_mode: str, generator: Any
) -> TrainInputs:
    """A batch (:func:`epoch_batches`) -> the model's inputs and target, on ``device``.

    The eye patches travel as uint8 (asynchronously from pinned memory; a resident batch is on the
    device already); a share of the samples is mirrored (:func:`gazeaug.train_augment.mirror_samples`:
    patches swapped and flipped, the yaws of the head pose and gaze negated, so the labels returned
    are the ones the model is given), the patches augmented
    (:func:`gazeaug.train_augment.augment_eyes`, with ``generator`` on ``device``), then converted by
    the model's input mode (:func:`gazeaug.models.preprocess.scale_eyes`) on the device, and the
    head pose jittered (:func:`gazeaug.train_augment.jitter_head_pose`; off by default).

    Returns:
        :class:`TrainInputs`: the face patches (when the batch has them) augmented after the eyes,
        with draws of their own; the eye keypoints (when the batch has them) moved as their patches.
    """
    torch = import_torch()
    eyes = tensors["eyes"].to(device, non_blocking=True)
    head = tensors["head_pose"].to(device, non_blocking=True)
    gaze = tensors["gaze"].to(device, non_blocking=True)
    face = tensors["face"].to(device, non_blocking=True) if "face" in tensors else None
    points = tensors["eye_keypoints"].to(device, non_blocking=True) if "eye_keypoints" in tensors else None
    with torch.no_grad():
        eyes, head, gaze, face, points = mirror_samples(
            eyes, head, gaze, augment, generator, face=face, keypoints=points
        )
        flat = None if points is None else torch.cat([points[:, 0], points[:, 1]])  # as the eyes: lefts, rights
        x, flat = augment_eyes_and_points(eyes, flat, augment, generator)
        x = scale_eyes(x, input_mode)
        if face is not None:
            face = scale_eyes(augment_eyes(face, augment, generator), input_mode)
        head = jitter_head_pose(head, augment, generator)  # last: nothing drawn when off
    n = x.shape[0] // 2
    if flat is not None:
        points = torch.stack([flat[:n], flat[n:]], dim=1)
    return TrainInputs(x[:n], x[n:], head, gaze, face, points)
