"""Hostile inputs to the library (third round): each defect a tester found, as a test that failed before its fix.

A. ``train --resume`` compares the training data, not only its path.
B. Damaged model files: non-finite weights, unusable ``normalization`` or ``patch_size_wh``.
C. Training sets: a ``settings`` attribute that is not JSON, labels beyond [-pi, pi].
D. Huge numbers: patch sizes, gaze targets, learning rates, rig images and focals.
E. A rig file gives every field (a truncated one is refused); the documented examples load.
F. A ``.glb`` whose head is behind the camera.
G. libpng's lines on stderr (damaged PNG, a bad iCCP chunk) are silenced.
H. Unreadable files give typed errors, not PermissionError.

Expected values come from the inputs (the bounds the documentation states, the rows written, the
fields of :class:`gazeaug.sampling.Rig`), never from the code under test.
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from helpers import synthetic_h5, unprivileged_prefix

from facemesh.types import CameraIntrinsics, FaceLandmarks, FaceMesh, FaceMeshError, HeadPose, InputError
from gazeaug.errors import GazeAugError

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent

torch_needed = pytest.mark.skipif(
    __import__("importlib").util.find_spec("torch") is None, reason="needs torch (pip install 'gazeaug[train]')"
)


def _one_line(err: str, *phrases: str) -> str:
    """One line on stderr (warnings aside), no traceback, holding every phrase, and naming no option."""
    lines = [ln for ln in err.strip().splitlines() if ln.strip() and ": warning: " not in ln]
    assert "Traceback" not in err, err
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}:\n{err}"
    for phrase in phrases:
        assert phrase in lines[0], f"{phrase!r} not in {lines[0]!r}"
    return lines[0]


def _gazeaug(argv, capsys) -> tuple[int, str]:
    from gazeaug.cli import main

    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


# ---------------------------------------------------------------------------------------------------------------------
# A. resume: the training data's fingerprint


def _rewrite_h5(path: Path, **kwargs) -> Path:
    """Put another training set at ``path`` (the old file removed first: the writer refuses to replace it)."""
    path.unlink()
    return synthetic_h5(path, **kwargs)


def test_training_set_fingerprint_follows_the_rows(tmp_path):
    h5py = pytest.importorskip("h5py")
    from gazeaug.io_h5 import H5TrainingSet

    a = synthetic_h5(tmp_path / "a.h5", n=32, seed=0)
    same = synthetic_h5(tmp_path / "same.h5", n=32, seed=0)  # another file, the same rows
    other = synthetic_h5(tmp_path / "other.h5", n=32, seed=1)  # the same shape, other labels
    fa = H5TrainingSet(a).fingerprint
    assert re.fullmatch(r"32 rows, sha1 [0-9a-f]{40}", fa)
    assert H5TrainingSet(same).fingerprint == fa
    assert H5TrainingSet(other).fingerprint != fa
    held_out = H5TrainingSet(a, exclude_subjects=["b"]).fingerprint  # subjects alternate a, b: 16 rows
    assert held_out.startswith("16 rows, ") and held_out != fa
    with h5py.File(same, "a") as f:  # one label of one row changed: another fingerprint
        g = f["gaze"][()]
        g[5, 1] += np.float32(0.01)
        f["gaze"][...] = g
    assert H5TrainingSet(same).fingerprint != fa
    with h5py.File(other, "a") as f:  # the labels of `a`, one subject renamed: another fingerprint
        with h5py.File(a, "r") as fa_file:
            for k in ("gaze", "head_pose"):
                f[k][...] = fa_file[k][()]
        subj = f["subject"][()]
        subj[0] = b"z"
        f["subject"][...] = subj
    assert H5TrainingSet(other).fingerprint != fa


@torch_needed
def test_resume_refuses_another_training_set_at_the_same_path(tmp_path):
    from gazeaug.train import TrainSettings, train

    h5 = synthetic_h5(tmp_path / "t.h5", n=32, seed=0)
    s = TrainSettings(epochs=2, batch_size=16)
    out = tmp_path / "m.pt"
    import gazeaug.train as tr

    real_save, calls = tr._save, []

    def save_then_die(obj, path):  # the first epoch's checkpoint, then an interruption
        real_save(obj, path)
        calls.append(path)
        raise KeyboardInterrupt

    tr._save = save_then_die
    try:
        with pytest.raises(KeyboardInterrupt):
            train(h5, out, s, progress=False)
    finally:
        tr._save = real_save
    ckpt = out.with_suffix(".ckpt.pt")
    assert ckpt.is_file() and not out.exists()
    before = ckpt.read_bytes()

    _rewrite_h5(h5, n=32, seed=1)  # the same path and size, other rows
    with pytest.raises(GazeAugError) as info:
        train(h5, out, s, resume=True, progress=False)
    msg = str(info.value)
    assert str(ckpt) in msg and "another data selection" in msg
    assert re.search(r"train_fingerprint: '32 rows, sha1 [0-9a-f]{40}' then, '32 rows, sha1 [0-9a-f]{40}' now", msg)
    assert ckpt.read_bytes() == before and not out.exists()

    _rewrite_h5(h5, n=32, seed=0)  # the original rows again, in a new file: the run continues
    log = train(h5, out, s, resume=True, progress=False)
    assert [r["epoch"] for r in log] == [1, 2]


@torch_needed
def test_resume_refuses_a_checkpoint_without_a_fingerprint(tmp_path):
    import torch

    from gazeaug.train import TrainSettings, train

    h5 = synthetic_h5(tmp_path / "t.h5", n=16)
    s = TrainSettings(epochs=1, batch_size=16)
    train(h5, tmp_path / "m.pt", s, progress=False)
    ckpt = tmp_path / "m.ckpt.pt"
    obj = torch.load(ckpt, weights_only=True)
    for k in ("train_fingerprint", "val_fingerprint"):
        obj["data_selection"].pop(k)  # as the previous version wrote it
    torch.save(obj, ckpt)
    with pytest.raises(GazeAugError, match="did not record its training data's fingerprint"):
        train(h5, tmp_path / "m.pt", s, resume=True, progress=False)


def _interrupted_after_one_epoch(monkeypatch, h5, out, settings, recorded_as=lambda ck: ck):
    """Train ``settings`` and stop after the first epoch's checkpoint, written as ``recorded_as`` makes it."""
    import gazeaug.train as tr

    real_save = tr._save

    def save_then_die(obj, path):
        real_save(recorded_as(obj), path)
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(tr, "_save", save_then_die)
        with pytest.raises(KeyboardInterrupt):
            tr.train(h5, out, settings, progress=False)


