"""Dataset runs: ``augment`` (K renders per sample at drawn head poses) and ``normalize-dataset`` (the baseline).

Every input sample goes through the same stages: read the image, detect the
landmarks (MediaPipe), solve the pose (or, for datasets that ship a face mesh
and head pose, UT Multiview, take theirs); then either normalize the real image
(``normalize-dataset``) or build the face mesh and render its eyes at K head
poses drawn from the distribution (``augment``). Rows go to an HDF5 file
(:mod:`gazeaug.io_h5`) in dataset order, whatever the number of workers.

Determinism: sample i draws its poses from ``numpy.random.default_rng([seed, i])``,
so the output does not depend on ``--workers`` or on resuming.

Samples whose face is not found, or whose pose fails, are skipped, counted and
listed in the summary (never fatal). Dataset errors (bad files, missing
columns, wrong calibration) stop the run with a message naming the file.
"""

from __future__ import annotations

import itertools
import json
import shutil
import sys
import time
import uuid
import warnings
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from . import __version__
from .background import interrupt_between_steps
from .datasets.base import DatasetError, DatasetReader, GazeSample
from .engine import Engine, WorkersLostError, chunks
from .errors import GazeAugError
from .io_h5 import H5Writer, Rows, rows_from_samples
from .normalize import NormalizationSettings, NormalizedSample, normalize_image, views_at
from .sampling import HeadPoseDistribution

__all__ = ["JobSettings", "run_dataset", "check_redirectable", "process_sample", "SampleOutcome", "shard_dir"]

KINDS = ("augment", "normalize-dataset")


@dataclass(frozen=True)
class JobSettings:
    """What a dataset run does (all recorded in the output's ``settings`` attribute).

    Attributes:
        kind: ``"augment"`` or ``"normalize-dataset"``.
        per_sample: K, augmented samples per input sample (``augment`` only; default 4).
        distribution: the head-pose distribution (default: the paper's).
        seed: base seed (default 0).
        renderer: ``"raycast"`` (default) or ``"filament"``.
        normalization: the normalized camera and patch.
        rig: the rig description the distribution came from, if any (recorded; with ``eyes="redirect"``
            its head poses and targets are drawn).
        eyes: ``"keep"`` (default, the paper's method): each augmented sample keeps the source's
            gaze in the head and its photographed eyes; ``"redirect"``: the eyes are re-made as 3D
            eyeballs (:func:`gazeaug.augment.redirect_subject`) and turned to the rig's targets, head
            poses and targets drawn jointly from ``rig`` (:func:`gazeaug.augment.rig_looks`), so the
            augmented set carries the application's eye-in-head gaze. Each of a source's
            ``per_sample`` samples draws eyes of its own (eyeball, iris, lid drop, kappa): on issue
            13's benchmark, pitch r 0.43 -> 0.52 at the same error (docs/simulation.md). Needs
            ``rig`` and MediaPipe's 478 landmarks.
        with_source: ``augment`` only: each source also writes its own normalized row (the row
            ``normalize-dataset`` writes for it) before its K augmented rows, so the set holds the
            original data and its augmentation (its ``sampled_yaw_pitch`` is NaN; the augmented rows
            are the same either way). Default False (the paper's protocol: the augmented rows
            alone). On issue 13's benchmark (3 draws of the sets, redirected eyes) 9.95 -> 9.12 deg
            on average, each of 5 runs better than without; one run's noise is about 1 deg
            (docs/model.md).
    """

    kind: str = "augment"
    per_sample: int = 4
    distribution: HeadPoseDistribution = field(default_factory=HeadPoseDistribution)
    seed: int = 0
    renderer: str = "raycast"
    normalization: NormalizationSettings = field(default_factory=NormalizationSettings)
    rig: dict[str, Any] | None = None
    eyes: str = "keep"
    with_source: bool = False

    #: The ``eyes`` choices.
    EYES: ClassVar[tuple[str, ...]] = ("keep", "redirect")

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise GazeAugError(f"kind: expected one of {KINDS}, got {self.kind!r}")
        if self.eyes not in self.EYES:
            raise GazeAugError(f"eyes: expected one of {self.EYES}, got {self.eyes!r}")
        if not isinstance(self.with_source, bool):
            raise GazeAugError(f"with_source: expected true or false, got {self.with_source!r}")
        if self.with_source and self.kind != "augment":
            raise GazeAugError("with_source is an augmentation setting: normalize-dataset writes the source rows only")
        if self.eyes == "redirect":
            if self.kind != "augment":
                raise GazeAugError("eyes='redirect' is an augmentation setting")
            if self.rig is None:
                raise GazeAugError(
                    "redirected eyes need a rig: its targets give the gazes (and its head poses the poses)"
                )
            if self.renderer != "raycast":
                raise GazeAugError(f"redirected eyes are ray cast: expected renderer 'raycast', got {self.renderer!r}")
        if self.kind == "augment" and self.normalization.face_patch_size_wh is not None and self.renderer != "raycast":
            raise GazeAugError(
                f"face patches are ray cast: expected renderer 'raycast' with --face-patch, got {self.renderer!r}"
            )
        if self.kind == "augment" and not (isinstance(self.per_sample, int) and self.per_sample >= 1):
            raise GazeAugError(f"per_sample: expected an integer >= 1, got {self.per_sample!r}")
        from .render import RENDERERS

        usable = RENDERERS.names(benchmark_only=False)
        if self.renderer not in usable:
            raise GazeAugError(f"renderer: expected one of {usable}, got {self.renderer!r}")

    @property
    def writes_eye_keypoints(self) -> bool:
        """Whether the output has the ``eye_keypoints`` column: the drawn eyes' points (``eyes="redirect"``)."""
        return self.kind == "augment" and self.eyes == "redirect"

    def as_dict(self) -> dict[str, Any]:
        """JSON-serialisable form."""
        d: dict[str, Any] = {"kind": self.kind, "normalization": self.normalization.as_dict(), "seed": self.seed}
        if self.kind == "augment":
            d.update(per_sample=self.per_sample, distribution=self.distribution.as_dict(), renderer=self.renderer)
            if self.rig is not None:
                d["rig"] = self.rig
            if self.eyes != "keep":  # recorded only when set, so earlier outputs' settings still match
                from .augment import REDIRECT_SUPERSAMPLE

                d["eyes"] = self.eyes
                if REDIRECT_SUPERSAMPLE != 1:  # rays per pixel side; a .part made with another count is not resumed
                    d["redirect_supersample"] = REDIRECT_SUPERSAMPLE
            if self.with_source:  # recorded only when set, as eyes
                d["with_source"] = True
        return d


