"""The original-vs-augmented experiment (the paper's Table 1), built so that it cannot fool us.

For a training dataset and a test dataset: normalize the training set
(``normalize-dataset``), and for each of several seeds augment it
(``augment``), train one model on each set with the same hyper-parameters
(a keypoint loss, which only the augmented set's drawn eyes can feed, is the
augmented model's alone, and the report says so)
*and the same number of optimizer steps*, evaluate both on the test set
through test-time normalization, and report every metric of
:mod:`gazeaug.metrics` as mean and standard deviation over the seeds, beside
the constant guess (the error of predicting the test set's mean gaze for
every image), with the error reduction and its bootstrap interval.

Same steps: the augmented set has ``per_sample`` times the rows of the
original one, so the same epochs would give the original model that many
times fewer optimizer steps. The augmented model trains ``train.epochs``
epochs (by default fitted to its size, :meth:`gazeaug.train.TrainSettings.fitted`);
the original model trains :func:`matched_epochs` epochs: the fewest
whose steps (``epochs * ceil(rows / batch_size)``) reach the augmented
run's.

Too few steps: the default model has BatchNorm layers, whose running
statistics (an exponential average, momentum 0.1, starting from mean 0 and
variance 1) are what the model uses at test time. After few steps they still
weigh the start values (``0.9 ** 20 = 0.12`` after 20 steps) and describe
weights that have since changed; such a model outputs a near-constant
direction and its error measures nothing. A run with fewer steps than
:data:`MIN_STEPS_BATCHNORM` (200) for a model with BatchNorm draws a
:class:`TooFewStepsWarning`.

A second test set of the *same people in the training rig* (``test_same_rig``)
splits the error into "new person" (same rig) and "new person and new rig".
The built-in setup (:func:`builtin_setup`) simulates both. Every model is also
evaluated on the original training images (``seen``): a model that does not
read the eyes even there has not learnt at all; one that reads them there but
not on new people does not generalize. :func:`reading_verdict` says which
model reads the eyes of which set (:data:`READS_EYES_BELOW`).

The report (``report.md``) holds a table per metric, the distribution plots
of the training sets and of the test set, and example patches of each.
"""

from __future__ import annotations

import json
import math
import shutil
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .datasets import open_dataset
from .errors import GazeAugError
from .jobs import JobSettings, check_redirectable, run_dataset
from .normalize import NormalizationSettings
from .sampling import HeadPoseDistribution, Rig
from .train import TrainSettings

__all__ = [
    "ExperimentSettings",
    "BuiltinSetup",
    "TooFewStepsWarning",
    "MIN_STEPS_BATCHNORM",
    "BUILTIN_TRAIN",
    "BUILTIN_TEST_RIG",
    "METRICS",
    "run_experiment",
    "simulated_setup",
    "builtin_setup",
    "optimizer_steps",
    "matched_epochs",
    "min_steps_for",
    "check_steps",
    "table",
    "metric_table",
    "reduction_table",
    "steps_table",
    "format_mean_std",
    "mean_std",
    "READS_EYES_BELOW",
    "reading_verdict",
]

#: The fewest optimizer steps a model with BatchNorm layers is trained for before its test
#: errors mean anything (see the module docstring).
MIN_STEPS_BATCHNORM = 200

#: The training hyper-parameters of the built-in simulated setup: the epochs and batch size fitted
#: to the augmented set's size (:meth:`gazeaug.train.TrainSettings.fitted`) for 100k samples (the
#: library's default is 500k: six runs of that would not fit the built-in run's half hour on two
#: cores), the original model trained as many optimizer steps.
BUILTIN_TRAIN = TrainSettings(auto_samples=100_000)

#: The rig the built-in setup's test set is simulated in (its training set: ``screen``), and the rig
#: its augmentation turns the eyes to unless told otherwise (``gazeaug experiment``'s default recipe).
BUILTIN_TEST_RIG = "wheelchair"

#: The metrics of :func:`gazeaug.metrics.summarize` the report tabulates: key, title, unit, digits.
METRICS: tuple[tuple[str, str, str, int], ...] = (
    ("mean_deg", "Mean angular error", "deg", 2),
    ("ratio_to_constant", "Error over the constant-guess error: 1 is no better than the constant guess", "", 3),
    ("bias_removed_deg", "Bias vs reading: the error after removing the model's global offset", "deg", 2),
    ("offset_pitch_deg", "Global offset of pitch: mean predicted - true", "deg", 2),
    ("offset_yaw_deg", "Global offset of yaw: mean predicted - true", "deg", 2),
    ("pearson_pitch", "Pearson r, predicted vs true pitch", "", 3),
    ("pearson_yaw", "Pearson r, predicted vs true yaw", "", 3),
    (
        "subject_offsets_removed_deg",
        "Per person: the error after removing each subject's own offset (a perfect one-offset calibration)",
        "deg",
        2,
    ),
    ("pearson_within_pitch", "Pearson r within subjects (each subject's means removed), pitch", "", 3),
    ("pearson_within_yaw", "Pearson r within subjects (each subject's means removed), yaw", "", 3),
    ("subject_mean_deg", "Mean of the per-subject mean errors", "deg", 2),
    ("median_deg", "Median angular error", "deg", 2),
)

