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
        high_frequency_share: the share of each patch's spectral energy (its mean removed, then a
            Hann window over rows and columns so the borders add no edge) at spatial frequencies
            above 0.25 cycles per pixel (half of Nyquist), averaged over patches.
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
        floor_accuracy, floor_auc: the same test between two disjoint random halves of the real set.
        patches_per_set: patches drawn per set (training and held-out; whole people held out may
            leave the classifier a few less, as many of each set).
        floor_patches_per_set: patches in each half of the floor: as many as ``patches_per_set``
            where the real set has twice that, else half the real set.
        mean_patch_rms: RMS difference between the two sets' mean patches, grey levels.
        mean_patch_rms_floor: the same between the two halves of the real set.
        real, simulated: :class:`PatchStatistics` of the ``patches_per_set`` patches drawn from each set.
        most_synthetic, most_real: (k, H, W) uint8 equalized grey: held-out simulated patches the
            classifier scored as the most simulated and the most real.
        settings: the settings used.
    """

    accuracy: float
    auc: float
    floor_accuracy: float
    floor_auc: float
    patches_per_set: int
    floor_patches_per_set: int
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
            "floor_patches_per_set": self.floor_patches_per_set,
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


def read_eye_patches(
    path: str | Path, max_rows: int | None = None, seed: int = 0
) -> tuple[NDArray[np.uint8], NDArray[Any]]:
    """Eye patches of a file, grey and equalized, with who each shows.

    Two formats:

    - an ``.npz`` with ``images``: (N, H, W) uint8 grey or (N, H, W, 3) uint8 RGB patches (the
      layout of the MPIIGaze patches in ``../shared/data/gaze/mpiigaze_eyes_unlabeled``), and
      optionally ``subject_id`` (N,); read without unpickling (``allow_pickle=False``);
    - a gazeaug training set (``.h5``/``.hdf5``, :mod:`gazeaug.io_h5`): both eyes of each row.

    Args:
        path: the file (``.npz``, ``.h5`` or ``.hdf5``).
        max_rows: read at most this many rows of an ``.h5``, drawn at random (default all): a large
            set is streamed, so only these rows are ever in memory (an ``.npz`` is read whole).
        seed: the draw of those rows.

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
        if max_rows is not None and max_rows < len(ts):  # rows drawn at random, read in file order
            ts.rows = np.sort(np.random.default_rng(seed).choice(ts.rows, max_rows, replace=False))
        left: list[NDArray[np.uint8]] = []
        right: list[NDArray[np.uint8]] = []
        who: list[NDArray[Any]] = []
        for batch in ts.batches(1024):  # the rows in use, and only those
            left.append(grey_equalized(batch["left_eye"]))
            right.append(grey_equalized(batch["right_eye"]))
            who.append(batch["subject"])
        if not left:
            raise GazeAugError(f"{p}: expected eye patches, got a training set of no rows")
        subjects = np.concatenate(who)
        return np.concatenate(left + right), np.concatenate([subjects, subjects])
    if p.suffix.lower() != ".npz":
        raise GazeAugError(f"{p}: expected an .npz of eye patches or a training set .h5, got a {p.suffix or 'file'}")
    import zipfile

    try:
        z = np.load(p, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):  # an .npy (one array) under an .npz name
            raise GazeAugError(f"{p}: expected an .npz archive of arrays, got a single array ({type(z).__name__})")
        with z:
            if "images" not in z.files:
                raise GazeAugError(f"{p}: expected an array 'images' of eye patches, got {sorted(z.files)}")
            images = z["images"]
            subjects = z["subject_id"] if "subject_id" in z.files else None
    except GazeAugError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise GazeAugError(f"{p}: not a readable .npz of eye patches ({exc})") from exc
    ok = images.ndim in (3, 4) and (images.ndim == 3 or images.shape[-1] == 3) and min(images.shape[1:3]) > 0
    if images.dtype != np.uint8 or not ok:
        found = f"{images.shape} {images.dtype}"
        raise GazeAugError(f"{p}: 'images': expected (N, H, W) or (N, H, W, 3) uint8, got {found}")
    if subjects is None:
        subjects = np.zeros(len(images), dtype=np.int64)
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
    window = np.outer(np.hanning(h), np.hanning(w))  # no wrap-around edge at the patch's borders
    power = np.abs(np.fft.fft2((x - x.mean(axis=(1, 2), keepdims=True)) * window)) ** 2
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


def _held_out(n: int, groups: NDArray[Any] | None, share: float, rng: np.random.Generator) -> NDArray[np.bool_]:
    """(n,) mask of the patches held out, about ``share`` of them.

    Whole groups (people) drawn until that share when ``groups`` names two or more; else single patches.
    """
    want = max(1, int(round(n * share)))
    mask = np.zeros(n, dtype=bool)
    if groups is None or len(np.unique(groups)) < 2:
        mask[rng.permutation(n)[:want]] = True
        return mask
    for g in rng.permutation(np.unique(groups)):
        if mask.sum() >= want:
            break
        mask |= groups == g
    if mask.all():  # every group held out: one goes back to training
        mask &= groups != groups[0]
    return mask


