"""HDF5 training sets: the schema, its one writer (:class:`H5Writer`, resumable) and its one reader.

:class:`H5TrainingSet` reads the schema (checks, subject selection, streamed
batches, whole columns; the patches' chunks inflated in parallel threads,
:class:`ChunkedColumn`); :func:`read_h5` is a shorthand for reading a whole
file.

Schema (one row per normalized or augmented sample; ETH-XGaze's ``.h5`` is
the field's convention, this extends it with both eyes):

========================  ===================  ==================================================
key                       shape, dtype         meaning
========================  ===================  ==================================================
``left_eye``              (N, H, W, 3) uint8   the subject's left eye (image right), RGB
``right_eye``             (N, H, W, 3) uint8   the subject's right eye, RGB
``head_pose``             (N, 2) float32       (pitch, yaw) rad, face-centre normalized frame
``gaze``                  (N, 2) float32       (pitch, yaw) rad, face-centre normalized frame
``head_pose_vector``      (N, 3) float32       the same as unit vectors (MPIIGaze convention)
``gaze_vector``           (N, 3) float32
``head_pose_left/right``  (N, 2) float32       (pitch, yaw) rad in each eye's normalized frame
``gaze_left/right``       (N, 2) float32
``R_norm_left/right``     (N, 3, 3) float32    each eye's normalizing rotation
``R_norm_face``           (N, 3, 3) float32    the face's normalizing rotation
``subject``               (N,) bytes           subject id
``source_index``          (N,) int64           the sample's index in its dataset
``sampled_yaw_pitch``     (N, 2) float32       the drawn (yaw, pitch) in degrees (NaN: not augmented)
``face`` (optional)       (N, Hf, Wf, 3) uint8 the normalized face patch, RGB (face-centre camera, the
                                               settings' ``face_patch_size_wh``; only when they ask for one)
``eye_keypoints``         (N, 2, 2, 2)         (optional) px, each eye (left, right), its iris centre and
(optional)                float32              eye opening's centre (``EYE_KEYPOINTS``), (u, v) in that
                                               eye's patch (pixel centres at whole numbers, principal point
                                               (w / 2, h / 2)); NaN where unknown (a source's own row); only
                                               in ``augment --redirect-eyes`` sets, whose eyes were drawn
``sources/index``         (M,) int64           every input sample that produced rows
``sources/labels``        (M, 2, 2) float32    its original (head pose, gaze) (pitch, yaw) rad, face frame
========================  ===================  ==================================================

File attributes (docs/datasets.md has them field by field): ``gazeaug_version``,
``kind`` (``augment`` or ``normalize-dataset``), ``dataset``, ``dataset_format``,
``settings`` (JSON of every parameter that shapes the rows), ``selection`` (JSON:
which samples of which dataset), ``complete`` (True only once the run finished),
``rows_done`` and ``sources_done`` (rows and ``sources/*`` entries made durable
by the last flush), ``next_source_index`` and ``skipped`` (a JSON list of
``{source_index, image, reason}``).

Per-row datasets: chunks of 64 rows (``face``: at most 1 MiB a chunk), gzip level 1
(shuffle filter on all but the eye and face patches); ``sources/*``: chunks of 1024, uncompressed. While a run is
going, the file is ``OUT.h5.part``; it is renamed to ``OUT.h5`` only when
complete, so a killed run never leaves a file that looks complete.
``--resume`` reopens the ``.part`` file when ``settings`` and ``selection``
are identical (otherwise it refuses, naming each difference), drops rows past
the last flush and continues at ``next_source_index``.
"""

from __future__ import annotations

import contextlib
import json
import os
import zlib
from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from facemesh.conventions import pitchyaw_to_vector
from facemesh.outputs import OutputExistsError
from facemesh.types import FaceMeshError

from .errors import GazeAugError
from .normalize import NormalizedSample

__all__ = [
    "H5Writer",
    "H5TrainingSet",
    "ChunkedColumn",
    "read_threads",
    "rows_from_samples",
    "part_path",
    "read_h5",
    "REQUIRED_KEYS",
    "PATCH_SAMPLE_ROWS",
]

REQUIRED_KEYS = ("left_eye", "right_eye", "head_pose", "gaze", "subject", "source_index")
_CHUNK = 64
_BLOCK = 2048  # rows read and shuffled at once when streaming batches (a window of chunk pieces)
#: Face-patch chunks hold at most this many bytes (h5py's default chunk cache, 1 MiB: a chunk larger
#: than it is read back and recompressed whenever a flush ends inside it), and a streamed block of
#: rows with faces at most :data:`_FACE_BLOCK_BYTES` of them.
_FACE_CHUNK_BYTES = 1 << 20
_FACE_BLOCK_BYTES = 64 << 20
#: Rows whose patches :attr:`H5TrainingSet.patch_fingerprint` hashes (64 chunks at most: milliseconds).
PATCH_SAMPLE_ROWS = 64


def part_path(path: str | Path) -> Path:
    """The in-progress name of an output: ``OUT.h5.part``."""
    p = Path(path)
    return p.with_name(p.name + ".part")


@dataclass(frozen=True)
class Rows:
    """A block of rows to append (arrays with the schema's shapes, length n)."""

    arrays: Mapping[str, NDArray[Any]]

    def __len__(self) -> int:
        return len(self.arrays["left_eye"])