#: A model *reads the eyes* of a test set when its error after removing its global offset (mean
#: over seeds) is below this fraction of the constant-guess error: following each image's gaze then
#: explains at least a tenth of what the best single direction leaves. Above it, any difference
#: between the models is a difference of global offset.
READS_EYES_BELOW = 0.9

#: Test sets with at least this many subjects are bootstrapped by subject, smaller ones by sample.
MIN_SUBJECTS_TO_RESAMPLE = 5


class TooFewStepsWarning(UserWarning):
    """A model was trained for fewer optimizer steps than its normalization layers need."""


# --------------------------------------------------------------------------- the built-in setup


def _wheel_faces() -> list[str | None]:
    """Face photos inside installed wheels: the built-in astronaut (None) and matplotlib's grace_hopper."""
    faces: list[str | None] = [None]
    try:
        import matplotlib

        p = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
        if p.is_file():
            faces.append(str(p))
    except ImportError:
        pass
    return faces


@dataclass(frozen=True)
class BuiltinSetup:
    """The folders of the built-in simulated setup (plain folder datasets).

    Attributes:
        train: ``screen`` rig, every face but the last.
        test: ``wheelchair`` rig, the last face (new person, new rig).
        test_same_rig: ``screen`` rig, the last face (new person, the training rig).
    """

    train: Path
    test: Path
    test_same_rig: Path


def _simulate_sets(
    out: Path,
    extra_faces: Sequence[str | Path] | None,
    large: bool,
    seed: int,
    progress: bool,
    sizes: tuple[int, int] | None,
    same_rig: bool,
) -> BuiltinSetup:
    from .sampling import BUILTIN_RIGS
    from .simulate import simulate

    faces: list[str | Path | None] = [*_wheel_faces(), *(extra_faces or [])]
    if len(faces) < 2:
        raise GazeAugError("the simulated setup needs at least two faces (one to train on, one to test on)")
    n_train, n_test = sizes or ((400, 200) if large else (60, 60))
    setup = BuiltinSetup(out / "sim_train_screen", out / "sim_test_wheelchair", out / "sim_test_screen")
    kw: dict[str, Any] = {"progress": progress, "overwrite": True}
    # every training image its own simulated identity (shape, eyes, skin, glasses): one photo, many people
    simulate(
        faces[:-1], BUILTIN_RIGS["screen"], setup.train, per_face=n_train, identities_per_face=n_train, seed=seed, **kw
    )
    simulate(faces[-1:], BUILTIN_RIGS[BUILTIN_TEST_RIG], setup.test, per_face=n_test, seed=seed + 1, **kw)
    if same_rig:  # the same seed: the same simulated person (the same kappa), in the training rig
        simulate(faces[-1:], BUILTIN_RIGS["screen"], setup.test_same_rig, per_face=n_test, seed=seed + 1, **kw)
    return setup


def builtin_setup(
    out_dir: str | Path,
    *,
    extra_faces: Sequence[str | Path] | None = None,
    large: bool = False,
    seed: int = 0,
    progress: bool = True,
    sizes: tuple[int, int] | None = None,
) -> BuiltinSetup:
    """Simulate the built-in setup: a ``screen`` training set; the test faces in the ``wheelchair`` and ``screen`` rigs.

    Faces: the photos inside installed wheels and ``extra_faces``; the training set gets every
    face but the last, both test sets the last one (a person the models never saw; the same
    simulated person in both rigs, with the same eye-axis offset). Default size: 60 training
    images per face and 60 images per test set (``large``: 400 and 200; ``sizes`` = (training
    images per face, test images per set) overrides both).

    Raises:
        GazeAugError: fewer than two faces.
    """
    return _simulate_sets(Path(out_dir), extra_faces, large, seed, progress, sizes, same_rig=True)


def simulated_setup(
    out_dir: str | Path,
    *,
    extra_faces: list[Path] | None = None,
    large: bool = False,
    seed: int = 0,
    progress: bool = True,
    sizes: tuple[int, int] | None = None,
) -> tuple[Path, Path]:
    """The built-in training set (``screen``) and test set (``wheelchair``) only; see :func:`builtin_setup`."""
    setup = _simulate_sets(Path(out_dir), extra_faces, large, seed, progress, sizes, same_rig=False)
    return setup.train, setup.test


# --------------------------------------------------------------------------- steps


