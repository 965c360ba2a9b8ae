"""Head-pose distributions and rigs, against hand-derived values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from facemesh.conventions import rotation_from_yaw_pitch, rotation_to_head_pitchyaw, yaw_pitch_from_rotation
from gazeaug.errors import GazeAugError
from gazeaug.sampling import BUILTIN_RIGS, HeadPoseDistribution, Rig, load_rig


def test_default_is_the_papers_equation():
    d = HeadPoseDistribution()
    assert d.mean_deg == (0.0, 30.0)
    assert d.cov_deg2 == ((10.0, 0.0), (0.0, 10.0))
    draws = np.degrees(d.sample(40000, 1))
    np.testing.assert_allclose(draws.mean(axis=0), [0, 30], atol=0.05)
    np.testing.assert_allclose(draws.var(axis=0), [10, 10], rtol=0.03)


def test_std_reading_and_correlation():
    d = HeadPoseDistribution.from_std(5.0, -10.0, 10.0, 2.0)
    assert d.cov_deg2 == ((100.0, 0.0), (0.0, 4.0))
    c = HeadPoseDistribution((0, 0), ((4, 3), (3, 9)))
    draws = np.degrees(c.sample(40000, 2))
    np.testing.assert_allclose(np.cov(draws.T), [[4, 3], [3, 9]], rtol=0.05, atol=0.1)


def test_seeded_and_reproducible():
    d = HeadPoseDistribution()
    np.testing.assert_array_equal(d.sample(10, 7), d.sample(10, 7))
    assert not np.array_equal(d.sample(10, 7), d.sample(10, 8))


@pytest.mark.parametrize(
    "mean, cov, match",
    [
        ((0, 30), ((-1, 0), (0, 10)), ">= 0"),
        ((0, 30), ((np.nan, 0), (0, 10)), "finite"),
        ((0, 30), ((1, 5), (5, 1)), "semi-definite"),
        ((0, 30), ((1, 0.5), (0, 1)), "symmetric"),
        ((np.inf, 30), ((1, 0), (0, 1)), "finite"),
        ((0, 95), ((1, 0), (0, 1)), "pitch"),
    ],
)
def test_bad_distributions(mean, cov, match):
    with pytest.raises(GazeAugError, match=match):
        HeadPoseDistribution(mean, cov)


def test_negative_std_is_refused():
    with pytest.raises(GazeAugError, match="standard deviation"):
        HeadPoseDistribution.from_std(yaw_std=-1)


def test_yaw_pitch_round_trip_through_the_papers_rotation():
    for y, p in [(0.3, -0.2), (-0.5, 0.6), (0.0, 0.52)]:
        np.testing.assert_allclose(yaw_pitch_from_rotation(rotation_from_yaw_pitch(y, p)), [y, p], atol=1e-12)


def test_wheelchair_rig_sees_the_head_pitched_up_30_degrees():
    # camera 30 deg below the eyes' horizontal line of sight, pointing at the eyes:
    # a level head is seen with pitch +30 (face pointing above the camera), yaw 0.
    rig = Rig(
        name="t",
        camera_position_mm=(0, 200 * math.sin(math.radians(30)), -200 * math.cos(math.radians(30))),
        head_yaw_std_deg=0,
        head_pitch_std_deg=0,
    )
    yp = np.degrees(rig.head_poses(3, 0))
    np.testing.assert_allclose(yp, [[0, 30]] * 3, atol=1e-9)
    # and through the MPIIGaze head-pose convention of the face direction: pitch +30 as well
    r = rotation_from_yaw_pitch(*np.radians(yp[0]))
    np.testing.assert_allclose(np.degrees(rotation_to_head_pitchyaw(r)), [30, 0], atol=1e-9)
    # a camera 20 deg to the user's right (x < 0), level: a head looking straight ahead points 20 deg
    # toward the user's left of that camera's line of sight, i.e. the image's right: yaw -20
    # (the user would turn the head by yaw +20, to the right, to face the camera)
    rig = Rig(
        name="t",
        camera_position_mm=(-500 * math.sin(math.radians(20)), 0, -500 * math.cos(math.radians(20))),
        head_yaw_std_deg=0,
        head_pitch_std_deg=0,
    )
    np.testing.assert_allclose(np.degrees(rig.head_poses(1, 0))[0], [-20, 0], atol=1e-9)


def test_builtin_rigs_and_their_fitted_distributions():
    d = BUILTIN_RIGS["wheelchair"].distribution()
    assert abs(d.mean_deg[1] - 30) < 0.5 and abs(d.mean_deg[0]) < 0.5
    assert 60 < d.cov_deg2[0][0] < 140  # head yaw std 10 deg, slightly shrunk by the pitch
    # the screen camera is 20 mm above the eyes at 550 mm (atan(20/550) = 2.1 deg above) and the head
    # tilts down 8 deg on average: seen pitch about -8 - 2.1 = -10.1
    s = BUILTIN_RIGS["screen"].distribution()
    assert abs(s.mean_deg[1] - (-8 - np.degrees(np.arctan2(20, 550)))) < 0.5


def _rig_yaml(**fields) -> str:
    """A complete rig file (every field but name): the built-in wheelchair's values, some replaced."""
    import yaml

    d = {k: v for k, v in BUILTIN_RIGS["wheelchair"].as_dict().items() if k != "name"}
    d.update(fields)
    return yaml.safe_dump(d)


def test_rig_files(tmp_path):
    p = tmp_path / "rig.yaml"
    p.write_text(_rig_yaml(camera_position_mm=[0, 100, -500], head_yaw_std_deg=3))
    rig = load_rig(p)
    assert rig.name == "rig" and rig.camera_position_mm == (0.0, 100.0, -500.0) and rig.head_yaw_std_deg == 3
    assert load_rig("wheelchair") is BUILTIN_RIGS["wheelchair"]
    (tmp_path / "bad.yaml").write_text("camera_position: [0, 0, -1]\n")
    with pytest.raises(GazeAugError, match="unknown rig fields"):
        load_rig(tmp_path / "bad.yaml")
    (tmp_path / "behind.yaml").write_text(_rig_yaml(camera_position_mm=[0, 0, 100]))
    with pytest.raises(GazeAugError, match="in front of the face"):
        load_rig(tmp_path / "behind.yaml")
    (tmp_path / "broken.yaml").write_text("camera_position_mm: [0, 0\n")
    with pytest.raises(GazeAugError, match="not valid"):
        load_rig(tmp_path / "broken.yaml")
    with pytest.raises(GazeAugError, match="no such file"):
        load_rig(tmp_path / "missing.yaml")