def rows_from_samples(
    samples: Sequence[NormalizedSample], subject: str, source_index: int, *, eye_keypoints: bool = False
) -> Rows:
    """Schema rows for the samples of one source image (each must have a gaze and face labels).

    ``eye_keypoints``: write the ``eye_keypoints`` column (NaN for a sample whose eyes carry none).
    """
    if not samples:
        raise GazeAugError("no samples to write")
    with_face = samples[0].face is not None and samples[0].face.image is not None
    dtypes = _dtypes(with_face, eye_keypoints)
    out: dict[str, list[Any]] = {k: [] for k in dtypes}
    for s in samples:
        if s.face is None or s.face.gaze is None or s.left.gaze is None or s.right.gaze is None:
            raise GazeAugError("training rows need a gaze label")
        if (s.face.image is not None) != with_face:
            raise GazeAugError("training rows: some samples have a face patch and some do not")
        if s.face.image is not None:
            out["face"].append(s.face.image)
        if eye_keypoints:
            known = s.left.keypoints_px is not None and s.right.keypoints_px is not None
            out["eye_keypoints"].append(
                [s.left.keypoints_px, s.right.keypoints_px] if known else np.full(_KEYPOINTS_TAIL, np.nan)
            )
        out["left_eye"].append(s.left.image)
        out["right_eye"].append(s.right.image)
        out["head_pose"].append(s.face.head_pose)
        out["gaze"].append(s.face.gaze)
        out["head_pose_vector"].append(pitchyaw_to_vector(s.face.head_pose))
        out["gaze_vector"].append(pitchyaw_to_vector(s.face.gaze))
        for side in ("left", "right"):
            e = s.eye(side)
            out[f"head_pose_{side}"].append(e.head_pose)
            out[f"gaze_{side}"].append(e.gaze)
            out[f"R_norm_{side}"].append(e.camera.rotation)
        out["R_norm_face"].append(s.face.camera.rotation)
        out["subject"].append(subject.encode("utf-8"))
        out["source_index"].append(source_index)
        yp = s.meta.get("yaw_pitch_deg")
        out["sampled_yaw_pitch"].append(yp if yp is not None else [np.nan, np.nan])
    return Rows({k: np.asarray(v, dtype=dtypes[k]) for k, v in out.items()})


_DTYPES: dict[str, Any] = {
    "left_eye": np.uint8,
    "right_eye": np.uint8,
    "head_pose": np.float32,
    "gaze": np.float32,
    "head_pose_vector": np.float32,
    "gaze_vector": np.float32,
    "head_pose_left": np.float32,
    "head_pose_right": np.float32,
    "gaze_left": np.float32,
    "gaze_right": np.float32,
    "R_norm_left": np.float32,
    "R_norm_right": np.float32,
    "R_norm_face": np.float32,
    "subject": "S32",
    "source_index": np.int64,
    "sampled_yaw_pitch": np.float32,
}


#: The image columns (not byte-shuffled before gzip).
_IMAGE_KEYS = ("left_eye", "right_eye", "face")