def optimizer_steps(epochs: int, rows: int, batch_size: int) -> int:
    """Optimizer steps of a training run: ``epochs * ceil(rows / batch_size)`` (an epoch's last batch may be short)."""
    for name, v, low in (("epochs", epochs, 0), ("rows", rows, 0), ("batch_size", batch_size, 1)):
        if not (isinstance(v, int) and v >= low):
            raise GazeAugError(f"{name}: expected an integer >= {low}, got {v!r}")
    return epochs * math.ceil(rows / batch_size)


def matched_epochs(steps: int, rows: int, batch_size: int) -> int:
    """The fewest epochs (>= 1) over ``rows`` rows whose optimizer steps reach ``steps``.

    Its steps are ``>= steps`` and fewer than ``steps + ceil(rows / batch_size)``: the
    original model is never trained for fewer steps than the augmented one.

    Raises:
        GazeAugError: ``rows`` < 1, ``batch_size`` < 1 or ``steps`` < 0.
    """
    if not (isinstance(rows, int) and rows >= 1):
        raise GazeAugError(f"rows: expected an integer >= 1, got {rows!r}")
    per_epoch = optimizer_steps(1, rows, batch_size)
    if not (isinstance(steps, int) and steps >= 0):
        raise GazeAugError(f"steps: expected an integer >= 0, got {steps!r}")
    return max(1, math.ceil(steps / per_epoch))


def min_steps_for(model: Any) -> int:
    """The documented minimum of optimizer steps for a model's normalization layers.

    Args:
        model: a ``torch.nn.Module``.

    Returns:
        :data:`MIN_STEPS_BATCHNORM` when the model has BatchNorm layers (running statistics), else 0.
    """
    from torch.nn.modules.batchnorm import _BatchNorm

    return MIN_STEPS_BATCHNORM if any(isinstance(m, _BatchNorm) for m in model.modules()) else 0


def check_steps(name: str, steps: int, minimum: int) -> bool:
    """Warn (:class:`TooFewStepsWarning`) when a run has fewer optimizer steps than ``minimum``; True if enough."""
    if steps >= minimum:
        return True
    warnings.warn(
        f"the {name} model gets {steps} optimizer steps, fewer than the {minimum} its BatchNorm layers need "
        "for usable running statistics: its test errors measure an untrained model. Raise the training "
        "epochs or lower the batch size (TrainSettings.epochs, TrainSettings.batch_size)",
        TooFewStepsWarning,
        stacklevel=2,
    )
    return False


# --------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class ExperimentSettings:
    """What the experiment does.

    Attributes:
        per_sample: K augmented samples per training sample.
        distribution: the application's head-pose distribution.
        train: hyper-parameters, shared by both models; ``train.epochs`` are the augmented
            model's epochs (the original model's are matched in steps), ``train.seed`` is
            replaced by each run's seed. Epochs and batch size left at None are fitted to the
            augmented set (:meth:`gazeaug.train.TrainSettings.fitted`) and the original model uses
            the same batch size. A keypoint loss (``train.keypoint_loss_weight``) teaches where the
            drawn eyes' points lie: only the augmented set's redirected eyes are drawn, so it needs
            ``eyes="redirect"`` and the original model trains without it (weight 0, recorded as
            ``keypoint_loss_weight`` in the results' ``runs``).
        workers: processes for the dataset runs.
        seed: the first seed; run ``i`` uses ``seed + i`` for the augmentation and the training.
        seeds: how many runs (default 3); every metric is reported as mean and standard
            deviation over them.
        n_boot: bootstrap replicates of the reduction's interval (default 2000).
        rig: the application's rig (default None); with ``eyes="redirect"`` the augmented set's head
            poses and gaze targets are drawn from it.
        eyes: ``"keep"`` (default, the paper's method) or ``"redirect"``: see
            :class:`gazeaug.jobs.JobSettings`.
        with_source: the augmented model trains on the original rows as well as the augmented
            ones (``JobSettings.with_source``; default False, the paper's protocol). The original
            model is matched in steps either way.
        normalization: the normalized camera and eye patch of every set, the original, the
            augmented and the test sets alike (default: :class:`gazeaug.normalize.NormalizationSettings`'s,
            the paper's 650 px at 600 mm, 60 x 36 patches). The models record it and are
            evaluated through it.
    """

    per_sample: int = 4
    distribution: HeadPoseDistribution = field(default_factory=HeadPoseDistribution)
    train: TrainSettings = field(default_factory=TrainSettings)
    workers: int = 1
    seed: int = 0
    seeds: int = 3
    n_boot: int = 2000
    rig: Rig | None = None
    eyes: str = "keep"
    with_source: bool = False
    normalization: NormalizationSettings = field(default_factory=NormalizationSettings)

    def __post_init__(self) -> None:
        if not isinstance(self.normalization, NormalizationSettings):
            raise GazeAugError(
                f"normalization: expected NormalizationSettings, got {type(self.normalization).__name__}"
            )
        if self.eyes not in JobSettings.EYES:
            raise GazeAugError(f"eyes: expected one of {JobSettings.EYES}, got {self.eyes!r}")
        if self.eyes == "redirect" and self.rig is None:
            raise GazeAugError("redirected eyes need the application's rig (its targets give the gazes)")
        if not isinstance(self.with_source, bool):
            raise GazeAugError(f"with_source: expected true or false, got {self.with_source!r}")
        if not (isinstance(self.per_sample, int) and self.per_sample >= 1):
            raise GazeAugError(f"per_sample: expected an integer >= 1, got {self.per_sample!r}")
        if not (isinstance(self.seeds, int) and 1 <= self.seeds <= 100):
            raise GazeAugError(f"seeds: expected an integer from 1 to 100, got {self.seeds!r}")
        if not (isinstance(self.n_boot, int) and self.n_boot >= 100):
            raise GazeAugError(f"n_boot: expected an integer >= 100, got {self.n_boot!r}")
        if not (isinstance(self.seed, int) and self.seed >= 0):
            raise GazeAugError(f"seed: expected an integer >= 0, got {self.seed!r}")
        if isinstance(self.train, TrainSettings) and self.train.keypoint_loss_weight > 0 and self.eyes != "redirect":
            # the eye keypoints are where the drawn eyes put them: only redirected eyes are drawn
            raise GazeAugError(
                "train.keypoint_loss_weight > 0 needs the augmented set's eye keypoints, which only "
                f"redirected eyes have: expected eyes='redirect', got eyes={self.eyes!r}"
            )
        side = min(self.normalization.patch_size_wh)
        if isinstance(self.train, TrainSettings) and self.train.shift_average_px >= side:
            # refused here, before the sets are made, not by the first training after minutes of work
            raise GazeAugError(
                f"shift_average_px: {self.train.shift_average_px} px must be smaller than the eye patches' sides "
                f"({self.normalization.patch_size_wh[0]} x {self.normalization.patch_size_wh[1]})"
            )


