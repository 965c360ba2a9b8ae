"""The rig's scene (targets, planes, where a gaze ray lands) and the time filters (One-Euro, dwell).

Expected values are derived by hand in the comments.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gazeaug.errors import GazeAugError
from gazeaug.sampling import BUILTIN_RIGS, load_rig
from gazeaug.scene import BoxTarget, Plane, Scene, SphereTarget, ray_box, ray_parallelogram, ray_sphere
from gazeaug.selection import DwellSelector, OneEuroFilter, SelectionSettings, SmoothingSettings

ORIGIN = np.zeros(3)
FWD = np.array([0.0, 0.0, -1.0])  # straight ahead of the user, rig frame


def test_ray_sphere_by_hand():
    # centre 500 mm ahead, radius 50: the near surface is 450 mm away
    assert ray_sphere(ORIGIN, FWD, np.array([0.0, 0.0, -500.0]), 50.0) == pytest.approx(450.0)
    # from inside a ball of radius 10 around the origin: leaves it at 10 mm
    assert ray_sphere(ORIGIN, FWD, ORIGIN, 10.0) == pytest.approx(10.0)
    # 100 mm to the side with radius 50: missed; behind the user: missed
    assert ray_sphere(ORIGIN, FWD, np.array([100.0, 0.0, -500.0]), 50.0) is None
    assert ray_sphere(ORIGIN, FWD, np.array([0.0, 0.0, 500.0]), 50.0) is None
    # 45 deg down (y down): direction (0, 1, -1)/sqrt2 reaches (0, 300, -300) at 300 sqrt2 mm; radius 10 -> 10 less
    d = np.array([0.0, 1.0, -1.0]) / math.sqrt(2)
    assert ray_sphere(ORIGIN, d, np.array([0.0, 300.0, -300.0]), 10.0) == pytest.approx(300 * math.sqrt(2) - 10)


def test_ray_box_by_hand():
    lo, hi = np.array([-10.0, -10.0, -510.0]), np.array([10.0, 10.0, -490.0])
    assert ray_box(ORIGIN, FWD, lo, hi) == pytest.approx(490.0)
    assert ray_box(np.array([0.0, 0.0, -500.0]), FWD, lo, hi) == 0.0  # from inside
    assert ray_box(np.array([20.0, 0.0, 0.0]), FWD, lo, hi) is None  # beside it, parallel to its x faces
    assert ray_box(ORIGIN, -FWD, lo, hi) is None  # looking away
    # toward (30, 0, -500) from the origin: at z = -490, x = 29.4 > 10: missed
    d = np.array([30.0, 0.0, -500.0]) / np.linalg.norm([30.0, 0.0, -500.0])
    assert ray_box(ORIGIN, d, lo, hi) is None


def test_ray_parallelogram_by_hand():
    # a table 300 mm below the eyes, from 750 to 300 mm ahead, 900 mm wide
    corner, e1, e2 = np.array([-450.0, 300.0, -750.0]), np.array([900.0, 0.0, 0.0]), np.array([0.0, 0.0, 450.0])
    # direction (0, 0.6, -0.8): y = 300 at t = 500, where z = -400 (on the table)
    assert ray_parallelogram(ORIGIN, np.array([0.0, 0.6, -0.8]), corner, e1, e2) == pytest.approx(500.0)
    # (0, 0.8, -0.6): t = 375, z = -225: nearer than the table's edge at -300
    assert ray_parallelogram(ORIGIN, np.array([0.0, 0.8, -0.6]), corner, e1, e2) is None
    # level: parallel to the table
    assert ray_parallelogram(ORIGIN, FWD, corner, e1, e2) is None
    # upward: the plane is behind the ray
    assert ray_parallelogram(ORIGIN, np.array([0.0, -0.6, -0.8]), corner, e1, e2) is None


def test_scene_point_of_gaze_and_margin():
    a = SphereTarget("a", (0.0, 0.0, -500.0), 10.0)
    b = SphereTarget("b", (100.0, 0.0, -500.0), 10.0)
    table = Plane("table", (-450.0, 300.0, -750.0), (900.0, 0.0, 0.0), (0.0, 0.0, 450.0))
    scene = Scene((a, b), (table,))
    look = scene.look(ORIGIN, FWD * 3.0)  # any length
    assert look.target == "a" and look.surface == "a"
    np.testing.assert_allclose(look.point_mm, [0.0, 0.0, -490.0], atol=1e-9)
    # 3 deg to the user's left (+x): 500 tan 3 = 26.2 mm off a's centre, more than its 10 mm radius
    d = np.array([math.sin(math.radians(3)), 0.0, -math.cos(math.radians(3))])
    assert scene.look(ORIGIN, d).target is None and scene.look(ORIGIN, d).surface is None
    assert np.isnan(scene.look(ORIGIN, d).point_mm).all()
    # with a 5 deg margin a grows to 10 + |c| tan 5 = 10 + 500 tan 5 = 53.7 mm and is hit; b's centre
    # lies at atan(100/500) = 11.3 deg, b grows to 10 + 509.9 tan 5 = 54.6 mm, and the ray passes
    # (500 (tan 11.3 - tan 3) cos ...) about 73 mm from it: a only
    assert scene.look(ORIGIN, d, margin_deg=5.0).target == "a"
    # halfway between a and b (5.7 deg from each) with a 10 deg margin both are hit: the nearer angle wins
    d2 = np.array([60.0, 0.0, -500.0]) / np.linalg.norm([60.0, 0.0, -500.0])
    assert scene.look(ORIGIN, d2, margin_deg=10.0).target == "b"  # 60 mm: closer to b (40) than to a (60)
    # down at the table: the point of gaze is on it, no target
    look = scene.look(ORIGIN, np.array([0.0, 0.6, -0.8]))
    assert look.surface == "table" and look.target is None
    np.testing.assert_allclose(look.point_mm, [0.0, 300.0, -400.0], atol=1e-9)
    # a box target: grown by |c| tan(m) on every side
    box = BoxTarget("box", (-10.0, -10.0, -510.0), (10.0, 10.0, -490.0))
    assert Scene((box,)).look(ORIGIN, d).target is None
    assert Scene((box,)).look(ORIGIN, d, margin_deg=5.0).target == "box"


def test_scene_checks():
    with pytest.raises(GazeAugError, match="unique names"):
        Scene((SphereTarget("a", (0, 0, -1), 1.0), SphereTarget("a", (0, 0, -2), 1.0)))
    with pytest.raises(GazeAugError, match="radius_mm"):
        SphereTarget("a", (0, 0, -1), 0.0)
    with pytest.raises(GazeAugError, match="min_mm < max_mm"):
        BoxTarget("b", (0, 0, 0), (1, 0, 1))
    with pytest.raises(GazeAugError, match="parallel"):
        Plane("p", (0, 0, 0), (1, 0, 0), (2, 0, 0))
    with pytest.raises(GazeAugError, match="commas"):
        SphereTarget("a,b", (0, 0, -1), 1.0)


RIG_HEAD = """\
camera_position_mm: [0.0, 230.0, -398.4]
head_yaw_std_deg: 10.0
head_pitch_std_deg: 5.0
head_yaw_mean_deg: 0.0
head_pitch_mean_deg: 0.0
image_size_wh: [640, 480]
focal_px: 600.0
target_box_mm:
- [-300.0, 50.0, -650.0]
- [300.0, 300.0, -350.0]
head_position_std_mm: 15.0
"""


def test_rig_file_with_targets(tmp_path):
    p = tmp_path / "r.yaml"
    p.write_text(
        RIG_HEAD
        + "targets:\n- {name: cup, centre_mm: [0, 200, -500], radius_mm: 40}\n"
        + "- {name: book, min_mm: [-50, 280, -450], max_mm: [50, 300, -350]}\n"
        + "planes:\n- {name: table, corner_mm: [-400, 300, -700], edge1_mm: [800, 0, 0], edge2_mm: [0, 0, 400]}\n"
    )
    rig = load_rig(p)
    assert [t.name for t in rig.targets] == ["cup", "book"] and rig.planes[0].name == "table"
    assert rig.as_dict()["targets"][0] == {"name": "cup", "centre_mm": [0.0, 200.0, -500.0], "radius_mm": 40.0}
    # the built-in rigs have none, and their recorded form has no such keys (older outputs resume)
    assert "targets" not in BUILTIN_RIGS["wheelchair"].as_dict() and not BUILTIN_RIGS["wheelchair"].scene
    # the shipped example loads
    assert load_rig(Path(__file__).parents[1] / "data_samples" / "rigs" / "wheelchair_objects.yaml").targets


@pytest.mark.parametrize(
    "extra, line, message",
    [
        ("targets:\n- {name: cup, centre_mm: [0, 200, -500]}\n", 13, "a target has the keys"),
        (
            "targets:\n- {name: a, centre_mm: [0, 0, -1], radius_mm: 1}\n"
            "- {name: b, centre_mm: [0, 0], radius_mm: 1}\n",
            14,
            "three",
        ),
        ("planes: 3\n", 12, "expected a list"),
        ("planes:\n- {name: t, corner_mm: [0, 0, 0], edge1_mm: [1, 0, 0], edge2_mm: [2, 0, 0]}\n", 13, "parallel"),
        ("colour: red\n", 12, "unknown rig fields"),
        ("head_yaw_std_deg: 3.0\n", 12, "given twice"),
        ("targets:\n- {name: a, centre_mm: [0, 0, -10], radius_mm: 20}\n", 13, "holds the eyes"),
        ("targets:\n- {name: a, centre_mm: [1.0e+308, 0, -100], radius_mm: 1}\n", 13, "within"),
        ('targets:\n- {name: "it\'s", centre_mm: [0, 0, -100], radius_mm: 1}\n', 13, "quotes"),
    ],
)
def test_rig_file_errors_name_the_line(tmp_path, extra, line, message):
    p = tmp_path / "r.yaml"
    p.write_text(RIG_HEAD + extra)
    with pytest.raises(GazeAugError, match=message) as info:
        load_rig(p)
    assert f"line {line}" in str(info.value)


def test_rig_field_error_names_the_line(tmp_path):
    p = tmp_path / "r.yaml"
    p.write_text(RIG_HEAD.replace("focal_px: 600.0", "focal_px: -1"))
    with pytest.raises(GazeAugError, match="focal_px") as info:
        load_rig(p)
    assert "line 7" in str(info.value)


def test_one_euro_by_hand():
    # beta 0: a plain exponential smoother, alpha = 1 / (1 + 1 / (2 pi fc dt)); fc = 1 Hz, dt = 0.1 s:
    # alpha = 0.2 pi / (1 + 0.2 pi) = 0.385870
    f = OneEuroFilter(SmoothingSettings(min_cutoff_hz=1.0, beta=0.0))
    a = 0.2 * math.pi / (1 + 0.2 * math.pi)
    assert f(0.0, [0.0, 10.0]).tolist() == [0.0, 10.0]  # the first sample passes
    np.testing.assert_allclose(f(0.1, [1.0, 10.0]), [a, 10.0])
    np.testing.assert_allclose(f(0.2, [1.0, 10.0]), [a + (1 - a) * a, 10.0])
    # a gap longer than reset_after_s (0.5 s): passed through
    np.testing.assert_allclose(f(0.8, [5.0, 5.0]), [5.0, 5.0])
    # beta > 0: speed 10 units/s estimated with alpha_d (d_cutoff 1 Hz, same dt) -> dx = a * 10,
    # fc = 1 + beta * dx
    g = OneEuroFilter(SmoothingSettings(min_cutoff_hz=1.0, beta=0.5, d_cutoff_hz=1.0))
    g(0.0, [0.0])
    fc = 1 + 0.5 * a * 10.0
    a2 = 1 / (1 + 1 / (2 * math.pi * fc * 0.1))
    np.testing.assert_allclose(g(0.1, [1.0]), [a2])


def _run(selector, seq, dt=0.1):
    """seq: targets per frame at dt spacing -> [(frame, time, target)] of the selections."""
    out = []
    for i, tg in enumerate(seq):
        s = selector.update(i, round(i * dt, 6), tg)
        if s is not None:
            out.append((s.frame, round(s.time_s, 6), s.target, round(s.start_s, 6)))
    return out


def test_dwell_by_hand():
    st = SelectionSettings(dwell_s=0.6, gap_s=0.15)
    # on A from t = 0: selected at t = 0.6 (frame 6), once
    assert _run(DwellSelector(st), ["A"] * 12) == [(6, 0.6, "A", 0.0)]
    # a one-frame blink (0.1 s <= gap) at t = 0.3 does not end the dwell: still t = 0.6
    assert _run(DwellSelector(st), ["A", "A", "A", None, "A", "A", "A", "A"]) == [(6, 0.6, "A", 0.0)]
    # a two-frame look away (last on A at 0.2, away at 0.3 and 0.4: 0.2 s > gap) restarts it at 0.5: 1.1
    assert _run(DwellSelector(st), ["A"] * 3 + [None] * 2 + ["A"] * 8) == [(11, 1.1, "A", 0.5)]
    # A then B: B's dwell counts from its first frame (0.3), once the gap has passed: 0.9
    assert _run(DwellSelector(st), ["A"] * 3 + ["B"] * 10) == [(9, 0.9, "B", 0.3)]
    # selected A, stays: no repeat; leaves for longer than the gap and comes back: selected again
    seq = ["A"] * 8 + [None] * 3 + ["A"] * 7
    assert _run(DwellSelector(st), seq) == [(6, 0.6, "A", 0.0), (17, 1.7, "A", 1.1)]
    # nothing looked at: nothing selected
    assert _run(DwellSelector(st), [None] * 20) == []


def test_dwell_progress_and_time_order():
    d = DwellSelector(SelectionSettings(dwell_s=1.0))
    d.update(0, 0.0, "A")
    d.update(1, 0.5, "A")
    assert d.progress(0.5) == pytest.approx(0.5)
    with pytest.raises(GazeAugError, match="backwards"):
        d.update(2, 0.4, "A")


from pathlib import Path  # noqa: E402


def test_margin_never_catches_a_gaze_from_inside_a_grown_target():
    # a box whose near face is 90 mm ahead, centre (0, 80, -100) at |c| = 128.06 mm: a 20 deg margin grows it
    # by 128.06 tan 20 = 46.6 mm per side, to y >= 23.4 and z <= -43.4: the eyes stay outside
    box = BoxTarget("box", (-20.0, 70.0, -110.0), (20.0, 90.0, -90.0))
    assert not box.contains(ORIGIN, 128.06 * math.tan(math.radians(20)))
    assert box.contains(np.array([0.0, 30.0, -50.0]), 46.6)
    # a sphere 60 mm ahead with radius 40 at a 20 deg margin grows to 40 + 60 tan 20 = 61.8 mm > 60: it
    # would contain the eyes and catch a gaze straight back into the head; it is skipped
    near = SphereTarget("near", (0.0, 0.0, -60.0), 40.0)
    assert near.contains(ORIGIN, 60 * math.tan(math.radians(20)))
    assert Scene((near,)).look(ORIGIN, -FWD, margin_deg=20.0).target is None
    assert Scene((near,)).look(ORIGIN, FWD, margin_deg=5.0).target == "near"  # 40 + 5.2 mm: not over the eyes
    with pytest.raises(GazeAugError, match="at most 20"):
        SelectionSettings(margin_deg=25.0)