@dataclass(frozen=True)
class SampleOutcome:
    """What processing one input sample gave.

    Attributes:
        source_index: the sample's index.
        rows: the rows to write, or None when skipped.
        skipped: ``{"source_index", "image", "reason"}`` when skipped.
        before: (2, 2) float64 radians: the source image's (head pose, gaze) in its face frame, or None.
    """

    source_index: int
    rows: Rows | None
    skipped: dict[str, Any] | None = None
    before: NDArray[np.float64] | None = None


_STATE: dict[str, Any] = {}


def _one_line_warning(
    message: Any, category: Any, filename: str, lineno: int, file: Any = None, line: Any = None
) -> None:
    """A worker process's warnings, one line each on stderr, the way the command line shows its own."""
    print(f"gazeaug: warning: {message}", file=sys.stderr)


def _worker_init(settings: JobSettings, threads: int = 0) -> None:
    """Per-process state: one landmark detector and one renderer, reused for every sample.

    ``threads``: Embree threads per ray cast (0: all cores; 1 when several worker processes share the cores).
    """
    from .pipeline import default_landmark_model

    _STATE["settings"] = settings
    if threads == 1:  # one of several worker processes sharing the cores
        import signal

        import cv2

        signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: no traceback per worker
        cv2.setNumThreads(1)  # no nested thread pools in OpenCV
        warnings.showwarning = _one_line_warning  # as the command line shows the parent's: no source lines
    _STATE["detector"] = default_landmark_model()
    if settings.kind == "augment":
        from .render import create_renderer

        options = {"threads": threads} if settings.renderer == "raycast" else {}
        _STATE["renderer"] = create_renderer(settings.renderer, settings=settings.normalization, **options)
        if settings.eyes == "redirect":
            from .sampling import rig_from_dict

            assert settings.rig is not None
            _STATE["rig"] = rig_from_dict(settings.rig)
            _STATE["threads"] = threads