@torch_needed
def test_a_run_begun_under_the_older_translation_default_resumes_with_it(tmp_path, monkeypatch):
    # shift_px was 2 by default before 2026-11-24; `gazeaug train --resume` has no option for it, so a
    # run interrupted then goes on with its own 2, recorded in the model; another value is refused
    import torch

    from gazeaug.train import TrainSettings, train
    from gazeaug.train_augment import TrainAugment

    h5 = synthetic_h5(tmp_path / "t.h5", n=32, seed=0)
    out = tmp_path / "m.pt"
    then = TrainSettings(epochs=2, batch_size=16, augment=TrainAugment(shift_px=2))
    _interrupted_after_one_epoch(monkeypatch, h5, out, then)
    with pytest.raises(GazeAugError, match=r"other settings .*'shift_px': 2.* then, .*'shift_px': 4"):
        train(h5, out, TrainSettings(epochs=2, batch_size=16, augment=TrainAugment(shift_px=4)), resume=True)
    log = train(h5, out, TrainSettings(epochs=2, batch_size=16), resume=True, progress=False)
    assert [r["epoch"] for r in log] == [1, 2]
    assert torch.load(out, weights_only=True)["train_settings"]["augment"]["shift_px"] == 2


@torch_needed
def test_a_run_begun_before_the_defaults_of_2026_11_25_resumes_as_it_began(tmp_path, monkeypatch):
    # lr was 1e-3, the loss the plain L1 and auto_samples 250k before 2026-11-25: a checkpoint of then
    # (which records no balance_axes) resumes with all three, and its model file says so; another lr
    # is still refused
    import torch

    from gazeaug.train import TrainSettings, train

    h5 = synthetic_h5(tmp_path / "t.h5", n=32, seed=0)
    out = tmp_path / "m.pt"

    def as_then(ck):  # as the previous version wrote it
        return dict(ck, settings={k: v for k, v in ck["settings"].items() if k != "balance_axes"})

    then = TrainSettings(epochs=2, batch_size=16, lr=1e-3, balance_axes=False, auto_samples=250_000)
    _interrupted_after_one_epoch(monkeypatch, h5, out, then, as_then)
    assert "balance_axes" not in torch.load(tmp_path / "m.ckpt.pt", weights_only=True)["settings"]
    with pytest.raises(GazeAugError, match=r"other settings \(lr: 0.001 then, 0.01 now\)"):
        train(h5, out, TrainSettings(epochs=2, batch_size=16, lr=1e-2), resume=True)
    # today's default given on purpose (`gazeaug train --resume --lr 0.003`) is another lr, refused too
    with pytest.raises(GazeAugError, match=r"other settings \(lr: 0.001 then, 0.003 now\)"):
        train(h5, out, TrainSettings(epochs=2, batch_size=16), resume=True, given=("lr",))
    from gazeaug.cli import main

    argv = ["train", str(h5), "-o", str(out), "--resume", "--epochs", "2", "--batch-size", "16", "--quiet"]
    assert main([*argv, "--lr", "0.003"]) == 2
    # today's default given on purpose is another setting where the epochs are left to it (with --epochs
    # given it decides nothing and is not compared)
    assert (
        main(["train", str(h5), "-o", str(out), "--resume", "--batch-size", "16", "--quiet", "--samples", "500000"])
        == 2
    )
    log = train(h5, out, TrainSettings(epochs=2, batch_size=16), resume=True, progress=False)
    assert [r["epoch"] for r in log] == [1, 2]
    made = torch.load(out, weights_only=True)
    assert made["train_settings"]["lr"] == 1e-3 and made["train_settings"]["balance_axes"] is False
    assert made["train_settings"]["auto_samples"] == 250_000
    assert made["loss_weights_pitch_yaw"] == [1.0, 1.0]


@torch_needed
def test_resume_refuses_the_same_labels_with_other_images(tmp_path, monkeypatch):
    # the labels' fingerprint alone let a set whose patches were made anew resume; the patches' sampled
    # fingerprint tells it apart, and a checkpoint from before it (no train_patches) resumes as before
    h5py = pytest.importorskip("h5py")
    import torch

    from gazeaug.io_h5 import PATCH_SAMPLE_ROWS, H5TrainingSet
    from gazeaug.train import TrainSettings, train

    h5 = synthetic_h5(tmp_path / "t.h5", n=32, seed=0)
    before = H5TrainingSet(h5)
    assert re.fullmatch(r"32 rows, sampled 32, sha1 [0-9a-f]{40}", before.patch_fingerprint)
    assert PATCH_SAMPLE_ROWS == 64
    big = synthetic_h5(tmp_path / "big.h5", n=300, seed=0)
    assert H5TrainingSet(big).patch_fingerprint.startswith("300 rows, sampled 64, ")
    assert H5TrainingSet(big, exclude_subjects=["b"]).patch_fingerprint.startswith("150 rows, sampled 64, ")
    out = tmp_path / "m.pt"
    s = TrainSettings(epochs=2, batch_size=16)
    _interrupted_after_one_epoch(monkeypatch, h5, out, s)
    ckpt = out.with_suffix(".ckpt.pt")
    assert torch.load(ckpt, weights_only=True)["data_selection"]["train_patches"] == before.patch_fingerprint
    with h5py.File(h5, "r+") as f:  # one pixel of one sampled row changed, the labels untouched
        eye = f["right_eye"][7]
        eye[0, 0, 0] ^= 0xFF
        f["right_eye"][7] = eye
    assert H5TrainingSet(h5).fingerprint == before.fingerprint
    with pytest.raises(GazeAugError, match=r"another data selection \(train_patches: '32 rows, sampled 32, sha1 "):
        train(h5, out, s, resume=True, progress=False)
    obj = torch.load(ckpt, weights_only=True)
    for k in ("train_patches", "val_patches"):
        obj["data_selection"].pop(k)  # as the previous version wrote it: its labels are compared, not its patches
    torch.save(obj, ckpt)
    log = train(h5, out, s, resume=True, progress=False)
    assert [r["epoch"] for r in log] == [1, 2]


