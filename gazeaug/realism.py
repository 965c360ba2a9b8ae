"""How far simulated eye patches are from real ones: a realism measure between two sets of patches.

Convention: both sets are normalized eye patches (Zhang et al. 2018) of one size, compared as
MPIIGaze stores its patches: grey (ITU-R BT.601 luma) and histogram-equalized per patch
(:func:`gazeaug.models.preprocess.equalize_grey`, equal to OpenCV's ``equalizeHist``). Equalization
takes overall brightness and contrast out, so what is compared is the eye's spatial structure
(iris, lids, sclera, skin, blur and noise). Left and right eyes are pooled, and every measure is
blind to horizontal mirroring (each patch is seen both ways), so a set that stores right eyes
mirrored as left ones (some of MPIIGaze's releases do) compares like one that does not.

The normalization must match: the same focal length and distance (MPIIGaze's patches are at
f = 960 px, d = 600 mm, 60 x 36 px; make the simulated set with ``--focal 960``). A different
scale of the eye is itself a difference the measure finds.

Measures (:func:`compare_patches`):

- **classifier two-sample test** (Lopez-Paz and Oquab, "Revisiting classifier two-sample tests",
  ICLR 2017): a small CNN is trained to tell real from simulated on part of each set and scored
  on the held-out rest (as many of each): its ROC AUC and its accuracy when the higher-scoring
  half is called simulated. 0.5 means the classifier cannot tell them apart; 1.0 means it tells
  every held-out patch. Reported beside a **floor**, the same test
  between two random halves of the real set (0.5 in expectation; its departure from 0.5 is the
  test's noise at that size).
- **what differs**, per set: sharpness (mean gradient magnitude), the share of spectral energy
  at high frequencies (blur lowers it, noise raises it), and the mean patch (the average eye:
  where iris and lids sit), with the RMS difference between the two mean patches and its floor.
- the held-out simulated patches the classifier finds the most and the least real, for a picture.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import GazeAugError

__all__ = [
    "RealismSettings",
    "PatchStatistics",
    "RealismReport",
    "read_eye_patches",
    "grey_equalized",
    "patch_statistics",
    "compare_patches",
    "realism_sheet",
]

#: Fewer patches than this per set are refused: the test's held-out part would say nothing.
MIN_PATCHES = 40


@dataclass(frozen=True)
class RealismSettings:
    """How :func:`compare_patches` measures.

    Attributes:
        max_patches: at most this many patches per set, drawn at random (default 3000); the larger
            set is subsampled to the smaller's size, so both classes are balanced.
        holdout: share of each set held out to score the classifier (default 0.3).
        epochs: passes of the classifier over its training part (default 8).
        batch_size: classifier batch size (default 128).
        learning_rate: Adam's learning rate (default 1e-3).
        seed: every random choice (subsets, split, initial weights, batch order, mirroring).
        examples: held-out simulated patches kept for the picture, per end (default 12).
    """

    max_patches: int = 3000
    holdout: float = 0.3
    epochs: int = 8
    batch_size: int = 128
    learning_rate: float = 1e-3
    seed: int = 0
    examples: int = 12

    def __post_init__(self) -> None:
        if not (isinstance(self.max_patches, int) and self.max_patches >= MIN_PATCHES):
            raise GazeAugError(f"max_patches: expected an integer >= {MIN_PATCHES}, got {self.max_patches!r}")
        if not 0.05 <= self.holdout <= 0.95:
            raise GazeAugError(f"holdout: expected a share in [0.05, 0.95], got {self.holdout!r}")
        for name in ("epochs", "batch_size"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise GazeAugError(f"{name}: expected an integer >= 1, got {v!r}")
        if not (np.isfinite(self.learning_rate) and self.learning_rate > 0):
            raise GazeAugError(f"learning_rate: expected a positive number, got {self.learning_rate!r}")
        if not (isinstance(self.examples, int) and self.examples >= 0):
            raise GazeAugError(f"examples: expected an integer >= 0, got {self.examples!r}")


@dataclass(frozen=True)
class PatchStatistics:
    """What one set of equalized grey patches looks like on average.

    Attributes:
        count: patches measured.
        sharpness: mean gradient magnitude, grey levels per pixel (central differences).
        high_frequency_share: the share of each patch's spectral energy (its mean removed) at
            spatial frequencies above 0.25 cycles per pixel (half of Nyquist), averaged over patches.
        mean_patch: (H, W) float64 grey levels: the average patch, averaged with its mirror image.
    """

    count: int
    sharpness: float
    high_frequency_share: float
    mean_patch: NDArray[np.float64] = field(repr=False)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (without the mean patch)."""
        return {
            "count": self.count,
            "sharpness": round(self.sharpness, 3),
            "high_frequency_share": round(self.high_frequency_share, 4),
        }


