"""The experiment's metrics, step matching and tables, against values derived by hand.

Angles: (pitch, yaw) radians in the MPIIGaze convention (facemesh.conventions). Two facts
the hand derivations use: two directions with the same yaw 0 and pitches p1, p2 (both
within +-90 deg) lie on one great circle, so the angle between them is |p1 - p2|; and two
directions with pitch 0 and yaws y1, y2 lie on the horizontal great circle: |y1 - y2|.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from gazeaug.errors import GazeAugError
from gazeaug.experiment import (
    MIN_STEPS_BATCHNORM,
    TooFewStepsWarning,
    check_steps,
    format_mean_std,
    matched_epochs,
    mean_std,
    metric_table,
    min_steps_for,
    optimizer_steps,
    reading_verdict,
    reduction_table,
    steps_table,
    table,
)
from gazeaug.metrics import (
    angular_errors_deg,
    bias_removed_error_deg,
    bootstrap_reduction,
    constant_guess_error_deg,
    global_offset,
    mean_error_deg,
    mean_gaze,
    pearson,
    per_subject_errors_deg,
    relative_reduction_percent,
    summarize,
)

DEG = 180.0 / math.pi


# --------------------------------------------------------------------------- metrics


def test_mean_error_of_three_samples_by_hand():
    # (0,0) vs (0,0.1): horizontal circle, 0.1 rad; (0.2,0) vs (0,0): yaw-0 meridian, 0.2 rad; equal: 0
    pred = [[0.0, 0.0], [0.2, 0.0], [0.0, 0.0]]
    true = [[0.0, 0.1], [0.0, 0.0], [0.0, 0.0]]
    np.testing.assert_allclose(angular_errors_deg(pred, true), [0.1 * DEG, 0.2 * DEG, 0.0], atol=1e-6)
    assert mean_error_deg(pred, true) == pytest.approx(0.1 * DEG)  # (0.1 + 0.2 + 0) / 3 rad


def test_mean_gaze_is_the_normalized_mean_of_unit_vectors():
    # v1 = (pitch 30, yaw 0) = (0, -1/2, -sqrt3/2); v2 = (pitch 0, yaw 90) = (-1, 0, 0)
    # sum s = (-1, -1/2, -sqrt3/2), |s| = sqrt(2): pitch = asin(1/2 / sqrt2), yaw = atan2(1, sqrt3/2)
    true = np.radians([[30.0, 0.0], [0.0, 90.0]])
    expected = [math.asin(0.5 / math.sqrt(2)), math.atan2(1.0, math.sqrt(3) / 2)]
    np.testing.assert_allclose(mean_gaze(true), expected, atol=1e-12)
    # not the mean of the angles, (15, 45) deg
    assert abs(np.degrees(mean_gaze(true))[0] - 15.0) > 5
    # v1 . s = 1/4 + 3/4 = 1 and v2 . s = 1: both at acos(1 / sqrt2) = 45 deg from the mean
    assert constant_guess_error_deg(true) == pytest.approx(45.0)


def test_constant_guess_of_a_symmetric_fan():
    # yaws 0, +30, -30 deg at pitch 0: the mean points at yaw 0; errors 0, 30, 30 -> 20 deg
    true = np.radians([[0.0, 0.0], [0.0, 30.0], [0.0, -30.0]])
    np.testing.assert_allclose(mean_gaze(true), [0.0, 0.0], atol=1e-12)
    assert constant_guess_error_deg(true) == pytest.approx(20.0)


def test_vectors_that_cancel_have_no_mean_direction():
    with pytest.raises(GazeAugError, match="cancel"):
        mean_gaze([[0.0, 0.0], [0.0, math.pi]])  # (0, 0, -1) and (0, 0, 1)


def test_perfect_predictor():
    true = np.radians([[0.0, 0.0], [10.0, -5.0], [-20.0, 15.0]])
    s = summarize(true, true, ["a", "a", "b"])
    assert s["mean_deg"] == pytest.approx(0.0, abs=1e-6) and s["bias_removed_deg"] == pytest.approx(0.0, abs=1e-6)
    assert s["ratio_to_constant"] == pytest.approx(0.0, abs=1e-6)
    assert s["pearson_pitch"] == pytest.approx(1.0) and s["pearson_yaw"] == pytest.approx(1.0)
    assert s["offset_deg"] == pytest.approx([0.0, 0.0], abs=1e-12)


def test_a_different_offset_per_person_is_removed_per_person_but_not_globally():
    from gazeaug.metrics import pearson_within_subjects, subject_offsets_removed_error_deg

    true = np.radians([[0.0, -10.0], [10.0, 10.0], [0.0, -10.0], [10.0, 10.0]])
    # person a read 5 deg too high in pitch, person b 5 deg too low: no global offset at all
    pred = true + np.radians([[5.0, 0.0], [5.0, 0.0], [-5.0, 0.0], [-5.0, 0.0]])
    people = ["a", "a", "b", "b"]
    assert subject_offsets_removed_error_deg(pred, true, people) == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(pearson_within_subjects(pred, true, people), [1.0, 1.0])
    s = summarize(pred, true, people)
    # a pitch error of 5 deg at yaw +-10 deg: the angle between the two gaze vectors, by the dot product
    # cos e = cos p1 cos p2 + sin p1 sin p2 (same yaw): e = 5 deg exactly
    assert s["bias_removed_deg"] == pytest.approx(5.0, abs=1e-6)
    assert s["subject_offsets_removed_deg"] == pytest.approx(0.0, abs=1e-6)
    assert s["pearson_within_pitch"] == pytest.approx(1.0) and s["pearson_within_yaw"] == pytest.approx(1.0)


def test_pearson_within_subjects_by_hand():
    from gazeaug.metrics import pearson_within_subjects

    # within a: true pitch -1, +1 about its mean, predicted -1, +1; within b: true -1, +1, predicted +1, -1
    # pooled: sum(dp dt) = 1 + 1 - 1 - 1 = 0 -> r 0. Yaw predicted 2x the truth about each mean -> r 1.
    true = np.radians([[9.0, 0.0], [11.0, 2.0], [-1.0, 5.0], [1.0, 7.0]])
    pred = np.radians([[0.0, 10.0], [2.0, 14.0], [21.0, -3.0], [19.0, 1.0]])
    np.testing.assert_allclose(pearson_within_subjects(pred, true, ["a", "a", "b", "b"]), [0.0, 1.0], atol=1e-12)
    # a constant per person: nothing varies within a person, no correlation
    const = np.radians([[3.0, 3.0], [3.0, 3.0], [-4.0, 1.0], [-4.0, 1.0]])
    assert np.isnan(pearson_within_subjects(const, true, ["a", "a", "b", "b"])).all()
    assert summarize(const, true, ["a", "a", "b", "b"])["pearson_within_pitch"] is None


def test_per_person_metrics_leave_out_people_seen_once():
    from gazeaug.metrics import pearson_within_subjects, subject_offsets_removed_error_deg

    true = np.radians([[0.0, 0.0], [10.0, 0.0], [0.0, 0.0], [20.0, 0.0]])
    pred = np.radians([[5.0, 0.0], [15.0, 0.0], [3.0, 0.0], [0.0, 0.0]])
    # c and d have one image each: removing their own offset would erase their errors (0 deg); they are
    # left out, and a and b (offset 5 deg, read exactly) give 0 by hand
    assert subject_offsets_removed_error_deg(pred, true, ["a", "a", "c", "d"]) == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(pearson_within_subjects(pred, true, ["a", "a", "c", "d"]), [1.0, math.nan])
    # every person seen once (a set of one image per identity): undefined, not a perfect 0, and quietly so
    # (numpy's "Mean of empty slice" reached the users of gazeaug experiment)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = summarize(pred, true, ["a", "b", "c", "d"])
    assert s["subject_offsets_removed_deg"] is None
    assert s["pearson_within_pitch"] is None and s["pearson_within_yaw"] is None


def test_constant_predictor_at_the_mean_gaze_has_ratio_one():
    true = np.radians([[0.0, 0.0], [0.0, 30.0], [0.0, -30.0], [10.0, 5.0]])
    pred = np.broadcast_to(mean_gaze(true), true.shape)
    s = summarize(pred, true, ["a"] * 4)
    assert s["ratio_to_constant"] == pytest.approx(1.0)
    assert s["pearson_pitch"] is None and s["pearson_yaw"] is None  # a constant has no correlation


def test_offset_predictor_has_zero_error_without_its_offset():
    true = np.radians([[0.0, 0.0], [10.0, -5.0], [-20.0, 15.0]])
    pred = true + [0.1, -0.2]
    np.testing.assert_allclose(global_offset(pred, true), [0.1, -0.2], atol=1e-12)
    assert bias_removed_error_deg(pred, true) == pytest.approx(0.0, abs=1e-6)
    assert mean_error_deg(pred, true) > 5.0
    np.testing.assert_allclose(pearson(pred, true), [1.0, 1.0])


def test_bias_removed_error_by_hand():
    # on the yaw-0 meridian: pred - true = 0.1, 0.3, 0.2 rad of pitch -> offset 0.2;
    # what is left: -0.1, 0.1, 0 -> errors 0.1, 0.1, 0 rad -> mean 0.2 / 3 rad
    true = [[0.0, 0.0], [0.1, 0.0], [0.2, 0.0]]
    pred = [[0.1, 0.0], [0.4, 0.0], [0.4, 0.0]]
    np.testing.assert_allclose(global_offset(pred, true), [0.2, 0.0], atol=1e-12)
    assert bias_removed_error_deg(pred, true) == pytest.approx(0.2 / 3 * DEG)


def test_yaw_offset_wraps_around():
    # yaw pi - 0.05 vs -pi + 0.05: 0.1 rad apart across +-pi, the difference -0.1 rad, not 2 pi - 0.1
    np.testing.assert_allclose(global_offset([[0.0, math.pi - 0.05]], [[0.0, -math.pi + 0.05]]), [0.0, -0.1])


def test_pearson_by_hand():
    # pitch: x = (1,2,3), y = (1,3,2): dx = (-1,0,1), dy = (-1,1,0): sum dx dy = 1, |dx|^2 = |dy|^2 = 2 -> 0.5
    # yaw: x = (0,1,2), y = (2,1,0): exactly opposite -> -1
    pred = 0.1 * np.array([[1.0, 0.0], [2.0, 1.0], [3.0, 2.0]])
    true = 0.1 * np.array([[1.0, 2.0], [3.0, 1.0], [2.0, 0.0]])
    np.testing.assert_allclose(pearson(pred, true), [0.5, -1.0], atol=1e-12)


def test_per_subject_errors_by_hand():
    assert per_subject_errors_deg([1.0, 2.0, 3.0, 6.0], ["a", "b", "a", "b"]) == {"a": 2.0, "b": 4.0}
    # the three samples of the first test: a gets 0.1 and 0 rad, b 0.2 rad; subjects weigh the same
    pred = [[0.0, 0.0], [0.2, 0.0], [0.0, 0.0]]
    true = [[0.0, 0.1], [0.0, 0.0], [0.0, 0.0]]
    s = summarize(pred, true, ["a", "b", "a"])
    assert s["per_subject_deg"] == pytest.approx({"a": 0.05 * DEG, "b": 0.2 * DEG})
    assert s["subject_mean_deg"] == pytest.approx(0.125 * DEG)


def test_bad_inputs_are_refused():
    with pytest.raises(GazeAugError, match=r"\(N, 2\)"):
        mean_error_deg([0.0, 0.0], [0.0, 0.0])
    with pytest.raises(GazeAugError, match="same shape"):
        mean_error_deg([[0.0, 0.0]], [[0.0, 0.0], [0.1, 0.0]])
    with pytest.raises(GazeAugError, match="finite"):
        mean_error_deg([[math.nan, 0.0]], [[0.0, 0.0]])
    with pytest.raises(GazeAugError, match="subjects"):
        per_subject_errors_deg([1.0, 2.0], ["a"])


def test_relative_reduction_by_hand():
    assert relative_reduction_percent([2.0, 4.0], [1.0, 2.0]) == pytest.approx(50.0)  # 3 -> 1.5
    assert relative_reduction_percent([2.0, 4.0], [3.0, 6.0]) == pytest.approx(-50.0)


def test_bootstrap_of_a_uniform_halving_has_no_spread():
    a = np.array([1.0, 2.0, 3.0, 4.0])
    b = a / 2  # every resample: 50 %
    r = bootstrap_reduction(a, b, resample="samples", n_boot=200)
    assert r["reduction_percent"] == pytest.approx(50.0) and r["low"] == pytest.approx(50.0)
    assert r["high"] == pytest.approx(50.0) and r["resample"] == "samples" and r["units"] == 4


def test_bootstrap_of_two_samples_by_hand():
    # a = (1, 1), b = (0, 1). Resamples: {1st, 1st}: 1 - 0/2 = 100 %, p = 1/4; {2nd, 2nd}: 0 %, p = 1/4;
    # mixed: 1 - 1/2 = 50 %, p = 1/2. With 2000 replicates the 2.5 % and 97.5 % quantiles are 0 and 100.
    r = bootstrap_reduction([1.0, 1.0], [0.0, 1.0], resample="samples", n_boot=2000, seed=3)
    assert r["reduction_percent"] == pytest.approx(50.0)
    assert (r["low"], r["high"]) == (pytest.approx(0.0), pytest.approx(100.0))
    assert bootstrap_reduction([1.0, 1.0], [0.0, 1.0], resample="samples", seed=3) == r  # seeded


def test_bootstrap_resamples_whole_subjects():
    # subject A: a = (1, 1), b = (0, 0); subject B: a = (1, 1), b = (2, 2). Totals A: 2 -> 0, B: 2 -> 4.
    # Resamples of two subjects: AA: 1 - 0/4 = 100 %; BB: 1 - 8/4 = -100 %; AB: 1 - 4/4 = 0 % (the point).
    a, b, subj = [1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 2.0, 2.0], ["A", "A", "B", "B"]
    r = bootstrap_reduction(a, b, subj, resample="subjects", n_boot=2000)
    assert r["reduction_percent"] == pytest.approx(0.0) and r["units"] == 2
    assert (r["low"], r["high"]) == (pytest.approx(-100.0), pytest.approx(100.0))
    # one subject: every resample is the whole set, so the interval is the point
    one = bootstrap_reduction([1.0, 3.0], [1.0, 1.0], ["A", "A"], n_boot=100)
    assert one["low"] == pytest.approx(50.0) and one["high"] == pytest.approx(50.0)
    with pytest.raises(GazeAugError, match="subjects"):
        bootstrap_reduction(a, b, resample="subjects")
    with pytest.raises(GazeAugError, match="resample"):
        bootstrap_reduction(a, b, subj, resample="people")


# --------------------------------------------------------------------------- steps


def test_optimizer_steps_count_the_short_last_batch():
    assert optimizer_steps(10, 360, 256) == 20  # the original model: 2 batches per epoch
    assert optimizer_steps(10, 1440, 256) == 60  # its augmented set (K = 4): 6 batches per epoch
    assert optimizer_steps(3, 256, 256) == 3 and optimizer_steps(3, 257, 256) == 6


def test_matched_epochs_give_at_least_the_same_steps():
    assert matched_epochs(60, 360, 256) == 30  # 30 epochs x 2 = 60 steps, exactly
    assert matched_epochs(240, 60, 32) == 120  # 2 steps per epoch
    # 201 steps over 2 steps per epoch: 101 epochs = 202 steps (>= 201, < 201 + 2)
    assert matched_epochs(201, 60, 32) == 101
    assert matched_epochs(0, 10, 4) == 1
    with pytest.raises(GazeAugError, match="rows"):
        matched_epochs(10, 0, 4)


def test_too_few_steps_warn():
    with pytest.warns(TooFewStepsWarning, match="20 optimizer steps, fewer than the 200"):
        assert check_steps("original", 20, 200) is False
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_steps("original", 200, 200) is True


def test_min_steps_follow_the_normalization_layers():
    torch = pytest.importorskip("torch")
    with_bn = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.BatchNorm2d(4))
    without = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.GroupNorm(2, 4))
    assert min_steps_for(with_bn) == MIN_STEPS_BATCHNORM == 200 and min_steps_for(without) == 0


# --------------------------------------------------------------------------- tables


def test_mean_std_over_seeds():
    s = mean_std([1.0, 2.0, None, 3.0])  # mean 2, sample std sqrt((1 + 0 + 1) / 2) = 1
    assert (s["mean"], s["std"], s["n"]) == (2.0, 1.0, 3)
    assert mean_std([4.0])["std"] is None and mean_std([None])["mean"] is None


def test_format_mean_std():
    assert format_mean_std({"mean": 17.904, "std": 0.1234}) == "17.90 ± 0.12"
    assert format_mean_std({"mean": 17.904, "std": 0.1234}, 1, "deg") == "17.9 ± 0.1 deg"
    assert format_mean_std({"mean": 17.904, "std": None}, 3) == "17.904"
    assert format_mean_std({"mean": None, "std": None}) == "n/a" and format_mean_std(None) == "n/a"


def _results() -> dict:
    def m(o, a, c):
        return {"original": {"mean": o[0], "std": o[1]}, "augmented": {"mean": a[0], "std": a[1]}, "constant": c}

    def test(label, n, red, boot):
        return {
            "label": label,
            "count": n,
            "metrics": {
                "mean_deg": m((20.0, 1.0), (18.5, 0.25), 17.9),
                "pearson_yaw": m((0.01234, 0.1), (None, None), None),
            },
            "reduction_percent": {"mean": red, "std": 2.0},
            "bootstrap": boot,
        }

    boot = {"reduction_percent": 7.5, "low": 1.3, "high": 12.0, "level": 0.95, "resample": "samples", "units": 60}
    boot["n_boot"] = 2000
    return {
        "train_dataset": "sim_train_screen",
        "tests": {
            "test": test("new person, new rig", 60, 7.5, boot),
            "test_same_rig": test("new person, training rig", 60, -1.0, None),
            "seen": {**test("training images (original set)", 60, -900.0, None), "anchor": True},
        },
        "runs": {
            "original": {"rows": 60, "batch_size": 32, "epochs": 120, "steps": 240, "min_steps": 200},
            "augmented": {"rows": 240, "batch_size": 32, "epochs": 30, "steps": 240, "min_steps": 200},
        },
    }


def test_headline_table():
    r = _results()
    assert table(r) == (
        "| training dataset | error, original data | error, augmented data | reduction |\n"
        "|---|---|---|---|\n"
        "| sim_train_screen | 20.00 ± 1.00 deg | 18.50 ± 0.25 deg | 7.5 ± 2.0 % [1.3, 12.0] |\n"
    )


def test_metric_table_has_a_row_per_test_set_and_the_constant_guess():
    r = _results()
    assert metric_table(r, "mean_deg") == (
        "### Mean angular error (deg)\n"
        "\n"
        "| test set | original | augmented | constant guess |\n"
        "|---|---|---|---|\n"
        "| new person, new rig | 20.00 ± 1.00 | 18.50 ± 0.25 | 17.90 |\n"
        "| new person, training rig | 20.00 ± 1.00 | 18.50 ± 0.25 | 17.90 |\n"
        "| training images (original set) | 20.00 ± 1.00 | 18.50 ± 0.25 | 17.90 |\n"
    )
    assert metric_table(r, "pearson_yaw").splitlines()[-2] == "| new person, training rig | 0.012 ± 0.100 | n/a | n/a |"
    with pytest.raises(GazeAugError, match="metric"):
        metric_table(r, "accuracy")


def test_reduction_and_steps_tables():
    r = _results()
    lines = reduction_table(r).splitlines()
    assert lines[2] == (
        "| new person, new rig | 60 | 7.5 ± 2.0 % | 7.5 %, 95% interval [1.3, 12.0] "
        "(resampling 60 samples, 2000 replicates) |"
    )
    assert lines[3] == "| new person, training rig | 60 | -1.0 ± 2.0 % | n/a |" and len(lines) == 4  # no anchor
    r["runs"]["original"].update(enough_steps=True)
    r["runs"]["augmented"].update(steps=20, enough_steps=False)
    lines = steps_table(r).splitlines()
    assert lines[2] == "| original | 60 | 32 | 120 | 240 | 200 |"
    assert lines[3] == "| augmented | 240 | 32 | 30 | 20 (**too few**) | 200 |"


def test_reading_verdict():
    # constant guess 20 deg: reading means below 0.9 x 20 = 18 deg once the offset is removed
    def t(label, original, augmented):
        return {
            "label": label,
            "metrics": {
                "mean_deg": {"constant": 20.0},
                "bias_removed_deg": {"original": {"mean": original}, "augmented": {"mean": augmented}},
            },
        }

    r = {"tests": {"test": t("new person, new rig", 19.0, 12.5), "seen": t("training images", 2.0, 18.0)}}
    lines = reading_verdict(r).splitlines()
    assert lines == [
        "- new person, new rig: original does not read the eyes (19.00 deg without its offset); "
        "augmented reads the eyes (12.50 deg without its offset); constant guess 20.00 deg.",
        "- training images: original reads the eyes (2.00 deg without its offset); "
        "augmented does not read the eyes (18.00 deg without its offset); constant guess 20.00 deg.",
    ]
    r["tests"]["test"] = t("new person, new rig", 19.0, 18.0)
    assert "**Neither model reads the eyes of the test people**" in reading_verdict(r)


def test_cli_refuses_a_same_rig_test_without_datasets(tmp_path, capsys):
    from gazeaug.cli import main

    assert main(["experiment", "--test-same-rig", str(tmp_path), "-o", str(tmp_path / "xp"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--test-same-rig goes with --train and --test" in err[0]


def test_cli_experiment_refuses_a_shift_average_the_patches_cannot_take_before_any_work(tmp_path, capsys):
    # refused before the built-in setup simulates its sets (minutes with the default sizes), not at the training
    from gazeaug.cli import main

    for extra, why in (
        (
            ["--patch-size", "6", "6", "--shift-average", "8"],
            "shift_average_px: 8 px must be smaller than the eye patches' sides (6 x 6)",
        ),
        (["--shift-average", "-1"], "shift_average_px: expected an integer from 0 to 8 pixels, got -1"),
    ):
        out = tmp_path / "xp"
        assert main(["experiment", *extra, "-o", str(out), "--quiet"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and why in err[0], err
        assert not out.exists()


def test_cli_experiment_with_a_missing_dataset_writes_nothing(tmp_path, capsys):
    from gazeaug.cli import main

    (tmp_path / "test").mkdir()
    args = ["experiment", "--train", str(tmp_path / "nope"), "--test", str(tmp_path / "test")]
    assert main([*args, "-o", str(tmp_path / "xp"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0], err
    assert not (tmp_path / "xp").exists()  # not even an empty report folder


def test_the_report_says_a_keypoint_loss_is_the_augmented_models_alone():
    from gazeaug.experiment import _augmentation_line

    plain = _augmentation_line({"per_sample": 4, "eyes": "redirect", "rig": "wheelchair", "train": {}})
    assert "keypoint" not in plain
    line = _augmentation_line(
        {"per_sample": 4, "eyes": "redirect", "rig": "wheelchair", "train": {"keypoint_loss_weight": 1.0}}
    )
    assert "keypoint loss, weight 1)" in line and "the reduction includes that loss's effect" in line
