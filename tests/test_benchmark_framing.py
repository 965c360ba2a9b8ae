"""benchmarks/framing.py: a simulated eye's true points in its patch, and the geometric reading from them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import benchmark_module


def _record(centre_left, axis_left, radius=12.0):
    return {
        "head_rotation": np.eye(3).tolist(),
        "eyeball_centres_mm": {"left": list(centre_left), "right": [-30.0, 0.0, 600.0]},
        "optical_axes": {"left": list(axis_left), "right": [0.0, 0.0, -1.0]},
        "subject_draw": {"eyeball_radius_mm": radius},
    }


def _seen(x, z, contour):
    """Zhang's normalized camera (f 650 px, d_n 600 mm, reference at the contour centre): 650 x / (z 600 / ||c||)."""
    return 650.0 * x / (z * 600.0 / math.hypot(*contour))


def test_eye_points_project_by_hand():
    framing = benchmark_module("framing")
    t = math.radians(10.0)
    records = [
        _record([10.0, 0.0, 600.0], [0.0, 0.0, -2.0]),  # the axis need not be a unit vector
        _record([0.0, 0.0, 600.0], [math.sin(t), 0.0, -math.cos(t)]),
        _record([10.0, 0.0, 600.0], [0.0, 0.0, -1.0], radius=13.0),
    ]
    d = {"source_index": np.array([0, 1, 2]), "R_norm_left": np.tile(np.eye(3), (3, 1, 1))}
    d["R_norm_right"] = d["R_norm_left"]
    pts = framing._eye_points_px(records, d, {}, 650.0, 600.0)
    # the contour 10.5 mm in front of a 12 mm eyeball (head +z is the camera's +z here): (10, 0, 589.5),
    # the camera's reference point; S scales depth by 600 / ||(10, 0, 589.5)||
    c = (10.0, 0.0, 589.5)
    assert np.allclose(pts["contour"][0, 0], [_seen(10, 589.5, c), 0.0])
    assert np.allclose(pts["eyeball"][0, 0], [_seen(10, 600, c), 0.0])  # the eyeball centre, 600 mm deep
    assert np.allclose(pts["pupil"][0, 0], [_seen(10, 588, c), 0.0])  # the pupil 12 mm toward the camera
    # at the axis's depth ||c|| a point 10 mm off it lands 650 * 10 / 600 px off the principal point
    assert _seen(10, math.hypot(*c), c) == pytest.approx(650.0 * 10 / 600)
    # the axis turned 10 deg to +x: the pole at (12 sin 10, 0, 600 - 12 cos 10); the contour on the axis
    assert np.allclose(pts["pupil"][1, 0], [_seen(12 * math.sin(t), 600 - 12 * math.cos(t), (0.0, 0.0, 589.5)), 0.0])
    # a 13 mm eyeball sits 1 mm deeper: its contour 11.5 mm in front of its centre, its pupil 13 mm
    c13 = (10.0, 0.0, 588.5)
    assert np.allclose(pts["contour"][2, 0], [_seen(10, 588.5, c13), 0.0])
    assert np.allclose(pts["pupil"][2, 0], [_seen(10, 587, c13), 0.0])
    # the subject's radius for both eyes; each eye's own reference (the right contour (-30, 0, 588.5))
    assert np.allclose(pts["pupil"][2, 1], [_seen(-30, 587, (-30.0, 0.0, 588.5)), 0.0])
    # a record without a drawn subject takes the settings' radius (11 mm: 9.5 mm deep)
    bare = _record([10.0, 0.0, 600.0], [0.0, 0.0, -1.0])
    del bare["subject_draw"]
    one = {k: v[:1] for k, v in d.items()}
    got = framing._eye_points_px([bare], one, {"eyeball_radius_mm": 11.0}, 650.0, 600.0)["pupil"][0, 0]
    assert np.allclose(got, [_seen(10, 589, (10.0, 0.0, 590.5)), 0.0])
    # another normalized distance scales every offset: d_n 300 mm sees the face twice as large
    half = framing._eye_points_px(records[:1], one, {}, 650.0, 300.0)
    assert np.allclose(half["pupil"][0, 0], 2 * pts["pupil"][0, 0])


def test_leave_one_subject_out_reads_an_exact_linear_law_exactly():
    framing = benchmark_module("framing")
    rng = np.random.default_rng(0)
    x = rng.normal(size=(30, 3))
    gaze = x @ np.array([[0.5, -1.0], [2.0, 0.25], [0.0, 1.5]]) + [0.1, -0.2]
    subjects = np.repeat(["a", "b", "c"], 10)
    assert np.allclose(framing._leave_one_subject_out(x, gaze, subjects), gaze)
    # a subject's own offset is not learnt from the others: the held-out subject keeps it as its error
    shifted = gaze.copy()
    shifted[subjects == "a"] += [0.05, 0.0]
    pred = framing._leave_one_subject_out(x, shifted, subjects)
    assert np.allclose(pred[subjects == "a"], gaze[subjects == "a"])