# --------------------------------------------------------------------------- aggregation


def _flat(metrics: Mapping[str, Any] | None) -> dict[str, float | None]:
    """The scalar metrics of one evaluation (the offset split into pitch and yaw)."""
    if metrics is None:
        return {k: None for k, *_ in METRICS}
    out = {k: metrics.get(k) for k, *_ in METRICS if k in metrics}
    off = metrics.get("offset_deg") or [None, None]
    out["offset_pitch_deg"], out["offset_yaw_deg"] = off[0], off[1]
    return out


def mean_std(values: Sequence[float | None]) -> dict[str, Any]:
    """Mean and sample standard deviation (n - 1) of the values that are not None or NaN, over seeds.

    Returns:
        ``mean`` (None without values), ``std`` (None with fewer than two), ``n`` (values used),
        ``per_seed`` (the values as given, None for undefined).
    """
    v = [float(x) for x in values if x is not None and math.isfinite(x)]
    return {
        "mean": float(np.mean(v)) if v else None,
        "std": float(np.std(v, ddof=1)) if len(v) >= 2 else None,
        "n": len(v),
        "per_seed": [None if x is None or not math.isfinite(x) else float(x) for x in values],
    }


def _rows_by_index(ev: Mapping[str, Any]) -> dict[int, dict[str, Any]]:
    return {int(r["index"]): r for r in ev.get("rows") or []}


def _test_summary(name: str, per_seed: list[dict[str, Any]], n_boot: int, seed: int) -> dict[str, Any]:
    """One test set over all seeds: metrics (mean, std) of both models and the constant guess, reduction, bootstrap."""
    from .metrics import bootstrap_reduction, mean_gaze, summarize

    evals = {m: [run[m]["eval"][name] for run in per_seed] for m in ("original", "augmented")}
    out: dict[str, Any] = {"metrics": {}}
    for key, *_ in METRICS:
        out["metrics"][key] = {
            m: mean_std([_flat(ev.get("metrics"))[key] for ev in evals[m]]) for m in ("original", "augmented")
        }
    # the rows every run evaluated (face fitting does not depend on the model: normally all of them)
    maps = [_rows_by_index(ev) for m in evals for ev in evals[m]]
    common = sorted(set.intersection(*(set(mp) for mp in maps))) if maps else []
    out["count"] = len(common)
    out["skipped"] = max(int(ev.get("skipped", 0)) for m in evals for ev in evals[m])
    if not common:
        for key, *_ in METRICS:
            out["metrics"][key]["constant"] = None
        out["reduction_percent"], out["bootstrap"] = mean_std([None] * len(per_seed)), None
        return out
    first = maps[0]
    true = np.array([[first[i]["true_pitch_rad"], first[i]["true_yaw_rad"]] for i in common])
    subjects = [str(first[i]["subject"]) for i in common]

    const = _flat(summarize(np.broadcast_to(mean_gaze(true), true.shape), true, subjects))
    for key, *_ in METRICS:
        out["metrics"][key]["constant"] = const[key]

    def errors(m: str) -> np.ndarray:  # (seeds, N) degrees
        return np.array([[_rows_by_index(ev)[i]["error_deg"] for i in common] for ev in evals[m]], dtype=float)

    eo, ea = errors("original"), errors("augmented")
    reds = [100.0 * (o.mean() - a.mean()) / o.mean() if o.mean() > 0 else None for o, a in zip(eo, ea)]
    out["reduction_percent"] = mean_std(reds)
    n_subjects = len(set(subjects))
    resample = "subjects" if n_subjects >= MIN_SUBJECTS_TO_RESAMPLE else "samples"
    # the seed-averaged error of each sample, so the interval covers the test samples (or people)
    out["bootstrap"] = bootstrap_reduction(
        eo.mean(axis=0), ea.mean(axis=0), subjects, resample=resample, n_boot=n_boot, seed=seed
    )
    out["bootstrap"]["subjects"] = n_subjects
    return out


