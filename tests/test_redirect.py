"""Gaze redirection in augmentation (``JobSettings(eyes="redirect")``, ``gazeaug augment --redirect-eyes``).

Expected values are derived by hand from the rig's geometry and the (pitch, yaw)
convention of docs/conventions.md (pitch + up, yaw + toward the camera's left;
head frame x left, y down, z into the head): never from the code's output.
"""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

from facemesh.camera import camera_for_image
from facemesh.io import load_image_rgb
from gazeaug.augment import face_asset, redirect_subject, render_redirected, rig_looks, source_eye_pitch
from gazeaug.cli import main
from gazeaug.errors import GazeAugError
from gazeaug.jobs import JobSettings
from gazeaug.pipeline import fit_face, mesh_for_fit
from gazeaug.sampling import BUILTIN_RIGS, Rig, rig_from_dict
from gazeaug.simulate import simulate


def _still_rig(target_rig_mm) -> Rig:
    """A camera straight ahead of the eyes, 500 mm away; a head that does not move; one target point."""
    t = tuple(float(v) for v in target_rig_mm)
    return Rig(
        name="still",
        camera_position_mm=(0.0, 0.0, -500.0),
        head_yaw_std_deg=0.0,
        head_pitch_std_deg=0.0,
        head_position_std_mm=0.0,
        target_box_mm=(t, t),
    )


@pytest.fixture(scope="module")
def astronaut(faces_dir, detector):
    img = load_image_rgb(faces_dir / "astronaut.png")
    h, w = img.shape[:2]
    fit = fit_face(img, camera_for_image(None, w, h, warn=False), detector, source="astronaut")
    return fit, face_asset(mesh_for_fit(fit))