def _read_image(sample: GazeSample) -> NDArray[np.uint8] | Exception:
    """The sample's image, or the InputError that reading it raised (run in the reader thread)."""
    from facemesh.types import InputError

    try:
        return sample.load_image()
    except InputError as exc:
        return exc


def process_sample(sample: GazeSample, image: NDArray[np.uint8] | Exception | None = None) -> SampleOutcome:
    """Process one sample with the worker's state (see :func:`_worker_init`).

    ``image``: the sample's image when already read (or the error reading it gave); None reads it here.
    """
    from facemesh.pose import PoseError
    from facemesh.types import InputError, NoFaceError

    from .augment import (
        face_asset,
        redirect_subject,
        render_poses,
        render_redirected,
        rig_looks,
        sampled_placements,
    )

    s: JobSettings = _STATE["settings"]
    idx = sample.source_index

    def skip(reason: str) -> SampleOutcome:
        return SampleOutcome(idx, None, {"source_index": idx, "image": str(sample.image_path), "reason": reason})

    if image is None:
        image = _read_image(sample)
    if isinstance(image, Exception):
        return skip(f"unreadable image: {image}")
    h, w = image.shape[:2]
    if sample.camera.image_size != (w, h):
        raise DatasetError(
            f"{sample.image_path}: the image is {w}x{h} but its calibration ({sample.camera.source}) "
            f"is for {sample.camera.image_size[0]}x{sample.camera.image_size[1]}"
        )
    provider = sample.face_provider  # detected, or the dataset's own (UT Multiview)
    try:
        fit = provider.fit(sample, image, _STATE["detector"])
    except NoFaceError as exc:
        return skip(f"no face: {exc}")
    except (PoseError, GazeAugError, InputError) as exc:
        return skip(f"pose failed: {exc}")
    target, vector = sample.gaze_target_mm, sample.gaze_vector

    def normalized() -> NormalizedSample:
        """The source image itself, normalized: the row ``normalize-dataset`` writes."""
        return normalize_image(
            image,
            fit.camera,
            fit.pose,
            fit.model.vertices_mm,
            fit.keypoints,
            gaze_target_mm=target,
            gaze_vector=vector,
            settings=s.normalization,
        )

    try:
        if s.kind == "normalize-dataset":
            samples = [normalized()]
            face = samples[0].face
            assert face is not None and face.gaze is not None  # every dataset sample has a gaze
            before = np.stack([face.head_pose, face.gaze])
        else:
            source = views_at(  # the source image's own labels, for the summary's "before"
                fit.model.vertices_mm,
                fit.keypoints,
                np.asarray(fit.pose.rotation)[None],
                np.asarray(fit.pose.translation_mm)[None],
                s.normalization,
                gaze_target_mm=target,
                gaze_vector=vector,
            )
            assert source.gaze is not None
            before = np.stack([source.head_pose[0, 2], source.gaze[0, 2]])  # face frame
            asset = face_asset(provider.mesh(fit, sample))
            rng = np.random.default_rng([s.seed, idx])
            if s.eyes == "redirect":
                places, looked_at = rig_looks(asset, _STATE["rig"], s.per_sample, rng)
                samples = []
                for j in range(len(places)):  # eyes of its own per sample: more eyes, not more views of them
                    subject = redirect_subject(fit, asset, rng, gaze_target_mm=target, gaze_vector=vector)
                    samples += render_redirected(
                        subject,
                        asset,
                        places[j : j + 1],
                        looked_at[j : j + 1],
                        settings=s.normalization,
                        threads=_STATE.get("threads", 0),
                        rng=rng,
                    )
            else:
                scene = _STATE["renderer"].scene(asset.render_mesh)
                places = sampled_placements(asset, s.distribution.sample(s.per_sample, rng))
                samples = render_poses(
                    scene,
                    asset,
                    places,
                    gaze_target_mm=target,
                    gaze_vector=vector,
                    settings=s.normalization,
                    renderer_name=s.renderer,
                )
            if s.with_source:  # after the draws, which it leaves as they are
                samples = [normalized(), *samples]
    except (PoseError, GazeAugError, InputError) as exc:
        return skip(f"failed: {exc}")
    rows = rows_from_samples(samples, sample.subject, idx, eye_keypoints=s.writes_eye_keypoints)
    return SampleOutcome(idx, rows, None, before)


