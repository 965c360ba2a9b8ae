"""Augmentation's re-rendered eye against the truly rendered eye at a new head pose: where the iris lands.

``python benchmarks/rerender_eyes.py [--identities 2] [--no-shape] [--eye-pitches -20 -10 0]``

The simulator renders one subject (the built-in astronaut's face, drawn identities,
the iris painted blue and the sclera green, no relighting, noise or kappa) at a `screen`-like head pose
(pitched 15 deg down in a 640 x 480 camera, focal 600 px, 550 mm away) looking at a
point fixed in the head, and again with the head turned up by 15 and 30 deg, the
same point looked at: the truth, with 3D eyeballs. Augmentation (our own pipeline:
MediaPipe, PnP, the textured mesh, the raycast renderer) re-renders the first image
at each turned pose (the eye drawn as the photo's texture on the landmark mesh's
triangles across the eye opening). Both go through normalization; the blue pixels
give the visible iris's centroid in each eye patch, relative to the eye opening's
(blue and green) centroid, and where the patch framed it (absolute).

Prints one JSON line: per pose change, the mean and range over eyes and gazes of the
iris's place in the eye opening and in the patch (re-rendered minus true, px; y down),
the largest differences of the gaze labels (deg), and the visible iris areas. With no pose change both agree exactly
(the renderer reproduces normalization); the gaze signal is 0.13-0.17 px per degree
of yaw and 0.04-0.06 px per degree of pitch (`benchmarks/eye_signal.py`).

``--eye-pitches P ...``: instead of the default gazes, the eyes turned by P deg in the head
(pitch; yaw -10, 0, +10 for each): the `wheelchair` task's users look about 18 deg down in
the head, the `screen` users about 3 (docs/simulation.md). Each row then also gives the whole
patch's difference: the mean absolute difference (0-255, all channels) between the
re-rendered and the true patch once the re-rendered one is shifted so that its eye opening's
centroid lies on the true one's (so the framing offset does not count), and the share of the
eye opening that is iris (how much the lids cover) in each.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from eye_signal import clean_setup, dominant  # noqa: E402  (benchmarks/eye_signal.py)

GAZES_DEG = ((-10, 0), (-10, 10), (0, -10))  # (pitch, yaw) in the head frame
TURNS_DEG = (0, 15, 30)


def iris_position(img: np.ndarray) -> tuple[float, float, float, float, int] | None:
    """The blue iris in an RGB patch: (x, y) relative to the eye opening's centroid, (x, y) in the patch, pixels.

    The opening is what shows of the eyeball: the blue iris and the green sclera. Relative to it,
    the iris's place does not depend on where the normalized camera framed the eye (a tenth of a
    degree of camera rotation moves a whole patch by about a pixel). None when under 9 iris
    pixels show.
    """
    iris = dominant(img, 2)
    opening = iris | dominant(img, 1)
    ys, xs = np.nonzero(iris)
    oy, ox = np.nonzero(opening)
    if len(xs) <= 8:
        return None
    x, y = float(xs.mean()), float(ys.mean())
    return (x - float(ox.mean()), y - float(oy.mean()), x, y, int(iris.sum()))


def patch_difference(true: np.ndarray, again: np.ndarray) -> tuple[float, float, float]:
    """Whole-patch difference with the framing removed, and how much of each eye opening is iris.

    Returns:
        The mean absolute difference (0-255, all channels) between ``true`` and ``again`` shifted
        (bilinear, border replicated) so that its eye opening's centroid lies on ``true``'s; the
        iris's share of the eye opening in ``true`` and in ``again``.
    """
    import cv2

    def opening(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        iris = dominant(img, 2)
        return iris, iris | dominant(img, 1)

    (iris_t, open_t), (iris_a, open_a) = opening(true), opening(again)
    yt, xt = np.nonzero(open_t)
    ya, xa = np.nonzero(open_a)
    shift = np.array([[1.0, 0.0, xt.mean() - xa.mean()], [0.0, 1.0, yt.mean() - ya.mean()]])
    h, w = true.shape[:2]
    moved = cv2.warpAffine(again, shift, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    mad = float(np.abs(moved.astype(np.float64) - true.astype(np.float64)).mean())
    return mad, float(iris_t.sum() / max(open_t.sum(), 1)), float(iris_a.sum() / max(open_a.sum(), 1))


def main() -> None:
    """Run the comparison."""
    from facemesh.build import sample_image
    from facemesh.conventions import rotation_from_yaw_pitch
    from gazeaug.augment import HeadPlacement, face_asset, render_poses
    from gazeaug.normalize import NormalizationSettings, normalize_image
    from gazeaug.pipeline import default_landmark_model, fit_face, mesh_for_fit
    from gazeaug.render import create_renderer
    from gazeaug.simulate import PhotoFace, SimSubject, draw_subject

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--identities", type=int, default=2)
    ap.add_argument(
        "--no-shape", action="store_true", help="identities without shape draws (the built-in face's shape, scale 1)"
    )
    ap.add_argument(
        "--eye-pitches", type=float, nargs="+", default=None, help="eye-in-head pitches, deg (rows per pitch)"
    )
    args = ap.parse_args()
    gazes = (
        GAZES_DEG if args.eye_pitches is None else tuple((p, y) for p in args.eye_pitches for y in (-10.0, 0.0, 10.0))
    )
    warnings.simplefilter("ignore")
    det = default_landmark_model()
    photo = PhotoFace.from_image(sample_image(), det, "astronaut")
    s, k, cam = clean_setup()
    w, h = cam.image_size
    norm = NormalizationSettings()
    renderer = create_renderer("raycast", settings=norm)
    t = np.array([0.0, 0.0, 550.0])
    ra = rotation_from_yaw_pitch(0.0, math.radians(-15))
    rows: dict[tuple[float, int], list[tuple[float, ...]]] = {}
    for ident in range(args.identities):
        d = draw_subject(s, np.random.default_rng(100 + ident))
        d = dataclasses.replace(d, iris_rgb=(0.0, 0.0, 255.0), glasses=None, kappa_deg=(0.0, 0.0))
        if args.no_shape:  # the face model PnP uses is then the subject's own shape: the pose is near exact
            d = dataclasses.replace(d, shape_coefficients=(), head_scale=1.0)
        subj = SimSubject(photo, f"s{ident}", s, d)
        subj.sclera_rgb = (0.0, 255.0, 0.0)  # green, to find the eye opening
        mid = (subj.eye_centre["left"] + subj.eye_centre["right"]) / 2
        for gp, gy in gazes:
            look = rotation_from_yaw_pitch(math.radians(gy), math.radians(gp)) @ np.array([0.0, 0.0, -1.0])
            target_head = mid + 500.0 * look
            frame_a = subj.render(ra, t, ra @ target_head + t, k, (w, h), np.random.default_rng(1))
            fit_a = fit_face(frame_a.image, cam, det)
            asset = face_asset(mesh_for_fit(fit_a))
            scene = renderer.scene(asset.render_mesh)
            for turn in TURNS_DEG:
                rb = rotation_from_yaw_pitch(0.0, math.radians(-15 + turn))
                target_b = rb @ target_head + t
                frame_b = subj.render(rb, t, target_b, k, (w, h), np.random.default_rng(1))
                fit_b = fit_face(frame_b.image, cam, det)
                pts, kp = fit_b.model.vertices_mm, fit_b.keypoints
                true = normalize_image(frame_b.image, cam, fit_b.pose, pts, kp, gaze_target_mm=target_b, settings=norm)
                delta = rb @ ra.T  # the estimated pose of the first image, turned by the same change
                place = HeadPlacement(
                    rotation=delta @ np.asarray(fit_a.pose.rotation),
                    translation_mm=delta @ (np.asarray(fit_a.pose.translation_mm) - t) + t,
                )
                [again] = render_poses(scene, asset, [place], gaze_target_mm=ra @ target_head + t, settings=norm)
                for side in ("left", "right"):
                    it, ir = true.eye(side).image, again.eye(side).image
                    ct, cr = iris_position(it), iris_position(ir)
                    if ct is None or cr is None:
                        continue
                    g_again, g_true = again.eye(side).gaze, true.eye(side).gaze
                    assert g_again is not None and g_true is not None  # a target was given
                    dl = np.degrees(g_again - g_true)
                    diff = [cr[i] - ct[i] for i in range(4)]
                    mad, share_t, share_r = patch_difference(it, ir)
                    key = (gp if args.eye_pitches is not None else 0.0, turn)
                    rows.setdefault(key, []).append(
                        (*diff, float(dl[0]), float(dl[1]), ct[4], cr[4], mad, share_t, share_r)
                    )
    summary = {}

    def stats(col: np.ndarray) -> list[float]:
        return [round(float(col.mean()), 2), round(float(col.min()), 2), round(float(col.max()), 2)]

    for (pitch, turn), rr in sorted(rows.items()):
        a = np.array(rr)
        name = f"turn_{turn}_deg" if args.eye_pitches is None else f"eye_pitch_{pitch:g}_turn_{turn}_deg"
        summary[name] = {
            "eyes": len(a),
            "iris_in_opening_dx_px": stats(a[:, 0]),
            "iris_in_opening_dy_px": stats(a[:, 1]),
            "framing_dx_px": stats(a[:, 2]),
            "framing_dy_px": stats(a[:, 3]),
            "label_diff_pitch_yaw_deg": [
                round(float(np.abs(a[:, 4]).max()), 2),
                round(float(np.abs(a[:, 5]).max()), 2),
            ],
            "iris_area_px_true_rerendered": [round(float(a[:, 6].mean()), 1), round(float(a[:, 7].mean()), 1)],
            "patch_mad_aligned": stats(a[:, 8]),
            "iris_share_of_opening_true_rerendered": [round(float(a[:, k].mean()), 3) for k in (9, 10)],
        }
    note = "[mean, min, max] over eyes and gazes; re-rendered minus true; y down"
    print(json.dumps({"note": note, **summary}))


if __name__ == "__main__":
    main()
