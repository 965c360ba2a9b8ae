"""The realism measure (gazeaug.realism): its parts against hand-derived values, its test on known sets."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from helpers import synthetic_h5

from gazeaug.errors import GazeAugError
from gazeaug.realism import (
    RealismSettings,
    _auc,
    compare_patches,
    grey_equalized,
    patch_statistics,
    read_eye_patches,
    realism_sheet,
)

FAST = RealismSettings(epochs=3, batch_size=64, examples=4)


def test_grey_equalized_is_opencvs():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (5, 36, 60, 3), dtype=np.uint8)
    rgb[1] = rng.integers(90, 140, (36, 60, 3))  # a narrow histogram, stretched by equalization
    want = np.stack([cv2.equalizeHist(cv2.cvtColor(x, cv2.COLOR_RGB2GRAY)) for x in rgb])
    np.testing.assert_array_equal(grey_equalized(rgb), want)
    grey = rgb[..., 0]
    np.testing.assert_array_equal(grey_equalized(grey), np.stack([cv2.equalizeHist(x) for x in grey]))


def test_statistics_by_hand():
    h, w = 36, 60
    ramp = np.tile(np.arange(w, dtype=np.uint8) * 2, (h, 1))  # 2 grey levels per column: gradient 2 everywhere
    assert patch_statistics(ramp[None]).sharpness == pytest.approx(2.0)
    checker = ((np.indices((h, w)).sum(0) % 2) * 200).astype(np.uint8)  # all energy at (0.5, 0.5) cycles/px
    # (the Hann window spreads it by a couple of frequency bins: still far above 0.25)
    assert patch_statistics(checker[None]).high_frequency_share == pytest.approx(1.0, abs=1e-3)
    slow = (100 + 50 * np.cos(2 * np.pi * np.arange(w) / w)).astype(np.uint8)  # 1/60 cycle/px (plus rounding)
    assert patch_statistics(np.tile(slow, (h, 1))[None]).high_frequency_share < 0.01
    flat = np.full((1, h, w), 7, np.uint8)
    st = patch_statistics(flat)
    assert (st.sharpness, st.high_frequency_share) == (0.0, 0.0)
    # the mean patch is averaged with its mirror: a bright left column and a bright right column agree
    a = np.zeros((1, h, w), np.uint8)
    a[:, :, 0] = 200
    np.testing.assert_allclose(patch_statistics(a).mean_patch, patch_statistics(a[:, :, ::-1]).mean_patch)
    assert patch_statistics(a).mean_patch[0, 0] == pytest.approx(100.0)


def test_auc_by_hand():
    # positives 0.35 and 0.8, negatives 0.1 and 0.4: of the 4 pairs, 3 ordered right
    assert _auc(np.array([0.1, 0.4, 0.35, 0.8]), np.array([0, 0, 1, 1])) == pytest.approx(0.75)
    assert _auc(np.array([0.5, 0.5]), np.array([0, 1])) == pytest.approx(0.5)  # a tie counts half


def _eyes(rng, n, sigma):
    """Patches of a dark disc on a lighter ground, at random places, blurred by ``sigma``, equalized."""
    out = np.empty((n, 36, 60), np.uint8)
    for i in range(n):
        img = np.full((36, 60), 180, np.uint8)
        cv2.circle(img, (int(rng.integers(20, 40)), int(rng.integers(14, 22))), int(rng.integers(6, 9)), 40, -1)
        img = (img + rng.normal(0, 6, img.shape)).clip(0, 255).astype(np.uint8)
        if sigma:
            img = cv2.GaussianBlur(img, (0, 0), sigma)
        out[i] = cv2.equalizeHist(img)
    return out


def test_two_sample_test_tells_what_differs_and_not_what_does_not(tmp_path):
    rng = np.random.default_rng(1)
    real = _eyes(rng, 300, 0)
    same = _eyes(rng, 300, 0)
    blurred = _eyes(rng, 300, 2.0)
    rep_same = compare_patches(real, same, FAST)
    rep_blur = compare_patches(real, blurred, FAST)
    assert 0.3 < rep_same.accuracy < 0.7, rep_same.as_dict()
    assert 0.3 < rep_same.floor_accuracy < 0.7
    assert rep_blur.accuracy > 0.9 and rep_blur.auc > 0.95, rep_blur.as_dict()
    assert rep_blur.simulated.sharpness < rep_blur.real.sharpness
    assert rep_blur.simulated.high_frequency_share < rep_blur.real.high_frequency_share
    assert rep_blur.patches_per_set == 300
    assert rep_blur.floor_patches_per_set == 150  # two disjoint halves of the 300 real patches
    assert rep_blur.most_synthetic.shape == (4, 36, 60) and rep_blur.most_real.shape == (4, 36, 60)
    # the same seed, the same figures
    assert compare_patches(real, blurred, FAST).as_dict() == rep_blur.as_dict()
    png = tmp_path / "sheet.png"
    realism_sheet(real, rep_blur, png, title="blurred", count=4)
    assert cv2.imread(str(png)) is not None


def test_ties_count_as_chance_not_as_a_verdict():
    # two identical constant sets: every held-out patch gets the same score; the test must read as
    # chance (AUC exactly 0.5, accuracy near 0.5), not call every tied real patch simulated
    flat = np.full((120, 36, 60), 90, np.uint8)
    rep = compare_patches(flat, flat.copy(), FAST)
    assert rep.auc == pytest.approx(0.5)
    assert 0.25 < rep.accuracy < 0.75


def test_held_out_part_is_whole_people():
    from gazeaug.realism import _held_out

    groups = np.repeat(np.arange(10), 12)  # 10 people x 12 patches
    mask = _held_out(len(groups), groups, 0.3, np.random.default_rng(0))
    held = set(groups[mask].tolist())
    assert not held & set(groups[~mask].tolist())  # nobody on both sides
    assert len(held) == 3  # 36 patches = 30 % of 120, reached with the third person
    one = _held_out(50, np.zeros(50), 0.3, np.random.default_rng(0))  # one person: single patches
    assert one.sum() == 15
    # the classifier test with people: the simulated set's held-out patches are other people's
    rng = np.random.default_rng(6)
    rep = compare_patches(_eyes(rng, 200, 0), _eyes(rng, 200, 2.0), FAST, simulated_groups=np.repeat(np.arange(10), 20))
    assert rep.auc > 0.95


def test_bad_inputs_are_named():
    rng = np.random.default_rng(2)
    real = _eyes(rng, 100, 0)
    with pytest.raises(GazeAugError, match="patch sizes differ: real 60x36, simulated 40x24.*--patch-size 60 36"):
        compare_patches(real, np.zeros((100, 24, 40), np.uint8), FAST)
    with pytest.raises(GazeAugError, match="too few patches"):
        compare_patches(real, real[:10], FAST)
    with pytest.raises(GazeAugError, match=r"expected \(N, H, W\) uint8 grey"):
        compare_patches(real.astype(np.float32), real, FAST)
    with pytest.raises(GazeAugError, match="holdout"):
        RealismSettings(holdout=1.5)
    with pytest.raises(GazeAugError, match="at least 4 x 4 pixels, got 3x3"):
        compare_patches(np.zeros((100, 3, 3), np.uint8), np.zeros((100, 3, 3), np.uint8), FAST)
    with pytest.raises(GazeAugError, match=r"simulated_groups: expected shape \(100,\)"):
        compare_patches(real, real, FAST, simulated_groups=np.zeros(7))


def test_read_eye_patches_npz_and_h5(tmp_path):
    rng = np.random.default_rng(3)
    grey = rng.integers(0, 256, (6, 36, 60), dtype=np.uint8)
    p = tmp_path / "eyes.npz"
    np.savez(p, images=grey, subject_id=np.arange(6))
    patches, who = read_eye_patches(p)
    np.testing.assert_array_equal(patches, np.stack([cv2.equalizeHist(x) for x in grey]))
    assert who.tolist() == list(range(6))
    h5 = synthetic_h5(tmp_path / "set.h5", n=10)
    patches, who = read_eye_patches(h5)
    assert patches.shape == (20, 36, 60) and len(who) == 20  # left eyes, then right eyes
    patches, who = read_eye_patches(h5, max_rows=3)
    assert patches.shape == (6, 36, 60)
    # the 3 rows are drawn at random: other seeds draw other rows
    drawn = {read_eye_patches(h5, max_rows=3, seed=k)[0][:3].tobytes() for k in range(5)}
    assert len(drawn) > 1


def test_read_eye_patches_refuses_bad_files_without_running_code(tmp_path):
    obj = tmp_path / "pickled.npz"
    np.savez(obj, images=np.array([{"a": 1}], dtype=object))
    with pytest.raises(GazeAugError, match="not a readable .npz"):
        read_eye_patches(obj)
    other = tmp_path / "other.npz"
    np.savez(other, pictures=np.zeros((2, 36, 60), np.uint8))
    with pytest.raises(GazeAugError, match=r"^\S+other.npz: expected an array 'images'.*'pictures'\]$"):
        read_eye_patches(other)
    floats = tmp_path / "floats.npz"
    np.savez(floats, images=np.zeros((2, 36, 60), np.float32))
    with pytest.raises(GazeAugError, match="uint8, got"):
        read_eye_patches(floats)
    single = tmp_path / "single.npz"
    with open(single, "wb") as fh:
        np.save(fh, np.zeros((2, 36, 60), np.uint8))  # an .npy under an .npz name
    with pytest.raises(GazeAugError, match=r"^\S+single.npz: expected an .npz archive of arrays, got a single array"):
        read_eye_patches(single)
    for bad in (np.zeros((), np.uint8), np.zeros((100, 0, 60), np.uint8)):
        odd = tmp_path / "odd.npz"
        np.savez(odd, images=bad)
        with pytest.raises(GazeAugError, match="'images': expected"):
            read_eye_patches(odd)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(GazeAugError, match="not a readable .npz"):
        read_eye_patches(junk)
    with pytest.raises(GazeAugError, match="expected an .npz of eye patches or a training set .h5"):
        read_eye_patches(_touch(tmp_path / "a.txt"))
    from facemesh.types import InputError

    with pytest.raises(InputError, match="no such file"):
        read_eye_patches(tmp_path / "missing.npz")


def _touch(p):
    p.write_text("x")
    return p


def test_mpiigaze_patches_read_as_equalized_grey(shared_data):
    npz = shared_data / "gaze" / "mpiigaze_eyes_unlabeled" / "test_eyes.npz"
    patches, who = read_eye_patches(npz)
    assert patches.shape == (3000, 36, 60) and patches.dtype == np.uint8
    # MPIIGaze's patches are equalized already: a near-flat histogram, moved little by our equalization
    raw = np.load(npz, allow_pickle=False)["images"]
    assert np.abs(patches.astype(int) - raw).mean() < 4
    hist = np.bincount(patches.ravel() // 16, minlength=16) / patches.size
    assert hist.min() > 0.04 and hist.max() < 0.09


def test_cli_realism(tmp_path, capsys):
    import json

    from gazeaug.cli import main

    rng = np.random.default_rng(4)
    real = tmp_path / "real.npz"
    np.savez(real, images=_eyes(rng, 100, 0))
    sim = synthetic_h5(tmp_path / "sim.h5", n=60)
    out = tmp_path / "report"
    assert main(["realism", str(real), str(sim), "-o", str(out), "--epochs", "1", "--patches", "80"]) == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert line["patches_per_set"] == 80 and 0.0 <= line["auc"] <= 1.0
    saved = json.loads((out / "realism.json").read_text())
    assert saved["auc"] == line["auc"] and saved["real_file"] == str(real) and saved["simulated_file"] == str(sim)
    assert saved["real"]["count"] == saved["simulated"]["count"] == 80
    assert (out / "realism.png").stat().st_size > 0
    small = tmp_path / "small.npz"
    np.savez(small, images=np.zeros((100, 24, 40), np.uint8))
    assert main(["realism", str(small), str(sim), "-o", str(tmp_path / "r2")]) == 2
    err = capsys.readouterr().err
    assert "patch sizes differ: real 40x24, simulated 60x36" in err and "Traceback" not in err
    assert not (tmp_path / "r2").exists()  # refused before anything was written
    assert main(["realism", str(tmp_path / "nope.npz"), str(sim), "-o", str(tmp_path / "r3")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["realism", str(real), str(sim), "-o", str(tmp_path / "r4"), "--patches", "5"]) == 2
    assert "--patches: expected an integer >= 40, got 5" in capsys.readouterr().err
    assert not (tmp_path / "r4").exists()