#: Samples per task sent to a worker process (each task reads its next image while processing the current one).
_CHUNK_SAMPLES = 8


def _process_stream(samples: Iterable[GazeSample]) -> Iterator[SampleOutcome]:
    """Process samples in order while a reader thread decodes the next sample's image.

    Image decoding (OpenCV releases the GIL there) overlaps the landmark
    detection and rendering of the previous sample.
    """
    from concurrent.futures import Future, ThreadPoolExecutor

    with ThreadPoolExecutor(1, thread_name_prefix="gazeaug-read") as reader:
        it = iter(samples)
        nxt = next(it, None)
        pending: Future | None = reader.submit(_read_image, nxt) if nxt is not None else None
        while nxt is not None and pending is not None:
            current, image = nxt, pending
            nxt = next(it, None)
            pending = reader.submit(_read_image, nxt) if nxt is not None else None
            yield process_sample(current, image.result())


def _process_chunk(samples: list[GazeSample]) -> list[SampleOutcome]:
    return list(_process_stream(samples))


def _outcomes(samples: Iterator[GazeSample], settings: JobSettings, workers: int) -> Iterator[SampleOutcome]:
    if workers <= 1:
        _worker_init(settings)
        yield from _process_stream(samples)
        return
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    with ctx.Pool(workers, initializer=_worker_init, initargs=(settings, 1)) as pool:
        for outcomes in pool.imap(_process_chunk, chunks(samples, _CHUNK_SAMPLES), chunksize=1):
            yield from outcomes


def _stats(angles_rad: NDArray[np.float64]) -> dict[str, Any]:
    if len(angles_rad) == 0:
        return {"count": 0}
    d = np.degrees(angles_rad)
    edges = np.arange(-90, 91, 5)
    return {
        "count": int(len(d)),
        "mean_deg": np.round(d.mean(axis=0), 3).tolist(),
        "std_deg": np.round(d.std(axis=0), 3).tolist(),
        "hist_edges_deg": edges.tolist(),
        "hist_pitch": np.histogram(d[:, 0], edges)[0].tolist(),
        "hist_yaw": np.histogram(d[:, 1], edges)[0].tolist(),
    }


def _take(writer: H5Writer, outcome: SampleOutcome) -> None:
    """Hand one sample's outcome to the writer (rows or the skip, and its source labels)."""
    writer.append(outcome.rows, outcome.source_index, outcome.skipped)
    if outcome.before is not None:
        writer.append_source(outcome.source_index, outcome.before)


def shard_dir(output: str | Path) -> Path:
    """Where the Ray engine's actors write their shards: ``OUT.h5.shards/`` beside the output."""
    p = Path(output)
    return p.with_name(p.name + ".shards")


#: (eye patch (width, height), face patch (width, height) or None), pixels.
_PatchSizes = tuple[tuple[int, int], tuple[int, int] | None]


@dataclass(frozen=True)
class _ShardTask:
    """One block for a Ray actor: samples ``first`` to ``stop - 1``, written to ``path`` (see :func:`_ray_work`)."""

    first: int
    stop: int
    samples: list[GazeSample]
    path: str
    attrs: dict[str, Any]
    patch_sizes: _PatchSizes


def _shard_matches(path: Path, attrs: dict[str, Any], eye_keypoints: bool = False) -> bool:
    """A complete shard written with these settings, data and sample range (reused on ``--resume``).

    ``eye_keypoints``: whether this run writes the column (a shard of a gazeaug without it is redone).
    """
    import h5py

    try:
        with h5py.File(path, "r") as f:
            if not f.attrs.get("complete", False) or ("eye_keypoints" in f) != eye_keypoints:
                return False
            return all(
                json.loads(f.attrs.get(k, "null")) == json.loads(json.dumps(attrs[k]))
                for k in ("settings", "selection", "shard")
            )
    except (OSError, ValueError, RecursionError):
        return False


