"""The original-vs-augmented experiment (the paper's Table 1).

For a training dataset and a test dataset: normalize the training set
(``normalize-dataset``), augment it (``augment``), train one model on each with
identical hyper-parameters, evaluate both on the test set through test-time
normalization, and report the errors and the reduction. The report
(``report.md``) holds the table, the distribution plots of both training sets
and of the test set, and example patches of each.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .datasets import open_dataset
from .errors import GazeAugError
from .jobs import JobSettings, run_dataset
from .sampling import HeadPoseDistribution
from .train import TrainSettings

__all__ = ["ExperimentSettings", "run_experiment", "simulated_setup", "table"]


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


def simulated_setup(
    out_dir: str | Path,
    *,
    extra_faces: list[Path] | None = None,
    large: bool = False,
    seed: int = 0,
    progress: bool = True,
    sizes: tuple[int, int] | None = None,
) -> tuple[Path, Path]:
    """The built-in setup: a simulated ``screen`` training set and a ``wheelchair`` test set of other faces.

    Faces: the photos inside installed wheels and ``extra_faces``; the training set
    gets every face but the last, the test set the last one (different people).
    Default size: 60 training images per face and 60 test images (``large``: 400 and 200;
    ``sizes`` overrides both).
    """
    from .sampling import BUILTIN_RIGS
    from .simulate import simulate

    faces: list[str | Path | None] = [*_wheel_faces(), *(extra_faces or [])]
    if len(faces) < 2:
        raise GazeAugError("the simulated setup needs at least two faces (one to train on, one to test on)")
    out = Path(out_dir)
    n_train, n_test = sizes or ((400, 200) if large else (60, 60))
    train_dir, test_dir = out / "sim_train_screen", out / "sim_test_wheelchair"
    simulate(
        faces[:-1], BUILTIN_RIGS["screen"], train_dir, per_face=n_train, seed=seed, progress=progress, overwrite=True
    )
    simulate(
        faces[-1:],
        BUILTIN_RIGS["wheelchair"],
        test_dir,
        per_face=n_test,
        seed=seed + 1,
        progress=progress,
        overwrite=True,
    )
    return train_dir, test_dir


@dataclass(frozen=True)
class ExperimentSettings:
    """What the experiment does.

    Attributes:
        per_sample: K augmented samples per training sample.
        distribution: the application's head-pose distribution.
        train: hyper-parameters, shared by both models.
        workers: processes for the dataset runs.
        seed: seed of the augmentation (training has its own in ``train``).
    """

    per_sample: int = 4
    distribution: HeadPoseDistribution = field(default_factory=HeadPoseDistribution)
    train: TrainSettings = field(default_factory=TrainSettings)
    workers: int = 1
    seed: int = 0


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


def run_experiment(
    train_dataset: str | Path,
    test_dataset: str | Path,
    out_dir: str | Path,
    settings: ExperimentSettings | None = None,
    *,
    train_format: str | None = None,
    test_format: str | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Run the experiment; returns the results (also in ``out_dir/results.json`` and ``report.md``)."""
    from .evaluate import evaluate_dataset, write_report
    from .train import load_model, train

    s = settings or ExperimentSettings()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    train_reader = open_dataset(train_dataset, train_format)
    test_reader = open_dataset(test_dataset, test_format)
    sets = {
        "original": (out / "train_original.h5", JobSettings(kind="normalize-dataset", seed=s.seed)),
        "augmented": (
            out / "train_augmented.h5",
            JobSettings(kind="augment", per_sample=s.per_sample, distribution=s.distribution, seed=s.seed),
        ),
    }
    results: dict[str, Any] = {"train_dataset": str(train_dataset), "test_dataset": str(test_dataset), "runs": {}}
    for name, (h5, job) in sets.items():
        summary = run_dataset(train_reader, h5, job, workers=s.workers, overwrite=True, progress=progress)
        if summary["rows"] == 0:
            raise GazeAugError(f"{train_dataset}: no training rows for the {name} set (no faces found?)")
        model_path = out / f"model_{name}.pt"
        train(h5, model_path, s.train, progress=progress)
        model, meta = load_model(model_path)
        ev = evaluate_dataset(model, meta, test_reader, progress=progress)
        write_report(ev, out / f"eval_{name}")
        _examples(h5, out / f"examples_{name}.png")
        results["runs"][name] = {
            "rows": summary["rows"],
            "skipped": summary["skipped"],
            "mean_error_deg": ev["mean_deg"],
            "median_error_deg": ev["median_deg"],
            "test_count": ev["count"],
            "test_skipped": ev["skipped"],
        }
    # the test set's own distribution (normalize it, no training)
    test_h5 = out / "test_normalized.h5"
    run_dataset(
        test_reader,
        test_h5,
        JobSettings(kind="normalize-dataset"),
        workers=s.workers,
        overwrite=True,
        progress=progress,
    )
    o, a = results["runs"]["original"]["mean_error_deg"], results["runs"]["augmented"]["mean_error_deg"]
    results["reduction_percent"] = None if not o or a is None else 100.0 * (o - a) / o
    results["settings"] = {
        "per_sample": s.per_sample,
        "distribution": s.distribution.as_dict(),
        "train": asdict(s.train),
        "seed": s.seed,
    }
    from facemesh.io import atomic_write

    with atomic_write(out / "results.json") as fh:
        fh.write(json.dumps(results, indent=1, default=float).encode("utf-8"))
    _report(out, results)
    return results


def table(results: dict[str, Any]) -> str:
    """The Markdown table: training dataset, error original, error augmented, reduction."""
    o = results["runs"]["original"]["mean_error_deg"]
    a = results["runs"]["augmented"]["mean_error_deg"]
    r = results.get("reduction_percent")

    def f(v: float | None, unit: str = " deg") -> str:
        return "n/a" if v is None else f"{v:.2f}{unit}"

    return (
        "| training dataset | error, original data | error, augmented data | reduction |\n"
        "|---|---|---|---|\n"
        f"| {results['train_dataset']} | {f(o)} | {f(a)} | {f(r, ' %')} |\n"
    )


def _report(out: Path, results: dict[str, Any]) -> None:
    from facemesh.io import atomic_write

    lines = [
        "# Original vs. augmented training",
        "",
        f"Test set: `{results['test_dataset']}`.",
        "",
        table(results),
        "",
        "Both models: the same hyper-parameters (`results.json`, `settings.train`).",
        "",
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