@torch_needed
def test_a_damaged_sampled_patch_is_named_by_dataset_and_row(tmp_path, capsys):
    # the patches' fingerprint reads its sample before any batch: a damaged chunk there is named as the
    # batches' reader names one (file, dataset, row), not as a bare h5py error
    h5py = pytest.importorskip("h5py")
    from gazeaug.cli import main

    h5 = synthetic_h5(tmp_path / "t.h5", n=100, seed=0)
    with h5py.File(h5, "r+") as f:
        k = f["right_eye"].chunks[0]
        f["right_eye"].id.write_direct_chunk((k, 0, 0, 0), b"not deflate at all")  # the second chunk
    capsys.readouterr()
    assert main(["train", str(h5), "-o", str(tmp_path / "m.pt"), "--epochs", "1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    # the sample: 64 rows at even steps through the 100; the first of them inside the damaged chunk
    first = min(r for r in np.linspace(0, 99, 64).round().astype(int) if r >= k)
    assert f"t.h5: /right_eye row {first}: cannot be read, the file is damaged" in err[0]


@torch_needed
def test_resume_with_epochs_given_does_not_compare_the_samples(tmp_path, monkeypatch):
    # with --epochs given, --samples decides nothing (the epochs are not fitted), so a resumed run that
    # gives another --samples is the same run: it goes on, with the value it recorded; without --epochs
    # another --samples would mean other epochs, and is refused
    import torch

    from gazeaug.cli import main
    from gazeaug.train import TrainSettings

    h5 = synthetic_h5(tmp_path / "t.h5", n=32, seed=0)
    out = tmp_path / "m.pt"
    _interrupted_after_one_epoch(monkeypatch, h5, out, TrainSettings(epochs=2, batch_size=16, auto_samples=1000))
    argv = ["train", str(h5), "-o", str(out), "--resume", "--quiet"]
    assert main([*argv, "--samples", "5000"]) == 2  # the epochs left to the samples: 5000 would fit other epochs
    assert main([*argv, "--epochs", "2", "--batch-size", "16", "--samples", "5000"]) == 0
    made = torch.load(out, weights_only=True)
    assert made["train_settings"]["auto_samples"] == 1000 and made["train_settings"]["epochs"] == 2
    assert [r["epoch"] for r in made["log"]] == [1, 2]
    # left out on resume, --samples is the run's own (as --epochs and --batch-size are)
    _interrupted_after_one_epoch(monkeypatch, h5, out, TrainSettings(epochs=2, batch_size=16, auto_samples=1000))
    assert main(argv) == 0
    assert torch.load(out, weights_only=True)["train_settings"]["auto_samples"] == 1000
    # a checkpoint of a gazeaug that did not record auto_samples (250k then) with --epochs and --samples given

    def as_then(ck):
        return dict(ck, settings={k: v for k, v in ck["settings"].items() if k != "auto_samples"})

    _interrupted_after_one_epoch(monkeypatch, h5, out, TrainSettings(epochs=2, batch_size=16), as_then)
    assert main([*argv, "--epochs", "2", "--batch-size", "16", "--samples", "1000"]) == 0
    assert torch.load(out, weights_only=True)["train_settings"]["auto_samples"] == 250_000


@torch_needed
def test_train_without_resume_keeps_an_unfinished_runs_checkpoint(tmp_path, monkeypatch, capsys):
    # `gazeaug train` without --resume used to replace an interrupted run's checkpoint at its first epoch
    from gazeaug.cli import main
    from gazeaug.train import TrainSettings, train

    h5 = synthetic_h5(tmp_path / "t.h5", n=32, seed=0)
    out = tmp_path / "m.pt"
    ckpt = out.with_suffix(".ckpt.pt")
    argv = ["train", str(h5), "-o", str(out), "--epochs", "2", "--batch-size", "16", "--quiet"]
    _interrupted_after_one_epoch(monkeypatch, h5, out, TrainSettings(epochs=2, batch_size=16))
    kept = ckpt.read_bytes()
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(ckpt) in err[0] and "a run that did not finish left it" in err[0]
    assert err[0].endswith("pass --resume to continue it, or delete it to start over")
    assert ckpt.read_bytes() == kept and not out.exists()
    assert main([*argv, "--resume"]) == 0 and out.is_file()
    # finished: its checkpoint's epoch is its last, and running the command again trains anew, whatever
    # the files' dates say (a copy without -p, or touch, makes the checkpoint the newer)
    os.utime(ckpt, ns=(out.stat().st_mtime_ns + 10**9,) * 2)
    assert main(argv) == 0
    # every epoch done, the model never written (a full disk at the end, say): unfinished too, and --resume
    # writes the model
    out.unlink()
    assert main(argv) == 2 and not out.exists()
    assert main([*argv, "--resume"]) == 0 and out.is_file()
    # a finished model with a newer, unfinished run's checkpoint beside it: refused too
    _interrupted_after_one_epoch(monkeypatch, h5, out, TrainSettings(epochs=3, batch_size=16))
    assert main(argv) == 2
    # the library keeps its own behaviour unless asked (an experiment's folder is its own)
    assert len(train(h5, out, TrainSettings(epochs=1, batch_size=16), progress=False)) == 1
    # Ctrl-C before a new run's first epoch ends, a finished run's checkpoint beside it: nothing to resume
    import gazeaug.train as tr

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    capsys.readouterr()
    with monkeypatch.context() as m:
        m.setattr(tr, "_save", stop)
        assert main([*argv[:-5], "--epochs", "3", "--batch-size", "16", "--quiet"]) == 130
    err = capsys.readouterr().err
    assert "--resume" not in err and "nothing was written" in err
    # and after an epoch, the checkpoint it kept is named, with --resume
    _interrupted_after_one_epoch(monkeypatch, h5, out, TrainSettings(epochs=3, batch_size=16))
    with monkeypatch.context() as m:
        m.setattr(tr, "_save", stop)
        assert main([*argv[:-5], "--epochs", "3", "--batch-size", "16", "--quiet", "--resume"]) == 130
    err = capsys.readouterr().err
    assert f"kept {ckpt}" in err and "with --resume to continue" in err


# ---------------------------------------------------------------------------------------------------------------------
# B. damaged model files


def _model_file(path: Path, **replace) -> Path:
    """A model file built by hand (not by train): a fresh mobilenet_gaze and the metadata train records."""
    import torch

    from gazeaug.models import create_model
    from gazeaug.models.preprocess import PREPROCESSING

    torch.manual_seed(0)
    obj = {
        "format": "gazeaug-model",
        "gazeaug_version": "test",
        "model": "mobilenet_gaze",
        "model_options": {},
        "state_dict": create_model("mobilenet_gaze").state_dict(),
        "preprocessing": PREPROCESSING,
        "normalization": {"distance_mm": 600.0, "focal_px": 650.0, "patch_size_wh": [60, 36], "antialias": True},
        "patch_size_wh": [60, 36],
        "log": [],
    }
    obj.update(replace)
    torch.save(obj, path)
    return path


@torch_needed
def test_a_model_with_non_finite_weights_is_refused(tmp_path, capsys):
    import torch

    from gazeaug.models import create_model
    from gazeaug.train import load_model

    load_model(_model_file(tmp_path / "good.pt"))  # the hand-made file is a usable model
    sd = create_model("mobilenet_gaze").state_dict()
    name = next(k for k, v in sd.items() if v.is_floating_point() and v.numel() > 1)
    for bad in (float("nan"), float("inf"), -float("inf")):
        damaged = {k: v.clone() for k, v in sd.items()}
        damaged[name].view(-1)[1] = bad
        p = _model_file(tmp_path / "bad.pt", state_dict=damaged)
        with pytest.raises(GazeAugError, match=re.escape(f"not a usable gazeaug model: non-finite weights in {name}")):
            load_model(p)
    onnx = tmp_path / "m.onnx"
    code, err = _gazeaug(["export", p, "-o", onnx], capsys)
    assert code == 2
    _one_line(err, str(p), "non-finite weights")
    assert not onnx.exists()
    # a non-finite buffer (BatchNorm's running variance) is refused as well
    buf = next(k for k in sd if k.endswith("running_var"))
    damaged = {k: v.clone() for k, v in sd.items()}
    damaged[buf][0] = float("nan")
    with pytest.raises(GazeAugError, match=f"non-finite weights in {re.escape(buf)}"):
        load_model(_model_file(tmp_path / "buf.pt", state_dict=damaged))
    assert torch.isfinite(sd[buf]).all()


@torch_needed
@pytest.mark.parametrize(
    "normalization",
    [
        "hello",
        None,
        [600.0, 650.0],
        {"distance_mm": "600"},
        {"distance_mm": True},
        {"focal_px": -1.0},
        {"patch_size_wh": "hello"},
        {"patch_size_wh": [60.5, 36]},
        {"patch_size_wh": [60, 36, 3]},
        {"antialias": "yes"},
        {"colour": "blue"},
    ],
)
def test_a_model_with_unusable_normalization_is_refused(tmp_path, capsys, normalization):
    from gazeaug.train import load_model

    p = _model_file(tmp_path / "m.pt", normalization=normalization)
    with pytest.raises(GazeAugError, match="normalization settings are not usable") as info:
        load_model(p)
    assert str(info.value).startswith(str(p))
    code, err = _gazeaug(["predict", p, tmp_path / "photo-not-needed.jpg"], capsys)
    assert code == 2
    line = _one_line(err, str(p), "normalization")
    assert " --" not in line


@torch_needed
def test_model_normalization_absent_keys_take_their_defaults(tmp_path):
    from gazeaug.evaluate import settings_from_meta
    from gazeaug.normalize import NormalizationSettings
    from gazeaug.train import load_model

    _, meta = load_model(_model_file(tmp_path / "m.pt", normalization={"distance_mm": 500}))
    # the paper's defaults (650 px, 60 x 36, antialias) for the keys the file leaves out
    assert meta["normalization"] == {
        "distance_mm": 500.0,
        "focal_px": 650.0,
        "patch_size_wh": [60, 36],
        "antialias": True,
    }
    assert settings_from_meta(meta) == NormalizationSettings(distance_mm=500.0)
    _, meta = load_model(_model_file(tmp_path / "m2.pt", normalization={}))
    assert settings_from_meta(meta) == NormalizationSettings()


@torch_needed
@pytest.mark.parametrize("patch", [[1e9, 1e9], [10**9, 10**9], [60, 36, 1], "60x36", [2, 2], [60, 1025], [True, 36]])
def test_a_model_with_an_unusable_patch_size_is_refused(tmp_path, capsys, patch):
    from gazeaug.train import load_model

    p = _model_file(tmp_path / "m.pt", patch_size_wh=patch)
    with pytest.raises(GazeAugError, match="patch_size_wh"):
        load_model(p)
    onnx = tmp_path / "m.onnx"
    code, err = _gazeaug(["export", p, "-o", onnx], capsys)
    assert code == 2
    _one_line(err, str(p), "patch")
    assert not onnx.exists()


@torch_needed
def test_export_checks_a_callers_meta(tmp_path):
    pytest.importorskip("onnx")
    from gazeaug.export import export_onnx
    from gazeaug.models import create_model

    with pytest.raises(GazeAugError, match="patch size"):
        export_onnx(create_model("mobilenet_gaze"), {"patch_size_wh": [10**9, 10**9]}, tmp_path / "m.onnx")
    assert not (tmp_path / "m.onnx").exists()


# ---------------------------------------------------------------------------------------------------------------------
# C. training sets: settings that are not JSON, labels beyond [-pi, pi]


def _set_attr(path: Path, key: str, value) -> None:
    import h5py

    with h5py.File(path, "a") as f:
        f.attrs[key] = value


@pytest.mark.parametrize(
    "settings, phrase",
    [
        ("{not json", "not valid JSON"),
        ("hello", "not valid JSON"),
        ("[1, 2]", "JSON object"),
        ('"text"', "JSON object"),
        (7, "JSON object"),
    ],
)
def test_a_training_set_whose_settings_are_not_json_is_refused(tmp_path, settings, phrase):
    pytest.importorskip("h5py")
    from gazeaug.io_h5 import H5TrainingSet

    p = synthetic_h5(tmp_path / "t.h5", n=8)
    _set_attr(p, "settings", settings)
    with pytest.raises(GazeAugError, match=phrase) as info:
        H5TrainingSet(p)
    assert str(info.value).startswith(str(p)) and "'settings'" in str(info.value)


@torch_needed
def test_training_refuses_settings_that_are_not_json_before_training(tmp_path, capsys):
    p = synthetic_h5(tmp_path / "t.h5", n=16)
    _set_attr(p, "settings", "{not json")
    code, err = _gazeaug(["train", p, "-o", tmp_path / "m.pt", "--epochs", "1", "--quiet"], capsys)
    assert code == 2
    _one_line(err, str(p), "not valid JSON")
    assert not (tmp_path / "m.pt").exists() and not (tmp_path / "m.ckpt.pt").exists()
    # valid JSON, but normalization settings no model could use: refused before any epoch as well
    _set_attr(p, "settings", json.dumps({"normalization": "hello"}))
    code, err = _gazeaug(["train", p, "-o", tmp_path / "m.pt", "--epochs", "1", "--quiet"], capsys)
    assert code == 2
    _one_line(err, str(p), "normalization settings are not usable")
    assert not (tmp_path / "m.ckpt.pt").exists()


def _set_label(path: Path, key: str, row: int, col: int, value: float) -> None:
    import h5py

    with h5py.File(path, "a") as f:
        a = f[key][()]
        a[row, col] = value
        f[key][...] = a


@pytest.mark.parametrize("key", ["gaze", "head_pose"])
@pytest.mark.parametrize("value", [1e30, -1e30, 3.2, -4.0])
def test_labels_beyond_pi_are_refused(tmp_path, key, value):
    pytest.importorskip("h5py")
    from gazeaug.io_h5 import H5TrainingSet

    p = synthetic_h5(tmp_path / "t.h5", n=8)
    _set_label(p, key, 6, 1, value)
    _set_label(p, key, 3, 0, value)
    with pytest.raises(GazeAugError) as info:
        H5TrainingSet(p)
    msg = str(info.value)
    assert msg.startswith(str(p)) and "2 rows" in msg and "[-pi, pi]" in msg and "first: row 3" in msg


def test_labels_at_plus_minus_pi_are_accepted(tmp_path):
    """+-pi rounded to float32 (3.1415927 > pi) is still an angle: accepted."""
    pytest.importorskip("h5py")
    from gazeaug.io_h5 import H5TrainingSet

    p = synthetic_h5(tmp_path / "t.h5", n=8)
    _set_label(p, "gaze", 0, 1, np.pi)
    _set_label(p, "head_pose", 1, 1, -np.pi)
    assert np.float32(np.pi) > np.pi  # the rounding the check must allow
    assert len(H5TrainingSet(p)) == 8


# ---------------------------------------------------------------------------------------------------------------------
# D. huge numbers


def test_patch_size_bounds():
    from gazeaug.normalize import NormalizationSettings

    for ok in ((4, 4), (60, 36), (224, 224), (1024, 1024)):
        assert NormalizationSettings(patch_size_wh=ok).patch_size_wh == ok
    for bad in ((100000, 100000), (1025, 36), (60, 3), (0, 36), (60.0, 36), (60,), "ab"):
        with pytest.raises(GazeAugError, match="patch size"):
            NormalizationSettings(patch_size_wh=bad)  # type: ignore[arg-type]


def test_patch_size_on_the_command_line(tmp_path, capsys):
    from facemesh.build import sample_image
    from facemesh.io import save_image_rgb

    photo = tmp_path / "face.png"
    save_image_rgb(photo, sample_image())
    code, err = _gazeaug(["normalize", photo, "-o", tmp_path / "n.npz", "--patch-size", "100000", "100000"], capsys)
    assert code == 2
    line = _one_line(err, "patch size", "1024")
    assert " --" not in line
    assert not (tmp_path / "n.npz").exists()


def _views(target=None, vector=None):
    from facemesh.face_models import builtin_face_model
    from gazeaug.camera import normalized_views

    model = builtin_face_model()
    return normalized_views(
        model.vertices_mm,
        model.keypoints,
        np.eye(3)[None],
        np.array([[0.0, 0.0, 600.0]]),
        distance_mm=600.0,
        focal_px=650.0,
        size_wh=(60, 36),
        gaze_target_mm=target,
        gaze_vector=vector,
    )


def test_gaze_targets_and_vectors_beyond_1e7_are_refused():
    # 1e7 mm (10 km) straight ahead: the gaze is straight ahead, (pitch, yaw) ~ 0 for the face reference
    v = _views(target=[0.0, 0.0, 1e7])
    assert v.gaze is not None and np.isfinite(v.gaze).all()
    for bad in ([0.0, 0.0, 1e308], [1e7 * (1 + 1e-9), 0.0, 0.0], [[0.0, -2e7, 0.0]]):
        with pytest.raises(GazeAugError, match=r"gaze target: expected components within \+-1e\+07 mm"):
            _views(target=bad)
    with pytest.raises(GazeAugError, match="gaze vector: expected components within"):
        _views(vector=[0.0, 1e308, -1.0])
    assert np.isfinite(_views(vector=[0.0, 0.0, -1e7]).gaze).all()


def test_train_settings_bounds():
    from gazeaug.train import TrainSettings

    for lr in (1e-9, 1e-3, 10):
        assert TrainSettings(lr=lr).lr == lr
    for lr in (0, -1e-3, 10.000001, 1e300, math.inf, math.nan, "1e-3", True):
        with pytest.raises(GazeAugError, match=r"learning rate: expected a number in \(0, 10\]"):
            TrainSettings(lr=lr)  # type: ignore[arg-type]
    for wd in (0, 1e-4, 9.99):
        assert TrainSettings(weight_decay=wd).weight_decay == wd
    for wd in (-1e-9, 10, 1e300, math.nan, "0"):
        with pytest.raises(GazeAugError, match=r"weight decay: expected a number in \[0, 10\)"):
            TrainSettings(weight_decay=wd)  # type: ignore[arg-type]


@torch_needed
def test_a_huge_learning_rate_on_the_command_line(tmp_path, capsys):
    h5 = synthetic_h5(tmp_path / "t.h5", n=16)
    code, err = _gazeaug(["train", h5, "-o", tmp_path / "m.pt", "--lr", "1e300", "--quiet"], capsys)
    assert code == 2
    line = _one_line(err, "learning rate", "(0, 10]")
    assert " --" not in line


def test_rig_camera_bounds():
    from gazeaug.sampling import Rig

    assert Rig(image_size_wh=(8192, 8192), focal_px=999_999.0).image_size_wh == (8192, 8192)
    assert Rig(image_size_wh=(32, 32)).image_size_wh == (32, 32)
    for size in ((100000, 100000), (8193, 480), (640, 31), (640.0, 480), (640,), "640x480"):
        with pytest.raises(GazeAugError, match="image_size_wh: expected two integers"):
            Rig(image_size_wh=size)  # type: ignore[arg-type]
    for focal in (1e6, 1e300, math.inf, math.nan, 0.0, -600.0, "600"):
        with pytest.raises(GazeAugError, match="focal_px: expected a number > 0 and < 1e"):
            Rig(focal_px=focal)  # type: ignore[arg-type]
    for spread in (-1.0, math.nan, "15"):
        with pytest.raises(GazeAugError, match="head_position_std_mm"):
            Rig(head_position_std_mm=spread)  # type: ignore[arg-type]


def _complete_rig(**fields) -> str:
    """Every Rig field but name, the built-in wheelchair's values, some replaced (YAML)."""
    import yaml

    from gazeaug.sampling import BUILTIN_RIGS

    d = {k: v for k, v in BUILTIN_RIGS["wheelchair"].as_dict().items() if k != "name"}
    d.update(fields)
    return yaml.safe_dump(d)


def test_a_rig_file_with_a_huge_image_is_refused(tmp_path, capsys):
    from gazeaug.sampling import load_rig

    p = tmp_path / "big.yaml"
    p.write_text(_complete_rig(image_size_wh=[100000, 100000]))
    with pytest.raises(GazeAugError, match="image_size_wh") as info:
        load_rig(p)
    assert str(info.value).startswith(str(p))
    code, err = _gazeaug(["simulate", "--rig", p, "--per-face", "1", "-o", tmp_path / "sim", "--quiet"], capsys)
    assert code == 2
    _one_line(err, str(p), "image_size_wh")


# ---------------------------------------------------------------------------------------------------------------------
# E. rig files give every field


def test_a_truncated_rig_file_is_refused_with_the_missing_fields(tmp_path, capsys):
    from gazeaug.sampling import load_rig

    p = tmp_path / "wheelchair.yaml"
    p.write_text("name: wheelchair\n")
    with pytest.raises(GazeAugError) as info:
        load_rig(p)
    msg = str(info.value)
    assert msg.startswith(str(p))
    expected = [  # Rig's fields as docs/simulation.md lists them, but the name
        "camera_position_mm",
        "head_yaw_std_deg",
        "head_pitch_std_deg",
        "head_yaw_mean_deg",
        "head_pitch_mean_deg",
        "image_size_wh",
        "focal_px",
        "target_box_mm",
        "head_position_std_mm",
    ]
    assert "missing" in msg and all(f"'{k}'" in msg for k in expected), msg
    # one field short: that one is named
    full = _complete_rig()
    p.write_text("\n".join(ln for ln in full.splitlines() if not ln.startswith("focal_px")))
    with pytest.raises(GazeAugError, match=r"missing \['focal_px'\]"):
        load_rig(p)
    p.write_text(full)  # complete, no name: the file's stem
    assert load_rig(p).name == "wheelchair"
    (tmp_path / "short.yaml").write_text("name: wheelchair\n")
    code, err = _gazeaug(["simulate", "--rig", tmp_path / "short.yaml", "-o", tmp_path / "s", "--quiet"], capsys)
    assert code == 2
    _one_line(err, "short.yaml", "missing")


def _yaml_blocks(doc: Path) -> list[str]:
    return [b for b in re.findall(r"```yaml\n(.*?)```", doc.read_text(), flags=re.S) if "camera_position_mm" in b]


@pytest.mark.parametrize(
    "source",
    ["data_samples/rigs/screen.yaml", "data_samples/rigs/wheelchair.yaml", "docs/simulation.md", "docs/gazeaug.md"],
)
def test_the_documented_rig_files_load_and_equal_the_builtins(tmp_path, source):
    import yaml

    from gazeaug.sampling import BUILTIN_RIGS, load_rig

    path = REPO / source
    blocks = [path.read_text()] if path.suffix == ".yaml" else _yaml_blocks(path)
    assert blocks, f"no rig example in {source}"
    for i, block in enumerate(blocks):
        p = tmp_path / f"rig{i}.yaml"
        p.write_text(block)
        rig = load_rig(p)
        name = yaml.safe_load(block)["name"]
        ref = BUILTIN_RIGS[name].as_dict()
        got = rig.as_dict()
        assert got["name"] == ref["name"]
        for k in ref:
            if k != "name":
                np.testing.assert_allclose(np.asarray(got[k], float), np.asarray(ref[k], float), rtol=1e-12, err_msg=k)


# ---------------------------------------------------------------------------------------------------------------------
# F. a .glb whose head is behind the camera


def _mesh(translation_z: float, texture: np.ndarray | None = None) -> FaceMesh:
    """Four vertices 500 mm in front of the camera, two triangles, a small texture."""
    rng = np.random.default_rng(7)
    v = np.array([[-40.0, -40.0, 500.0], [40.0, -40.0, 500.0], [-40.0, 40.0, 500.0], [40.0, 40.0, 500.0]])
    return FaceMesh(
        vertices_mm=v,
        triangles=np.array([[0, 2, 3], [0, 3, 1]]),
        uv=rng.uniform(0, 1, (4, 2)),
        texture=rng.integers(0, 256, (40, 48, 3), dtype=np.uint8) if texture is None else texture,
        texture_origin_px=(10, 20),
        landmarks=FaceLandmarks(points_px=rng.uniform(100, 300, (4, 2)), model_name="test"),
        camera=CameraIntrinsics(
            matrix=np.array([[600.0, 0, 320.0], [0, 600.0, 240.0], [0, 0, 1]]),
            distortion=np.zeros(5),
            image_size=(640, 480),
            source="test",
        ),
        pose=HeadPose(rotation=np.eye(3), translation_mm=np.array([0.0, 0.0, translation_z])),
        face_model_name="test",
        vertex_placement="backprojected",
    )


@pytest.mark.parametrize("z", [-100.0, 0.0, -1e-9])
def test_a_glb_with_the_head_behind_the_camera_is_refused(tmp_path, capsys, z):
    from facemesh.gltf import load_glb, save_glb

    good = tmp_path / "good.glb"
    save_glb(_mesh(500.0), good)
    assert load_glb(good).pose.translation_mm[2] == 500.0
    p = tmp_path / "behind.glb"
    save_glb(_mesh(z), p)
    with pytest.raises(InputError) as info:
        load_glb(p)
    msg = str(info.value)
    assert msg.startswith(str(p)) and f"the head is behind the camera (z = {z:g} mm" in msg
    code, err = _gazeaug(["render", p, "--original-pose", "-o", tmp_path / "r.npz"], capsys)
    assert code == 2
    _one_line(err, str(p), "behind the camera")
    assert not (tmp_path / "r.npz").exists()


# ---------------------------------------------------------------------------------------------------------------------
# G. libpng's own lines on stderr


def _chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def _png(rgb: np.ndarray, iccp: bool = False, damage_idat: bool = False) -> bytes:
    """An 8-bit RGB PNG written by hand; optionally an iCCP chunk of garbage, or a damaged IDAT stream."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[r].tobytes() for r in range(h))  # filter 0 per row
    out = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    if iccp:  # profile name, NUL, method 0, then a zlib stream that is no ICC profile
        out += _chunk(b"iCCP", b"garbage\x00\x00" + zlib.compress(b"not an ICC profile" * 4))
    idat = bytearray(zlib.compress(raw))
    if damage_idat:
        idat[8] ^= 0xFF  # the CRC is recomputed: libpng reads the chunk and zlib fails inside it
    out += _chunk(b"IDAT", bytes(idat)) + _chunk(b"IEND", b"")
    return out


def _run_python(code: str, *args: str, prefix: list[str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*(prefix or []), sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=REPO,
    )


_LOAD_IMAGE = """
import sys
from facemesh.io import load_image_rgb
from facemesh.types import FaceMeshError
try:
    print("shape", load_image_rgb(sys.argv[1]).shape)
except FaceMeshError as exc:
    print("error", type(exc).__name__, exc)
"""


def test_a_png_with_a_bad_iccp_chunk_loads_silently(tmp_path):
    rgb = np.random.default_rng(0).integers(0, 256, (40, 48, 3), dtype=np.uint8)
    p = tmp_path / "iccp.png"
    p.write_bytes(_png(rgb, iccp=True))
    # the chunk is one libpng complains about, straight to descriptor 2 (checked here, so the test means something)
    raw = _run_python("import sys, cv2, numpy as np; cv2.imdecode(np.fromfile(sys.argv[1], np.uint8), -1)", str(p))
    assert "libpng" in raw.stderr, raw.stderr
    res = _run_python(_LOAD_IMAGE, str(p))
    assert res.returncode == 0 and res.stderr == "", res.stderr
    assert res.stdout.strip() == "shape (40, 48, 3)"
    from facemesh.io import load_image_rgb

    np.testing.assert_array_equal(load_image_rgb(p), rgb)  # the pixels as written (RGB)


def test_a_damaged_png_is_one_typed_error_and_no_native_lines(tmp_path):
    rgb = np.random.default_rng(1).integers(0, 256, (40, 48, 3), dtype=np.uint8)
    p = tmp_path / "damaged.png"
    p.write_bytes(_png(rgb, damage_idat=True))
    res = _run_python(_LOAD_IMAGE, str(p))
    assert res.returncode == 0 and res.stderr == "", res.stderr
    assert res.stdout.startswith("error InputError") and str(p) in res.stdout
    # on the command line: the one error line and nothing from libpng
    cli = subprocess.run(
        [str(BIN / "facemesh"), "build", str(p), "-o", str(tmp_path / "m.glb")], capture_output=True, text=True
    )
    assert cli.returncode == 2
    assert "libpng" not in cli.stderr
    _one_line(cli.stderr, str(p))


def test_a_glb_texture_with_a_bad_iccp_chunk_loads_silently(tmp_path, monkeypatch):
    import facemesh.gltf as gltf

    texture = np.random.default_rng(2).integers(0, 256, (40, 48, 3), dtype=np.uint8)
    monkeypatch.setattr(gltf, "_encode_texture", lambda tex, fmt: (_png(np.asarray(tex), iccp=True), "image/png"))
    p = tmp_path / "iccp.glb"
    gltf.save_glb(_mesh(500.0, texture), p)
    code = "import sys; from facemesh.gltf import load_glb; print(load_glb(sys.argv[1]).texture.shape)"
    res = _run_python(code, str(p))
    assert res.returncode == 0 and res.stderr == "", res.stderr
    assert res.stdout.strip() == "(40, 48, 3)"


def test_mediapipe_keeps_its_silencer():
    from facemesh._native import native_stderr_silenced
    from facemesh.landmarks import mediapipe

    assert mediapipe.native_stderr_silenced is native_stderr_silenced
    assert "native_stderr_silenced" in mediapipe.__all__


def test_the_silencer_restores_descriptor_2(tmp_path):
    code = (
        "import os, sys\n"
        "from facemesh._native import native_stderr_silenced\n"
        "os.write(2, b'before\\n')\n"
        "with native_stderr_silenced():\n"
        "    os.write(2, b'hidden\\n')\n"
        "try:\n"
        "    with native_stderr_silenced():\n"
        "        raise ValueError\n"
        "except ValueError:\n"
        "    pass\n"
        "os.write(2, b'after\\n')\n"
    )
    res = _run_python(code)
    assert res.returncode == 0 and res.stderr == "before\nafter\n"


# ---------------------------------------------------------------------------------------------------------------------
# H. unreadable inputs


_LOAD_ANY = """
import json, sys
from facemesh.types import FaceMeshError
kind, path = sys.argv[1], sys.argv[2]
try:
    if kind == "image":
        from facemesh.io import load_image_rgb as load
    elif kind == "glb":
        from facemesh.gltf import load_glb as load
    elif kind == "rig":
        from gazeaug.sampling import load_rig as load
    else:
        from gazeaug.train import load_model as load
    load(path)
    print(json.dumps(["loaded", ""]))
except FaceMeshError as exc:
    print(json.dumps([type(exc).__name__, str(exc)]))
except Exception as exc:
    print(json.dumps(["untyped " + type(exc).__name__, str(exc)]))
"""


@pytest.mark.parametrize(
    "kind, name, error",
    [("image", "secret.png", "InputError"), ("glb", "secret.glb", "InputError"), ("rig", "secret.yaml", "GazeAugError")]
    + ([("model", "secret.pt", "GazeAugError")] if __import__("importlib").util.find_spec("torch") else []),
)
def test_unreadable_files_are_typed_errors(tmp_path, kind, name, error):
    prefix = unprivileged_prefix()
    p = tmp_path / name
    if kind == "image":
        p.write_bytes(_png(np.zeros((40, 48, 3), np.uint8)))
    elif kind == "glb":
        from facemesh.gltf import save_glb

        save_glb(_mesh(500.0), p)
    elif kind == "rig":
        p.write_text(_complete_rig())
    else:
        _model_file(p)
    res = _run_python(_LOAD_ANY, kind, str(p), prefix=prefix)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout) == ["loaded", ""]  # readable: it loads
    os.chmod(p, 0)
    try:
        res = _run_python(_LOAD_ANY, kind, str(p), prefix=prefix)
    finally:
        os.chmod(p, 0o644)
    assert res.returncode == 0, res.stderr
    got, message = json.loads(res.stdout)
    assert got == error, (got, message)
    assert message.startswith(str(p)) and "cannot read" in message and "Permission denied" in message


def test_an_unreadable_image_in_a_dataset_run_is_skipped(tmp_path, monkeypatch):
    """The reader thread turns an InputError into a skipped sample: an OSError must arrive as one."""
    from facemesh.io import load_image_rgb
    from gazeaug.jobs import _read_image

    p = tmp_path / "face.png"
    p.write_bytes(_png(np.zeros((40, 48, 3), np.uint8)))

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(p))

    monkeypatch.setattr(np, "fromfile", refuse)

    class Sample:
        image_path = p

        def load_image(self):
            return load_image_rgb(p)

    out = _read_image(Sample())  # type: ignore[arg-type]
    assert isinstance(out, InputError) and isinstance(out, FaceMeshError)
    assert str(out).startswith(str(p)) and "Permission denied" in str(out)