def _chunk_rows(key: str, tail: tuple[int, ...]) -> int:
    """Rows per HDF5 chunk of a column: :data:`_CHUNK`, fewer for face patches (:data:`_FACE_CHUNK_BYTES`)."""
    if key != "face":
        return _CHUNK
    return max(1, min(_CHUNK, _FACE_CHUNK_BYTES // int(np.prod(tail))))


#: The shape of a row's ``eye_keypoints``: (eye, point, (u, v)).
_KEYPOINTS_TAIL = (2, 2, 2)


def _dtypes(with_face: bool, with_keypoints: bool = False) -> dict[str, Any]:
    """The per-row keys and dtypes of a file: the schema's, ``face`` with face patches, ``eye_keypoints`` with them."""
    out = dict(_DTYPES)
    if with_face:
        out["face"] = np.uint8
    if with_keypoints:
        out["eye_keypoints"] = np.float32
    return out


def _differences(what: str, then_json: Any, now_json: str) -> list[str]:
    """What differs between two JSON objects recorded in a file (``"what.key: THEN then, NOW now"``)."""
    try:
        then = json.loads(then_json) if isinstance(then_json, str) else {}
    except (json.JSONDecodeError, RecursionError):
        then = {}
    now = json.loads(now_json)
    if not isinstance(then, dict):
        then = {}
    keys = sorted(set(then) | set(now))

    def shown(d: dict[str, Any], k: str) -> str:  # a key recorded only when set (with_source, eyes) reads "not set"
        return repr(d[k]) if k in d else "not set"

    return [f"{what}.{k}: {shown(then, k)} then, {shown(now, k)} now" for k in keys if then.get(k) != now.get(k)]


def _import_h5py() -> Any:
    try:
        import h5py  # noqa: PLC0415
    except ImportError as exc:
        raise ImportError(f"HDF5 output needs h5py: pip install h5py ({exc})") from exc
    return h5py


def open_h5_for_reading(path: str | Path, error: type[FaceMeshError] = GazeAugError) -> Any:
    """``h5py.File(path, "r")``, or ``error`` with one line saying why not.

    A missing path and one that is not a file (a folder) are said as
    :func:`facemesh.io.check_input_file` says them; any other file h5py cannot open is "not a
    readable HDF5 file" with h5py's reason (a file of another format: "file signature not found").
    """
    from facemesh.io import check_input_file
    from facemesh.types import InputError

    h5py = _import_h5py()
    try:
        p = check_input_file(path)
    except InputError as exc:  # the one check of an input path, said as this reader's error
        raise error(str(exc)) from None
    try:
        return h5py.File(p, "r")
    except OSError as exc:
        raise error(f"{p}: not a readable HDF5 file ({exc})") from exc


def check_output_state(path: Path, *, resume: bool, overwrite: bool) -> None:
    """What :class:`H5Writer` refuses before writing, checked alone (before starting a cluster, say).

    Raises:
        GazeAugError: not ``.h5``; a ``.part`` left by an interrupted run, without ``resume``.
        OutputExistsError: the output exists, without ``overwrite``.
    """
    if path.suffix not in (".h5", ".hdf5"):
        raise GazeAugError(f"{path}: the output must end in .h5")
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path} exists and is complete", remedy="overwrite")
    part = part_path(path)
    if part.exists() and not resume:
        raise GazeAugError(f"{part}: an interrupted run left it (no run is writing it now)", remedy="resume")


class H5Writer:
    """Append rows to ``OUT.h5.part``; :meth:`finish` marks it complete and renames it to ``OUT.h5``.

    Args:
        path: the final output (``.h5``).
        attrs: file attributes (JSON-serialisable values; ``settings`` should hold every parameter).
        patch_size_wh: eye patch (width, height).
        face_patch_size_wh: face patch (width, height) when rows carry one (the ``face`` column), else None.
        resume: continue an interrupted run's ``.part`` file (whose ``settings`` must match).
        overwrite: replace an existing complete output.
        compress: gzip the rows (default; off for the Ray engine's shards, which only live until merged).

    Raises:
        GazeAugError: the output exists (without ``overwrite``), a ``.part`` exists without
            ``resume``, or the ``.part`` file was written with other settings.
    """

    def __init__(
        self,
        path: str | Path,
        attrs: Mapping[str, Any],
        patch_size_wh: tuple[int, int],
        *,
        face_patch_size_wh: tuple[int, int] | None = None,
        eye_keypoints: bool = False,
        resume: bool = False,
        overwrite: bool = False,
        compress: bool = True,
    ):
        h5py = _import_h5py()
        self.path = Path(path)
        self._dtypes = _dtypes(face_patch_size_wh is not None, eye_keypoints)
        check_output_state(self.path, resume=resume, overwrite=overwrite)
        self.part = part_path(self.path)
        settings = json.dumps(attrs.get("settings", {}), sort_keys=True)
        selection = json.dumps(attrs.get("selection", {}), sort_keys=True)
        self.created = False  # True when this run made the .part file (see :meth:`discard`)
        self.skipped: list[dict[str, Any]] = []
        self._pending: list[Rows] = []
        self._pending_sources: list[tuple[int, NDArray[np.float32]]] = []
        self.next_source_index = 0
        self._rows_written = self._sources_written = 0  # rows / sources in the file after the last write
        if self.part.exists() and resume:
            try:
                self._f = h5py.File(self.part, "a")
            except OSError as exc:
                raise GazeAugError(
                    f"{self.part}: cannot reopen the interrupted run ({exc}); delete it to start over"
                ) from exc
            changed = [
                *_differences("settings", self._f.attrs.get("settings", "{}"), settings),
                *_differences("data", self._f.attrs.get("selection", "{}"), selection),
            ]
            if changed:
                self._f.close()
                raise GazeAugError(
                    f"{self.part} was written with other settings or data ({'; '.join(changed)})",
                    remedy="same_settings",
                )
            lacking = [k for k in self._dtypes if k not in self._f]
            if lacking:
                self._f.close()
                raise GazeAugError(
                    f"{self.part}: made by an older gazeaug without the column(s) {lacking}; delete it to start over"
                )
            done = int(self._f.attrs.get("rows_done", 0))
            for k in self._dtypes:
                self._f[k].resize(done, axis=0)
            sources = int(self._f.attrs.get("sources_done", 0))
            for k in ("sources/index", "sources/labels"):
                self._f[k].resize(sources, axis=0)
            self._rows_written, self._sources_written = done, sources
            self.next_source_index = int(self._f.attrs.get("next_source_index", 0))
            self.skipped = json.loads(self._f.attrs.get("skipped", "[]"))
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f = h5py.File(self.part, "w")
            self.created = True
            w, h = patch_size_wh
            shapes = {
                "left_eye": (h, w, 3),
                "right_eye": (h, w, 3),
                "R_norm_left": (3, 3),
                "R_norm_right": (3, 3),
                "R_norm_face": (3, 3),
                "head_pose_vector": (3,),
                "gaze_vector": (3,),
                "subject": (),
                "source_index": (),
            }
            if face_patch_size_wh is not None:
                shapes["face"] = (face_patch_size_wh[1], face_patch_size_wh[0], 3)
            shapes["eye_keypoints"] = _KEYPOINTS_TAIL
            for k, dt in self._dtypes.items():
                tail = shapes.get(k, (2,))
                self._f.create_dataset(
                    k,
                    shape=(0, *tail),
                    maxshape=(None, *tail),
                    dtype=dt,
                    chunks=(_chunk_rows(k, tail), *tail),
                    **(
                        {"compression": "gzip", "compression_opts": 1, "shuffle": k not in _IMAGE_KEYS}
                        if compress
                        else {}
                    ),
                )
            # per input sample (not per row): its index and its original (head pose, gaze), for the summary
            g = self._f.create_group("sources")
            g.create_dataset("index", shape=(0,), maxshape=(None,), dtype=np.int64, chunks=(1024,))
            g.create_dataset("labels", shape=(0, 2, 2), maxshape=(None, 2, 2), dtype=np.float32, chunks=(1024, 2, 2))
            for k, v in attrs.items():
                self._f.attrs[k] = json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else v
            self._f.attrs["sources_done"] = 0
            self._f.attrs["complete"] = False
            self._f.attrs["rows_done"] = 0
            self._f.attrs["next_source_index"] = 0
            self._f.attrs["skipped"] = "[]"
            self._f.flush()

    @property
    def rows_done(self) -> int:
        """Rows written so far (buffered rows included)."""
        return self._rows_written + sum(len(r) for r in self._pending)

    def append(self, rows: Rows | None, source_index: int, skipped: Mapping[str, Any] | None = None) -> None:
        """Append the rows of one source sample (or record it as skipped) and advance the resume point.

        Rows are buffered in memory and written by :meth:`flush` (a few samples' worth).
        """
        if rows is not None and len(rows):
            self._pending.append(rows)
        if skipped is not None:
            self.skipped.append(dict(skipped))
        self.next_source_index = source_index + 1

    def append_source(self, source_index: int, labels: NDArray[np.float64]) -> None:
        """Record one input sample's original labels: (2, 2) radians, rows (head pose, gaze), columns (pitch, yaw)."""
        self._pending_sources.append((source_index, np.asarray(labels, dtype=np.float32)))

    def append_file(self, path: str | Path) -> int:
        """Append every row, source and skip of another complete file of this schema (a shard), in its order.

        The file's resume point becomes this writer's: shards are appended in dataset order.

        Returns:
            The rows appended.
        """
        h5py = _import_h5py()
        with h5py.File(path, "r") as f:
            if not f.attrs.get("complete", False):
                raise GazeAugError(f"{path}: the shard is not complete")
            for key, what in (("face", "face patches"), ("eye_keypoints", "eye keypoints")):
                if (key in f) != (key in self._dtypes):
                    raise GazeAugError(f"{path}: the shard {'has' if key in f else 'lacks'} {what}, the output not")
            arrays = {k: f[k][()] for k in self._dtypes}
            index, labels = f["sources/index"][()], f["sources/labels"][()]
            skipped = json.loads(f.attrs.get("skipped", "[]"))
            next_index = int(f.attrs["next_source_index"])
        rows = Rows(arrays)
        if len(rows):
            self._pending.append(rows)
        self._pending_sources.extend((int(i), lab) for i, lab in zip(index, labels))
        self.skipped.extend(skipped)
        self.next_source_index = next_index
        return len(rows)

    def _write_pending(self) -> None:
        """Write the buffered rows after the last rows known written.

        Idempotent: the start row is the count of rows written by a *completed* call, not the
        datasets' current length, so a call interrupted half-way (Ctrl-C between two keys)
        and called again writes the same rows at the same place instead of appending them twice.
        """
        if self._pending:
            n0 = self._rows_written
            n1 = n0 + sum(len(r) for r in self._pending)
            for k, dt in self._dtypes.items():
                ds = self._f[k]
                ds.resize(n1, axis=0)
                ds[n0:n1] = np.concatenate([np.asarray(r.arrays[k], dtype=dt) for r in self._pending])
            self._rows_written = n1
            self._pending = []
        if self._pending_sources:
            n0 = self._sources_written
            n1 = n0 + len(self._pending_sources)
            self._f["sources/index"].resize(n1, axis=0)
            self._f["sources/index"][n0:n1] = [i for i, _ in self._pending_sources]
            self._f["sources/labels"].resize(n1, axis=0)
            self._f["sources/labels"][n0:n1] = np.stack([lab for _, lab in self._pending_sources])
            self._sources_written = n1
            self._pending_sources = []

    def flush(self) -> None:
        """Write the buffered rows and make them durable: the resume point moves only here."""
        self._write_pending()
        self._f.attrs["sources_done"] = self._sources_written
        self._f.attrs["rows_done"] = self.rows_done
        self._f.attrs["next_source_index"] = self.next_source_index
        self._f.attrs["skipped"] = json.dumps(self.skipped)
        self._f.flush()

    def finish(self) -> None:
        """Mark complete, close and rename ``.part`` to the final name."""
        import os

        self._f.attrs["complete"] = True
        self.flush()
        self._f.close()
        os.replace(self.part, self.path)

    def discard(self) -> None:
        """Close and remove the ``.part`` file if this run created it (a run that failed, not one interrupted)."""
        import os

        if self._f.id.valid:
            self._f.close()
        if self.created:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.part)

    def close(self) -> None:
        """Close without finishing (the ``.part`` file stays for ``--resume``)."""
        if self._f.id.valid:
            self.flush()
            self._f.close()