def _ray_setup(settings: JobSettings) -> None:
    """A Ray actor's state: what a local worker process builds (:func:`_worker_init`)."""
    _worker_init(settings, 1)


def _ray_work(task: _ShardTask) -> dict[str, Any]:
    """Process one block in a Ray actor into its shard file (one writer per shard), unless already there."""
    import contextlib
    import os

    from .engine import node_name

    node = node_name()
    path = Path(task.path)
    result = {"shard": task.path, "node": node, "samples": task.stop - task.first, "reused": True}
    keypoints = _STATE["settings"].writes_eye_keypoints  # the actor's settings (set up before any task)
    if path.exists() and _shard_matches(path, task.attrs, keypoints):
        return result
    path.parent.mkdir(parents=True, exist_ok=True)
    # A name of its own for this attempt: an actor presumed lost that is still writing never
    # shares a file with the one redoing its block (both write the same rows; the last rename wins).
    mine = path.with_name(f"{path.stem}.{uuid.uuid4().hex[:12]}.h5")
    eyes, face = task.patch_sizes  # uncompressed: read once by the driver, then deleted
    writer = H5Writer(mine, task.attrs, eyes, face_patch_size_wh=face, eye_keypoints=keypoints, compress=False)
    try:
        for outcome in _process_stream(task.samples):
            if outcome.skipped is not None:  # where it failed: a path one node cannot see is named with it
                outcome = SampleOutcome(outcome.source_index, None, {**outcome.skipped, "node": node}, outcome.before)
            _take(writer, outcome)
        writer.finish()
        os.replace(mine, path)
    except BaseException:
        writer.discard()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(mine)
        raise
    return {**result, "reused": False}