@dataclass(frozen=True)
class RealismReport:
    """The realism measure between a real and a simulated set of eye patches.

    Attributes:
        accuracy: held-out accuracy of the classifier telling real from simulated, the higher-scoring
            half called simulated (0.5: it cannot; 1.0: every patch told apart).
        auc: its ROC AUC (probability that a simulated patch scores as more simulated than a real one).
        floor_accuracy, floor_auc: the same test between two random halves of the real set.
        patches_per_set: patches per set the classifier saw (training and held-out).
        mean_patch_rms: RMS difference between the two sets' mean patches, grey levels.
        mean_patch_rms_floor: the same between the two halves of the real set.
        real, simulated: :class:`PatchStatistics` of each set (all patches given, up to ``max_patches``).
        most_synthetic, most_real: (k, H, W) uint8 equalized grey: held-out simulated patches the
            classifier scored as the most simulated and the most real.
        settings: the settings used.
    """

    accuracy: float
    auc: float
    floor_accuracy: float
    floor_auc: float
    patches_per_set: int
    mean_patch_rms: float
    mean_patch_rms_floor: float
    real: PatchStatistics
    simulated: PatchStatistics
    most_synthetic: NDArray[np.uint8] = field(repr=False)
    most_real: NDArray[np.uint8] = field(repr=False)
    settings: RealismSettings = field(default_factory=RealismSettings)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: every figure (without the patches)."""
        return {
            "accuracy": round(self.accuracy, 4),
            "auc": round(self.auc, 4),
            "floor_accuracy": round(self.floor_accuracy, 4),
            "floor_auc": round(self.floor_auc, 4),
            "patches_per_set": self.patches_per_set,
            "mean_patch_rms": round(self.mean_patch_rms, 3),
            "mean_patch_rms_floor": round(self.mean_patch_rms_floor, 3),
            "real": self.real.as_dict(),
            "simulated": self.simulated.as_dict(),
            "seed": self.settings.seed,
        }


def grey_equalized(patches: NDArray[Any]) -> NDArray[np.uint8]:
    """Eye patches -> grey, histogram-equalized per patch, as MPIIGaze's (and ``--input grey_equalized``'s).

    Args:
        patches: (N, H, W, 3) uint8 RGB, or (N, H, W) uint8 grey.

    Returns:
        (N, H, W) uint8: BT.601 luma in OpenCV's fixed point, then ``cv2.equalizeHist`` per patch
        (:func:`gazeaug.models.preprocess.scale_eyes`'s ``grey_equalized`` path, one code for both).
    """
    from .models import import_torch
    from .models.preprocess import equalize_grey, eyes_to_float, scale_eyes

    a = np.asarray(patches)
    if a.dtype != np.uint8 or a.ndim not in (3, 4) or (a.ndim == 4 and a.shape[-1] != 3):
        raise GazeAugError(f"eye patches: expected (N, H, W) or (N, H, W, 3) uint8, got {a.shape} {a.dtype}")
    torch = import_torch()
    if len(a) == 0:
        return np.zeros(a.shape[:3], dtype=np.uint8)
    if a.ndim == 3:
        out = equalize_grey(torch.from_numpy(np.ascontiguousarray(a)).float())
    else:
        x = scale_eyes(eyes_to_float(torch.from_numpy(np.ascontiguousarray(a))), "grey_equalized")
        out = (x[:, 0] + 1.0) * 127.5
    return np.rint(out.numpy()).astype(np.uint8)


def read_eye_patches(path: str | Path, max_rows: int | None = None) -> tuple[NDArray[np.uint8], NDArray[Any]]:
    """Eye patches of a file, grey and equalized, with who each shows.

    Two formats:

    - an ``.npz`` with ``images``: (N, H, W) uint8 grey or (N, H, W, 3) uint8 RGB patches (the
      layout of the MPIIGaze patches in ``../shared/data/gaze/mpiigaze_eyes_unlabeled``), and
      optionally ``subject_id`` (N,); read without unpickling (``allow_pickle=False``);
    - a gazeaug training set (``.h5``/``.hdf5``, :mod:`gazeaug.io_h5`): both eyes of each row.

    Args:
        path: the file (``.npz``, ``.h5`` or ``.hdf5``).
        max_rows: read at most this many rows of an ``.h5`` (its first rows; default all): a large
            set is streamed, so only these rows are ever in memory.

    Returns:
        patches: (N, H, W) uint8 equalized grey (:func:`grey_equalized`; an ``.h5`` gives 2 per row,
        left eyes then right eyes); subjects: (N,) array naming who each patch shows.

    Raises:
        InputError: a missing or unreadable file.
        GazeAugError: not one of the two formats, or patches of the wrong shape or type.
    """
    from facemesh.io import check_input_file

    p = check_input_file(path)
    if p.suffix.lower() in (".h5", ".hdf5"):
        from .io_h5 import H5TrainingSet

        ts = H5TrainingSet(p, allow_empty=True)
        n = len(ts) if max_rows is None else min(len(ts), max_rows)
        left: list[NDArray[np.uint8]] = []
        right: list[NDArray[np.uint8]] = []
        who: list[NDArray[Any]] = []
        got = 0
        for batch in ts.batches(1024) if n else ():
            take = min(len(batch["left_eye"]), n - got)
            left.append(grey_equalized(batch["left_eye"][:take]))
            right.append(grey_equalized(batch["right_eye"][:take]))
            who.append(batch["subject"][:take])
            got += take
            if got >= n:
                break
        if not left:
            raise GazeAugError(f"{p}: expected eye patches, got a training set of no rows")
        subjects = np.concatenate(who)
        return np.concatenate(left + right), np.concatenate([subjects, subjects])
    if p.suffix.lower() != ".npz":
        raise GazeAugError(f"{p}: expected an .npz of eye patches or a training set .h5, got a {p.suffix or 'file'}")
    import zipfile

    try:
        with np.load(p, allow_pickle=False) as z:
            if "images" not in z.files:
                raise GazeAugError(f"{p}: expected an array 'images' of eye patches, got {sorted(z.files)}")
            images = z["images"]
            subjects = z["subject_id"] if "subject_id" in z.files else np.zeros(len(images), dtype=np.int64)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise GazeAugError(f"{p}: not a readable .npz of eye patches ({exc})") from exc
    if images.dtype != np.uint8 or images.ndim not in (3, 4) or (images.ndim == 4 and images.shape[-1] != 3):
        found = f"{images.shape} {images.dtype}"
        raise GazeAugError(f"{p}: 'images': expected (N, H, W) or (N, H, W, 3) uint8, got {found}")
    if subjects.shape != (len(images),):
        raise GazeAugError(f"{p}: 'subject_id': expected shape ({len(images)},), got {subjects.shape}")
    return grey_equalized(images), subjects


def patch_statistics(patches: NDArray[np.uint8]) -> PatchStatistics:
    """:class:`PatchStatistics` of (N, H, W) uint8 grey patches (equalized, as :func:`grey_equalized` gives)."""
    x = np.asarray(patches, dtype=np.float64)
    if x.ndim != 3 or len(x) == 0:
        raise GazeAugError(f"patches: expected (N, H, W) with N >= 1, got {x.shape}")
    gy, gx = np.gradient(x, axis=(1, 2))
    sharp = float(np.hypot(gx, gy).mean())
    h, w = x.shape[1:]
    power = np.abs(np.fft.fft2(x - x.mean(axis=(1, 2), keepdims=True))) ** 2
    fy, fx = np.meshgrid(np.fft.fftfreq(h), np.fft.fftfreq(w), indexing="ij")
    high = np.hypot(fy, fx) > 0.25
    total = power.sum(axis=(1, 2))
    share = np.where(total > 0, power[:, high].sum(axis=1) / np.maximum(total, 1e-300), 0.0)
    mean = x.mean(axis=0)
    return PatchStatistics(len(x), sharp, float(share.mean()), 0.5 * (mean + mean[:, ::-1]))


def _auc(scores: NDArray[np.float64], labels: NDArray[np.int64]) -> float:
    """ROC AUC of ``scores`` for ``labels`` 1 against 0 (Mann-Whitney; ties count half)."""
    from scipy.stats import rankdata

    ranks = rankdata(scores)
    pos = labels == 1
    n1, n0 = int(pos.sum()), int((~pos).sum())
    return float((ranks[pos].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def _classifier(torch: Any) -> Any:
    """The two-sample test's CNN: (N, 1, H, W) in [-1, 1] -> (N,) logits (positive: the second set)."""
    nn = torch.nn
    return nn.Sequential(
        nn.Conv2d(1, 16, 3, padding=1),
        nn.BatchNorm2d(16),
        nn.ReLU(),
        nn.MaxPool2d(2),
        nn.Conv2d(16, 32, 3, padding=1),
        nn.BatchNorm2d(32),
        nn.ReLU(),
        nn.MaxPool2d(2),
        nn.Conv2d(32, 64, 3, padding=1),
        nn.BatchNorm2d(64),
        nn.ReLU(),
        nn.AdaptiveAvgPool2d(1),
        nn.Flatten(),
        nn.Linear(64, 1),
        nn.Flatten(0),
    )


def _two_sample_test(
    a: NDArray[np.uint8], b: NDArray[np.uint8], s: RealismSettings, rng: np.random.Generator
) -> tuple[float, float, NDArray[np.uint8], NDArray[np.float64]]:
    """Train the CNN on part of ``a`` (label 0) and ``b`` (label 1) of equal size, score the held-out rest.

    Returns: accuracy, AUC, the held-out patches of ``b`` and their scores (probability of ``b``,
    averaged over the patch and its mirror image).
    """
    from .models import import_torch

    torch = import_torch()
    n = len(a)
    k = max(1, int(round(n * s.holdout)))
    ia, ib = rng.permutation(n), rng.permutation(len(b))
    train_x = np.concatenate([a[ia[k:]], b[ib[k:]]])
    train_y = np.concatenate([np.zeros(n - k), np.ones(len(b) - k)]).astype(np.float32)
    test_x = np.concatenate([a[ia[:k]], b[ib[:k]]])
    test_y = np.concatenate([np.zeros(k, dtype=np.int64), np.ones(k, dtype=np.int64)])

    def tensor(x: NDArray[np.uint8]) -> Any:
        return torch.from_numpy(x.astype(np.float32) / 127.5 - 1.0).unsqueeze(1)

    torch.manual_seed(int(rng.integers(2**31)))
    net = _classifier(torch)
    opt = torch.optim.Adam(net.parameters(), lr=s.learning_rate)
    loss_fn = torch.nn.BCEWithLogitsLoss()
    xt, yt = tensor(train_x), torch.from_numpy(train_y)
    net.train()
    for _ in range(s.epochs):
        order = rng.permutation(len(xt))
        for i in range(0, len(order), s.batch_size):
            idx = torch.from_numpy(order[i : i + s.batch_size])
            xb = xt[idx]
            flip = torch.from_numpy(rng.uniform(size=len(idx)) < 0.5)
            xb = torch.where(flip[:, None, None, None], xb.flip(-1), xb)
            opt.zero_grad()
            loss = loss_fn(net(xb), yt[idx])
            loss.backward()
            opt.step()
    net.eval()
    with torch.no_grad():
        xv = tensor(test_x)
        p = 0.5 * (torch.sigmoid(net(xv)) + torch.sigmoid(net(xv.flip(-1))))
    scores = p.numpy().astype(np.float64)
    # both classes are k patches: the k highest scores are called the second set's (ties broken by
    # position), so a classifier whose scores are shifted as a whole (BatchNorm's running statistics
    # after few steps) is judged by its ranking, as the AUC judges it
    called = np.zeros(2 * k, dtype=bool)
    called[np.argsort(-scores, kind="stable")[:k]] = True
    acc = float((called == (test_y == 1)).mean())
    return acc, _auc(scores, test_y), test_x[k:], scores[k:]


def compare_patches(
    real: NDArray[np.uint8], simulated: NDArray[np.uint8], settings: RealismSettings | None = None
) -> RealismReport:
    """The realism measure (module docstring) between two sets of equalized grey eye patches.

    Args:
        real: (N, H, W) uint8, as :func:`read_eye_patches` or :func:`grey_equalized` give.
        simulated: (M, H, W) uint8, the same H and W.
        settings: :class:`RealismSettings` (defaults when None).

    Raises:
        GazeAugError: patches of different sizes, or fewer than :data:`MIN_PATCHES` in either set
        (the floor needs twice that of the real set).
    """
    s = settings or RealismSettings()
    real, simulated = np.asarray(real), np.asarray(simulated)
    for name, x in (("real", real), ("simulated", simulated)):
        if x.dtype != np.uint8 or x.ndim != 3:
            raise GazeAugError(f"{name} patches: expected (N, H, W) uint8 grey, got {x.shape} {x.dtype}")
    if real.shape[1:] != simulated.shape[1:]:
        (h0, w0), (h1, w1) = real.shape[1:], simulated.shape[1:]
        raise GazeAugError(
            f"patch sizes differ: real {w0}x{h0}, simulated {w1}x{h1} "
            f"(make the simulated set with --patch-size {w0} {h0})"
        )
    if len(real) < 2 * MIN_PATCHES or len(simulated) < MIN_PATCHES:
        raise GazeAugError(
            f"too few patches: expected at least {2 * MIN_PATCHES} real and {MIN_PATCHES} simulated, "
            f"got {len(real)} and {len(simulated)}"
        )
    rng = np.random.default_rng(s.seed)
    n = min(len(real), len(simulated), s.max_patches)
    r = real[rng.choice(len(real), n, replace=False)]
    m = simulated[rng.choice(len(simulated), n, replace=False)]
    acc, auc, held, scores = _two_sample_test(r, m, s, rng)
    half = rng.permutation(min(len(real), 2 * s.max_patches))
    h = len(half) // 2
    r1, r2 = real[half[:h]], real[half[h : 2 * h]]
    facc, fauc, _, _ = _two_sample_test(r1, r2, s, rng)
    st_r, st_m = patch_statistics(r), patch_statistics(m)
    st_1, st_2 = patch_statistics(r1), patch_statistics(r2)
    order = np.argsort(-scores, kind="stable")
    k = min(s.examples, len(order) // 2)
    return RealismReport(
        accuracy=acc,
        auc=auc,
        floor_accuracy=facc,
        floor_auc=fauc,
        patches_per_set=n,
        mean_patch_rms=float(np.sqrt(np.mean((st_r.mean_patch - st_m.mean_patch) ** 2))),
        mean_patch_rms_floor=float(np.sqrt(np.mean((st_1.mean_patch - st_2.mean_patch) ** 2))),
        real=st_r,
        simulated=st_m,
        most_synthetic=held[order[:k]],
        most_real=held[order[::-1][:k]],
        settings=s,
    )


def realism_sheet(
    real: NDArray[np.uint8], report: RealismReport, path: str | Path, *, title: str = "", count: int = 12
) -> None:
    """One picture: real patches, the mean patches, the most synthetic and the most real simulated ones.

    Rows: ``count`` real patches (the first of ``real``); the real and the simulated mean patch and
    their difference; the held-out simulated patches the classifier found the most simulated, then
    the most real. Written whole (:func:`facemesh.io.atomic_write`) as a PNG.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facemesh.io import atomic_write

    rows = [
        ("real", list(real[:count])),
        (
            "mean: real, simulated, |difference| x 4",
            [
                report.real.mean_patch,
                report.simulated.mean_patch,
                np.clip(4 * np.abs(report.real.mean_patch - report.simulated.mean_patch), 0, 255),
            ],
        ),
        ("simulated, the most synthetic to the classifier", list(report.most_synthetic[:count])),
        ("simulated, the most real to the classifier", list(report.most_real[:count])),
    ]
    cols = max(count, 3)
    fig, axes = plt.subplots(len(rows), cols, figsize=(cols * 1.0, len(rows) * 0.85), squeeze=False)
    for i, (name, images) in enumerate(rows):
        for j in range(cols):
            ax = axes[i][j]
            ax.axis("off")
            if j < len(images):
                ax.imshow(np.asarray(images[j]), cmap="gray", vmin=0, vmax=255)
        axes[i][0].set_title(name, loc="left", fontsize=8)
    d = report.as_dict()
    fig.suptitle(
        f"{title}  classifier accuracy {d['accuracy']:.3f} (real vs real {d['floor_accuracy']:.3f}), "
        f"AUC {d['auc']:.3f}",
        fontsize=8,
    )
    with atomic_write(Path(path)) as fh:
        fig.savefig(fh, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