def _balanced(idx: NDArray[np.int64], k: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """``k`` of ``idx`` drawn at random (all of them, in a random order, when there are only ``k``)."""
    return rng.permutation(idx)[:k]


def _two_sample_test(
    a: NDArray[np.uint8],
    b: NDArray[np.uint8],
    s: RealismSettings,
    rng: np.random.Generator,
    groups_a: NDArray[Any] | None = None,
    groups_b: NDArray[Any] | None = None,
) -> tuple[float, float, NDArray[np.uint8], NDArray[np.float64]]:
    """Train the CNN on part of ``a`` (label 0) and ``b`` (label 1), score the held-out rest.

    The held-out part of each set is whole groups (people) when the set names two or more, so no
    person is on both sides of the split; both classes are then cut to the same size, in training
    and held out alike.

    Returns: accuracy, AUC, the held-out patches of ``b`` and their scores (the classifier's logit
    for ``b``, averaged over the patch and its mirror image).
    """
    from .models import import_torch

    torch = import_torch()
    held_a, held_b = _held_out(len(a), groups_a, s.holdout, rng), _held_out(len(b), groups_b, s.holdout, rng)
    k = int(min(held_a.sum(), held_b.sum()))
    t = int(min((~held_a).sum(), (~held_b).sum()))
    if k < 1 or t < 1:
        raise GazeAugError(f"too few patches to split into training and held-out parts (held out {k}, training {t})")
    ta, tb = _balanced(np.flatnonzero(~held_a), t, rng), _balanced(np.flatnonzero(~held_b), t, rng)
    va, vb = _balanced(np.flatnonzero(held_a), k, rng), _balanced(np.flatnonzero(held_b), k, rng)
    train_x = np.concatenate([a[ta], b[tb]])
    train_y = np.concatenate([np.zeros(t), np.ones(t)]).astype(np.float32)
    test_x = np.concatenate([a[va], b[vb]])
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
        logit = 0.5 * (net(xv) + net(xv.flip(-1)))  # logits, not probabilities: these rarely tie
    scores = logit.numpy().astype(np.float64)
    # both classes are k patches: the k highest scores are called the second set's (ties in a random
    # order), so a classifier whose scores are shifted as a whole (BatchNorm's running statistics
    # after few steps) is judged by its ranking, as the AUC judges it
    called = np.zeros(2 * k, dtype=bool)
    called[np.lexsort((rng.permutation(2 * k), -scores))[:k]] = True
    acc = float((called == (test_y == 1)).mean())
    return acc, _auc(scores, test_y), test_x[k:], scores[k:]


def compare_patches(
    real: NDArray[np.uint8],
    simulated: NDArray[np.uint8],
    settings: RealismSettings | None = None,
    *,
    real_groups: NDArray[Any] | None = None,
    simulated_groups: NDArray[Any] | None = None,
) -> RealismReport:
    """The realism measure (module docstring) between two sets of equalized grey eye patches.

    Args:
        real: (N, H, W) uint8, as :func:`read_eye_patches` or :func:`grey_equalized` give; H, W >= 4.
        simulated: (M, H, W) uint8, the same H and W.
        settings: :class:`RealismSettings` (defaults when None).
        real_groups: (N,): who each real patch shows (``read_eye_patches``' subjects), or None. With
            two or more people in a set, its held-out part is whole people.
        simulated_groups: (M,): the same for the simulated patches.

    Raises:
        GazeAugError: patches of different sizes or smaller than 4 x 4, groups of the wrong length, or
        fewer than :data:`MIN_PATCHES` in either set (the floor needs twice that of the real set).
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
    if min(real.shape[1:]) < 4:
        raise GazeAugError(f"patches: expected at least 4 x 4 pixels, got {real.shape[2]}x{real.shape[1]}")
    if len(real) < 2 * MIN_PATCHES or len(simulated) < MIN_PATCHES:
        raise GazeAugError(
            f"too few patches: expected at least {2 * MIN_PATCHES} real and {MIN_PATCHES} simulated, "
            f"got {len(real)} and {len(simulated)}"
        )
    gr = None if real_groups is None else np.asarray(real_groups)
    gs = None if simulated_groups is None else np.asarray(simulated_groups)
    for name, g, x in (("real_groups", gr, real), ("simulated_groups", gs, simulated)):
        if g is not None and g.shape != (len(x),):
            raise GazeAugError(f"{name}: expected shape ({len(x)},), got {g.shape}")
    rng = np.random.default_rng(s.seed)
    n = min(len(real), len(simulated), s.max_patches)
    ir, im = rng.choice(len(real), n, replace=False), rng.choice(len(simulated), n, replace=False)
    r, m = real[ir], simulated[im]
    acc, auc, held, scores = _two_sample_test(
        r, m, s, rng, None if gr is None else gr[ir], None if gs is None else gs[im]
    )
    # the floor: two disjoint random halves of the real set, each as large as the test's sets where
    # the real set allows (at most half of it each)
    h = min(n, len(real) // 2)
    both = rng.choice(len(real), 2 * h, replace=False)
    i1, i2 = both[:h], both[h:]
    facc, fauc, _, _ = _two_sample_test(
        real[i1], real[i2], s, rng, None if gr is None else gr[i1], None if gr is None else gr[i2]
    )
    st_r, st_m = patch_statistics(r), patch_statistics(m)
    st_1, st_2 = patch_statistics(real[i1]), patch_statistics(real[i2])
    order = np.argsort(-scores, kind="stable")
    k = min(s.examples, len(order) // 2)
    return RealismReport(
        accuracy=acc,
        auc=auc,
        floor_accuracy=facc,
        floor_auc=fauc,
        patches_per_set=n,
        floor_patches_per_set=h,
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