def test_rig_looks_keep_the_rig_target_in_the_head_frame(astronaut):
    _, asset = astronaut
    # the rig frame is the frontal head frame, and a camera straight ahead of it sees it unturned:
    # rotation I, the head placed at (0, 0, D), the target (0, 200, -400) of the head frame at (0, 200, D - 400)
    places, targets = rig_looks(asset, _still_rig((0.0, 200.0, -400.0)), 3, np.random.default_rng(0), 650.0)
    for p, t in zip(places, targets):
        np.testing.assert_allclose(p.rotation, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(p.translation_mm, [0.0, 0.0, 650.0], atol=1e-12)
        np.testing.assert_allclose(t, [0.0, 200.0, 250.0], atol=1e-9)
        np.testing.assert_allclose(p.yaw_pitch_rad, [0.0, 0.0], atol=1e-12)


def test_source_eye_pitch_from_a_hand_made_gaze(astronaut):
    _, asset = astronaut
    r, t = asset.mesh.pose.rotation, asset.mesh.pose.translation_mm
    mid = asset.reference_points_mm[:2].mean(axis=0)
    for pitch_deg in (-25.0, 0.0, 15.0):
        p = math.radians(pitch_deg)
        g_head = np.array([0.0, -math.sin(p), -math.cos(p)])  # pitch + up = -y; looking out of the face = -z
        target = r @ (mid + 300.0 * g_head) + t
        assert math.degrees(source_eye_pitch(asset, gaze_target_mm=target)) == pytest.approx(pitch_deg, abs=1e-9)
        assert math.degrees(source_eye_pitch(asset, gaze_vector=r @ g_head)) == pytest.approx(pitch_deg, abs=1e-9)


def _dark_centroid_y(patch: np.ndarray) -> float:
    """Row of the darkest 4 % of the patch's middle third (pupil and iris)."""
    grey = patch.astype(np.float64).mean(axis=2)
    h, w = grey.shape
    mid = grey[:, w // 3 : 2 * w // 3]
    ys, _ = np.nonzero(mid <= np.quantile(mid, 0.04))
    return float(ys.mean())


def test_redirected_labels_follow_the_target_not_the_source(astronaut):
    fit, asset = astronaut
    r, t = asset.mesh.pose.rotation, asset.mesh.pose.translation_mm
    source_up_left = r @ np.array([200.0, -150.0, -500.0]) + t  # the source looked up and aside: must not matter
    labels, rows = {}, {}
    for name, y in (("down", 200.0), ("up", -200.0)):
        subject = redirect_subject(fit, asset, np.random.default_rng(1), gaze_target_mm=source_up_left)
        places, targets = rig_looks(asset, _still_rig((0.0, y, -400.0)), 1, np.random.default_rng(0))
        (sample,) = render_redirected(subject, asset, places, targets)
        assert sample.left.coverage > 0.99 and sample.right.coverage > 0.99
        labels[name] = np.degrees([sample.left.gaze, sample.right.gaze])  # (pitch, yaw) per eye
        rows[name] = [_dark_centroid_y(sample.left.image), _dark_centroid_y(sample.right.image)]
    # each eye (about 32 mm from the midline) looks 400 mm ahead and 200 mm down or up: pitch
    # -+atan(200 / hypot(400, 32)) = -+26.5 deg in the head frame; the normalized cameras, aimed at eyes
    # a few degrees off the optical axis, turn it by at most a few degrees
    assert labels["down"][:, 0] == pytest.approx([-26.5, -26.5], abs=4.0)
    assert labels["up"][:, 0] == pytest.approx([26.5, 26.5], abs=4.0)
    assert np.abs(labels["down"][:, 1]).max() < 8.0 and np.abs(labels["up"][:, 1]).max() < 8.0
    # the rendered eyes look that way: iris and pupil lower in the patch looking down (image y down)
    assert min(rows["down"]) > max(rows["up"]) + 1.0


def _pupil_centroid(patch: np.ndarray, near: np.ndarray) -> np.ndarray:
    """(u, v) of the darkest 6 % of a 15 x 15 px window about ``near``: the pupil (2 mm, about 2 px wide)."""
    grey = patch.astype(np.float64).mean(axis=2)
    vs, us = np.mgrid[0 : grey.shape[0], 0 : grey.shape[1]]
    window = (np.abs(us - near[0]) <= 7) & (np.abs(vs - near[1]) <= 7)
    dark = window & (grey <= np.quantile(grey[window], 0.06))
    return np.array([us[dark].mean(), vs[dark].mean()])


def test_redirected_eyes_record_where_their_iris_is_drawn(astronaut):
    # the eyes look at the camera or 150 mm beside it, iris and pupil in full view: the pupil drawn in
    # the patch lies on the recorded iris centre (the pole and the limbus's centre project within a
    # fraction of a pixel of each other for eyes turned this little), and the recorded points move
    # the way the eyes turn (image u to the right for a target toward the camera's +x)
    fit, asset = astronaut
    seen = {}
    for name, x in (("ahead", 0.0), ("right", 150.0), ("left", -150.0)):
        subject = redirect_subject(fit, asset, np.random.default_rng(1))
        places, targets = rig_looks(asset, _still_rig((x, 0.0, -500.0)), 1, np.random.default_rng(0))
        (sample,) = render_redirected(subject, asset, places, targets)
        for eye in (sample.left, sample.right):
            kp = eye.keypoints_px
            assert kp.shape == (2, 2) and np.isfinite(kp).all()
            np.testing.assert_allclose(_pupil_centroid(eye.image, kp[0]), kp[0], atol=0.8)
            # the opening's centre: near the patch centre, where normalization puts the eye
            assert np.abs(kp[1] - [30.0, 18.0]).max() < 4.0
        seen[name] = np.stack([sample.left.keypoints_px, sample.right.keypoints_px])
    # the same head, the same openings; the irises move: right of ahead for +x, left for -x
    np.testing.assert_allclose(seen["right"][:, 1], seen["ahead"][:, 1], atol=1e-9)
    assert (seen["right"][:, 0, 0] > seen["ahead"][:, 0, 0] + 1.0).all()
    assert (seen["left"][:, 0, 0] < seen["ahead"][:, 0, 0] - 1.0).all()


def test_supersampled_eyes_soften_edges_and_keep_the_picture(astronaut):
    # 2 x 2 rays per pixel, averaged: the same eyes and labels, edges (the lids' on the eyeball, the
    # iris's, the pupil's) averaged over each pixel as a camera's pixel averages them, so less of the
    # patch's energy lies at high spatial frequencies than with one ray through each pixel centre
    from gazeaug.realism import grey_equalized, patch_statistics

    fit, asset = astronaut
    places, targets = rig_looks(asset, _still_rig((30.0, 100.0, -400.0)), 3, np.random.default_rng(0))
    out = {}
    for ss in (1, 2):
        subject = redirect_subject(fit, asset, np.random.default_rng(5))
        out[ss] = render_redirected(subject, asset, places, targets, supersample=ss)
    one = np.stack([e.image for s in out[1] for e in (s.left, s.right)])
    four = np.stack([e.image for s in out[2] for e in (s.left, s.right)])
    for a, b in zip(out[1], out[2]):
        np.testing.assert_allclose(a.left.gaze, b.left.gaze, atol=1e-12)
        assert b.left.coverage == pytest.approx(a.left.coverage, abs=0.01)
    assert np.abs(one.astype(float) - four).mean() < 4.0  # the same picture, edges aside
    hf = [patch_statistics(grey_equalized(x)).high_frequency_share for x in (one, four)]
    assert hf[1] < hf[0]
    with pytest.raises(GazeAugError, match="supersample: expected an integer >= 1"):
        render_redirected(redirect_subject(fit, asset, np.random.default_rng(5)), asset, places, targets, supersample=0)


def test_redirected_eyes_draw_their_iris_colour(astronaut):
    # the simulator's draw: the photo's own iris for photo_iris_share of the subjects, else a palette
    # colour times a brightness in [0.8, 1.2] and a per-channel factor in [0.92, 1.08]
    from gazeaug.simulate import IRIS_PALETTE, SimSettings, draw_subject, eyes_only

    fit, asset = astronaut
    own = 0
    for seed in range(60):
        draw = eyes_only(draw_subject(SimSettings(), np.random.default_rng(seed)))
        if draw.iris_rgb is None:
            own += 1
            continue
        c = np.asarray(draw.iris_rgb)
        assert any(
            np.all(c >= 0.8 * 0.92 * np.asarray(p) - 1e-9) and np.all(c <= 1.2 * 1.08 * np.asarray(p) + 1e-9)
            for p in IRIS_PALETTE
        ), c
    # 30 % of 60: 18 expected, binomial standard deviation 3.5
    assert 7 <= own <= 29
    # the subject's eyes take the drawn colour, or the photo's (measured around MediaPipe's iris points):
    # both occur among 12 subjects (a miss of either has probability below 2 %)
    kinds = set()
    for seed in range(12):
        subject = redirect_subject(fit, asset, np.random.default_rng(seed))
        drawn = subject.draw.iris_rgb
        kinds.add(drawn is None)
        for side in ("left", "right"):
            expected = subject.photo.iris_rgb[side] if drawn is None else np.asarray(drawn)
            np.testing.assert_allclose(subject.iris_colour[side], expected)
    assert kinds == {True, False}


def test_job_settings_redirect_needs_a_rig_and_is_recorded_only_when_set():
    wheel = BUILTIN_RIGS["wheelchair"].as_dict()
    assert "eyes" not in JobSettings(kind="augment", rig=wheel).as_dict()  # earlier outputs' settings still match
    recorded = JobSettings(kind="augment", rig=wheel, eyes="redirect").as_dict()
    assert recorded["eyes"] == "redirect" and "redirect_supersample" not in recorded  # 1 ray per pixel, as before
    with pytest.raises(GazeAugError, match="need a rig"):
        JobSettings(kind="augment", eyes="redirect")
    with pytest.raises(GazeAugError, match="augmentation setting"):
        JobSettings(kind="normalize-dataset", rig=wheel, eyes="redirect")
    with pytest.raises(GazeAugError, match="expected one of"):
        JobSettings(kind="augment", rig=wheel, eyes="sideways")
    assert rig_from_dict(wheel) == BUILTIN_RIGS["wheelchair"]


def test_cli_augment_redirect_eyes(tmp_path, capsys):
    sim = tmp_path / "sim"
    simulate([None], BUILTIN_RIGS["screen"], sim, per_face=2, progress=False)
    out = tmp_path / "red.h5"
    assert main(["augment", str(sim), "-o", str(out), "--redirect-eyes", "--per-sample", "3", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--rig" in err[0] and not out.exists()
    assert (
        main(["augment", str(sim), "-o", str(out), "--rig", "wheelchair", "--redirect-eyes", "--per-sample", "3"]) == 0
    )
    with h5py.File(out) as f:
        assert len(f["gaze"]) == 6 and '"eyes": "redirect"' in f.attrs["settings"]
        head_minus_gaze = np.degrees(f["head_pose"][:, 0] - f["gaze"][:, 0])
        points = f["eye_keypoints"][()]
    # the wheelchair user looks down at the table: the eyes about 15-20 deg below the head's direction
    # (docs/simulation.md measures -18.1 on average), where kept eyes stay near the screen users' -3
    assert head_minus_gaze.mean() > 8.0
    # every drawn eye records its points, inside its 60 x 36 patch
    assert points.shape == (6, 2, 2, 2) and np.isfinite(points).all()
    assert (points[..., 0] > 0).all() and (points[..., 0] < 60).all() and (points[..., 1] > 0).all()
    assert (points[..., 1] < 36).all()
    # with the sources' own rows: theirs are unknown (NaN), the drawn rows' known
    both = tmp_path / "both.h5"
    args = ["augment", str(sim), "-o", str(both), "--rig", "wheelchair", "--redirect-eyes", "--per-sample", "3"]
    assert main([*args, "--with-source", "--quiet"]) == 0
    with h5py.File(both) as f:
        source_rows = np.isnan(f["sampled_yaw_pitch"][:, 0])
        known = np.isfinite(f["eye_keypoints"][()]).all(axis=(1, 2, 3))
    assert source_rows.sum() == 2 and (known == ~source_rows).all()
    # kept eyes (the photo's own): no column
    kept = tmp_path / "kept.h5"
    assert main(["augment", str(sim), "-o", str(kept), "--per-sample", "1", "--quiet"]) == 0
    with h5py.File(kept) as f:
        assert "eye_keypoints" not in f


def test_augment_draws_eyes_per_sample(tmp_path, monkeypatch):
    # every augmented sample of a source gets eyes of its own: K draws per source, each from the
    # sample's generator in turn, so the eyes of one sample differ from the next's
    import gazeaug.augment as aug
    from gazeaug.datasets import open_dataset
    from gazeaug.jobs import JobSettings, run_dataset

    sim = tmp_path / "sim"
    simulate([None], BUILTIN_RIGS["screen"], sim, per_face=2, progress=False)
    drawn = []
    real = aug.redirect_subject

    def spy(*args, **kwargs):
        subject = real(*args, **kwargs)
        drawn.append(subject.draw)
        return subject

    monkeypatch.setattr(aug, "redirect_subject", spy)
    rig = BUILTIN_RIGS["wheelchair"]
    job = JobSettings(kind="augment", per_sample=3, distribution=rig.distribution(), rig=rig.as_dict(), eyes="redirect")
    summary = run_dataset(open_dataset(sim), tmp_path / "a.h5", job, workers=1, progress=False)
    assert summary["rows"] == 6 and len(drawn) == 6
    assert len({(d.eyeball_radius_mm, d.lid_drop_mm) for d in drawn}) == 6


def test_cli_experiment_redirect_eyes_needs_a_rig(tmp_path, capsys):
    (tmp_path / "train").mkdir()
    (tmp_path / "test").mkdir()
    args = ["experiment", "--train", str(tmp_path / "train"), "--test", str(tmp_path / "test")]
    assert main([*args, "-o", str(tmp_path / "xp"), "--redirect-eyes", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--redirect-eyes" in err[0] and "--rig" in err[0]
    assert not (tmp_path / "xp").exists()  # refused before any work


@pytest.mark.parametrize(
    ("extra", "named"),
    [
        (["--keep-eyes", "--redirect-eyes"], "--keep-eyes"),
        (["--yaw-mean", "5", "--pitch-std", "3"], "--keep-eyes to augment with --yaw-mean, --pitch-std"),
        (["--rig", "screen", "--yaw-mean", "5"], "--keep-eyes to augment with --yaw-mean"),
    ],
)
def test_cli_builtin_experiment_refuses_a_mixed_recipe(tmp_path, capsys, extra, named):
    # the built-in setup redirects the eyes to the rig's targets: distribution options (with a rig or
    # without) ask for the paper's method by name instead of being silently ignored
    assert main(["experiment", "-o", str(tmp_path / "xp"), *extra, "--per-face", "2", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and named in err[0], err
    assert not (tmp_path / "xp").exists()  # refused before any simulation


def test_cli_builtin_experiment_keep_eyes_is_the_papers_method(tmp_path, monkeypatch):
    import gazeaug.experiment as xp_mod
    from gazeaug.sampling import HeadPoseDistribution

    seen = {}

    def setup(out, **kw):
        return xp_mod.BuiltinSetup(tmp_path / "a", tmp_path / "b", tmp_path / "c")

    def run(train, test, out, settings, **kw):
        seen["settings"] = settings
        raise KeyboardInterrupt  # stop here: only the recipe is under test

    monkeypatch.setattr(xp_mod, "builtin_setup", setup)
    monkeypatch.setattr(xp_mod, "run_experiment", run)
    assert main(["experiment", "-o", str(tmp_path / "xp"), "--keep-eyes", "--quiet"]) == 130
    s = seen["settings"]
    assert s.eyes == "keep" and s.rig is None
    assert s.distribution == HeadPoseDistribution.from_variance(0.0, 30.0, 10.0, 10.0)  # the paper's
    assert main(["experiment", "-o", str(tmp_path / "xp"), "--keep-eyes", "--yaw-mean", "5", "--quiet"]) == 130
    assert seen["settings"].distribution == HeadPoseDistribution.from_variance(5.0, 30.0, 10.0, 10.0)
    assert main(["experiment", "-o", str(tmp_path / "xp"), "--rig", "screen", "--quiet"]) == 130
    assert seen["settings"].eyes == "redirect" and seen["settings"].rig.name == "screen"
    assert seen["settings"].with_source is False  # the paper's protocol: the augmented rows alone
    assert main(["experiment", "-o", str(tmp_path / "xp"), "--with-source", "--quiet"]) == 130
    assert seen["settings"].with_source is True


def test_cli_builtin_experiment_redirects_the_eyes_by_default(tmp_path):
    import json

    from gazeaug.train import load_model

    xp = tmp_path / "xp"
    args = ["experiment", "-o", str(xp), "--per-face", "2"]  # the built-in recipe: --rig wheelchair --redirect-eyes
    # with a keypoint loss: the augmented model learns the drawn eyes' keypoints, the original model
    # (whose set has none: no eye is drawn in it) trains at weight 0
    assert main([*args, "--epochs", "1", "--seeds", "1", "--keypoint-loss", "1", "--quiet"]) == 0
    results = json.loads((xp / "results.json").read_text())
    settings = results["settings"]
    assert settings["eyes"] == "redirect" and settings["rig"] == "wheelchair"
    report = (xp / "report.md").read_text()
    assert "redirected eyes: head poses and gaze targets drawn from the `wheelchair` rig" in report
    assert results["runs"]["original"]["keypoint_loss_weight"] == 0
    assert results["runs"]["augmented"]["keypoint_loss_weight"] == 1
    for name, weight in (("original", 0), ("augmented", 1)):  # what each model file says it was trained with
        _, meta = load_model(xp / "seed0" / f"model_{name}.pt")
        assert meta["train_settings"]["keypoint_loss_weight"] == weight, name


def test_cli_experiment_keypoint_loss_needs_redirected_eyes(tmp_path, capsys):
    # the keypoints are where the drawn eyes put them: with the paper's method no eye is drawn
    assert main(["experiment", "-o", str(tmp_path / "xp"), "--keep-eyes", "--keypoint-loss", "1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--keypoint-loss needs redirected eyes" in err[0] and "drop --keep-eyes" in err[0], err
    assert not (tmp_path / "xp").exists()  # refused before any simulation
    # with datasets of one's own the paper's method is the default: the line says what to add
    data = ["--train", str(tmp_path / "a"), "--test", str(tmp_path / "b")]
    assert main(["experiment", *data, "-o", str(tmp_path / "xp"), "--keypoint-loss", "1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "add --redirect-eyes" in err[0], err
    assert not (tmp_path / "xp").exists()
    # the library's own check names its settings, not the command's options
    from gazeaug.experiment import ExperimentSettings
    from gazeaug.train import TrainSettings

    with pytest.raises(GazeAugError, match="expected eyes='redirect', got eyes='keep'"):
        ExperimentSettings(train=TrainSettings(keypoint_loss_weight=1.0), eyes="keep")
