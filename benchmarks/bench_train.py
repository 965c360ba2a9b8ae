"""Training data path speed: samples per second reading, reading + augmenting, and training.

``python benchmarks/bench_train.py [--rows 20000] [--batch-sizes 256 1024] [--threads 2] [--face-patch W H]
[--no-cpu | --no-cuda]``
builds a synthetic training set (36 x 60 patches: a grey level that encodes the
gaze, a darker "iris" disc and pixel noise, gzip-compressed like the real sets;
the schema of ``gazeaug augment``; with ``--face-patch`` a face patch of that size
per row too, and the model is ``mobilenet_gaze(face=True)``) and, on the CPU (``--threads`` torch threads)
and on CUDA when there is one, for every batch size measures one pass over it:

- ``read``: the rows from HDF5 through :func:`gazeaug.train_data.prefetch_batches`
  (background thread, uint8 tensors; pinned and copied to the GPU on CUDA);
- ``read_augment``: the same plus :func:`gazeaug.train.train_inputs` (the
  training-time augmentation and the input scaling, on the device);
- ``file_1_thread``, ``file_threads``: the rows in use of the eye-patch columns straight from
  :meth:`gazeaug.io_h5.H5TrainingSet.batches`, h5py reading (1 thread) and the stored chunks
  inflated by :func:`gazeaug.io_h5.read_threads` threads (the default);
- ``load_resident``: rows per second of reading the whole set onto the device
  once (:class:`gazeaug.train_data.ResidentSet`);
- ``read_resident``, ``read_augment_resident``: the passes above with the
  batches gathered from the resident set (what training does when the set fits:
  ``preload="auto"``);
- ``train``, ``train_resident``: :func:`gazeaug.train.train`, the default model
  with the default settings (augmentation on), streamed (``preload="no"``) and
  resident (``preload="yes"``): the samples per second of the second epoch's log
  (the first holds the warm-up);
- ``train_no_augment_resident``: resident, ``TrainAugment(enabled=False)``.

Prints one JSON line: ``{"rows", "threads", "cpu": {BATCH: {what: samples/s}} or null,
"cuda": {...} or null, "cuda_device", "torch"}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gazeaug.io_h5 import H5TrainingSet, H5Writer, Rows, read_threads  # noqa: E402
from gazeaug.train import TrainSettings, train, train_inputs  # noqa: E402
from gazeaug.train_augment import TrainAugment, augment_generator  # noqa: E402
from gazeaug.train_data import ResidentSet, epoch_batches  # noqa: E402

_BLOCK = 2048


def synthetic(path: Path, n: int, seed: int = 0, face_size: tuple[int, int] | None = None) -> Path:
    """A schema-complete training set of ``n`` eye-like patches, written in blocks (bounded memory).

    With ``face_size`` (width, height) each row has a face patch too: the eye image resized, plus noise.
    """
    import cv2

    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:36, 0:60]
    norm: dict[str, Any] = {"distance_mm": 600.0, "focal_px": 650.0, "patch_size_wh": [60, 36], "antialias": True}
    if face_size is not None:
        norm.update(face_patch_size_wh=list(face_size), face_distance_mm=600.0, face_focal_px=960.0)
    w = H5Writer(path, {"settings": {"normalization": norm}}, (60, 36), face_patch_size_wh=face_size)
    for lo in range(0, n, _BLOCK):
        m = min(_BLOCK, n - lo)
        gaze = rng.uniform(-0.4, 0.4, (m, 2)).astype(np.float32)
        head = rng.uniform(-0.3, 0.3, (m, 2)).astype(np.float32)
        level = (150 + 150 * gaze[:, 0]).astype(np.float32)
        cx, cy = 30 + 40 * gaze[:, 1], 18 + 20 * gaze[:, 0]
        iris = (xx[None] - cx[:, None, None]) ** 2 + (yy[None] - cy[:, None, None]) ** 2 < 36
        img = level[:, None, None] - 90 * iris + rng.normal(0, 3, (m, 36, 60)).astype(np.float32)
        eyes = np.repeat(img[..., None], 3, axis=3).clip(0, 255).astype(np.uint8)
        eye3 = np.tile(np.eye(3, dtype=np.float32), (m, 1, 1))
        cols = {
            "left_eye": eyes,
            "right_eye": eyes[:, :, ::-1],
            "head_pose": head,
            "gaze": gaze,
            "head_pose_vector": np.zeros((m, 3)),
            "gaze_vector": np.zeros((m, 3)),
            "head_pose_left": head,
            "head_pose_right": head,
            "gaze_left": gaze,
            "gaze_right": gaze,
            "R_norm_left": eye3,
            "R_norm_right": eye3,
            "R_norm_face": eye3,
            "subject": np.array([f"s{i % 10}".encode() for i in range(lo, lo + m)]),
            "source_index": np.arange(lo, lo + m),
            "sampled_yaw_pitch": np.full((m, 2), np.nan),
        }
        if face_size is not None:
            big = np.stack([cv2.resize(e, face_size) for e in eyes]).astype(np.int16)
            cols["face"] = (big + rng.integers(-3, 4, big.shape)).clip(0, 255).astype(np.uint8)
        w.append(Rows(cols), lo + m - 1)
    w.finish()
    return path


def _pass(h5: Path, batch_size: int, device: Any, augment: bool, resident: ResidentSet | None = None) -> float:
    """Samples per second of one pass: reading (and augmenting) every row onto ``device``.

    From ``resident`` when given (the batches gathered on the device), else streamed from ``h5``.
    """
    import torch

    data = H5TrainingSet(h5)
    face = data.face_patch_size_wh is not None
    cuda = device.type == "cuda"
    gen = augment_generator(0, 0, device)
    aug = TrainAugment()
    seen = 0
    t0 = time.perf_counter()
    for tensors in epoch_batches(data, resident, batch_size, np.random.default_rng(0), pin=cuda, face=face):
        if augment:
            train_inputs(tensors, device, aug, "rgb", gen)
        else:
            for k in ("eyes", "face") if face else ("eyes",):
                tensors[k].to(device, non_blocking=True)
        seen += len(tensors["gaze"])
    if cuda:
        torch.cuda.synchronize()
    return round(seen / (time.perf_counter() - t0), 1)


def measure(h5: Path, tmp: Path, batch_size: int, device_name: str, face: bool = False) -> dict[str, float]:
    """Every figure for one device and batch size (``face``: the model reads the face patch too)."""
    import torch

    device = torch.device(device_name)
    out = {"read": _pass(h5, batch_size, device, False), "read_augment": _pass(h5, batch_size, device, True)}
    data = H5TrainingSet(h5)
    for what, threads in (("file_1_thread", 1), ("file_threads", None)):
        t0 = time.perf_counter()
        for _ in data.batches(batch_size, np.random.default_rng(0), H5TrainingSet.batch_keys(face), threads=threads):
            pass
        out[what] = round(len(data) / (time.perf_counter() - t0), 1)
    t0 = time.perf_counter()
    resident = ResidentSet(data, device, face)
    if device.type == "cuda":
        torch.cuda.synchronize()
    out["load_resident"] = round(len(data) / (time.perf_counter() - t0), 1)
    out["read_resident"] = _pass(h5, batch_size, device, False, resident)
    out["read_augment_resident"] = _pass(h5, batch_size, device, True, resident)
    del resident
    runs = (
        ("train", TrainAugment(), "no"),
        ("train_resident", TrainAugment(), "yes"),
        ("train_no_augment_resident", TrainAugment(enabled=False), "yes"),
    )
    for what, aug, preload in runs:
        s = TrainSettings(
            epochs=2,
            batch_size=batch_size,
            device=device_name,
            augment=aug,
            model_options={"face": True} if face else {},
        )
        log = train(h5, tmp / f"m_{device_name}_{batch_size}_{what}.pt", s, progress=False, preload=preload)
        out[what] = log[-1]["samples_per_second"]
    return out


def main(argv: list[str] | None = None) -> None:
    """Build the set, measure, print one JSON line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rows", type=int, default=20000)
    p.add_argument("--batch-sizes", type=int, nargs="+", default=[256, 1024])
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    p.add_argument("--no-cuda", action="store_true", help="CPU only, even with a GPU")
    p.add_argument("--no-cpu", action="store_true", help="CUDA only (where there is a GPU); the CPU figures are null")
    p.add_argument(
        "--face-patch", type=int, nargs=2, default=None, metavar=("W", "H"), help="face patches too, and a face model"
    )
    args = p.parse_args(argv)
    face = None if args.face_patch is None else (args.face_patch[0], args.face_patch[1])
    warnings.simplefilter("ignore")
    import torch

    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        h5 = synthetic(Path(tmp) / "bench.h5", args.rows, face_size=face)
        cpu = None
        if not args.no_cpu:
            cpu = {str(b): measure(h5, Path(tmp), b, "cpu", face is not None) for b in args.batch_sizes}
        cuda = None
        if torch.cuda.is_available() and not args.no_cuda:
            cuda = {str(b): measure(h5, Path(tmp), b, "cuda", face is not None) for b in args.batch_sizes}
        result = {
            "rows": args.rows,
            "read_threads": read_threads(),
            "face_patch_wh": face,
            "threads": torch.get_num_threads(),
            "cpu": cpu,
            "cuda": cuda,
            "cuda_device": torch.cuda.get_device_name(0) if cuda is not None else None,
            "torch": torch.__version__,
        }
        print(json.dumps(result))


if __name__ == "__main__":
    main()