# --------------------------------------------------------------------------- the run


def _examples(h5: Path, out: Path, n: int = 8) -> None:
    from facemesh.io import save_image_rgb

    from .io_h5 import read_h5

    d = read_h5(h5, ["left_eye", "right_eye"])
    k = min(n, len(d["left_eye"]))
    if k == 0:
        return
    idx = np.linspace(0, len(d["left_eye"]) - 1, k).astype(int)
    tiles = [np.concatenate([d["right_eye"][i], d["left_eye"][i]], axis=1) for i in idx]
    save_image_rgb(out, np.concatenate(tiles, axis=0))


def _slim(ev: Mapping[str, Any]) -> dict[str, Any]:
    """An evaluation without its per-row lists (those are in the eval folders' errors.json)."""
    return {k: v for k, v in ev.items() if k not in ("rows", "skipped_samples")}


def run_experiment(
    train_dataset: str | Path,
    test_dataset: str | Path,
    out_dir: str | Path,
    settings: ExperimentSettings | None = None,
    *,
    train_format: str | None = None,
    test_format: str | None = None,
    test_same_rig: str | Path | None = None,
    test_same_rig_format: str | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Run the experiment; returns the results (also in ``out_dir/results.json`` and ``report.md``).

    Args:
        train_dataset: the training dataset folder.
        test_dataset: the test dataset folder (people, and usually a rig, the training set lacks).
        out_dir: where everything goes (``seedS/`` folders hold each run's models and evaluations).
        settings: see :class:`ExperimentSettings`.
        train_format: the training dataset's format (None: detected).
        test_format: the test dataset's format (None: detected).
        test_same_rig: optional: the test people in the training set's rig, to split the error
            into "new person" and "new person and new rig".
        test_same_rig_format: its format (None: detected).
        progress: show progress bars.

    Warns:
        TooFewStepsWarning: a model gets fewer optimizer steps than its normalization layers need.

    Raises:
        GazeAugError, DatasetError: bad settings or datasets; no training rows.
    """
    from facemesh.io import atomic_write

    from .evaluate import evaluate_dataset, evaluate_h5, write_report
    from .models import create_model
    from .train import load_model, train

    s = settings or ExperimentSettings()
    out = Path(out_dir)
    train_reader = open_dataset(train_dataset, train_format)
    if s.eyes == "redirect":
        check_redirectable(train_reader)  # before minutes of normalizing the original set
    tests = {"test": (test_dataset, open_dataset(test_dataset, test_format))}
    if test_same_rig is not None:
        tests["test_same_rig"] = (test_same_rig, open_dataset(test_same_rig, test_same_rig_format))
    minimum = min_steps_for(create_model(s.train.model, **s.train.model_options))
    out.mkdir(parents=True, exist_ok=True)  # once the datasets and the model are known good: a refusal writes nothing

    def dataset(reader: Any, h5: Path, job: JobSettings, what: str) -> dict[str, Any]:
        summary = run_dataset(reader, h5, job, workers=s.workers, overwrite=True, progress=progress)
        if summary["rows"] == 0:
            raise GazeAugError(f"{train_dataset}: no training rows for the {what} set (no faces found?)")
        return summary

    original_h5 = out / "train_original.h5"
    original = dataset(
        train_reader,
        original_h5,
        JobSettings(kind="normalize-dataset", seed=s.seed, normalization=s.normalization),
        "original",
    )
    _examples(original_h5, out / "examples_original.png")
    runs_info: dict[str, dict[str, Any]] = {}
    per_seed: list[dict[str, Any]] = []
    for i in range(s.seeds):
        seed = s.seed + i
        d = out / f"seed{seed}"
        d.mkdir(exist_ok=True)
        aug_h5 = d / "train_augmented.h5"
        job = JobSettings(
            kind="augment",
            per_sample=s.per_sample,
            distribution=s.distribution,
            seed=seed,
            rig=None if s.rig is None else s.rig.as_dict(),
            eyes=s.eyes,
            normalization=s.normalization,
            with_source=s.with_source,
        )
        augmented = dataset(train_reader, aug_h5, job, "augmented")
        if i == 0:  # the report's pictures of the augmented set: the first seed's
            _examples(aug_h5, out / "examples_augmented.png")
            shutil.copyfile(aug_h5.with_suffix(".distribution.png"), out / "train_augmented.distribution.png")
        fitted = s.train.fitted(augmented["rows"])  # epochs and batch left to None: fitted to the augmented set
        batch, aug_epochs = int(fitted.batch_size or 0), int(fitted.epochs or 0)
        aug_steps = optimizer_steps(aug_epochs, augmented["rows"], batch)
        orig_epochs = matched_epochs(aug_steps, original["rows"], batch)
        plan = {
            "augmented": (aug_h5, augmented, aug_epochs),
            "original": (original_h5, original, orig_epochs),
        }
        run: dict[str, Any] = {"seed": seed}
        for name in ("original", "augmented"):
            h5, summary, epochs = plan[name]
            steps = optimizer_steps(epochs, summary["rows"], batch)
            if i == 0:
                check_steps(name, steps, minimum)
            ts = replace(s.train, epochs=epochs, batch_size=batch, seed=seed)
            if name == "original":  # no eye is drawn in the original set: it has no keypoints to learn
                ts = replace(ts, keypoint_loss_weight=0.0)
            model_path = d / f"model_{name}.pt"
            train(h5, model_path, ts, progress=progress)
            model, meta = load_model(model_path)
            run[name] = {"rows": summary["rows"], "epochs": epochs, "steps": steps, "eval": {}}
            for tname, (_, reader) in tests.items():
                ev = evaluate_dataset(model, meta, reader, progress=progress)
                write_report(ev, d / f"eval_{name}_{tname}")
                run[name]["eval"][tname] = ev
            # the sanity anchor: the original training images (the original model saw these very
            # images, the augmented one their faces re-rendered at other poses)
            ev = evaluate_h5(model, original_h5)
            write_report(ev, d / f"eval_{name}_seen")
            run[name]["eval"]["seen"] = ev
            runs_info[name] = {  # the same for every seed unless the augmentation finds other faces
                "rows": summary["rows"],
                "skipped": summary["skipped"],
                "batch_size": batch,
                "epochs": epochs,
                "steps": steps,
                "min_steps": minimum,
                "enough_steps": steps >= minimum,
                "keypoint_loss_weight": ts.keypoint_loss_weight,
            }
        per_seed.append(run)
    # the test set's own distribution (normalize it, no training)
    run_dataset(
        tests["test"][1],
        out / "test_normalized.h5",
        JobSettings(kind="normalize-dataset", normalization=s.normalization),
        workers=s.workers,
        overwrite=True,
        progress=progress,
    )
    labels = (
        {"test": "new person, new rig", "test_same_rig": "new person, training rig"}
        if "test_same_rig" in tests
        else {"test": "test set"}
    )
    labels["seen"] = "training images (original set)"
    results: dict[str, Any] = {
        "train_dataset": str(train_dataset),
        "test_dataset": str(test_dataset),
        "test_same_rig_dataset": None if test_same_rig is None else str(test_same_rig),
        "seeds": [run["seed"] for run in per_seed],
        "tests": {},
    }
    for tname, tpath in [*((k, v[0]) for k, v in tests.items()), ("seen", original_h5)]:
        t = _test_summary(tname, per_seed, s.n_boot, s.seed)
        results["tests"][tname] = {"label": labels[tname], "dataset": str(tpath), **t}
    results["tests"]["seen"]["anchor"] = True  # a sanity check, not a test set: no reduction reported
    main_test = results["tests"]["test"]
    results["runs"] = {}
    for name in ("original", "augmented"):
        m = main_test["metrics"]
        results["runs"][name] = {
            **runs_info[name],
            "mean_error_deg": m["mean_deg"][name]["mean"],
            "median_error_deg": m["median_deg"][name]["mean"],
            "test_count": main_test["count"],
            "test_skipped": main_test["skipped"],
        }
    results["reduction_percent"] = main_test["reduction_percent"]["mean"]
    results["per_seed"] = [
        {
            "seed": run["seed"],
            **{
                name: {
                    "rows": run[name]["rows"],
                    "epochs": run[name]["epochs"],
                    "steps": run[name]["steps"],
                    "eval": {t: _slim(ev) for t, ev in run[name]["eval"].items()},
                }
                for name in ("original", "augmented")
            },
        }
        for run in per_seed
    ]
    results["settings"] = {
        "per_sample": s.per_sample,
        "distribution": s.distribution.as_dict(),
        "eyes": s.eyes,
        "with_source": s.with_source,
        "rig": None if s.rig is None else s.rig.name,
        "normalization": s.normalization.as_dict(),
        "train": asdict(s.train),
        "seed": s.seed,
        "seeds": s.seeds,
        "n_boot": s.n_boot,
    }
    with atomic_write(out / "results.json") as fh:
        fh.write(json.dumps(results, indent=1, default=float).encode("utf-8"))
    _report(out, results)
    return results


# --------------------------------------------------------------------------- the tables


def format_mean_std(stat: Mapping[str, Any] | None, digits: int = 2, unit: str = "") -> str:
    """``"mean ± std unit"`` of a :func:`mean_std` entry; ``"mean unit"`` without a std; ``"n/a"`` without a mean."""
    if not stat or stat.get("mean") is None:
        return "n/a"
    u = f" {unit}" if unit else ""
    if stat.get("std") is None:
        return f"{stat['mean']:.{digits}f}{u}"
    return f"{stat['mean']:.{digits}f} ± {stat['std']:.{digits}f}{u}"


def _value(v: float | None, digits: int, unit: str = "") -> str:
    if v is None or not math.isfinite(v):
        return "n/a"
    return f"{v:.{digits}f}" + (f" {unit}" if unit else "")


def table(results: Mapping[str, Any]) -> str:
    """The headline Markdown table: training dataset, error original, error augmented, reduction (main test set).

    Errors and reduction are mean ± standard deviation over the seeds; the reduction's bootstrap
    interval follows in brackets.
    """
    t = results["tests"]["test"]
    m = t["metrics"]["mean_deg"]
    b = t.get("bootstrap")
    interval = "" if not b else f" [{_value(b['low'], 1)}, {_value(b['high'], 1)}]"
    return (
        "| training dataset | error, original data | error, augmented data | reduction |\n"
        "|---|---|---|---|\n"
        f"| {results['train_dataset']} | {format_mean_std(m['original'], 2, 'deg')} | "
        f"{format_mean_std(m['augmented'], 2, 'deg')} | {format_mean_std(t['reduction_percent'], 1, '%')}{interval} |\n"
    )


def metric_table(results: Mapping[str, Any], key: str) -> str:
    """One metric's Markdown table: a row per test set; original, augmented (mean ± std over seeds), constant guess."""
    spec = {k: (title, unit, digits) for k, title, unit, digits in METRICS}
    if key not in spec:
        raise GazeAugError(f"metric: expected one of {', '.join(spec)}, got {key!r}")
    title, unit, digits = spec[key]
    lines = [
        f"### {title}" + (f" ({unit})" if unit else ""),
        "",
        "| test set | original | augmented | constant guess |",
        "|---|---|---|---|",
    ]
    for t in results["tests"].values():
        m = t["metrics"][key]
        lines.append(
            f"| {t['label']} | {format_mean_std(m['original'], digits)} | {format_mean_std(m['augmented'], digits)} | "
            f"{_value(m.get('constant'), digits)} |"
        )
    return "\n".join(lines) + "\n"


def reduction_table(results: Mapping[str, Any]) -> str:
    """The augmentation's reduction of the mean error per test set: mean ± std over seeds, bootstrap interval.

    Sets marked ``anchor`` (the training images) are left out: a reduction there means nothing.
    """
    lines = [
        "| test set | samples | reduction (mean ± std over seeds) | bootstrap interval, seed-averaged errors |",
        "|---|---|---|---|",
    ]
    for t in results["tests"].values():
        if t.get("anchor"):
            continue
        b = t.get("bootstrap")
        interval = (
            "n/a"
            if not b
            else f"{_value(b['reduction_percent'], 1, '%')}, {round(100 * b['level'])}% interval "
            f"[{_value(b['low'], 1)}, {_value(b['high'], 1)}] (resampling {b['units']} {b['resample']}, "
            f"{b['n_boot']} replicates)"
        )
        lines.append(
            f"| {t['label']} | {t['count']} | {format_mean_std(t['reduction_percent'], 1, '%')} | {interval} |"
        )
    return "\n".join(lines) + "\n"


def reading_verdict(results: Mapping[str, Any]) -> str:
    """Whether each model reads the eyes of each test set (see :data:`READS_EYES_BELOW`), in Markdown.

    One line per test set; a closing warning when neither model reads the eyes of the main test set,
    since the reduction then measures only a change of global offset.
    """
    lines = []
    neither = False
    for name, t in results["tests"].items():
        const = t["metrics"]["mean_deg"].get("constant")
        parts = []
        reads = {}
        for model in ("original", "augmented"):
            b = t["metrics"]["bias_removed_deg"][model].get("mean")
            reads[model] = b is not None and const is not None and b < READS_EYES_BELOW * const
            parts.append(
                f"{model} {'reads the eyes' if reads[model] else 'does not read the eyes'} "
                f"({_value(b, 2)} deg without its offset)"
            )
        lines.append(f"- {t['label']}: {'; '.join(parts)}; constant guess {_value(const, 2)} deg.")
        neither = neither or (name == "test" and not any(reads.values()))
    if neither:
        lines += [
            "",
            "**Neither model reads the eyes of the test people**: without their global offsets both stay "
            f"at or above {100 * READS_EYES_BELOW:g}% of the constant-guess error, so the reduction measures "
            "how far each model's single offset lies from the test set's mean gaze, not gaze estimation.",
        ]
    return "\n".join(lines) + "\n"


def steps_table(results: Mapping[str, Any]) -> str:
    """Each model's training: rows, batch size, epochs, optimizer steps, and whether they reach the minimum."""
    lines = [
        "| model | training rows | batch size | epochs | optimizer steps | minimum for its normalization layers |",
        "|---|---|---|---|---|---|",
    ]
    for name in ("original", "augmented"):
        r = results["runs"][name]
        ok = "" if r["enough_steps"] else " (**too few**)"
        lines.append(
            f"| {name} | {r['rows']} | {r['batch_size']} | {r['epochs']} | {r['steps']}{ok} | {r['min_steps']} |"
        )
    return "\n".join(lines) + "\n"


def _augmentation_line(settings: Mapping[str, Any]) -> str:
    """What the augmented set was, in one sentence of the report."""
    k = settings.get("per_sample", "?")
    source = " The augmented model also trains on the original rows (`--with-source`)."
    source = source if settings.get("with_source") else ""
    weight = (settings.get("train") or {}).get("keypoint_loss_weight") or 0
    if weight:  # only the augmented set's drawn eyes have keypoints: not a setting both models share
        source += (
            f" The augmented model also learns where its drawn eyes' iris and opening centres lie (keypoint "
            f"loss, weight {weight:g}); the original set has no drawn eyes and its model trains without it, "
            "so the reduction includes that loss's effect."
        )
    if settings.get("eyes") == "redirect":
        return (
            f"Augmentation: K = {k} per sample, redirected eyes: head poses and gaze targets drawn from the "
            f"`{settings.get('rig')}` rig, the eyes turned to the targets.{source}"
        )
    d = settings.get("distribution") or {}
    mean = np.round(np.asarray(d.get("mean_deg", [np.nan] * 2), dtype=float), 1).tolist()
    cov = np.round(np.asarray(d.get("cov_deg2", [[np.nan] * 2] * 2), dtype=float), 1).tolist()
    return (
        f"Augmentation: K = {k} per sample, head poses (yaw, pitch) drawn from mean {mean} deg, "
        f"covariance {cov} deg^2; each keeps its source's gaze in the head (the paper's method).{source}"
    )


def _report(out: Path, results: Mapping[str, Any]) -> None:
    from facemesh.io import atomic_write

    seeds = results["seeds"]
    lines = [
        "# Original vs. augmented training",
        "",
        f"Training set: `{results['train_dataset']}`. Test set: `{results['test_dataset']}`"
        + (
            f"; the same people in the training rig: `{results['test_same_rig_dataset']}`."
            if results.get("test_same_rig_dataset")
            else "."
        ),
        f"Seeds {', '.join(map(str, seeds))}: every figure is the mean ± standard deviation over "
        f"{len(seeds)} runs (augmentation and training seeded alike).",
        _augmentation_line(results.get("settings", {})),
        "",
        table(results),
        reading_verdict(results),
        "## Training: the same optimizer steps for both models",
        "",
        steps_table(results),
        "## Error reduction by the augmentation",
        "",
        reduction_table(results),
        "## Metrics (face-normalized frame; see gazeaug.metrics)",
        "",
        "The constant guess predicts the test set's mean gaze direction (the normalized mean of "
        "the unit gaze vectors) for every image. A model near the constant guess, with a ratio near 1 "
        "and correlations near 0, does not read the eyes.",
        "",
    ]
    for key, *_ in METRICS:
        lines += [metric_table(results, key)]
    lines += [
        "## Distributions (face-normalized head pose and gaze)",
        "",
        "![original](train_original.distribution.png)",
        "![augmented](train_augmented.distribution.png)",
        "![test](test_normalized.distribution.png)",
        "",
        "## Example patches (right eye | left eye)",
        "",
        "original: ![original examples](examples_original.png)",
        "augmented: ![augmented examples](examples_augmented.png)",
        "",
    ]
    with atomic_write(out / "report.md") as fh:
        fh.write("\n".join(lines).encode("utf-8"))