def _ray_blocks(
    samples: Iterable[GazeSample], size: int, shards: Path, attrs: dict[str, Any], patch_sizes: _PatchSizes
) -> Iterator[tuple[int, _ShardTask]]:
    """Blocks of consecutive samples, cut at multiples of ``size`` (so a resumed run cuts the same shards)."""
    groups = itertools.groupby(samples, key=lambda s: s.source_index // size)
    for b, (_, group) in enumerate(groups):
        yield b, _shard_task(list(group), shards, attrs, patch_sizes)


def _shard_task(chunk: list[GazeSample], shards: Path, attrs: dict[str, Any], patch_sizes: _PatchSizes) -> _ShardTask:
    first, stop = chunk[0].source_index, chunk[-1].source_index + 1
    path = shards / f"samples-{first:09d}-{stop:09d}.h5"
    return _ShardTask(first, stop, chunk, str(path), {**attrs, "shard": {"first": first, "stop": stop}}, patch_sizes)


def check_redirectable(reader: DatasetReader) -> None:
    """Refuse, before any work, a dataset whose faces redirected eyes cannot use.

    Redirection needs the landmark model's faces (MediaPipe's 478 points: eye contours
    and iris); a dataset that gives its own face (UT Multiview's head models) has none.

    Raises:
        GazeAugError: the dataset's first sample brings its own face.
    """
    from .datasets.base import DetectedFace

    first = next(iter(reader), None)
    if first is not None and not isinstance(first.face_provider, DetectedFace):
        raise GazeAugError(
            f"{getattr(reader, 'root', reader.name)}: redirected eyes need faces found by MediaPipe (478 landmarks "
            f"with the eye contours and iris); the {reader.name} dataset gives its own face models: augment it "
            "keeping its eyes"
        )


def run_dataset(
    reader: DatasetReader,
    output: str | Path,
    settings: JobSettings,
    *,
    workers: int = 1,
    resume: bool = False,
    overwrite: bool = False,
    limit: int | None = None,
    progress: bool = True,
    flush_every: int = 16,
    engine: Engine | None = None,
) -> dict[str, Any]:
    """Run ``augment`` or ``normalize-dataset`` over a dataset into ``output`` (.h5).

    Writes ``output`` (renamed from ``output.part`` when done), ``output`` with
    ``.summary.json`` and ``.distribution.png`` suffixes beside it.

    With ``engine`` on Ray, the actors write one shard per block into
    ``OUT.h5.shards/`` (see :func:`shard_dir`); the driver appends each shard to
    ``OUT.h5.part`` in dataset order as soon as the blocks before it are in, and
    deletes it. The arrays are those of the local engine with the same seed.
    ``--resume`` continues after the last appended shard, reusing the complete
    shards already written.

    Args:
        reader: the dataset.
        output: the ``.h5`` to write.
        settings: what the run does.
        workers: processes of the local engine (``engine.workers`` for Ray).
        resume: continue an interrupted run (the same settings and data only).
        overwrite: replace a complete output.
        limit: only the first ``limit`` samples.
        progress: show a progress bar.
        flush_every: local engine: samples between flushes (the resume granularity).
        engine: where the work runs (default: this machine, ``workers`` processes).

    Returns:
        The summary (also written as JSON).

    Raises:
        DatasetError: bad dataset files; GazeAugError: bad settings or output state, or Ray
        cannot be reached.
    """
    engine = engine or Engine()
    if engine.kind == "ray":
        from .engine import ray_session
        from .io_h5 import check_output_state

        check_output_state(Path(output), resume=resume, overwrite=overwrite)  # at once, not after Ray's start

        with ray_session(engine):  # connected (or failed to) before anything is written
            return _run_dataset(
                reader, output, settings, workers, resume, overwrite, limit, progress, flush_every, engine
            )
    return _run_dataset(reader, output, settings, workers, resume, overwrite, limit, progress, flush_every, engine)


def _run_dataset(
    reader: DatasetReader,
    output: str | Path,
    settings: JobSettings,
    workers: int,
    resume: bool,
    overwrite: bool,
    limit: int | None,
    progress: bool,
    flush_every: int,
    engine: Engine,
) -> dict[str, Any]:
    from facemesh.outputs import output_lock

    out = Path(output)
    if limit is not None and not (isinstance(limit, int) and limit >= 1):
        raise GazeAugError(f"limit: expected an integer >= 1, got {limit!r}")
    total = len(reader) if limit is None else min(len(reader), limit)
    if total == 0:
        raise DatasetError(f"{getattr(reader, 'root', reader.name)}: the dataset has no samples")
    if settings.eyes == "redirect":
        check_redirectable(reader)
    attrs = {
        "gazeaug_version": __version__,
        "kind": settings.kind,
        "dataset": str(getattr(reader, "root", "")),
        "dataset_format": reader.name,
        "settings": settings.as_dict(),
        # what is read: a resumed run must read the same (the same dataset, samples and limit)
        "selection": {
            "dataset": str(Path(str(getattr(reader, "root", ""))).resolve()),
            "format": reader.name,
            "dataset_samples": len(reader),
            "samples": total,
        },
    }
    with output_lock(out):  # held for the whole run: a second run is told this one is writing
        norm = settings.normalization
        writer = H5Writer(
            out,
            attrs,
            norm.patch_size_wh,
            face_patch_size_wh=norm.face_patch_size_wh,
            eye_keypoints=settings.writes_eye_keypoints,
            resume=resume,
            overwrite=overwrite,
        )
        start = writer.next_source_index
        todo = (s for s in reader if start <= s.source_index < total)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=total, initial=start, unit="sample", desc=settings.kind, dynamic_ncols=True)
        t0 = time.perf_counter()
        t_first = None
        at_first = 0  # samples done at t_first (1 locally, a block on Ray)
        processed = 0
        shards = shard_dir(out.resolve())  # absolute: actors may run in another folder

        def merge(_b: int, result: dict[str, Any]) -> None:
            """Append one Ray shard (in block order) to the output and drop it."""
            nonlocal t_first, processed, at_first
            path = Path(result["shard"])
            if not path.exists():
                raise GazeAugError(
                    f"{path}: the shard written on {result['node']} is not visible on this machine; "
                    "-o must be on a filesystem every node shares (docs/ray.md)"
                )
            writer.append_file(path)
            writer.flush()
            path.unlink()
            processed += result["samples"]
            if t_first is None:
                t_first, at_first = time.perf_counter(), processed
            if bar is not None:
                bar.update(result["samples"])

        try:
            with interrupt_between_steps() as interrupted:
                if engine.kind == "ray":
                    from .engine import map_blocks

                    blocks = _ray_blocks(
                        todo, engine.block_size, shards, attrs, (norm.patch_size_wh, norm.face_patch_size_wh)
                    )
                    map_blocks(
                        engine, blocks, _ray_work, _ray_setup, (settings,), on_result=merge, interrupted=interrupted
                    )
                else:
                    for n, outcome in enumerate(_outcomes(todo, settings, workers), start=1):
                        _take(writer, outcome)
                        processed += 1
                        if t_first is None:
                            t_first, at_first = time.perf_counter(), processed
                        if bar is not None:
                            bar.update(1)
                        if n % flush_every == 0:
                            writer.flush()
                        if interrupted():
                            raise KeyboardInterrupt
        except KeyboardInterrupt:
            writer.close()  # the .part (and the complete shards) stay for --resume
            if bar is not None:
                bar.close()
            raise
        except WorkersLostError as exc:  # the cluster, not the data: what was done stays, as for Ctrl-C
            writer.close()
            if bar is not None:
                bar.close()
            raise WorkersLostError(
                f"{exc}; kept {writer.part} and the finished shards: run the same command with --resume to continue"
            ) from None
        except BaseException:
            created = writer.created
            writer.discard()  # a failed run (bad dataset file...) leaves nothing to resume that it made
            if created:
                shutil.rmtree(shards, ignore_errors=True)
            if bar is not None:
                bar.close()
            raise
        if bar is not None:
            bar.close()
        t_end = time.perf_counter()
        seconds = t_end - t0
        steady = (
            (processed - at_first) / (t_end - t_first)
            if t_first is not None and processed > at_first and t_end > t_first
            else None
        )
        writer.finish()
        shutil.rmtree(shards, ignore_errors=True)  # only leftovers of lost actors remain there
        return _summarise(out, reader, settings, writer, processed, seconds, total, steady)


