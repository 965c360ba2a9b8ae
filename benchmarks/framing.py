"""How far test-time normalization's framing moves an eye in its patch, on simulated people.

``python benchmarks/framing.py SIMULATED_DIR NORMALIZED.h5 [--focal F] [--reference contour|eyeball]
[--reading] [--classical] [--model M.pt]``

``SIMULATED_DIR`` is a ``gazeaug simulate`` output (``simulation.jsonl`` holds
each image's true eyeball centres, mm, camera frame, its head rotation and
the subject's drawn eyeball radius; ``simulation.json`` the settings) and
``NORMALIZED.h5`` the same images through ``gazeaug normalize-dataset`` (one
row per image, in the simulation's order: ``source_index``), which placed each
eye's normalized camera from the landmarks MediaPipe detected and the head
pose PnP found. Redirected training eyes are framed from the rendered pose
itself, exactly; a test image's eye lands wherever detection puts it.

For every image and eye, a true point of the eye is projected into the patch
as the patch's normalized camera sees it (``C_n S R p``,
:meth:`gazeaug.camera.NormalizedCamera.project`): the row's normalizing
rotation (``R_norm_left``/``R_norm_right``), Zhang's scale ``S`` (``d_n /
||e||``, ``e`` the camera's reference point, taken as the true eye contour's
centre: the detected one lies within a few mm of it, under 1 % of ``||e||``)
and the normalized focal length (``--focal``, default the set's): where it
sits relative to the patch centre, px (x right, y down). Before 2026-11-30's
twenty-third session the scale was left out, which made every offset
``d_n / ||e||`` times too large (1.28 x on average in the wheelchair rig,
faces 0.70-0.86 x ``d_n`` from the camera). The point (``--reference``) is the
**eye contour's centre** (default: what normalization aims at, the eyeball
centre moved forward by :func:`gazeaug.simulate.eyeball_depth_mm` along the
head's -z) or the **eyeball centre** (the first version of this script; it
also moves with the head's rotation, about a pixel over a few degrees, since
it lies 10.5 mm behind the contour). Normalization aims at the eye corners of
a generic face, not at this subject's contour, so each subject's median is
removed; what is left is the image-to-image framing error (detection, PnP).

With ``--reading``, what a reader of the eyes' geometry alone could reach on these people:
the pupil (the eyeball's centre plus its radius along the optical axis) relative to the eye
contour's centre, both eyes, px, and the head pose, mapped to the gaze by a linear least-squares
fit on every other subject and read on the one left out (leave one subject out). Two readings: the
pupil from the true contour centre (a reader that finds both points exactly; what is left is each
subject's kappa and eyeball radius, and the linear map), and the pupil from the patch centre (a
reader that finds the pupil exactly but takes the framing of normalization, from the landmarks and
PnP, as the contour's place). Both are true points from ``simulation.jsonl``, not detections.

With ``--classical``, each eye's iris centre is also found in its patch by two classical finders
that learn nothing from people (:func:`iris_by_gradients`, Timm and Barth's means of gradients;
:func:`iris_by_circles`, Daugman's integro-differential operator on the limbus's lower and side
arcs), compared with the true pupil (px), and read linearly as above: from the true contour centre
(the finder's pupil against a perfect opening centre) and from the patch centre.

With ``--model``, the model is also evaluated on the patches re-framed by
these offsets (a sub-pixel translation, edges replicated): as normalized,
with each image's deviation from its subject's median removed, and with
every eye's reference point at the patch centre. The gain from re-framing is
what better framing at test time could still buy that model.

Prints one JSON line: percentiles of the distance (px) and the standard
deviation per axis, both eyes pooled, each subject's median offset (the part
the subject's median removes), and with ``--model`` the mean error (deg) and
Pearson's r of pitch and yaw for each framing; with ``--reading``, the two readings' mean
error (deg), Pearson's r and the best constant guess (deg); with ``--classical``, each finder's
distance from the true pupil (median, 90th percentile, mean miss per axis, px) and its two readings.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _reframed(patches: np.ndarray, shift_px: np.ndarray) -> np.ndarray:
    """(N, H, W, 3) uint8 patches moved by -shift_px ((N, 2) px, x right, y down), edges replicated."""
    import cv2

    out = np.empty_like(patches)
    h, w = patches.shape[1:3]
    for i, (p, (dx, dy)) in enumerate(zip(patches, shift_px, strict=True)):
        m = np.float32([[1, 0, -dx], [0, 1, -dy]])
        out[i] = cv2.warpAffine(p, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out


def _eye_points_px(
    records: list, d: dict, settings: dict, focal: float, distance_mm: float = 600.0
) -> dict[str, np.ndarray]:
    """Each row's true eye points in its patches: ``{"eyeball", "contour", "pupil"}`` -> (N, 2, 2) px.

    Axis 1 is the eye (left, right), axis 2 (x right, y down) from the patch's principal point,
    as the normalized camera (focal length ``focal``, distance ``distance_mm``) sees them:
    :meth:`gazeaug.camera.NormalizedCamera.project` (``C_n S R p``, ``S`` scaling depth by
    ``distance_mm / ||contour centre||``). The eyeball centre is the record's; the contour's
    centre lies :func:`gazeaug.simulate.eyeball_depth_mm` in front of it along the head's -z; the
    pupil is the eyeball centre plus the subject's eyeball radius along the optical axis (the iris
    is painted on the sphere, its centre at the pole).
    """
    from facemesh.geometry import nearest_rotation
    from gazeaug.camera import NormalizedCamera
    from gazeaug.simulate import SimSettings, eyeball_depth_mm

    base_depth = float(settings.get("eyeball_depth_mm", SimSettings.eyeball_depth_mm))
    base_radius = float(settings.get("eyeball_radius_mm", SimSettings.eyeball_radius_mm))
    out = {name: np.zeros((len(d["source_index"]), 2, 2)) for name in ("eyeball", "contour", "pupil")}
    for i, k in enumerate(d["source_index"]):
        rec = records[int(k)]
        radius = float((rec.get("subject_draw") or {}).get("eyeball_radius_mm", base_radius))
        into_head = np.asarray(rec["head_rotation"], dtype=np.float64) @ [0.0, 0.0, 1.0]  # head +z in camera
        for e, side in enumerate(("left", "right")):
            centre = np.asarray(rec["eyeball_centres_mm"][side], dtype=np.float64)
            axis = np.asarray(rec["optical_axes"][side], dtype=np.float64)
            found = {
                "eyeball": centre,
                "contour": centre - eyeball_depth_mm(base_depth, radius) * into_head,
                "pupil": centre + radius * axis / np.linalg.norm(axis),
            }
            camera = NormalizedCamera(  # the set stores R in float32: re-orthonormalized
                rotation=nearest_rotation(d[f"R_norm_{side}"][i]),
                reference_mm=found["contour"],
                distance_mm=distance_mm,
                focal_px=focal,
                size_wh=(2, 2),  # any size: offsets from its principal point
            )
            for name, point in found.items():
                out[name][i, e] = camera.project(point) - camera.camera_matrix[:2, 2]
    return out


def _leave_one_subject_out(features: np.ndarray, gaze: np.ndarray, subjects: np.ndarray) -> np.ndarray:
    """(N, 2) gaze from (N, F) features: per subject, a linear least-squares fit (with a constant) on the others."""
    x = np.c_[features, np.ones(len(features))]
    pred = np.zeros_like(gaze)
    for s in np.unique(subjects):
        held = subjects == s
        w, *_ = np.linalg.lstsq(x[~held], gaze[~held], rcond=None)
        pred[held] = x[held] @ w
    return pred


def _scored(pred: np.ndarray, gaze: np.ndarray) -> dict:
    """A reading's mean error (deg) and Pearson's r of pitch and yaw, rounded for the JSON line."""
    from gazeaug.metrics import mean_error_deg, pearson

    r = pearson(pred, gaze)
    return {
        "error_deg": round(mean_error_deg(pred, gaze), 2),
        "r_pitch": round(float(r[0]), 3),
        "r_yaw": round(float(r[1]), 3),
    }


def _linear_reading(eye_points: np.ndarray, d: dict, subjects: np.ndarray) -> dict:
    """The gaze read linearly (leave one subject out) from (N, 2, 2) px per eye and the head pose, scored."""
    gaze = d["gaze"].astype(np.float64)
    features = np.c_[eye_points.reshape(len(gaze), 4), d["head_pose"].astype(np.float64)]
    return _scored(_leave_one_subject_out(features, gaze, subjects), gaze)


def _geometric_reading(points: dict, d: dict, subjects: np.ndarray) -> dict:
    """``--reading``: the pupil from the true contour centre and from the patch centre (module docstring)."""
    from gazeaug.metrics import constant_guess_error_deg

    out: dict = {"constant_deg": round(constant_guess_error_deg(d["gaze"].astype(np.float64)), 2)}
    out["pupil_from_contour"] = _linear_reading(points["pupil"] - points["contour"], d, subjects)
    out["pupil_from_patch_centre"] = _linear_reading(points["pupil"], d, subjects)
    return out


def _subpixel_peak(score: np.ndarray) -> tuple[float, float]:
    """(x, y) of ``score``'s maximum, in its cells, refined by a parabola through each axis's neighbours."""
    iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
    found = [float(ix), float(iy)]
    for axis, (i, line) in enumerate(((ix, score[iy, :]), (iy, score[:, ix]))):
        if 0 < i < len(line) - 1:
            a, b, c = (float(v) for v in line[i - 1 : i + 2])
            curve = a - 2.0 * b + c
            if curve < 0.0:
                found[axis] += float(np.clip(0.5 * (a - c) / curve, -0.5, 0.5))
    return found[0], found[1]


def iris_by_gradients(grey: np.ndarray, box_px: tuple[int, int] = (14, 9), reach_px: float = 8.0) -> np.ndarray:
    """The iris centre by means of gradients (Timm and Barth 2011), darkness-weighted.

    Convention: ``grey`` (H, W), any numeric dtype, grey levels 0-255; returns (2,) float64 (x right, y
    down) px from the patch's principal point ``(W / 2, H / 2)``, pixel centres at whole numbers.
    The candidates lie within ``box_px`` (half-width, half-height) of the principal point (the eye
    is framed there within a few px); each scores the mean of ``max(0, d . g)^2`` over the strong
    gradients ``g`` (unit; magnitude above its mean + 0.3 sd) within ``reach_px`` of it, ``d`` the
    unit vector from the candidate, times the darkness there (``255`` minus the grey blurred by 2 px).
    Searched on the patch enlarged 2 x (bicubic), then refined by a parabola.
    """
    import cv2

    up = 2
    big = cv2.resize(np.asarray(grey, np.float32), None, fx=up, fy=up, interpolation=cv2.INTER_CUBIC)
    soft = cv2.GaussianBlur(big, (0, 0), 1.0 * up)
    gx = cv2.Sobel(soft, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(soft, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.hypot(gx, gy)
    ys, xs = np.nonzero(mag > mag.mean() + 0.3 * mag.std())
    ux, uy = gx[ys, xs] / mag[ys, xs], gy[ys, xs] / mag[ys, xs]
    h, w = big.shape
    # the enlarged patch's pixel j covers the patch's (j + 0.5) / up - 0.5; its principal point sits at w / 2
    cols = np.arange(w)[np.abs((np.arange(w) + 0.5) / up - 0.5 - w / (2 * up)) <= box_px[0]]
    rows = np.arange(h)[np.abs((np.arange(h) + 0.5) / up - 0.5 - h / (2 * up)) <= box_px[1]]
    cy, cx = (a.ravel() for a in np.meshgrid(rows, cols, indexing="ij"))
    dx, dy = xs[None, :] - cx[:, None], ys[None, :] - cy[:, None]
    dist = np.hypot(dx, dy)
    near = (dist > 0) & (dist < reach_px * up)
    dot = np.maximum(np.where(near, (dx * ux + dy * uy) / np.maximum(dist, 1e-6), 0.0), 0.0)
    score = (dot**2).sum(axis=1) / np.maximum(near.sum(axis=1), 1)
    score = score * (255.0 - cv2.GaussianBlur(big, (0, 0), 2.0 * up))[cy, cx]
    x, y = _subpixel_peak(score.reshape(len(rows), len(cols)))
    return np.array([(cols[0] + x + 0.5) / up - 0.5 - w / (2 * up), (rows[0] + y + 0.5) / up - 0.5 - h / (2 * up)])


def iris_by_circles(
    grey: np.ndarray, box_px: tuple[int, int] = (14, 9), radii_px: tuple[float, float] = (4.0, 8.5)
) -> np.ndarray:
    """The iris centre by an integro-differential operator (Daugman's) on the limbus's lower and side arcs.

    Convention: as :func:`iris_by_gradients` (returns (2,) px from the principal point). Each
    candidate on a quarter-pixel grid within ``box_px`` of the principal point takes the mean grey
    level on arcs of radius ``radii_px`` (every 0.5 px; the two sides within 35 deg of the horizontal
    and the bottom within 30 deg of the vertical: the upper lid covers the top), on the patch blurred
    by 0.7 px; it scores the largest rise of that mean from one radius to the next (the dark iris
    inside the bright sclera), smoothed over three radii; the best candidate is refined by a parabola.
    """
    import cv2

    g = cv2.GaussianBlur(np.asarray(grey, np.float32), (0, 0), 0.7)
    h, w = g.shape
    step = 0.25
    xs = w / 2.0 + np.arange(-box_px[0], box_px[0] + step / 2, step)
    ys = h / 2.0 + np.arange(-box_px[1], box_px[1] + step / 2, step)
    cy, cx = (a.ravel() for a in np.meshgrid(ys, xs, indexing="ij"))
    angles = np.deg2rad(np.r_[np.linspace(-35, 35, 15), np.linspace(145, 215, 15), np.linspace(60, 120, 9)])
    means = []
    for r in np.arange(radii_px[0], radii_px[1] + 0.25, 0.5):
        mx = (cx[:, None] + r * np.cos(angles)[None]).astype(np.float32)
        my = (cy[:, None] + r * np.sin(angles)[None]).astype(np.float32)  # y down: +sin is below
        means.append(cv2.remap(g, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).mean(axis=1))
    rise = np.diff(np.stack(means, axis=1), axis=1).astype(np.float32)
    rise = cv2.GaussianBlur(rise, (3, 1), 0)  # over radii (the columns)
    x, y = _subpixel_peak(rise.max(axis=1).reshape(len(ys), len(xs)))
    return np.array([xs[0] + x * step - w / 2.0, ys[0] + y * step - h / 2.0])


def _classical_reading(points: dict, d: dict, subjects: np.ndarray) -> dict:
    """``--classical``: each finder's iris centres against the true pupil, and the linear readings from them."""
    import cv2

    out: dict = {}
    for name, finder in (("gradients", iris_by_gradients), ("circles", iris_by_circles)):
        found = np.stack(
            [
                [finder(cv2.cvtColor(patch, cv2.COLOR_RGB2GRAY)) for patch in d[f"{side}_eye"]]
                for side in ("left", "right")
            ],
            axis=1,
        )  # (N, 2 eyes, 2)
        miss = found - points["pupil"]
        dist = np.hypot(miss[..., 0], miss[..., 1]).ravel()
        row: dict = {
            "median_px": round(float(np.median(dist)), 2),
            "p90_px": round(float(np.percentile(dist, 90)), 2),
            "mean_miss_px_xy": [round(float(v), 2) for v in miss.reshape(-1, 2).mean(axis=0)],
        }
        row["from_true_contour"] = _linear_reading(found - points["contour"], d, subjects)
        row["from_patch_centre"] = _linear_reading(found, d, subjects)
        out[name] = row
    return out


def _model_under_framings(model_path: Path, d: dict, offsets: np.ndarray, deviations: np.ndarray) -> dict:
    from gazeaug.train import load_model, predict_arrays

    model, _ = load_model(model_path)
    out = {}
    for name, shift in (
        ("as_normalized", np.zeros_like(offsets)),
        ("deviation_removed", deviations),
        ("centred", offsets),
    ):
        pred = predict_arrays(
            model,
            _reframed(d["left_eye"], shift[:, 0]),
            _reframed(d["right_eye"], shift[:, 1]),
            d["head_pose"].astype(np.float32),
        )
        out[name] = _scored(pred, d["gaze"])
    return out


def main() -> int:
    from gazeaug.errors import GazeAugError
    from gazeaug.io_h5 import H5TrainingSet

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("simulated", type=Path, help="a gazeaug simulate output folder")
    ap.add_argument("normalized", type=Path, help="its images through gazeaug normalize-dataset (.h5)")
    ap.add_argument(
        "--focal", type=float, default=None, help="the normalized focal length, px (default: the set's, else 650)"
    )
    ap.add_argument(
        "--reference",
        choices=("contour", "eyeball"),
        default="contour",
        help="the eye's point to follow: the eye contour's centre (default) or the eyeball centre",
    )
    ap.add_argument(
        "--reading",
        action="store_true",
        help="also fit a linear reading of the gaze from the true pupil and contour centres (leave one subject out)",
    )
    ap.add_argument(
        "--classical",
        action="store_true",
        help="also find each iris centre classically (gradients, circles) and read the gaze from it linearly",
    )
    ap.add_argument("--model", type=Path, default=None, help="a model (.pt) to evaluate under each framing")
    args = ap.parse_args()
    if not (args.simulated / "simulation.jsonl").is_file():
        print(f"{args.simulated}: no simulation.jsonl (expected a gazeaug simulate output folder)", file=sys.stderr)
        return 2
    try:
        lines = (args.simulated / "simulation.jsonl").read_text().splitlines()
        records = [json.loads(line) for line in lines if line]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        print(f"{args.simulated / 'simulation.jsonl'}: not a simulation's records ({exc})", file=sys.stderr)
        return 2
    settings: dict = {}
    if (args.simulated / "simulation.json").is_file():
        try:
            settings = json.loads((args.simulated / "simulation.json").read_text()).get("settings", {})
        except (json.JSONDecodeError, AttributeError) as exc:
            print(f"{args.simulated / 'simulation.json'}: not a simulation summary ({exc})", file=sys.stderr)
            return 2
    if args.model is not None and not args.model.is_file():
        print(f"{args.model}: no such model file", file=sys.stderr)
        return 2
    keys = ["R_norm_left", "R_norm_right", "source_index"]
    if args.model is not None or args.classical:
        keys += ["left_eye", "right_eye"]
    if args.model is not None or args.reading or args.classical:
        keys += ["head_pose", "gaze"]
    try:
        ts = H5TrainingSet(args.normalized)
        d = ts.read(keys)
    except GazeAugError as exc:
        print(exc, file=sys.stderr)
        return 2
    made_from = ts.attrs.get("dataset")  # the folder the set was normalized from, as recorded then
    read = ts.attrs.get("next_source_index")  # how many of its images the run read
    moved = made_from is None or not Path(str(made_from)).is_dir()  # a moved set: judged by its count alone
    if (
        (len(d["source_index"]) and int(d["source_index"].max()) >= len(records))
        or (read is not None and int(read) != len(records))
        or (not moved and Path(str(made_from)).resolve() != args.simulated.resolve())
    ):
        print(
            f"{args.normalized}: made from {made_from} ({read} images), not from {args.simulated} "
            f"({len(records)} images)",
            file=sys.stderr,
        )
        return 2
    subjects = ts.subjects[ts.rows]
    try:
        norm = ts.settings.get("normalization", {}) if isinstance(ts.settings, dict) else {}
        focal = float(args.focal if args.focal is not None else norm.get("focal_px", 650.0))
        points = _eye_points_px(records, d, settings, focal, float(norm.get("distance_mm", 600.0)))
    except (AttributeError, IndexError, KeyError, TypeError, ValueError) as exc:
        print(f"{args.simulated / 'simulation.jsonl'}: a record without its eyes ({exc!r:.80})", file=sys.stderr)
        return 2
    off = points[args.reference]
    medians = {s: np.median(off[subjects == s], axis=0) for s in np.unique(subjects)}
    dev = off - np.stack([medians[s] for s in subjects])
    dist = np.hypot(dev[..., 0], dev[..., 1]).ravel()
    pct = (50, 75, 90, 95, 100)
    result = {
        "images": len(off),
        "reference": args.reference,
        "focal_px": focal,
        "distance_px_percentiles": {
            str(p): round(float(v), 2) for p, v in zip(pct, np.percentile(dist, pct), strict=True)
        },
        "std_px_xy": [round(float(v), 2) for v in dev.reshape(-1, 2).std(axis=0)],
        "subject_median_px_xy": {s: [[round(float(v), 1) for v in eye] for eye in m] for s, m in medians.items()},
    }
    if args.reading:
        result["reading"] = _geometric_reading(points, d, subjects)
    if args.classical:
        result["classical"] = _classical_reading(points, d, subjects)
    if args.model is not None:
        try:
            result["model"] = _model_under_framings(args.model, d, off, dev)
        except GazeAugError as exc:
            print(exc, file=sys.stderr)
            return 2
    print(json.dumps(_finite_or_none(result)))
    return 0


def _finite_or_none(value: Any) -> Any:
    """``value`` with every NaN or infinite float replaced by None (JSON has no NaN: one subject has no r)."""
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # nothing is written: the result is one line on stdout at the end
        print("framing: interrupted", file=sys.stderr)
        sys.exit(130)