@contextmanager
def _reading(path: Path) -> Iterator[None]:
    """Turn what h5py raises on a damaged file into a GazeAugError naming it (our own errors pass)."""
    try:
        yield
    except FaceMeshError:
        raise
    except (OSError, KeyError, IndexError, ValueError, TypeError, AttributeError, RuntimeError) as exc:
        raise GazeAugError(f"{path}: a damaged training set ({exc.__class__.__name__}: {exc})") from exc


def _decode_attrs(attrs: Mapping[str, Any]) -> dict[str, Any]:
    """File attributes, the JSON ones (``settings``, ``skipped``) decoded; undecodable ones kept as text."""
    out: dict[str, Any] = {}
    for k, v in attrs.items():
        if isinstance(v, str) and v[:1] in ("[", "{"):
            try:
                v = json.loads(v)
            except (json.JSONDecodeError, RecursionError):
                pass
        out[k] = v
    return out


#: Labels (pitch, yaw) beyond this, radians, are refused: an angle lies in [-pi, pi] (the slack
#: lets a float32 rounding of +-pi pass).
_LABEL_LIMIT_RAD = np.pi * (1 + 1e-6)


def _check_schema(f: Any, path: Path) -> tuple[int, NDArray[np.float32]]:
    """The checks every read makes; returns the number of rows N and the labels.

    Required keys, the ``complete`` mark, eye patches (N, H, W, 3) uint8 alike, labels (N, 2), finite
    and within [-pi, pi] radians, every required key N rows long. The labels come back as
    (N, 4) float32: head pose (pitch, yaw), gaze (pitch, yaw).
    """
    missing = [k for k in REQUIRED_KEYS if k not in f]
    if missing:
        raise GazeAugError(f"{path}: missing keys {missing} (not a gazeaug training set)")
    if not bool(f.attrs.get("complete", False)):
        raise GazeAugError(f"{path}: the run that wrote it did not finish (no 'complete' mark)")
    n = int(f["left_eye"].shape[0])
    eye_shape = f["left_eye"].shape[1:]
    if len(eye_shape) != 3 or eye_shape[2] != 3 or f["right_eye"].shape != f["left_eye"].shape:
        raise GazeAugError(f"{path}: eye patches must be (N, H, W, 3), got {f['left_eye'].shape}")
    for k in ("head_pose", "gaze"):
        if f[k].shape != (n, 2):
            raise GazeAugError(f"{path}: {k} must be ({n}, 2), got {f[k].shape}")
    if "face" in f:
        face_shape = f["face"].shape
        if len(face_shape) != 4 or face_shape[0] != n or face_shape[3] != 3:
            raise GazeAugError(f"{path}: face patches must be ({n}, H, W, 3), got {face_shape}")
    for k in REQUIRED_KEYS:
        _check_rows(f, path, k, n)
    if "eye_keypoints" in f:
        ks = f["eye_keypoints"]
        if ks.shape != (n, *_KEYPOINTS_TAIL) or ks.dtype.kind != "f":
            raise GazeAugError(f"{path}: /eye_keypoints: expected float ({n}, 2, 2, 2) px, got {ks.dtype} {ks.shape}")
    for key in ("left_eye", "right_eye", "face"):
        if key in f and f[key].dtype != np.uint8:  # what augment writes and the models read
            raise GazeAugError(f"{path}: /{key}: expected uint8 RGB patches, got {f[key].dtype}")
    labels = np.concatenate([f["head_pose"][()], f["gaze"][()]], axis=1)
    bad = ~np.isfinite(labels).all(axis=1)
    if bad.any():
        raise GazeAugError(f"{path}: {int(bad.sum())} rows have NaN or infinite labels (first: {int(np.argmax(bad))})")
    bad = (np.abs(labels.astype(np.float64)) > _LABEL_LIMIT_RAD).any(axis=1)
    if bad.any():
        first = int(np.argmax(bad))
        raise GazeAugError(
            f"{path}: {int(bad.sum())} rows have head-pose or gaze labels outside [-pi, pi] radians "
            f"(first: row {first}, head pose {labels[first, :2].tolist()}, gaze {labels[first, 2:].tolist()})"
        )
    return n, labels.astype(np.float32, copy=False)


