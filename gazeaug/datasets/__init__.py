"""Gaze dataset readers behind one sample schema (:class:`~gazeaug.datasets.base.GazeSample`).

``open_dataset(path, format=None)`` picks the reader; formats:

``mpiifacegaze``
    the raw MPIIFaceGaze release (``pXX/pXX.txt`` + ``pXX/Calibration/Camera.mat``).
``ethxgaze``
    the raw ETH-XGaze release (per-subject annotation CSVs + per-camera XML calibrations); its
    training split (the test split has no gaze labels and is refused with that reason).
``ethxgaze_normalized``
    ETH-XGaze's normalized ``subjectXXXX.h5`` release (face patches as images of the normalized camera).
``gazecapture``
    GazeCapture with FAZE's supplementary HDF5 (intrinsics, distortion, head pose, 3D gaze targets).
``utmultiview``
    UT Multiview's raw part (8 cameras per capture, a reconstructed face mesh per capture;
    :mod:`gazeaug.datasets.utmultiview`).
``folder``
    your own data: images plus ``labels.csv`` or ``labels.jsonl`` (:mod:`gazeaug.datasets.folder`).
"""

from __future__ import annotations

from pathlib import Path

from .base import DatasetError, DatasetReader, GazeSample
from .ethxgaze import ETHXGaze
from .ethxgaze_normalized import ETHXGazeNormalized, looks_like_ethxgaze_normalized
from .folder import LABEL_FILES, FolderDataset
from .gazecapture import SUPPLEMENTARY_NAME, GazeCapture
from .mpiifacegaze import MPIIFaceGaze
from .utmultiview import UTMultiview, looks_like_utmultiview

__all__ = ["FORMATS", "open_dataset", "detect_format", "DatasetError", "DatasetReader", "GazeSample"]

#: Formats :func:`open_dataset` knows.
FORMATS = ("mpiifacegaze", "ethxgaze", "ethxgaze_normalized", "gazecapture", "utmultiview", "folder")


def detect_format(path: str | Path) -> str:
    """Guess a dataset folder's format from its layout.

    Raises:
        DatasetError: not a folder, or no known layout.
    """
    p = Path(path)
    if not p.is_dir():
        raise DatasetError(f"{p}: not a folder (give the dataset's root folder)")
    if any((p / n).is_file() for n in LABEL_FILES):
        return "folder"
    if (p / SUPPLEMENTARY_NAME).is_file():
        return "gazecapture"
    if (p / "data" / "annotation_train").is_dir() or (p / "data" / "annotation_test").is_dir():
        return "ethxgaze"  # a test split alone is ETH-XGaze too: its reader says why it is refused
    if looks_like_ethxgaze_normalized(p):
        return "ethxgaze_normalized"
    if looks_like_utmultiview(p):
        return "utmultiview"
    if any(d.is_dir() and (d / f"{d.name}.txt").is_file() for d in p.iterdir()):
        return "mpiifacegaze"
    raise DatasetError(
        f"{p}: cannot tell the dataset format (no {' / '.join(LABEL_FILES)}, no pXX/pXX.txt, "
        f"no {SUPPLEMENTARY_NAME}, no data/annotation_train/, no sNN/raw/gazedata.csv); pass --format"
    )


def open_dataset(path: str | Path, format: str | None = None) -> DatasetReader:  # noqa: A002 - the CLI's name
    """The reader of a dataset folder (``format`` None: auto-detected)."""
    fmt = format or detect_format(path)
    if fmt == "mpiifacegaze":
        return MPIIFaceGaze(path)
    if fmt == "folder":
        return FolderDataset(path)
    if fmt == "ethxgaze":
        return ETHXGaze(path)
    if fmt == "gazecapture":
        return GazeCapture(path)
    if fmt == "ethxgaze_normalized":
        return ETHXGazeNormalized(path)
    if fmt == "utmultiview":
        return UTMultiview(path)
    raise DatasetError(f"format: expected one of {FORMATS}, got {fmt!r}")
