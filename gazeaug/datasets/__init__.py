"""Gaze dataset readers behind one sample schema (:class:`~gazeaug.datasets.base.GazeSample`).

``open_dataset(path, format=None)`` picks the reader; formats, in the order
:func:`detect_format` tries them:

``folder``
    your own data: images plus ``labels.csv`` or ``labels.jsonl`` (:mod:`gazeaug.datasets.folder`).
``gazecapture``
    GazeCapture with FAZE's supplementary HDF5 (intrinsics, distortion, head pose, 3D gaze targets).
``ethxgaze``
    the raw ETH-XGaze release (per-subject annotation CSVs + per-camera XML calibrations); its
    training split (the test split has no gaze labels and is refused with that reason).
``ethxgaze_normalized``
    ETH-XGaze's normalized ``subjectXXXX.h5`` release (face patches as images of the normalized camera).
``utmultiview``
    UT Multiview's raw part (8 cameras per capture, a reconstructed face mesh per capture;
    :mod:`gazeaug.datasets.utmultiview`).
``mpiifacegaze``
    the raw MPIIFaceGaze release (``pXX/pXX.txt`` + ``pXX/Calibration/Camera.mat``).

Readers are registered by name in :data:`DATASETS` (a
:class:`gazeaug.registry.Registry`, the style models and renderers share) with
``register_dataset(name, target, detect=...)``: ``target`` is the reader class
(or ``"package.module:Class"``, imported when first opened), ``detect(path) ->
bool`` tells its layout; detectors run in registration order and the first
that answers True names the format.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..registry import Registry, Target, resolve
from .base import DatasetError, DatasetReader, GazeSample

__all__ = [
    "DATASETS",
    "register_dataset",
    "open_dataset",
    "detect_format",
    "DatasetError",
    "DatasetReader",
    "GazeSample",
]

#: format name -> reader class (``DatasetReader``, constructed with the dataset's root folder), in detection order.
DATASETS = Registry("format", DatasetError)


def register_dataset(
    name: str, target: Target | None = None, *, detect: Callable[[Path], bool] | str | None = None
) -> Any:
    """Make a dataset reader available to :func:`open_dataset` under ``name``.

    Use as a decorator on the reader class, or give ``target``: the class (or a factory of a
    root folder) or ``"package.module:Class"``, imported when first opened.

    Args:
        name: the format's name.
        target: see above.
        detect: ``detect(root: Path) -> bool``, True when a folder has this format's layout (or
            ``"package.module:function"``); :func:`detect_format` tries the detectors in
            registration order. None: the format is not auto-detected (or, registering a name
            again, keeps its detector).
    """
    return DATASETS.register(name, target, **({} if detect is None else {"detect": detect}))


def _has_label_file(p: Path) -> bool:
    from .folder import LABEL_FILES

    return any((p / n).is_file() for n in LABEL_FILES)


def _has_gazecapture_supplementary(p: Path) -> bool:
    from .gazecapture import SUPPLEMENTARY_NAME

    return (p / SUPPLEMENTARY_NAME).is_file()


def _has_ethxgaze_annotations(p: Path) -> bool:
    # a test split alone is ETH-XGaze too: its reader says why it is refused
    return (p / "data" / "annotation_train").is_dir() or (p / "data" / "annotation_test").is_dir()


def _has_mpii_subject_files(p: Path) -> bool:
    return any(d.is_dir() and (d / f"{d.name}.txt").is_file() for d in p.iterdir())


# The order is the detection order: from the most specific layout to the loosest (pXX/pXX.txt).
register_dataset("folder", "gazeaug.datasets.folder:FolderDataset", detect=_has_label_file)
register_dataset("gazecapture", "gazeaug.datasets.gazecapture:GazeCapture", detect=_has_gazecapture_supplementary)
register_dataset("ethxgaze", "gazeaug.datasets.ethxgaze:ETHXGaze", detect=_has_ethxgaze_annotations)
register_dataset(
    "ethxgaze_normalized",
    "gazeaug.datasets.ethxgaze_normalized:ETHXGazeNormalized",
    detect="gazeaug.datasets.ethxgaze_normalized:looks_like_ethxgaze_normalized",
)
register_dataset(
    "utmultiview",
    "gazeaug.datasets.utmultiview:UTMultiview",
    detect="gazeaug.datasets.utmultiview:looks_like_utmultiview",
)
register_dataset("mpiifacegaze", "gazeaug.datasets.mpiifacegaze:MPIIFaceGaze", detect=_has_mpii_subject_files)


def detect_format(path: str | Path) -> str:
    """Guess a dataset folder's format from its layout (the registered detectors, in order).

    Raises:
        DatasetError: not a folder, or no known layout (``remedy="format"``: name the format).
    """
    from .folder import LABEL_FILES
    from .gazecapture import SUPPLEMENTARY_NAME

    p = Path(path)
    if not p.is_dir():
        raise DatasetError(f"{p}: not a folder (give the dataset's root folder)")
    for name in DATASETS:
        detect = DATASETS.options(name).get("detect")
        if detect is not None and resolve(detect)(p):
            return name
    raise DatasetError(
        f"{p}: cannot tell the dataset format (no {' / '.join(LABEL_FILES)}, no pXX/pXX.txt, "
        f"no {SUPPLEMENTARY_NAME}, no data/annotation_train/, no sNN/raw/gazedata.csv)",
        remedy="format",
    )


def open_dataset(path: str | Path, format: str | None = None) -> DatasetReader:  # noqa: A002 - the CLI's name
    """The reader of a dataset folder (``format`` None: auto-detected).

    Raises:
        DatasetError: an unknown format (the message lists the registered ones), no known layout,
            or what the reader finds wrong with the dataset.
    """
    fmt = format or detect_format(path)
    reader: DatasetReader = DATASETS.create(fmt, path)
    return reader
