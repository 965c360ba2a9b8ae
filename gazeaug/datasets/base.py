"""One sample schema for every gaze dataset, and the errors readers raise.

Readers (:mod:`gazeaug.datasets`) turn a dataset on disk into
:class:`GazeSample` s; the augmenter, the normalizer and the evaluator only
ever see those, never the dataset's own format.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from facemesh.types import CameraIntrinsics

if TYPE_CHECKING:
    from facemesh.build import FaceFit
    from facemesh.types import FaceMesh

from ..errors import GazeAugError

__all__ = [
    "GazeSample",
    "FaceProvider",
    "DetectedFace",
    "DETECTED",
    "DatasetReader",
    "DatasetError",
    "H5ImageRef",
    "image_size",
    "parse_numbers",
    "require_image",
]


class H5ImageRef:
    """A picklable reference to one image stored in an HDF5 dataset (``path``, ``key``, row ``index``).

    ``bgr=True`` when the file stores BGR (ETH-XGaze's normalized release does).
    """

    def __init__(self, path: str | Path, key: str, index: int, bgr: bool = False):
        self.path, self.key, self.index, self.bgr = str(path), key, int(index), bool(bgr)

    def __call__(self) -> NDArray[np.uint8]:
        """(H, W, 3) uint8 RGB."""
        import h5py

        with h5py.File(self.path, "r") as f:
            img = np.asarray(f[self.key][self.index], dtype=np.uint8)
        return np.ascontiguousarray(img[..., ::-1] if self.bgr else img)

    def __repr__(self) -> str:
        return f"{self.path}#{self.key}[{self.index}]"


class DatasetError(GazeAugError):
    """A dataset file is missing, malformed or inconsistent (the message names the file and line)."""


def require_image(path: Path, where: str) -> Path:
    """``path`` if it names an existing file; a DatasetError naming ``where`` otherwise.

    A name the system cannot even look up (too long, a NUL byte: a damaged label file) is
    reported as such rather than as an OS error.
    """
    try:
        found = path.is_file()
    except (OSError, ValueError) as exc:
        raise DatasetError(
            f"{where}: not a usable image file name ({exc.__class__.__name__}: {str(path)[:80]}...)"
        ) from exc
    if not found:
        raise DatasetError(f"{where}: image {path} not found")
    return path


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file, read from its header only."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            return int(im.size[0]), int(im.size[1])
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot read the image's size ({exc})") from exc


def parse_numbers(cells: list[str], where: str) -> NDArray[np.float64]:
    """Annotation cells -> finite float64 array; errors name ``where`` (file and line)."""
    try:
        values = np.array([float(c) for c in cells])
    except ValueError as exc:
        raise DatasetError(f"{where}: non-numeric value ({exc})") from exc
    if not np.isfinite(values).all():
        raise DatasetError(f"{where}: NaN or infinite value")
    return values


class FaceProvider(Protocol):
    """How a sample's face is fitted and meshed (one implementation per source of faces).

    :class:`DetectedFace` (the default) detects the landmarks and builds the mesh
    from them; a dataset that ships its own pose and mesh (UT Multiview's
    :class:`~gazeaug.datasets.utmultiview.DatasetFace`) provides both itself.
    """

    def fit(self, sample: GazeSample, image: NDArray[np.uint8], detector: Any) -> FaceFit:
        """The face of ``image`` (the sample's image, as loaded) with its pose."""
        ...

    def mesh(self, fit: FaceFit, sample: GazeSample) -> FaceMesh:
        """The textured mesh of a fitted face, to render at new head poses."""
        ...


@dataclass(frozen=True)
class DetectedFace:
    """The default :class:`FaceProvider`: the landmark model's largest face, and a mesh built from its landmarks."""

    def fit(self, sample: GazeSample, image: NDArray[np.uint8], detector: Any) -> FaceFit:
        """:func:`facemesh.build.fit_face` with the sample's camera."""
        from facemesh.build import fit_face

        return fit_face(image, sample.camera, detector, source=str(sample.image_path))

    def mesh(self, fit: FaceFit, sample: GazeSample) -> FaceMesh:
        """:func:`gazeaug.pipeline.mesh_for_fit` (augmentation's texture margin)."""
        from ..pipeline import mesh_for_fit

        return mesh_for_fit(fit)


#: The default face provider.
DETECTED = DetectedFace()


@dataclass(frozen=True)
class GazeSample:
    """One labelled image of a gaze dataset.

    Attributes:
        image_path: the image file.
        camera: the camera that took it (intrinsics and distortion).
        subject: subject identifier (``"p00"``, ...).
        source_index: position of the sample in its dataset (stable across runs; the key
            for resuming and for per-sample random seeds).
        gaze_target_mm: (3,) float64, mm, camera frame: the 3D point looked at; or ``None``.
        gaze_vector: (3,) float64 unit vector, camera frame, when the dataset gives a
            direction instead of a target; ``None`` otherwise.
        gaze_origin_mm: (3,) float64, mm, camera frame: where the dataset's gaze direction
            starts (its face centre), when it says; ``None`` otherwise.
        head_rotation: (3, 3) float64 head -> camera rotation from the dataset, or ``None``.
        head_translation_mm: (3,) float64, mm, from the dataset, or ``None``.
        landmarks_px: (L, 2) float64, pixels, image frame: the dataset's own landmarks, or ``None``.
        rotate_180: the image file must be turned by 180 deg before use (ETH-XGaze's cameras
            3, 6 and 13 were mounted upside down; their labels refer to the turned image).
        image_ref: where the image is when it is not a file of its own (an HDF5 row); then
            ``image_path`` names the container, for messages.
        face: how the face is found and meshed when the dataset says more than the image
            (UT Multiview's own pose, landmarks and mesh: a :class:`FaceProvider`); ``None``:
            detected by the landmark model (:data:`DETECTED`). See :attr:`face_provider`.
        extras: anything else the reader wants to keep (JSON-serialisable).

    The head pose, landmarks and gaze origin are the dataset's own annotations, kept
    for users and for checks of the readers; the pipeline fits the face itself
    unless ``face`` says otherwise.
    """

    image_path: Path
    camera: CameraIntrinsics
    subject: str
    source_index: int
    gaze_target_mm: NDArray[np.float64] | None = None
    gaze_vector: NDArray[np.float64] | None = None
    gaze_origin_mm: NDArray[np.float64] | None = None
    head_rotation: NDArray[np.float64] | None = None
    head_translation_mm: NDArray[np.float64] | None = None
    landmarks_px: NDArray[np.float64] | None = None
    rotate_180: bool = False
    image_ref: H5ImageRef | None = None
    face: FaceProvider | None = None
    extras: Mapping[str, Any] = field(default_factory=dict)

    @property
    def face_provider(self) -> FaceProvider:
        """:attr:`face`, or :data:`DETECTED` (the landmark model's face and a mesh built from it)."""
        return self.face if self.face is not None else DETECTED

    def load_image(self) -> NDArray[np.uint8]:
        """(H, W, 3) uint8 RGB, turned when :attr:`rotate_180` says so."""
        from facemesh.io import load_image_rgb

        image = self.image_ref() if self.image_ref is not None else load_image_rgb(self.image_path)
        return np.ascontiguousarray(image[::-1, ::-1]) if self.rotate_180 else image

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_path", Path(self.image_path))
        for name, shape in (
            ("gaze_target_mm", (3,)),
            ("gaze_vector", (3,)),
            ("gaze_origin_mm", (3,)),
            ("head_rotation", (3, 3)),
            ("head_translation_mm", (3,)),
        ):
            v = getattr(self, name)
            if v is None:
                continue
            a = np.array(v, dtype=np.float64)
            if a.shape != shape or not np.isfinite(a).all():
                raise DatasetError(
                    f"sample {self.source_index} ({self.image_path}): {name}: expected finite {shape}, got {a.tolist()}"
                )
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        if self.gaze_target_mm is None and self.gaze_vector is None:
            raise DatasetError(f"sample {self.source_index} ({self.image_path}): no gaze target or gaze vector")
        if self.gaze_vector is not None:
            n = float(np.linalg.norm(self.gaze_vector))
            if n < 1e-9:
                raise DatasetError(f"sample {self.source_index} ({self.image_path}): zero gaze vector")
            g = np.asarray(self.gaze_vector) / n
            g.setflags(write=False)
            object.__setattr__(self, "gaze_vector", g)
        if self.landmarks_px is not None:
            a = np.array(self.landmarks_px, dtype=np.float64)
            if a.ndim != 2 or a.shape[1] != 2 or not np.isfinite(a).all():
                raise DatasetError(
                    f"sample {self.source_index} ({self.image_path}): landmarks_px: expected finite (L, 2)"
                )
            a.setflags(write=False)
            object.__setattr__(self, "landmarks_px", a)


class DatasetReader(Protocol):
    """A dataset on disk: a name, a length and its samples in a stable order."""

    name: str

    def __len__(self) -> int:
        """Number of samples."""
        ...

    def __iter__(self) -> Iterator[GazeSample]:
        """The samples, ``source_index`` 0, 1, 2, ..."""
        ...
