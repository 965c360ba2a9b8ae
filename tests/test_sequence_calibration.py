"""Simulated sequences (truth per frame), their scoring, and per-user calibration.

Expected values of the calibration fits are derived by hand in the comments.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from gazeaug.calibration import Calibration, fit_calibration, load_calibration, model_digest
from gazeaug.errors import GazeAugError
from gazeaug.sequence import TRUTH_COLUMNS, SequenceSettings, read_truth, sequence_accuracy

RIG = Path(__file__).resolve().parents[1] / "data_samples" / "rigs" / "wheelchair_objects.yaml"


def _points(n=5, seed=0):
    rng = np.random.default_rng(seed)
    true = rng.uniform(-0.4, 0.4, (n, 2))
    return true


def test_fit_bias_by_hand():
    # every point off by the same (0.05, -0.03) rad: the bias recovers it exactly, and the affine fit
    # (as exact) does not win the tie: the simpler correction is kept
    true = _points()
    pred = true - [0.05, -0.03]
    ids = np.arange(5)
    cal = fit_calibration(np.repeat(pred, 3, axis=0), np.repeat(true, 3, axis=0), np.repeat(ids, 3), "d")
    assert cal.kind == "bias" and cal.points == 5
    np.testing.assert_allclose(cal.offset, [0.05, -0.03], atol=1e-12)
    np.testing.assert_allclose(cal.apply(pred), true, atol=1e-12)
    assert cal.error_deg["left_out"]["bias"] < 1e-6 < cal.error_deg["left_out"]["none"]


def test_fit_scale_and_affine_by_hand():
    # true = diag(1.2, 0.8) pred + b: the per-angle gain fits exactly and, as the simpler of the two
    # exact fits, beats the affine map
    pred = _points(6, seed=1)
    true = pred @ np.diag([1.2, 0.8]).T + [0.02, 0.01]
    cal = fit_calibration(pred, true, np.arange(6), "d")
    assert cal.kind == "scale"
    np.testing.assert_allclose(cal.matrix, [[1.2, 0.0], [0.0, 0.8]], atol=1e-9)
    np.testing.assert_allclose(cal.offset, [0.02, 0.01], atol=1e-9)
    # a map that mixes the angles: only the affine fit is exact left out (12 points, the least it takes)
    pred12 = _points(12, seed=4)
    m = np.array([[1.1, 0.2], [-0.1, 0.9]])
    cal = fit_calibration(pred12, pred12 @ m.T + [0.02, 0.01], np.arange(12), "d")
    assert cal.kind == "affine"
    np.testing.assert_allclose(cal.matrix, m, atol=1e-9)
    # with 9 points (the calibration grid) the affine map is not tried; with 2, neither is the gain
    assert "affine" not in fit_calibration(pred12[:9], pred12[:9], np.arange(9), "d").error_deg["left_out"]
    cal2 = fit_calibration(pred[:2], true[:2], np.arange(2), "d")
    assert set(cal2.error_deg["left_out"]) == {"none", "bias"}


def test_fit_needs_a_clear_gain():
    # a bias that lowers the left-out error by under 10 % is not kept: 4 points whose residuals are
    # (+d, +d, +d, -d) in pitch, d = 0.1 rad. Left out, no correction errs d at each (mean d); the bias
    # fitted on the other three is d/3 (leaving out a +d point: (2d - d)/3) or d (leaving out -d):
    # errors |d - d/3| = 2d/3 three times and |-d - d| = 2d once: mean (2d + 2d) / 4 = d: no gain
    true = _points(4, seed=5)
    pred = true.copy()
    pred[:, 0] -= [0.1, 0.1, 0.1, -0.1]
    assert fit_calibration(pred, true, np.arange(4), "d").kind == "none"


def test_fit_keeps_none_when_nothing_helps():
    # the model is right at 4 points but one, which is off by 0.2 rad in pitch: a bias fitted
    # without that point is 0 (no help for it), a bias fitted with it moves the other three
    # off by 0.05: left out, the bias errs more on average than no correction
    true = _points(4, seed=2)
    pred = true.copy()
    pred[0, 0] += 0.2
    cal = fit_calibration(pred, true, np.arange(4), "d")
    assert cal.kind == "none" and cal.offset == (0.0, 0.0)


def test_fit_needs_two_points():
    with pytest.raises(GazeAugError, match="at least 2"):
        fit_calibration(np.zeros((5, 2)), np.zeros((5, 2)), np.zeros(5), "d")


def test_calibration_file_round_trip_and_refusals(tmp_path):
    cal = Calibration("bias", ((1.0, 0.0), (0.0, 1.0)), (0.1, -0.2), "ab" * 32, 9, {})
    p = cal.save(tmp_path / "u.json")
    assert load_calibration(p, "ab" * 32) == cal
    with pytest.raises(GazeAugError, match="another model"):
        load_calibration(p, "cd" * 32)
    good = json.loads(p.read_text())
    for change, message in [
        ({"matrix": [[1]]}, "matrix"),
        ({"kind": "none"}, "'none' correction cannot"),  # an offset under kind none
        ({"matrix": [[2.0, 0.0], [0.0, 1.0]]}, "'bias' correction cannot"),
        ({"kind": "affine", "matrix": [[1e300, 0.0], [0.0, 1.0]]}, "gains up to"),
        ({"offset": [True, False]}, "expected numbers"),
        ({"offset": [1.0, 0.0]}, "offsets up to"),  # 57 deg
        ({"version": 2}, "version"),
        ({"model_sha256": 12345}, "64 hexadecimal"),
        ({"offset": [10**400, 0]}, "bad calibration values"),  # an integer no float holds
    ]:
        (tmp_path / "bad.json").write_text(json.dumps({**good, **change}))
        with pytest.raises(GazeAugError, match=message):
            load_calibration(tmp_path / "bad.json")
    (tmp_path / "mirror.json").write_text(json.dumps({**good, "mirror_average": "yes"}))
    with pytest.raises(GazeAugError, match="mirror_average: expected true, false or null"):
        load_calibration(tmp_path / "mirror.json")
    (tmp_path / "other.json").write_text("[]")
    with pytest.raises(GazeAugError, match="not a gazeaug calibration"):
        load_calibration(tmp_path / "other.json")
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)  # deeper than Python's JSON reader goes
    with pytest.raises(GazeAugError, match="not a readable calibration file"):
        load_calibration(tmp_path / "deep.json")


def test_calibration_records_how_the_model_was_read(tmp_path):
    """A correction fitted on the averaged answers is refused for the plain ones, and the other way."""
    pred, ids = np.array([[0.0, 0.0], [0.1, 0.2]]), np.arange(2)
    on = fit_calibration(pred, pred + 0.01, ids, "ab" * 32, mirror_average=True)
    assert on.mirror_average is True
    p = on.save(tmp_path / "on.json")
    assert json.loads(p.read_text())["mirror_average"] is True
    assert load_calibration(p, "ab" * 32, mirror_average=True) == on
    assert load_calibration(p, "ab" * 32) == on  # not asked: not checked
    with pytest.raises(
        GazeAugError, match=r"on\.json: .*mirror averaging on, .* now with it off: give --mirror-average on"
    ):
        load_calibration(p, "ab" * 32, mirror_average=False)
    off = fit_calibration(pred, pred, ids, "ab" * 32, mirror_average=False)
    with pytest.raises(GazeAugError, match="averaging off, .* with it on: give --mirror-average off"):
        off.check_for("ab" * 32, True)
    # a file written before the field existed: taken as it is, whichever way the model is read
    old = json.loads(p.read_text())
    del old["mirror_average"]
    (tmp_path / "old.json").write_text(json.dumps(old))
    for way in (True, False):
        assert load_calibration(tmp_path / "old.json", "ab" * 32, mirror_average=way).mirror_average is None


def test_sequence_settings_checks():
    assert SequenceSettings(seconds=2.0, fps=10.0).frames == 20
    with pytest.raises(GazeAugError, match="pattern"):
        SequenceSettings(pattern="spiral")
    with pytest.raises(GazeAugError, match="fixation_s"):
        SequenceSettings(fixation_s=(2.0, 1.0))


def test_sequence_accuracy_by_hand():
    # 30 frames at 10 fps: frames 0-14 fixate "a" at (0, 0, 1000) (camera frame), 15-29 glance elsewhere
    truth = [
        {
            "frame": i,
            "time_s": i / 10,
            "phase": "fixation" if i < 15 else "glance",
            "target": "a" if i < 15 else "",
            "blink": 0.0,
            "target_x": 0.0,
            "target_y": 0.0,
            "target_z": 1000.0,
        }
        for i in range(30)
    ]
    # the gaze from the origin tilted by 10 deg: 10 deg off on every frame
    g = [np.sin(np.radians(10)), 0.0, np.cos(np.radians(10))]
    rows = [
        {"frame": str(i), "status": "ok", "gaze_x": g[0], "gaze_y": g[1], "gaze_z": g[2]}
        | {"origin_x_mm": 0, "origin_y_mm": 0, "origin_z_mm": 0}
        for i in range(30)
    ]
    sel = [{"frame": 8, "target": "a"}, {"frame": 20, "target": "a"}]  # one right, one during the glance
    acc = sequence_accuracy(rows, sel, truth, dwell_s=0.6)
    assert acc["gaze_error_deg"]["median"] == pytest.approx(10.0, abs=0.01)
    # at 1000 mm: the chord 2 * 1000 * sin(5 deg) = 174.3 mm
    assert acc["gaze_error_mm"]["median"] == pytest.approx(174.3, abs=0.1)
    # the fixation lasts 1.5 s >= 0.6 + 0.2: eligible, and selected during it
    assert acc["fixations"] == 1 and acc["selected_right"] == 1 and acc["selection_accuracy"] == 1.0
    # one false selection in 3 s: 20 per minute; precision 1/2
    assert acc["false_selections"] == 1 and acc["false_per_minute"] == 20.0 and acc["precision"] == 0.5


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    pytest.importorskip("torch")
    from helpers import synthetic_h5

    from gazeaug.train import TrainSettings, train

    d = tmp_path_factory.mktemp("model")
    train(synthetic_h5(d / "t.h5", n=64), d / "m.pt", TrainSettings(epochs=1, batch_size=32), progress=False)
    return d / "m.pt"


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    """A 2 s sequence at 10 fps of the built-in face in the wheelchair rig with objects."""
    from gazeaug.sampling import load_rig
    from gazeaug.sequence import simulate_sequence

    out = tmp_path_factory.mktemp("seq") / "s"
    seq = SequenceSettings(seconds=2.0, fps=10.0, fixation_s=(0.6, 0.8), blink_every_s=(0.8, 0.9), glance_share=0.5)
    summary = simulate_sequence(None, load_rig(RIG), out, sequence=seq, seed=3, progress=False)
    assert summary["frames"] == 20 and summary["blinks"] >= 1
    return out


def test_sequence_folder(sequence):
    from gazeaug.datasets import open_dataset

    names = sorted(p.name for p in sequence.iterdir())
    assert names[:3] == ["00000.jpg", "00001.jpg", "00002.jpg"] and "truth.csv" in names
    with open(sequence / "truth.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == list(TRUTH_COLUMNS) and len(rows) == 20
    assert {r["phase"] for r in rows} <= {"fixation", "glance", "saccade"}
    assert any(float(r["blink"]) > 0 for r in rows)
    assert {r["target"] for r in rows if r["phase"] == "fixation"} <= {"cup", "bottle", "apple", "book"}
    truth = read_truth(sequence)
    assert truth is not None and truth[3]["time_s"] == pytest.approx(0.3)
    meta = json.loads((sequence / "sequence.json").read_text())
    assert meta["fps"] == 10.0 and meta["identity_seed"] == 3
    assert len(open_dataset(sequence)) == 20  # also a folder dataset (labels.csv)


def test_track_scores_a_sequence_and_calibrate(model, sequence, tmp_path, capsys):
    from gazeaug.cli import main

    code = main(
        ["track", str(sequence), "-o", str(tmp_path / "t"), "--model", str(model), "--rig", str(RIG), "--quiet"]
    )
    out, err = capsys.readouterr()
    assert code == 0, err
    acc = json.loads(out.strip().splitlines()[-1])["accuracy"]
    assert acc["frames"] == 20 and acc["frames_scored"] > 0 and acc["gaze_error_deg"]["median"] is not None
    # a calibration from the sequence's truth (no targets file needed), applied by track; refused for another model
    code = main(
        [
            "calibrate",
            str(sequence),
            "--model",
            str(model),
            "--rig",
            str(RIG),
            "-o",
            str(tmp_path / "u.json"),
            "--quiet",
            "--settle",
            "0",
        ]
    )
    out, err = capsys.readouterr()
    assert code == 0, err
    report = json.loads(out.strip().splitlines()[-1])
    assert report["points"] >= 2 and report["kind"] in ("none", "bias", "affine")
    assert load_calibration(tmp_path / "u.json", model_digest(model)).points == report["points"]
    code = main(
        ["track", str(sequence), "-o", str(tmp_path / "t2"), "--model", str(model), "--rig", str(RIG), "--quiet"]
        + ["--calibration", str(tmp_path / "u.json"), "--no-video"]
    )
    out, err = capsys.readouterr()
    assert code == 0, err
    assert json.loads(out.strip().splitlines()[-1])["calibration"] == report["kind"]
    # fitted on the model as its file says (mirror averaging on): refused for it read plainly
    assert report["mirror_average"] is True
    code = main(
        ["track", str(sequence), "-o", str(tmp_path / "t5"), "--model", str(model), "--rig", str(RIG), "--quiet"]
        + ["--calibration", str(tmp_path / "u.json"), "--no-video", "--mirror-average", "off"]
    )
    out, err = capsys.readouterr()
    assert code == 2 and "give --mirror-average on" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "t5").exists()
    other = tmp_path / "other.pt"
    other.write_bytes(model.read_bytes() + b"\0")
    code = main(
        [
            "track",
            str(sequence),
            "-o",
            str(tmp_path / "t3"),
            "--model",
            str(other),
            "--calibration",
            str(tmp_path / "u.json"),
            "--quiet",
        ]
    )
    _, err = capsys.readouterr()
    assert code == 2 and "another model" in err
    # the library refuses it too (the CLI checks it on loading the file)
    from gazeaug.estimator import load_estimator
    from gazeaug.track import track

    with pytest.raises(GazeAugError, match="fitted for another model"):
        track(sequence, tmp_path / "t4", load_estimator(other), calibration=load_calibration(tmp_path / "u.json"))
    assert not (tmp_path / "t4").exists()


def test_calibrate_needs_truth(model, tmp_path, capsys):
    from gazeaug.cli import main

    folder = tmp_path / "frames"
    folder.mkdir()
    from facemesh.build import sample_image
    from facemesh.io import save_image_rgb

    save_image_rgb(folder / "0.png", sample_image())
    code = main(["calibrate", str(folder), "--model", str(model), "-o", str(tmp_path / "u.json"), "--quiet"])
    _, err = capsys.readouterr()
    assert code == 2 and "--targets" in err and not (tmp_path / "u.json").exists()
    code = main(["calibrate", str(tmp_path / "nothing"), "--model", str(model), "-o", str(tmp_path / "u.json")])
    _, err = capsys.readouterr()
    assert code == 2 and "no such folder" in err and not (tmp_path / "u.json").exists()
    bad = tmp_path / "t.csv"
    bad.write_text("start_s,end_s,target\n0,1,teapot\n")
    code = main(
        [
            "calibrate",
            str(folder),
            "--model",
            str(model),
            "--rig",
            str(RIG),
            "--targets",
            str(bad),
            "-o",
            str(tmp_path / "u.json"),
            "--quiet",
        ]
    )
    _, err = capsys.readouterr()
    assert code == 2 and "line 2" in err and "teapot" in err


def test_a_sequence_file_nested_too_deeply_is_refused_in_words(tmp_path):
    from gazeaug.track import _sequence_fps

    (tmp_path / "sequence.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(GazeAugError, match="not a readable sequence file"):
        _sequence_fps(tmp_path)


def test_an_estimator_is_tied_to_the_bytes_it_read(tmp_path):
    import hashlib
    import shutil

    from gazeaug.estimator import load_estimator
    from gazeaug.models.train_demo import DEMO_MODEL

    if not DEMO_MODEL.is_file():
        pytest.skip("the built-in demo model is not there")
    path = tmp_path / "m.pt"
    shutil.copyfile(DEMO_MODEL, path)
    want = hashlib.sha256(path.read_bytes()).hexdigest()
    est = load_estimator(path)
    assert est.model_sha256 == want == model_digest(path)
    # the file replaced after loading: the estimator still names the model it holds, a new one the new file
    path.write_bytes(path.read_bytes() + b"\0")
    assert est.model_sha256 == want != model_digest(path)
    cal = fit_calibration(_points(), _points(), np.arange(5), want)
    cal.check_for(est.model_sha256, est.mirror_average)
    with pytest.raises(GazeAugError, match="another model"):
        cal.check_for(model_digest(path))