def _check_rows(f: Any, path: Path, key: str, n: int) -> None:
    if key not in f:
        raise GazeAugError(f"{path}: missing key {key!r}")
    rows = f[key].shape[0] if f[key].shape else 0
    if rows != n:
        raise GazeAugError(f"{path}: {key!r} has {rows} rows, left_eye {n}")


@contextmanager
def _no_pool() -> Iterator[None]:
    """No thread pool (one thread: h5py reads)."""
    yield None


def read_threads() -> int:
    """Threads that inflate a training set's chunks (:class:`ChunkedColumn`): this process's CPUs, at most 8."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on every platform
        cpus = os.cpu_count() or 1
    return max(1, min(8, cpus))


class ChunkedColumn:
    """Rows of one per-row column, read chunk by chunk, the chunks decompressed in parallel threads.

    HDF5's own reading decompresses one chunk at a time under h5py's global lock (about 20,000 rows
    of two eyes a second, one core). A column stored as this module's writer stores it (chunks of
    whole rows, gzip alone) is read here as its compressed chunks (``read_direct_chunk``: the bytes
    as stored, fast) and inflated by :mod:`zlib`, which releases the GIL, in ``pool``'s threads.
    Any other layout or filter (a file from elsewhere) is read by h5py, the same rows.

    Args:
        dset: an open ``h5py.Dataset``, rows along its first axis.
        pool: a ``concurrent.futures.Executor`` for the decompression, or None (h5py reads).
    """

    def __init__(self, dset: Any, pool: Any):
        h5py = _import_h5py()
        self.dset = dset
        self.pool = pool
        chunks = dset.chunks
        plist = dset.id.get_create_plist()
        self.direct = bool(
            pool is not None
            and dset.dtype.kind in "biuf"  # fixed-size numbers (variable-length strings are h5py's)
            and chunks is not None
            and tuple(chunks[1:]) == tuple(dset.shape[1:])  # a chunk holds whole rows
            and plist.get_nfilters() == 1
            and plist.get_filter(0)[0] == h5py.h5z.FILTER_DEFLATE
        )
        self.rows_per_chunk = int(chunks[0]) if chunks is not None else 0
        self._chunk_shape = tuple(int(c) for c in chunks) if chunks is not None else ()
        # read here, not in the pool's threads (only zlib runs there: h5py's calls take its lock)
        self._dtype = dset.dtype
        self._chunk_bytes = int(np.prod(self._chunk_shape)) * dset.dtype.itemsize
        self._where = f"{dset.file.filename}: {dset.name}"
        # the last chunk when it is partial: HDF5 may store it unfiltered (H5D_CHUNK_DONT_FILTER_PARTIAL_CHUNKS,
        # which h5py does not expose) with a filter mask of 0
        rows = int(dset.shape[0])
        self._edge = rows // self.rows_per_chunk if self.rows_per_chunk and rows % self.rows_per_chunk else -1

    def _chunk(self, c: int) -> tuple[int, bytes]:
        offset = (c * self.rows_per_chunk,) + (0,) * (len(self._chunk_shape) - 1)
        mask, raw = self.dset.id.read_direct_chunk(offset)
        return int(mask), bytes(raw)

    def _inflate(self, item: tuple[int, int, bytes]) -> NDArray[Any]:
        c, mask, raw = item
        want = self._chunk_bytes
        try:
            data = raw if mask & 1 else zlib.decompress(raw)  # mask bit 0: the deflate filter was skipped
        except zlib.error as exc:
            if not (c == self._edge and len(raw) == want):  # a partial edge chunk stored unfiltered is read as is
                raise GazeAugError(f"{self._where} chunk {c} is damaged ({exc})") from exc
            data = raw
        if len(data) != want:
            raise GazeAugError(f"{self._where} chunk {c} holds {len(data)} bytes, expected {want}")
        return np.frombuffer(data, dtype=self._dtype).reshape(self._chunk_shape)

    def _h5py_rows(self, lo: int, hi: int) -> NDArray[Any]:
        """``dset[lo:hi]`` read by h5py; what it raises on a damaged chunk named by file, dataset and rows."""
        try:
            return self.dset[lo:hi]
        except _H5PY_READ_ERRORS as exc:
            raise _unreadable(self.dset, f"rows {lo}-{hi - 1}", exc) from exc

    def read_runs(self, runs: Sequence[tuple[int, int]]) -> list[NDArray[Any]]:
        """The rows ``[lo, hi)`` of each run, as arrays (the same as ``dset[lo:hi]`` each).

        Raises:
            GazeAugError: a chunk that cannot be read or inflated (the message names the file,
                the dataset and the chunk or rows).
        """
        if not self.direct or any(hi <= lo for lo, hi in runs):
            return [self._h5py_rows(lo, hi) for lo, hi in runs]
        k = self.rows_per_chunk
        wanted = sorted({c for lo, hi in runs for c in range(lo // k, (hi - 1) // k + 1)})
        try:
            raws = [(c, *self._chunk(c)) for c in wanted]  # the stored bytes: fast, under h5py's lock
        except _H5PY_READ_ERRORS:  # a chunk never written (h5py gives its fill value)
            return [self._h5py_rows(lo, hi) for lo, hi in runs]
        chunks = dict(zip(wanted, self.pool.map(self._inflate, raws)))
        out = []
        for lo, hi in runs:
            parts = [chunks[c][max(lo - c * k, 0) : hi - c * k] for c in range(lo // k, (hi - 1) // k + 1)]
            out.append(parts[0].copy() if len(parts) == 1 else np.concatenate(parts))
        return out


class H5TrainingSet:
    """The reader of the schema above: the rows of a training set, optionally of some subjects only.

    Opening checks the schema (required keys, the ``complete`` mark, eye patch and label shapes,
    finite labels) and the subject selection; :meth:`batches` streams the rows for training and
    evaluation, :meth:`read` loads whole columns.

    Args:
        path: the ``.h5`` written by ``augment`` or ``normalize-dataset`` (:class:`H5Writer`).
        subjects: keep only these subjects.
        exclude_subjects: drop these subjects (leave-one-subject-out).
        allow_empty: accept a set with no rows (to inspect it); training needs rows.

    Attributes:
        path: the file.
        rows: (K,) int64, the file's row indices in use, increasing.
        subjects: (N,) str, the subject of every row of the file.
        patch_size_wh: eye patch (width, height), pixels.
        face_patch_size_wh: face patch (width, height), pixels, when the rows carry one (``face``); else None.
        has_eye_keypoints: whether the file has the ``eye_keypoints`` column (:meth:`eye_keypoints`).
        attrs: the file attributes (``settings`` and ``skipped`` decoded from JSON).
        settings: the run's parameters (``attrs["settings"]``; {} when absent).
        fingerprint: ``"K rows, sha1 HEX"``: the rows in use and a SHA-1 of their labels (head pose
            and gaze, float32 little-endian) and subjects; another file, or the same file with other
            rows, has another (a resumed training compares it).
        patch_fingerprint: ``"K rows, sampled S, sha1 HEX"``: a SHA-1 of the patches of a sample
            of the rows in use (read when first asked for; a resumed training compares it too).

    Raises:
        GazeAugError: unreadable or damaged file, unfinished run, missing keys, wrong shapes, NaN
            labels or labels outside [-pi, pi] radians, a ``settings`` attribute that is not a JSON
            object, an unknown subject, no rows.
    """

    #: The columns :meth:`batches` yields.
    KEYS = ("left_eye", "right_eye", "head_pose", "gaze", "subject")

    @classmethod
    def batch_keys(cls, face: bool, keypoints: bool = False) -> tuple[str, ...]:
        """The columns a model's batches need: :attr:`KEYS`, ``face`` for a model that reads it, ``eye_keypoints``."""
        return (*cls.KEYS, *(("face",) if face else ()), *(("eye_keypoints",) if keypoints else ()))

    def __init__(
        self,
        path: str | Path,
        subjects: Sequence[str] | None = None,
        exclude_subjects: Sequence[str] | None = None,
        *,
        allow_empty: bool = False,
    ):
        self.path = Path(path)
        self._fingerprint: str | None = None
        self._patch_fingerprint: str | None = None
        self._eye_keypoints: NDArray[np.float32] | None = None  # the whole column, read when first asked for
        f = open_h5_for_reading(self.path)
        with f, _reading(self.path):
            n, labels = _check_schema(f, self.path)
            eye_shape = f["left_eye"].shape[1:]
            face_shape = f["face"].shape[1:] if "face" in f else None
            self.has_eye_keypoints = "eye_keypoints" in f
            subj = np.array([s.decode() if isinstance(s, bytes) else str(s) for s in f["subject"][()]], dtype=str)
            self.attrs = _decode_attrs(f.attrs)
            raw_settings = f.attrs.get("settings")
        self._n = n
        known = sorted(set(subj.tolist()))
        unknown = sorted({str(x) for x in (*(subjects or ()), *(exclude_subjects or ()))} - set(known))
        if unknown:
            shown = ", ".join(known[:20]) + (f", ... ({len(known)} in all)" if len(known) > 20 else "")
            raise GazeAugError(f"{self.path}: no subject {', '.join(unknown)} in this file; its subjects are {shown}")
        keep = np.ones(n, dtype=bool)
        if subjects is not None:
            keep &= np.isin(subj, list(subjects))
        if exclude_subjects is not None:
            keep &= ~np.isin(subj, list(exclude_subjects))
        self.rows = np.flatnonzero(keep)
        if len(self.rows) == 0 and not allow_empty:
            raise GazeAugError(f"{self.path}: no rows to use (after the subject selection)")
        self.subjects = subj
        self.patch_size_wh = (int(eye_shape[1]), int(eye_shape[0]))
        self.face_patch_size_wh = None if face_shape is None else (int(face_shape[1]), int(face_shape[0]))
        self.settings: dict[str, Any] = _settings_attr(raw_settings, self.path)
        self._labels = labels

    @property
    def fingerprint(self) -> str:
        """``"K rows, sha1 HEX"``: the K rows in use, a SHA-1 of their labels and subjects (see the class)."""
        if self._fingerprint is None:
            self._fingerprint = _fingerprint(self._labels[self.rows], self.subjects[self.rows])
        return self._fingerprint

    @property
    def patch_fingerprint(self) -> str:
        """``"K rows, sampled S, sha1 HEX"``: a SHA-1 of the patches of S rows spread over the K in use.

        The eye patches (and the face patches, when the file has them) of :data:`PATCH_SAMPLE_ROWS`
        rows (all of them in a smaller set) at even steps through the rows in use, so a file whose
        images were made anew (another renderer, other settings) with the same labels is told apart
        without reading every patch; a change confined to rows outside the sample goes unseen.
        """
        if self._patch_fingerprint is None:
            import hashlib

            h5py = _import_h5py()
            k = len(self.rows)
            picked = np.unique(self.rows[np.linspace(0, k - 1, min(k, PATCH_SAMPLE_ROWS)).round().astype(np.int64)])
            h = hashlib.sha1(usedforsecurity=False)
            with h5py.File(self.path, "r") as f, _reading(self.path):
                for key in ("left_eye", "right_eye", "face"):
                    if key in f:
                        h.update(key.encode("ascii"))
                        h.update(np.ascontiguousarray(_sampled_rows(f[key], picked), dtype=np.uint8).tobytes())
            self._patch_fingerprint = f"{k} rows, sampled {len(picked)}, sha1 {h.hexdigest()}"
        return self._patch_fingerprint

    def __len__(self) -> int:
        return len(self.rows)

    @property
    def gaze(self) -> NDArray[np.float32]:
        """(K, 2) float32 radians (pitch, yaw), face-centre normalized frame: the gaze of the rows in use."""
        return self._labels[self.rows, 2:]

    @property
    def head_pose(self) -> NDArray[np.float32]:
        """(K, 2) float32 radians (pitch, yaw), face-centre normalized frame: the head pose of the rows in use."""
        return self._labels[self.rows, :2]

    def eye_keypoints(self, *, every_row: bool = False) -> NDArray[np.float32]:
        """(K, 2, 2, 2) float32 px: the rows' ``eye_keypoints`` (schema), NaN where unknown.

        ``every_row``: the file's N rows, not only the K in use. The column (32 bytes a row) is read
        once, on the first call, and kept (as the labels are).

        Raises:
            GazeAugError: the file has none.
        """
        if not self.has_eye_keypoints:
            raise GazeAugError(f"{self.path}: no eye keypoints (made without augment --redirect-eyes)")
        if self._eye_keypoints is None:
            h5py = _import_h5py()
            with h5py.File(self.path, "r") as f, _reading(self.path):
                self._eye_keypoints = np.asarray(f["eye_keypoints"][()], dtype=np.float32)
        column = self._eye_keypoints
        return column if every_row else column[self.rows]

    def read(self, keys: Sequence[str] | None = None) -> dict[str, Any]:
        """Whole columns of the rows in use, and the file attributes.

        Args:
            keys: the schema's keys to read (default: every per-row key; ``sources/`` is per input
                sample, not per row, and is left out).

        Returns:
            ``{key: array (K, ...) with the schema's shape and dtype, ..., "attrs": self.attrs}``.

        Raises:
            GazeAugError: a key the file lacks, or of another length than ``left_eye``.
        """
        h5py = _import_h5py()
        out: dict[str, Any] = {}
        everything = len(self.rows) == self._n
        with h5py.File(self.path, "r") as f, _reading(self.path):
            for k in keys or [k for k in f.keys() if k != "sources"]:
                _check_rows(f, self.path, k, self._n)
                column = f[k][()]
                out[k] = column if everything else column[self.rows]
        out["attrs"] = dict(self.attrs)
        return out

    def batches(
        self,
        batch_size: int,
        rng: np.random.Generator | None = None,
        keys: Sequence[str] | None = None,
        *,
        threads: int | None = None,
    ) -> Iterator[dict[str, NDArray[Any]]]:
        """Batches of the rows in use: ``keys`` (default :attr:`KEYS`), numpy arrays of B rows (the last may be fewer).

        ``left_eye``, ``right_eye``: (B, H, W, 3) uint8 RGB; ``head_pose``, ``gaze``: (B, 2) float32,
        (pitch, yaw) radians, face-centre normalized frame; ``subject``: (B,) str; ``face`` (when
        asked for): (B, Hf, Wf, 3) uint8 RGB.

        With ``rng``, the rows are shuffled across the whole file in bounded memory: pieces (the
        rows in use of one eye-patch chunk, :data:`_CHUNK` rows) in a random order, read a window
        of about :data:`_BLOCK` rows at a time (fewer with face patches) and shuffled within it, so
        every batch mixes rows from all over the file. (Rows are stored source by source, and so person
        by person: a batch drawn from one stretch of the file would hold a few people only.)
        Without ``rng``, in file order.

        The patches' chunks are decompressed by ``threads`` threads (default :func:`read_threads`;
        1: h5py reads them, one at a time), :class:`ChunkedColumn`: the same rows either way.

        Raises:
            GazeAugError: a key the file lacks (``face`` in a file made without face patches).
        """
        h5py = _import_h5py()
        wanted = tuple(keys) if keys is not None else self.KEYS
        if "face" in wanted and self.face_patch_size_wh is None:
            raise GazeAugError(f"{self.path}: no face patches (made without --face-patch)")
        if "eye_keypoints" in wanted and not self.has_eye_keypoints:
            raise GazeAugError(f"{self.path}: no eye keypoints (made without augment --redirect-eyes)")
        carry: dict[str, list[NDArray[Any]]] = {k: [] for k in wanted}
        carried = 0
        in_memory = {  # read once when the file was opened
            "subject": self.subjects,
            "head_pose": self._labels[:, :2],
            "gaze": self._labels[:, 2:],
        }
        if "eye_keypoints" in wanted:  # 32 bytes a row: read whole, once per set (eye_keypoints keeps it)
            in_memory["eye_keypoints"] = self.eye_keypoints(every_row=True)
        n_threads = read_threads() if threads is None else max(1, int(threads))
        pool_cm = ThreadPoolExecutor(n_threads, thread_name_prefix="gazeaug-inflate") if n_threads > 1 else _no_pool()
        with h5py.File(self.path, "r") as f, pool_cm as pool:
            stored = {k: ChunkedColumn(f[k], pool) for k in wanted if k not in in_memory}
            for runs, perm in self._windows(rng, "face" in wanted):
                spans = [(int(idx[0]), int(idx[-1]) + 1) for idx in runs]
                for k in wanted:
                    if k in in_memory:
                        part = [in_memory[k][idx] for idx in runs]
                    else:  # the runs read whole, then the rows in use picked
                        part = [block[idx - lo] for block, idx, (lo, _) in zip(stored[k].read_runs(spans), runs, spans)]
                    carry[k].append(np.concatenate(part)[perm])
                carried += len(perm)
                while carried >= batch_size:
                    joined = {k: np.concatenate(v) for k, v in carry.items()}
                    yield {k: v[:batch_size] for k, v in joined.items()}
                    carry = {k: [v[batch_size:]] for k, v in joined.items()}
                    carried -= batch_size
        if carried:
            yield {k: np.concatenate(v) for k, v in carry.items()}

    def order(self, rng: np.random.Generator | None = None, *, face: bool = False) -> NDArray[np.int64]:
        """(K,) int64: the file's row indices in use, in the order :meth:`batches` yields them.

        ``batches(B, rng)``'s i-th batch is the rows ``order(rng)[i * B:(i + 1) * B]`` (read with a
        fresh ``rng`` of the same seed: both draw the same numbers from it, in the same order).
        ``face``: the order of batches that read face patches (their windows are smaller).
        """
        plan = self._windows(rng, face)
        if not plan:
            return np.zeros(0, dtype=np.int64)
        return np.concatenate([np.concatenate(runs)[perm] for runs, perm in plan])

    def _windows(
        self, rng: np.random.Generator | None, face: bool
    ) -> list[tuple[list[NDArray[np.int64]], NDArray[np.int64]]]:
        """The reading plan of :meth:`batches`: windows, each ``(runs, perm)``.

        ``runs``: file row indices, each run consecutive in the file (read at once); ``perm``: the
        window's shuffle, applied to the runs' rows concatenated. Pieces (the rows in use of one
        eye-patch chunk, :data:`_CHUNK` rows; a selection's gap never inside a read) in a random
        order, gathered into windows of at least about :data:`_BLOCK` rows (fewer with face
        patches: bounded memory). Every number is drawn from ``rng`` here, in a fixed order: the
        pieces' order, then each window's shuffle. Without ``rng``, file order.
        """
        size = _BLOCK
        if face and self.face_patch_size_wh is not None:  # bounded memory: faces are large
            fw, fh = self.face_patch_size_wh
            size = max(_CHUNK, min(_BLOCK, _FACE_BLOCK_BYTES // (fw * fh * 3)))
        pieces = np.split(self.rows, np.flatnonzero(np.diff(self.rows // _CHUNK)) + 1) if len(self.rows) else []
        order = rng.permutation(len(pieces)) if rng is not None else np.arange(len(pieces))
        windows: list[list[NDArray[np.int64]]] = [[]]
        filled = 0
        for b in order:  # windows of at least `size` rows
            if filled >= size:
                windows.append([])
                filled = 0
            windows[-1].append(pieces[b])
            filled += len(pieces[b])
        plan = []
        for window in windows:
            if not window:
                continue
            # pieces that follow each other in the file (file order) are read at once
            runs: list[NDArray[np.int64]] = []
            for idx in window:
                if runs and idx[0] == runs[-1][-1] + 1:
                    runs[-1] = np.concatenate([runs[-1], idx])
                else:
                    runs.append(idx)
            n = sum(len(idx) for idx in runs)
            plan.append((runs, rng.permutation(n) if rng is not None else np.arange(n)))
        return plan


def _settings_attr(raw: Any, path: Path) -> dict[str, Any]:
    """The ``settings`` attribute as a dict ({} when absent); anything but a JSON object is an error."""
    if raw is None:
        return {}
    if isinstance(raw, (bytes, np.bytes_)):
        raw = bytes(raw).decode("utf-8", errors="replace")
    if not isinstance(raw, str):
        raise GazeAugError(
            f"{path}: the 'settings' attribute must be a JSON object of the run's parameters, "
            f"got a {type(raw).__name__} ({raw!r:.60})"
        )
    try:
        value = json.loads(raw)
    except RecursionError as exc:
        raise GazeAugError(f"{path}: the 'settings' attribute is JSON nested too deeply to read") from exc
    except json.JSONDecodeError as exc:
        raise GazeAugError(
            f"{path}: the 'settings' attribute is not valid JSON ({exc.msg} at character {exc.pos}; "
            f"expected an object of the run's parameters, got {raw!r:.60})"
        ) from exc
    if not isinstance(value, dict):
        raise GazeAugError(
            f"{path}: the 'settings' attribute must be a JSON object of the run's parameters, "
            f"got a JSON {type(value).__name__} ({raw!r:.60})"
        )
    return value


#: What h5py raises reading a damaged chunk.
_H5PY_READ_ERRORS = (OSError, RuntimeError, ValueError)


def _unreadable(dset: Any, rows: str, exc: BaseException) -> GazeAugError:
    """The error for ``rows`` (``"rows 0-9"``, ``"row 7"``) of ``dset`` that h5py could not read."""
    return GazeAugError(f"{dset.file.filename}: {dset.name} {rows}: cannot be read, the file is damaged ({exc})")


def _sampled_rows(dset: Any, rows: NDArray[np.int64]) -> NDArray[Any]:
    """``dset[rows]`` (rows increasing); a row h5py cannot read named with its file and dataset."""
    try:
        return dset[rows]
    except _H5PY_READ_ERRORS as exc:
        bad = next((int(r) for r in rows if not _readable(dset, int(r))), None)
        raise _unreadable(dset, f"rows {int(rows[0])}-{int(rows[-1])}" if bad is None else f"row {bad}", exc) from exc


def _readable(dset: Any, row: int) -> bool:
    try:
        dset[row]
    except _H5PY_READ_ERRORS:
        return False
    return True


def _fingerprint(labels: NDArray[Any], subjects: NDArray[Any]) -> str:
    """``"K rows, sha1 HEX"`` of K rows' labels (K, 4) and subjects (K,)."""
    import hashlib

    h = hashlib.sha1(usedforsecurity=False)
    h.update(np.ascontiguousarray(labels, dtype="<f4").tobytes())
    h.update(json.dumps([str(x) for x in subjects.tolist()]).encode("utf-8"))
    return f"{len(labels)} rows, sha1 {h.hexdigest()}"


def read_h5(path: str | Path, keys: Sequence[str] | None = None) -> dict[str, Any]:
    """Read a training set (all of it, or ``keys``) with its attributes; checks the schema.

    ``H5TrainingSet(path, allow_empty=True).read(keys)``: ``{key: array (N, ...), ..., "attrs": {...}}``.

    Raises:
        GazeAugError: not HDF5, incomplete (no ``complete`` mark), missing keys, wrong shapes,
            NaN labels or inconsistent lengths.
    """
    return H5TrainingSet(path, allow_empty=True).read(keys)