def _summarise(
    out: Path,
    reader: DatasetReader,
    settings: JobSettings,
    writer: H5Writer,
    processed: int,
    seconds: float,
    total: int,
    steady: float | None,
) -> dict[str, Any]:
    import h5py

    from facemesh.io import atomic_write

    from .viz import plot_distributions

    with h5py.File(out, "r") as f:
        after = np.stack([f["head_pose"][()], f["gaze"][()]], axis=1).astype(np.float64)
        before = f["sources/labels"][()].astype(np.float64)
        rows = int(f["left_eye"].shape[0])
    summary = {
        "output": str(out),
        "kind": settings.kind,
        "dataset": str(getattr(reader, "root", "")),
        "dataset_format": reader.name,
        "samples": total,
        "processed_this_run": processed,
        "seconds_this_run": round(seconds, 3),
        "samples_per_second": round(processed / seconds, 3) if seconds > 0 else None,
        # after the first result: excludes starting the workers and loading the models
        "steady_samples_per_second": None if steady is None else round(steady, 3),
        "rows": rows,
        "skipped": len(writer.skipped),
        "skipped_samples": writer.skipped,
        "distributions": {
            "before": {"head_pose": _stats(before[:, 0]), "gaze": _stats(before[:, 1])},
            "after": {"head_pose": _stats(after[:, 0]), "gaze": _stats(after[:, 1])},
        },
        "settings": settings.as_dict(),
        "gazeaug_version": __version__,
    }
    with atomic_write(out.with_suffix(".summary.json")) as fh:
        fh.write(json.dumps(summary, indent=1).encode("utf-8"))
    plot_distributions(
        {
            "dataset": {"head_pose": before[:, 0], "gaze": before[:, 1]},
            settings.kind: {"head_pose": after[:, 0], "gaze": after[:, 1]},
        },
        out.with_suffix(".distribution.png"),
        title=f"{reader.name}: head pose and gaze (face-normalized), before and after",
    )
    return summary