def test_eye_points_follow_the_head_and_the_normalizing_rotation():
    framing = benchmark_module("framing")
    # the head turned 90 deg about the camera's y: its +z (into the head) is the camera's +x
    head = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    rec = _record([0.0, 0.0, 600.0], [0.0, 0.0, -1.0])
    rec["head_rotation"] = head.tolist()
    # the normalized camera's rows (its x, y, z axes in the camera frame): x along the camera's -y,
    # y along the camera's +x, z along z (a 90 deg roll)
    r_norm = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    d = {"source_index": np.array([0]), "R_norm_left": r_norm[None], "R_norm_right": r_norm[None]}
    pts = framing._eye_points_px([rec], d, {}, 650.0, 600.0)
    # the contour 10.5 mm in front of the eyeball along the head's -z: camera (-10.5, 0, 600);
    # in the normalized camera (0, -10.5, 600): 10.5 mm up in the patch
    assert np.allclose(pts["contour"][0, 0], [0.0, _seen(-10.5, 600, (-10.5, 600.0))])
    # the right eyeball at camera (-30, 0, 600): normalized (0, -30, 600); its contour (-40.5, 0, 600)
    assert np.allclose(pts["eyeball"][0, 1], [0.0, _seen(-30, 600, (-40.5, 600.0))])


def test_geometric_reading_fits_the_pupils_offset_from_the_contour():
    framing = benchmark_module("framing")
    rng = np.random.default_rng(1)
    n = 30
    contour = rng.normal(scale=3.0, size=(n, 2, 2))
    offset = rng.normal(scale=2.0, size=(n, 2, 2))
    head = rng.normal(scale=0.1, size=(n, 2))
    # the gaze a linear law of the offset (both eyes) and the head pose; the contour itself says nothing
    gaze = offset.reshape(n, 4) @ rng.normal(scale=0.05, size=(4, 2)) + head @ np.diag([0.5, -0.3])
    points = {"pupil": contour + offset, "contour": contour}
    d = {"gaze": gaze.astype(np.float32), "head_pose": head.astype(np.float32)}
    got = framing._geometric_reading(points, d, np.repeat(["a", "b", "c"], 10))
    assert got["pupil_from_contour"]["error_deg"] < 0.01  # float32 labels: exact to rounding
    assert got["pupil_from_patch_centre"]["error_deg"] > 0.5  # the contour's place unknown: not exact
    assert got["constant_deg"] > 1.0


def _disc_patch(centre_xy, radius=6.0, lid_y=None, size_wh=(60, 36)):
    """A dark disc (grey 40) on a bright patch (200), area-sampled 8 x 8 per pixel; pixel centres at whole numbers.

    With ``lid_y``, everything above that row (y down) is skin (150): an upper lid over the disc's top.
    """
    w, h = size_wh
    sub = (np.arange(8) + 0.5) / 8 - 0.5
    ys = (np.arange(h)[:, None] + sub[None, :]).ravel()
    xs = (np.arange(w)[:, None] + sub[None, :]).ravel()
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    fine = np.where((xx - centre_xy[0]) ** 2 + (yy - centre_xy[1]) ** 2 < radius**2, 40.0, 200.0)
    if lid_y is not None:
        fine[yy < lid_y] = 150.0
    return fine.reshape(h, 8, w, 8).mean(axis=(1, 3))


@pytest.mark.parametrize("centre", [(30.0, 18.0), (33.3, 15.6), (24.7, 21.2)])
def test_classical_finders_place_a_dark_disc(centre):
    framing = benchmark_module("framing")
    grey = _disc_patch(centre)
    # offsets from the principal point (w / 2, h / 2) = (30, 18)
    want = np.array(centre) - [30.0, 18.0]
    assert np.allclose(framing.iris_by_gradients(grey), want, atol=0.25)
    assert np.allclose(framing.iris_by_circles(grey), want, atol=0.25)


def test_a_lid_over_the_iris_moves_the_circle_finder_least():
    framing = benchmark_module("framing")
    grey = _disc_patch((31.5, 19.0), radius=6.5, lid_y=16.0)  # the top 3.5 px of the disc hidden
    circles = framing.iris_by_circles(grey)
    gradients = framing.iris_by_gradients(grey)
    # the lid's edge pulls both down (y +); the circles' arcs mostly lie below it: well under a pixel
    assert circles[0] == pytest.approx(1.5, abs=0.1)
    assert 0.0 <= circles[1] - 1.0 < 0.7
    assert gradients[1] - 1.0 > circles[1] - 1.0


def test_the_printed_result_is_json_without_nan():
    # one subject has no correlation (NaN): JSON has no NaN, the line must parse as JSON
    import json

    framing = benchmark_module("framing")
    out = framing._finite_or_none({"r": [float("nan"), 0.5], "x": {"y": float("inf"), "z": 1}, "n": 3})
    assert json.loads(json.dumps(out, allow_nan=False)) == {"r": [None, 0.5], "x": {"y": None, "z": 1}, "n": 3}


def test_post_hoc_person_shift_and_linear_oracle_by_hand():
    import numpy as np

    post = benchmark_module("post_hoc")
    pred = np.array([[0.1, 0.0], [0.3, 0.2], [-0.2, 0.5]])
    subjects = np.array(["a", "a", "b"])
    # a's mean (0.2, 0.1) moves to (0, 0): -0.2, -0.1 each; b's single row lands on the target
    got = post.shift_each_person(pred, subjects, np.array([0.0, 0.0]))
    assert np.allclose(got, [[-0.1, -0.1], [0.1, 0.1], [0.0, 0.0]])
    # true = 2 * pred + 1 on each axis: the fitted line recovers it exactly
    true = 2 * pred + 1
    assert np.allclose(post.linear_oracle(pred, true), true)
