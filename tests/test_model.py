"""The gaze model: registry, preprocessing, training (log, checkpoints, resume), evaluation, prediction, ONNX."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the gaze model needs torch (pip install 'gazeaug[train]')")

from conftest import face_photo  # noqa: E402
from helpers import synthetic_h5 as _synthetic_h5  # noqa: E402

from gazeaug.cli import main  # noqa: E402
from gazeaug.errors import GazeAugError  # noqa: E402
from gazeaug.models import create_model  # noqa: E402
from gazeaug.models.preprocess import prepare_inputs  # noqa: E402
from gazeaug.train import H5TrainingSet, TrainSettings, load_model, predict_arrays, train  # noqa: E402


def test_registry_and_shapes():
    m = create_model("mobilenet_gaze")
    a, b, c = prepare_inputs(
        np.zeros((4, 36, 60, 3), np.uint8), np.full((4, 36, 60, 3), 255, np.uint8), np.zeros((4, 2))
    )
    assert m(a, b, c).shape == (4, 2)
    assert float(a.min()) == -1.0 and float(b.max()) == 1.0 and a.shape == (4, 3, 36, 60)
    with pytest.raises(GazeAugError, match="model: expected one of"):
        create_model("resnet9000")


def test_preprocessing_does_not_mirror():
    img = np.zeros((1, 36, 60, 3), np.uint8)
    img[0, :, :10, 0] = 255  # red on the left of the patch
    a, _, _ = prepare_inputs(img, img, np.zeros((1, 2)))
    assert float(a[0, 0, :, :10].mean()) == 1.0 and float(a[0, 0, :, 50:].mean()) == -1.0


def test_training_learns_logs_and_resumes(tmp_path):
    data = _synthetic_h5(tmp_path / "t.h5")
    s = TrainSettings(epochs=4, batch_size=32, lr=3e-3, seed=1)
    log = train(data, tmp_path / "m.pt", s, val_subjects=["b"], progress=False)
    assert len(log) == 4 and log[-1]["train_error_deg"] < log[0]["train_error_deg"]
    assert log[-1]["val_error_deg"] is not None
    for suffix in (".log.csv", ".curves.png", ".ckpt.pt"):
        assert (tmp_path / f"m{suffix}").is_file()
    model, meta = load_model(tmp_path / "m.pt")
    assert meta["model"] == "mobilenet_gaze" and meta["normalization"]["distance_mm"] == 600.0
    # interrupted after 2 epochs, then resumed: the same model as the uninterrupted run
    import gazeaug.train as tr

    real_save, calls = tr._save, []

    def save_then_die(obj, path):
        real_save(obj, path)
        calls.append(path)
        if len(calls) == 2:
            raise KeyboardInterrupt

    tr._save = save_then_die
    try:
        with pytest.raises(KeyboardInterrupt):
            train(data, tmp_path / "r.pt", s, val_subjects=["b"], progress=False)
    finally:
        tr._save = real_save
    assert not (tmp_path / "r.pt").exists()
    log2 = train(data, tmp_path / "r.pt", s, val_subjects=["b"], resume=True, progress=False)
    assert [r["epoch"] for r in log2] == [1, 2, 3, 4]
    resumed, _ = load_model(tmp_path / "r.pt")
    for (k, a), b in zip(model.state_dict().items(), resumed.state_dict().values()):
        np.testing.assert_allclose(a.numpy(), b.numpy(), atol=1e-5, err_msg=k)
    with pytest.raises(GazeAugError, match="other settings"):
        train(
            data,
            tmp_path / "r.pt",
            TrainSettings(epochs=5, batch_size=32),
            val_subjects=["b"],
            resume=True,
            progress=False,
        )
    # mirror averaging changes only the prediction, yet a recorded setting must match as every one does;
    # a checkpoint from before the setting resumes with either
    with pytest.raises(GazeAugError, match="mirror_average"):
        train(
            data, tmp_path / "r.pt", replace(s, mirror_average=False), val_subjects=["b"], resume=True, progress=False
        )
    ck = torch.load(tmp_path / "r.ckpt.pt", weights_only=True)
    del ck["settings"]["mirror_average"]
    torch.save(ck, tmp_path / "r.ckpt.pt")
    for flag in (False, True):
        log3 = train(
            data, tmp_path / "r.pt", replace(s, mirror_average=flag), val_subjects=["b"], resume=True, progress=False
        )
        assert [r["epoch"] for r in log3] == [1, 2, 3, 4] and load_model(tmp_path / "r.pt")[1]["mirror_average"] is flag


def test_bad_training_inputs(tmp_path):
    with pytest.raises(GazeAugError, match="NaN"):
        H5TrainingSet(_synthetic_h5(tmp_path / "nan.h5", nan_rows=3))
    good = _synthetic_h5(tmp_path / "g.h5")
    with pytest.raises(GazeAugError, match="no subject zz in this file; its subjects are a, b"):
        H5TrainingSet(good, subjects=["zz"])
    with pytest.raises(GazeAugError, match="no rows"):
        H5TrainingSet(good, exclude_subjects=["a", "b"])
    import h5py

    with h5py.File(tmp_path / "missing.h5", "w") as f:
        f["left_eye"] = np.zeros((2, 36, 60, 3), np.uint8)
    with pytest.raises(GazeAugError, match="missing keys"):
        H5TrainingSet(tmp_path / "missing.h5")
    (tmp_path / "junk.h5").write_bytes(b"junk")
    with pytest.raises(GazeAugError, match="not a readable HDF5"):
        H5TrainingSet(tmp_path / "junk.h5")
    with pytest.raises(GazeAugError, match=r"nothing\.h5: no such file$"):  # not h5py's errno paragraph
        H5TrainingSet(tmp_path / "nothing.h5")
    with pytest.raises(GazeAugError, match=f"{re.escape(str(tmp_path))}: not a file$"):
        H5TrainingSet(tmp_path)
    with pytest.raises(GazeAugError, match="epochs"):
        TrainSettings(epochs=0)


def test_epochs_and_batch_fitted_to_the_data_size():
    # hand-derived: batch = 2 ** round(log2(rows / 128)) within [32, 256];
    # epochs = min(2000, max(10, ceil(500000 / rows)))
    cases = {
        480: (32, 1042),  # 480 / 128 = 3.75 -> log2 1.91 -> 2 -> 4 -> 32 (the floor); 500000 / 480 = 1041.7 -> 1042
        1440: (32, 348),  # 11.25 -> 8 -> 32; 347.2 -> 348
        9000: (64, 56),  # 70.3 -> log2 6.14 -> 64; 55.6 -> 56
        20000: (128, 25),  # 156.25 -> log2 7.29 -> 128; 25 exactly
        100000: (256, 10),  # 781 -> 256 (the ceiling); 5 -> 10 (the floor of epochs)
        24: (32, 2000),  # 0.19 -> 32; 500000 / 24 = 20833.3 -> 2000 (the ceiling of epochs)
        250: (32, 2000),  # 500000 / 250 = 2000 exactly
        251: (32, 1993),  # 1992.03 -> 1993
    }
    for rows, (batch, epochs) in cases.items():
        f = TrainSettings().fitted(rows)
        assert (f.batch_size, f.epochs) == (batch, epochs), rows
    kept = TrainSettings(epochs=3, batch_size=7).fitted(240)
    assert (kept.batch_size, kept.epochs) == (7, 3)
    assert TrainSettings(batch_size=64).fitted(480).epochs == 1042
    with pytest.raises(GazeAugError, match="rows"):
        TrainSettings().fitted(0)
    with pytest.raises(GazeAugError, match="batch size"):
        TrainSettings(batch_size=True)


def test_numpy_subject_names_give_a_loadable_model(tmp_path):
    # names read from an HDF5 file or a numpy array are numpy strings; the model file must still load
    data = _synthetic_h5(tmp_path / "t.h5")
    held = np.array(["b"])
    train(data, tmp_path / "m.pt", TrainSettings(epochs=1, batch_size=32), val_subjects=list(held), progress=False)
    _, meta = load_model(tmp_path / "m.pt")
    assert meta["val_subjects"] == ["b"] and type(meta["val_subjects"][0]) is str
    with pytest.raises(GazeAugError, match="list of names"):
        train(data, tmp_path / "n.pt", TrainSettings(epochs=1), val_subjects="b", progress=False)


def test_a_model_file_records_the_fitted_epochs_and_batch(tmp_path):
    data = _synthetic_h5(tmp_path / "t.h5")
    import h5py

    with h5py.File(data) as f:
        rows = len(f["gaze"])
    # the batch size left to the data (the epochs given, for the test's time): a set under 5793 rows
    # (rows / 128 < 2 ** 5.5) trains at the floor of 32, and the file records the fitted value
    s = TrainSettings(epochs=1)
    train(data, tmp_path / "m.pt", s, progress=False)
    _, meta = load_model(tmp_path / "m.pt")
    ts = meta["train_settings"]
    assert ts["epochs"] == 1 and ts["batch_size"] == 32 and rows < 5793
    # the samples the fitted epochs show (gazeaug train --samples): 1440 over 96 rows is 15 epochs, by hand
    assert rows == 96
    out = tmp_path / "s.pt"
    assert main(["train", str(data), "-o", str(out), "--samples", "1440", "--quiet"]) == 0
    ts = load_model(out)[1]["train_settings"]
    assert ts["auto_samples"] == 1440 and ts["epochs"] == 15 and ts["batch_size"] == 32


def test_one_reader_of_the_training_set_schema(tmp_path):
    import h5py

    import gazeaug.io_h5 as io_h5
    from gazeaug.io_h5 import read_h5

    assert H5TrainingSet is io_h5.H5TrainingSet  # gazeaug.train re-exports the reader that lives beside the writer
    path = _synthetic_h5(tmp_path / "t.h5", n=10)
    with h5py.File(path, "r") as f:  # the truth, read without gazeaug
        gaze, subject = f["gaze"][()], f["subject"][()]
    b_rows = np.flatnonzero(subject == b"b")
    np.testing.assert_array_equal(b_rows, [1, 3, 5, 7, 9])  # helpers.synthetic_h5 alternates subjects a, b
    only_b = H5TrainingSet(path, subjects=["b"])
    np.testing.assert_array_equal(only_b.rows, b_rows)
    got = only_b.read(["gaze", "subject"])
    np.testing.assert_array_equal(got["gaze"], gaze[b_rows])
    assert set(got["subject"].tolist()) == {b"b"} and got["attrs"]["complete"]
    assert got["attrs"]["settings"]["normalization"]["focal_px"] == 650.0
    whole = read_h5(path)
    np.testing.assert_array_equal(whole["gaze"], gaze)
    assert "sources" not in whole and len(whole["left_eye"]) == 10
    # the same checks whichever way a file is read
    nan = _synthetic_h5(tmp_path / "nan.h5", nan_rows=2)
    for read in (H5TrainingSet, read_h5):
        with pytest.raises(GazeAugError, match="2 rows have NaN or infinite labels"):
            read(nan)
    with h5py.File(tmp_path / "short.h5", "w") as f:
        f.attrs["complete"] = True
        for k in io_h5.REQUIRED_KEYS:
            f[k] = np.zeros((4, 36, 60, 3) if k.endswith("_eye") else (4, 2) if k in ("head_pose", "gaze") else (4,))
        del f["source_index"]
        f["source_index"] = np.arange(3)
    for read in (H5TrainingSet, read_h5):
        with pytest.raises(GazeAugError, match="'source_index' has 3 rows, left_eye 4"):
            read(tmp_path / "short.h5")
    with h5py.File(path, "a") as f:
        f.attrs["complete"] = False
    for read in (H5TrainingSet, read_h5):
        with pytest.raises(GazeAugError, match="did not finish"):
            read(path)


def test_shuffled_batches_mix_the_whole_file(tmp_path):
    import h5py

    # 16 subjects stored one after another, 250 rows each (augment writes source by source; 250 is no
    # multiple of the 64-row chunks, so subjects begin and end inside chunks)
    subjects = tuple(f"s{i:02d}" for i in range(16))
    path = _synthetic_h5(tmp_path / "runs.h5", n=4000, subjects=subjects, runs=True)
    with h5py.File(path, "r") as f:  # the truth, read without gazeaug
        gaze, subject, left = f["gaze"][()], f["subject"][()], f["left_eye"][()]
    assert len(set(subject[:2048].tolist())) == 9  # a 2048-row stretch of the file holds 9 subjects
    row_of = {g.tobytes(): i for i, g in enumerate(gaze)}
    assert len(row_of) == len(gaze)  # every row's gaze is its name
    data = H5TrainingSet(path)
    batches = list(data.batches(32, np.random.default_rng(3), keys=("gaze", "subject")))
    seen = [row_of[g.tobytes()] for b in batches for g in b["gaze"]]
    assert sorted(seen) == list(range(4000))  # one epoch: every row once
    for b in batches:  # each row with its own subject
        np.testing.assert_array_equal(b["subject"], subject[[row_of[g.tobytes()] for g in b["gaze"]]].astype(str))
    # 32 rows drawn uniformly from 16 equal subjects hold 16 (1 - (15/16)^32) = 14.3 subjects on average;
    # 32 drawn from a 2048-row stretch of the file at most 9
    assert np.mean([len(set(b["subject"].tolist())) for b in batches]) > 12
    # the same rng, the same batches; no rng, file order
    again = list(data.batches(32, np.random.default_rng(3), keys=("gaze",)))
    np.testing.assert_array_equal(np.concatenate([b["gaze"] for b in again]), gaze[seen])
    ordered = np.concatenate([b["gaze"] for b in data.batches(100, None, keys=("gaze",))])
    np.testing.assert_array_equal(ordered, gaze)
    # selections with gaps inside chunks: their rows once each, in file order without rng, both subjects in
    # almost every batch, and no read reaches beyond the chunks that hold the rows
    some = H5TrainingSet(path, subjects=["s03", "s11"])
    want = list(range(750, 1000)) + list(range(2750, 3000))
    chosen = list(some.batches(16, np.random.default_rng(1), keys=("gaze", "subject", "left_eye")))
    picked = [row_of[g.tobytes()] for b in chosen for g in b["gaze"]]
    assert sorted(picked) == want
    assert sum(len(set(b["subject"].tolist())) == 2 for b in chosen) >= 0.9 * len(chosen)
    ordered = np.concatenate([b["gaze"] for b in some.batches(64, None, keys=("gaze", "left_eye"))])
    np.testing.assert_array_equal(ordered, gaze[want])
    from gazeaug.io_h5 import ChunkedColumn

    reads, chunks = [], []
    real, real_chunk = h5py.Dataset.__getitem__, ChunkedColumn._chunk

    def counted(self, key):
        if self.name == "/left_eye" and isinstance(key, slice):
            reads.append((key.start, key.stop))
        return real(self, key)

    def counted_chunk(self, c):
        if self.dset.name == "/left_eye":
            chunks.append(c)
        return real_chunk(self, c)

    h5py.Dataset.__getitem__, ChunkedColumn._chunk = counted, counted_chunk
    try:
        for rng in (np.random.default_rng(2), None):
            for threads in (1, 2):  # h5py reads slices; or the stored chunks, inflated in threads
                got = list(some.batches(16, rng, keys=("left_eye", "gaze"), threads=threads))
                np.testing.assert_array_equal(  # the same rows either way: each row's eye is its own
                    np.concatenate([b["left_eye"] for b in got]),
                    left[[row_of[g.tobytes()] for b in got for g in b["gaze"]]],
                )
    finally:
        h5py.Dataset.__getitem__, ChunkedColumn._chunk = real, real_chunk
    assert reads and all(lo >= 750 // 64 * 64 and hi <= 3000 and not (1000 <= lo < 2750) for lo, hi in reads)
    assert all(not (lo < 1000 and hi > 2750) for lo, hi in reads)  # never across the excluded subjects
    # rows 750-999 and 2750-2999 lie in the 64-row chunks 11-15 and 42-46: no other chunk is read
    assert chunks and set(chunks) == set(range(11, 16)) | set(range(42, 47))


def test_axis_weights_by_hand():
    from gazeaug.train import axis_weights

    # pitch +-8 deg and yaw +-20 deg about 0 (three rows): sd 8 sqrt(2/3) = 6.532 and 20 sqrt(2/3) = 16.330,
    # their mean 11.431; weights 11.431 / 6.532 = 1.75 and 11.431 / 16.330 = 0.70
    w = axis_weights(np.radians([[0.0, 0.0], [8.0, 20.0], [-8.0, -20.0]]))
    np.testing.assert_allclose(w, (1.75, 0.70), rtol=1e-12)
    # pitch +-1 deg against yaw +-20: the pitch's spread taken as a quarter of the yaw's (5 and 20 deg
    # times sqrt(2/3)), weights 12.5 / 5 = 2.5 and 12.5 / 20 = 0.625: the yaw still counts
    np.testing.assert_allclose(axis_weights(np.radians([[0, 0], [1, 20], [-1, -20]])), (2.5, 0.625), rtol=1e-12)
    assert axis_weights(np.radians([[3.0, 5.0]])) == (1.0, 1.0)  # one row: no spread
    assert axis_weights(np.radians([[3.0, 5.0], [4.0, 5.0]])) == (1.0, 1.0)  # one yaw for all
    assert axis_weights(np.zeros((0, 2))) == (1.0, 1.0)
    with pytest.raises(GazeAugError, match="balance_axes: expected true or false"):
        TrainSettings(balance_axes="yes")


def test_the_loss_weighs_each_axis_by_its_spread(tmp_path, monkeypatch):
    import h5py
    import torch

    from gazeaug.models import MODELS, register_model

    monkeypatch.setattr(MODELS, "_entries", dict(MODELS._entries))  # the test's model leaves with the test

    @register_model("test_constant_zero")
    def constant_zero():  # predicts (0, 0) whatever it is given; one weight, never moved at lr 1e-12
        class Zero(torch.nn.Module):
            def __init__(self):
                super().__init__()
                self.w = torch.nn.Parameter(torch.zeros(()))

            def forward(self, left, right, head_pose):
                return self.w * head_pose

        return Zero()

    path = _synthetic_h5(tmp_path / "t.h5", n=64)
    with h5py.File(path, "r") as f:  # the truth, read without gazeaug
        gaze = f["gaze"][()].astype(np.float64)
    sd = gaze.std(axis=0)
    w = sd.mean() / sd  # by hand: each axis by the inverse of its spread, the two averaging 1 for equal spreads
    for balance, weights in ((True, w), (False, np.ones(2))):
        s = TrainSettings(model="test_constant_zero", epochs=1, batch_size=16, lr=1e-12, balance_axes=balance)
        log = train(path, tmp_path / f"m{balance}.pt", s, progress=False)
        # the loss of a (0, 0) prediction: the mean over rows and axes of |gaze| times the axis weight
        want = float((np.abs(gaze) * weights).mean())
        assert log[0]["train_loss"] == pytest.approx(want, rel=1e-5)
        made = torch.load(tmp_path / f"m{balance}.pt", weights_only=True)
        np.testing.assert_allclose(made["loss_weights_pitch_yaw"], weights, rtol=1e-6)
    # the command line: balanced by default at lr 3e-3, --no-balance-axes for the plain loss
    args = ["train", str(path), "--model", "test_constant_zero", "--epochs", "1", "--batch-size", "16", "--quiet"]
    for extra, balance in (([], True), (["--no-balance-axes"], False)):
        assert main([*args, "-o", str(tmp_path / f"cli{balance}.pt"), *extra]) == 0
        made = torch.load(tmp_path / f"cli{balance}.pt", weights_only=True)
        assert made["train_settings"]["balance_axes"] is balance and made["train_settings"]["lr"] == 3e-3


def test_model_files_that_are_not_ours(tmp_path):
    (tmp_path / "x.pt").write_bytes(b"not a model")
    with pytest.raises(GazeAugError, match="not a gazeaug model .truncated, damaged or not a PyTorch file"):
        load_model(tmp_path / "x.pt")
    torch.save({"weights": 1}, tmp_path / "y.pt")
    with pytest.raises(GazeAugError, match="not a gazeaug model"):
        load_model(tmp_path / "y.pt")
    data = _synthetic_h5(tmp_path / "t.h5", n=32)
    train(data, tmp_path / "m.pt", TrainSettings(epochs=1, batch_size=16), progress=False)
    blob = (tmp_path / "m.pt").read_bytes()
    (tmp_path / "cut.pt").write_bytes(blob[: len(blob) // 2])
    with pytest.raises(GazeAugError, match="not a gazeaug model .truncated, damaged or not a PyTorch file"):
        load_model(tmp_path / "cut.pt")
    with pytest.raises(GazeAugError, match="no such gazeaug model file"):
        load_model(tmp_path / "none.pt")


def test_onnx_export_matches_pytorch(tmp_path):
    ort = pytest.importorskip("onnxruntime")
    data = _synthetic_h5(tmp_path / "t.h5", n=32)
    train(data, tmp_path / "m.pt", TrainSettings(epochs=1, batch_size=16), progress=False)
    assert main(["export", str(tmp_path / "m.pt"), "-o", str(tmp_path / "m.onnx")]) == 0
    model, _ = load_model(tmp_path / "m.pt")
    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (5, 36, 60, 3), dtype=np.uint8)
    right = rng.integers(0, 255, (5, 36, 60, 3), dtype=np.uint8)
    head = rng.uniform(-0.3, 0.3, (5, 2)).astype(np.float32)
    expected = predict_arrays(model, left, right, head)
    a, b, c = prepare_inputs(left, right, head)
    sess = ort.InferenceSession(str(tmp_path / "m.onnx"))
    got = sess.run(None, {"left_eye": a.numpy(), "right_eye": b.numpy(), "head_pose": c.numpy()})[0]
    np.testing.assert_allclose(got, expected, atol=1e-4)
    empty = sess.run(None, {"left_eye": a[:0].numpy(), "right_eye": b[:0].numpy(), "head_pose": c[:0].numpy()})[0]
    assert empty.shape == (0, 2)  # an empty batch through the averaging graph (mirror and shift)
    # wrong inputs: one message naming what is wrong, from predict_arrays and from both estimators alike
    from gazeaug.estimator import load_estimator

    estimators = [load_estimator(tmp_path / "m.pt"), load_estimator(tmp_path / "m.onnx")]
    bad = [
        ((left[:, :, :30], right[:, :, :30], head), r"left eye patches: the model reads 60 x 36 px ones, got 30 x 36"),
        (
            (left / 255.0, right, head),
            r"left eye patches: expected \(N, H, W, 3\) uint8 RGB, got \(5, 36, 60, 3\) float64",
        ),
        ((left, right[:4], head), r"right eye patches: expected 5, one per left eye patch, got 4"),
        (
            (left, right, head[:, :1]),
            r"head poses: expected \(5, 2\) radians \(pitch, yaw\), one per eye patch, got \(5, 1\)",
        ),
        (
            (left, right, np.where(np.eye(5, 2) > 0, np.nan, head)),
            r"head poses: expected finite numbers, got 2 row\(s\)",
        ),
        ((left.tolist(), right, head), None),  # a nested list of uint8-range ints is int64: refused as not uint8
    ]
    for args, message in bad:
        for predict in (lambda *x: predict_arrays(model, *x), *(e.predict for e in estimators)):
            with pytest.raises(GazeAugError, match=message or "uint8"):
                predict(*args)
    for size in (0, -1, 2.5):
        with pytest.raises(GazeAugError, match="batch size: expected an integer >= 1"):
            predict_arrays(model, left, right, head, batch_size=size)  # type: ignore[arg-type]
    # the file says how to feed it: the input mode and the normalization the model was trained for
    import onnx

    props = {p.key: p.value for p in onnx.load(str(tmp_path / "m.onnx")).metadata_props}
    assert props["gazeaug.input_mode"] == "rgb" and json.loads(props["gazeaug.patch_size_wh"]) == [60, 36]
    assert json.loads(props["gazeaug.mirror_average"]) is True  # the default; the graph holds the averaging
    assert json.loads(props["gazeaug.shift_average_px"]) == 3  # likewise the translations
    plain = TrainSettings(epochs=1, batch_size=16, mirror_average=False)
    train(data, tmp_path / "p.pt", plain, progress=False)
    assert main(["export", str(tmp_path / "p.pt"), "-o", str(tmp_path / "p.onnx")]) == 0
    props = {p.key: p.value for p in onnx.load(str(tmp_path / "p.onnx")).metadata_props}
    assert json.loads(props["gazeaug.mirror_average"]) is False
    assert json.loads(props["gazeaug.shift_average_px"]) == 3  # found inside the network when not mirror-wrapped
    assert json.loads(props["gazeaug.normalization"])["focal_px"] == 650.0
    # crafted metadata: JSON nested deeper than Python reads, or a patch size of infinity

    for key, value in (
        ("gazeaug.normalization", "[" * 100_000 + "]" * 100_000),
        ("gazeaug.patch_size_wh", "[1e999999, 36]"),
    ):
        crafted = onnx.load(str(tmp_path / "p.onnx"))
        for prop in crafted.metadata_props:
            if prop.key == key:
                prop.value = value
        onnx.save(crafted, str(tmp_path / "crafted.onnx"))
        with pytest.raises(GazeAugError, match="unusable gazeaug metadata"):
            load_estimator(tmp_path / "crafted.onnx")
    train(data, tmp_path / "g.pt", TrainSettings(epochs=1, batch_size=16, input_mode="grey_equalized"), progress=False)
    assert main(["export", str(tmp_path / "g.pt"), "-o", str(tmp_path / "g.onnx")]) == 0
    props = {p.key: p.value for p in onnx.load(str(tmp_path / "g.onnx")).metadata_props}
    assert props["gazeaug.input_mode"] == "grey_equalized"


def _copy_photo(faces_dir, name, root):
    """Copy photo ``name`` (without ../shared, the astronaut) into ``root``; its file name there and its (w, h)."""
    import shutil

    import cv2

    src = face_photo(faces_dir, name, any_face=True)
    dest = name if src.name == name else f"astronaut_for_{name}"
    shutil.copy(src, root / dest)
    h, w = cv2.imread(str(src)).shape[:2]
    return dest, (w, h)


def test_evaluate_predict_cli(tmp_path, faces_dir, capsys):
    from gazeaug.datasets import open_dataset
    from gazeaug.jobs import JobSettings, run_dataset

    # a real (tiny) augmented training set from two photos, evaluated on the raw photos and on an .h5
    root = tmp_path / "ds"
    root.mkdir()
    rows = ["image,subject,fx,fy,cx,cy,target_x,target_y,target_z"]
    for i, name in enumerate(("astronaut.png", "sergey.png")):
        file, (w, h) = _copy_photo(faces_dir, name, root)
        rows.append(f"{file},s{i},600,600,{w / 2 - 0.5},{h / 2 - 0.5},0,150,0")
    (root / "labels.csv").write_text("\n".join(rows) + "\n")
    run_dataset(open_dataset(root), tmp_path / "aug.h5", JobSettings(per_sample=8), progress=False)
    # the test set also has an image without a face: counted and reported, not fatal
    import cv2

    cv2.imwrite(str(root / "blank.png"), np.full((300, 300, 3), 128, np.uint8))
    with (root / "labels.csv").open("a") as fh:
        fh.write("blank.png,s9,300,300,149.5,149.5,0,150,0\n")
    assert main(["train", str(tmp_path / "aug.h5"), "-o", str(tmp_path / "m.pt"), "--epochs", "2", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "m.pt"), str(root), "-o", str(tmp_path / "ev"), "--quiet"]) == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert res["count"] == 2 and res["skipped"] == 1 and set(res["per_subject"]) == {"s0", "s1"}
    assert (tmp_path / "ev" / "errors.csv").is_file() and (tmp_path / "ev" / "errors_hist.png").is_file()
    assert main(["evaluate", str(tmp_path / "m.pt"), str(tmp_path / "aug.h5"), "-o", str(tmp_path / "ev2")]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["count"] == 16
    assert main(["predict", str(tmp_path / "m.pt"), str(root / file), "-o", str(tmp_path / "p.png")]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert len(out["gaze_vector_camera"]) == 3 and (tmp_path / "p.png").is_file()
    assert main(["predict", str(tmp_path / "nothing.pt"), str(root / file)]) == 2


def test_evaluate_runs_the_model_on_one_thread_as_ray_actors_do(tmp_path, faces_dir):
    """Local evaluation runs the network on one PyTorch thread, as each Ray actor does, so the two
    engines give the same rows bit for bit (a CPU kernel may split its sums by thread count: 2 threads
    against 1 moved errors by 2e-6 deg); the caller's thread count is restored after."""
    from gazeaug.datasets import open_dataset
    from gazeaug.evaluate import evaluate_dataset
    from gazeaug.train import load_model

    root = tmp_path / "ds"
    root.mkdir()
    file, (w, h) = _copy_photo(faces_dir, "astronaut.png", root)
    (root / "labels.csv").write_text(
        f"image,subject,fx,fy,cx,cy,target_x,target_y,target_z\n{file},s0,600,600,{w / 2},{h / 2},0,150,0\n"
    )
    model, meta = load_model(Path(__file__).parents[1] / "gazeaug" / "models" / "demo_wheelchair.pt")
    seen = []
    model.register_forward_pre_hook(lambda module, inputs: seen.append(torch.get_num_threads()))
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        res = evaluate_dataset(model, meta, open_dataset(root), progress=False)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    assert res["count"] == 1 and seen and set(seen) == {1}


def test_experiment_runs_end_to_end(tmp_path, faces_dir, capsys):
    # train on astronaut and sergey, test on business-person (without ../shared, the astronaut throughout)
    for split, names in (("train", ("astronaut.png", "sergey.png")), ("test", ("business-person.png",))):
        root = tmp_path / split
        root.mkdir()
        rows = ["image,subject,fx,fy,cx,cy,target_x,target_y,target_z"]
        for i, name in enumerate(names):
            file, (w, h) = _copy_photo(faces_dir, name, root)
            rows.append(f"{file},s{i},1000,1000,300,300,0,150,0")
        (root / "labels.csv").write_text("\n".join(rows) + "\n")
    # the test photo (business-person: 958 x 1358) gets its own principal point, width/height-free intrinsics
    (tmp_path / "test" / "labels.csv").write_text(
        f"image,subject,fx,fy,cx,cy,target_x,target_y,target_z\n{file},t0,{max(w, h)},{max(w, h)},"
        f"{w / 2 - 0.5},{h / 2 - 0.5},0,150,0\n"
    )
    out = tmp_path / "exp"
    args = ["experiment", "--train", str(tmp_path / "train"), "--test", str(tmp_path / "test"), "-o", str(out)]
    # a normalization of its own (MPIIGaze's focal length, a smaller patch): every set and model takes it
    norm = ["--focal", "960", "--patch-size", "40", "24"]
    # --with-source: the augmented model's set holds the 2 original rows beside the 2 x 2 drawn ones
    assert main(args + ["--epochs", "1", "--per-sample", "2", "--seeds", "2", *norm, "--with-source", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "| training dataset | error, original data | error, augmented data | reduction |" in text
    res = json.loads((out / "results.json").read_text())
    assert res["runs"]["original"]["test_count"] == 1 and res["runs"]["augmented"]["rows"] == 6
    assert res["runs"]["original"]["rows"] == 2 and res["settings"]["with_source"] is True
    assert "also trains on the original rows (`--with-source`)" in (out / "report.md").read_text()
    assert res["settings"]["normalization"]["focal_px"] == 960 and res["settings"]["normalization"][
        "patch_size_wh"
    ] == [
        40,
        24,
    ]
    for h5 in ("train_original.h5", "seed0/train_augmented.h5", "seed1/train_augmented.h5", "test_normalized.h5"):
        with h5py.File(out / h5, "r") as f:
            assert f["left_eye"].shape[1:] == (24, 40, 3), h5
            assert json.loads(f.attrs["settings"])["normalization"]["focal_px"] == 960, h5
    for name in ("original", "augmented"):
        _, meta = load_model(out / "seed1" / f"model_{name}.pt")
        assert meta["normalization"]["focal_px"] == 960 and list(meta["patch_size_wh"]) == [40, 24]
    for f in (
        "report.md",
        "examples_augmented.png",
        "train_augmented.distribution.png",
        "test_normalized.distribution.png",
    ):
        assert (out / f).is_file(), f


# --------------------------------------------------------------------------- mirror averaging


def _column_net():
    """A hand-made network: pitch = the left patch's mean grey; yaw = (its bright column - w / 2) / 100 + head yaw."""

    class Net(torch.nn.Module):
        def forward(self, left, right, head):
            w = left.shape[-1]
            profile = left.mean(dim=(1, 2))  # (N, W)
            x = (profile * torch.arange(w, dtype=left.dtype)).sum(-1) / profile.sum(-1)
            return torch.stack([left.mean(dim=(1, 2, 3)), (x - w / 2) / 100 + head[:, 1]], dim=1)

    return Net()


def _bright_column(x, w=60, h=36):
    p = torch.zeros(1, 3, h, w)
    p[..., x] = 1.0
    return p


def test_mirror_average_by_hand():
    from gazeaug.models.mirror import mirror_averaged

    # left eye: bright column 10, right eye: bright column 20 (w = 60), head yaw 0.05.
    # Plain: yaw (10 - 30) / 100 + 0.05 = -0.15. Mirrored face: its left eye is the right one mirrored,
    # column x from w - x, so the bright column lands at 60 - 20 = 40 and the head yaw is -0.05:
    # yaw (40 - 30) / 100 - 0.05 = 0.05, negated back -0.05. Average: (-0.15 - 0.05) / 2 = -0.10.
    # Pitch: the mean grey, 3 * 36 / (3 * 36 * 60) = 1 / 60 for both patches, unchanged by the mirror.
    left, right = _bright_column(10), _bright_column(20)
    head = torch.tensor([[0.2, 0.05]])
    got = mirror_averaged(_column_net())(left, right, head)
    np.testing.assert_allclose(got.numpy(), [[1 / 60, -0.10]], atol=1e-6)
    # and the plain network alone, for contrast
    np.testing.assert_allclose(_column_net()(left, right, head).numpy(), [[1 / 60, -0.15]], atol=1e-6)


def test_mirror_averaged_model_is_mirror_equivariant(tmp_path):
    # the averaged model answers the mirrored face with the mirrored answer (exactly, any weights):
    # f(M r, M l, m h) = m f(l, r, h), M mirroring columns about the principal point, m negating yaw
    from facemesh.conventions import MIRROR_PITCHYAW, mirrored_columns

    data = _synthetic_h5(tmp_path / "t.h5", n=32)
    train(data, tmp_path / "m.pt", TrainSettings(epochs=1, batch_size=16), progress=False)
    model, meta = load_model(tmp_path / "m.pt")
    assert meta["mirror_average"] is True
    rng = np.random.default_rng(1)
    left = rng.integers(0, 255, (4, 36, 60, 3), dtype=np.uint8)
    right = rng.integers(0, 255, (4, 36, 60, 3), dtype=np.uint8)
    # mirroring twice gives a patch back but for column 0 (its source lies outside; it repeats column 1)
    for p in (left, right):
        p[:, :, 0] = p[:, :, 1]
    head = rng.uniform(-0.3, 0.3, (4, 2))
    cols = mirrored_columns(60)
    plain = predict_arrays(model, left, right, head)
    mirrored = predict_arrays(model, right[:, :, cols], left[:, :, cols], head * MIRROR_PITCHYAW)
    np.testing.assert_allclose(mirrored, plain * MIRROR_PITCHYAW, atol=1e-5)


def test_mirror_average_is_recorded_and_can_be_turned_off(tmp_path):
    data = _synthetic_h5(tmp_path / "t.h5", n=32)
    args = ["train", str(data), "--epochs", "1", "--batch-size", "16", "--quiet"]
    assert main([*args, "-o", str(tmp_path / "plain.pt"), "--no-mirror-average", "--shift-average", "0"]) == 0
    model, meta = load_model(tmp_path / "plain.pt")
    assert meta["mirror_average"] is False and meta["prediction"] == {"mirror_average": False, "shift_average_px": 0}
    assert not hasattr(model, "net")  # the network itself
    # a file from before the entry predicts as it always did; a bad entry is refused
    obj = torch.load(tmp_path / "plain.pt", weights_only=True)
    del obj["prediction"]
    torch.save(obj, tmp_path / "old.pt")
    assert load_model(tmp_path / "old.pt")[1]["mirror_average"] is False
    obj["prediction"] = {"mirror_average": "yes"}
    torch.save(obj, tmp_path / "bad.pt")
    with pytest.raises(GazeAugError, match="'prediction': expected"):
        load_model(tmp_path / "bad.pt")


def test_mirror_average_can_be_chosen_when_loading(tmp_path, capsys):
    # reading a file with mirror averaging off equals the same weights in a file that says off;
    # turning it on equals the same weights in a file that says on
    from gazeaug.estimator import load_estimator
    from gazeaug.evaluate import evaluate_h5

    data = _synthetic_h5(tmp_path / "t.h5", n=32)
    train(data, tmp_path / "on.pt", TrainSettings(epochs=1, batch_size=16), progress=False)
    obj = torch.load(tmp_path / "on.pt", weights_only=True)
    assert obj["prediction"]["mirror_average"] is True
    obj["prediction"] = {**obj["prediction"], "mirror_average": False}
    torch.save(obj, tmp_path / "off.pt")
    rng = np.random.default_rng(3)
    left, right = (rng.integers(0, 255, (6, 36, 60, 3), dtype=np.uint8) for _ in range(2))
    head = rng.uniform(-0.3, 0.3, (6, 2))

    def pred(path, **kw):
        model, meta = load_model(path, **kw)
        return predict_arrays(model, left, right, head), meta

    on, off = pred(tmp_path / "on.pt")[0], pred(tmp_path / "off.pt")[0]
    assert np.abs(on - off).max() > 1e-6  # the two readings differ for these weights
    got, meta = pred(tmp_path / "on.pt", mirror_average=False)
    np.testing.assert_allclose(got, off, atol=1e-6)
    assert meta["mirror_average"] is False and meta["prediction"]["mirror_average"] is True  # the file's own
    got, meta = pred(tmp_path / "off.pt", mirror_average=True)
    np.testing.assert_allclose(got, on, atol=1e-6)
    assert meta["mirror_average"] is True and meta["prediction"]["mirror_average"] is False
    for bad in ("no", "off", 1, np.array([True, False])):
        with pytest.raises(GazeAugError, match="mirror_average: expected None, True or False, got"):
            load_model(tmp_path / "on.pt", mirror_average=bad)  # type: ignore[arg-type]
    # the CLI: evaluate reads it off on request and says how it read
    for name, extra in (("a", ["--mirror-average", "off"]), ("b", [])):
        model = tmp_path / ("on.pt" if name == "a" else "off.pt")
        assert main(["evaluate", str(model), str(data), "-o", str(tmp_path / name), "--quiet", *extra]) == 0
        line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert line["mirror_average"] is False
    a, b = (json.loads((tmp_path / n / "errors.json").read_text()) for n in "ab")
    assert a["mean_deg"] == pytest.approx(b["mean_deg"], abs=1e-4) and a["mirror_average"] is False
    # an ONNX export has the averaging in its graph: asking otherwise is refused, in one line
    assert main(["export", str(tmp_path / "on.pt"), "-o", str(tmp_path / "on.onnx")]) == 0
    est = load_estimator(tmp_path / "on.onnx", mirror_average=True)
    assert est.kind == "onnx" and est.mirror_average is True
    assert evaluate_h5(est, data)["mirror_average"] is True  # the library records it, not only the CLI
    with pytest.raises(GazeAugError, match="the ONNX graph averages with the mirrored eyes .* needs the .pt model"):
        load_estimator(tmp_path / "on.onnx", mirror_average=False)
    for bad in ("off", 1, np.array([True, False])):  # checked as for a .pt file
        with pytest.raises(GazeAugError, match="mirror_average: expected None, True or False, got"):
            load_estimator(tmp_path / "on.onnx", mirror_average=bad)  # type: ignore[arg-type]
    capsys.readouterr()
    cmd = ["evaluate", str(tmp_path / "on.onnx"), str(data), "-o", str(tmp_path / "c"), "--mirror-average", "off"]
    assert main(cmd) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mirror averaging off needs the .pt model" in err[0]
    assert not (tmp_path / "c").exists()


# --------------------------------------------------------------------------- shift averaging


def _pixel_net(row, col):
    """A hand-made network: pitch = the left patch's channel 0 at (row, col); yaw = the right patch's there."""

    class Net(torch.nn.Module):
        def forward(self, left, right, head):
            return torch.stack([left[:, 0, row, col], right[:, 0, row, col]], dim=1)

    return Net()


def test_shift_average_by_hand():
    from gazeaug.models.shift import shift_averaged, shift_offsets

    assert shift_offsets(0) == ()
    assert shift_offsets(2)[0] == (0, 0) and len(set(shift_offsets(2))) == 9
    assert set(shift_offsets(2)) == {(dy, dx) for dy in (-2, 0, 2) for dx in (-2, 0, 2)}
    # patch value 10 * row + column (5 x 6). Inside, at (2, 2), 1 px: content moved dy down and dx right
    # puts there the value from (2 - dy, 2 - dx): rows 1, 2, 3 and columns 1, 2, 3 each thrice, mean 22
    # for the identity; for its square, mean over a, b in {1, 2, 3} of (10 a + b)^2 =
    # (100 * 14 + 2 * 10 * 6 * 6 / 3 * ... ) computed term by term: sum of (10a+b)^2 = 100 * 3 * 14 + 20 * 6 * 6
    # + 3 * 14 = 4200 + 720 + 42 = 4962, over 9: 551.333...
    grid = (10 * torch.arange(5.0)[:, None] + torch.arange(6.0)[None, :]).expand(1, 3, 5, 6)
    head = torch.zeros(1, 2)
    got = shift_averaged(_pixel_net(2, 2), 1)(grid, grid**2, head)
    np.testing.assert_allclose(got.numpy(), [[22.0, 4962 / 9]], rtol=1e-6)
    # at the corner (0, 0) the translations read outside the patch: filled by reflection (as the training's
    # translations fill it), the row above row 0 is row 1, so rows {1, 0, 1} and columns {1, 0, 1}:
    # mean of 10 r + c = 10 * 2/3 + 2/3 = 22/3
    got = shift_averaged(_pixel_net(0, 0), 1)(grid, grid, head)
    np.testing.assert_allclose(got.numpy(), [[22 / 3, 22 / 3]], rtol=1e-6)
    # 2 px at (2, 3): rows {0, 2, 4}, columns {1, 3, 5}: mean 10 * 2 + 3 = 23
    got = shift_averaged(_pixel_net(2, 3), 2)(grid, grid, head)
    np.testing.assert_allclose(got.numpy(), [[23.0, 23.0]], rtol=1e-6)
    with pytest.raises(GazeAugError, match="shift_average_px: expected an integer from 0 to 8, got 9"):
        shift_averaged(_pixel_net(0, 0), 9)
    net = _pixel_net(0, 0)
    assert shift_averaged(net, 0) is net  # 0: no averaging, the network itself
    # an empty batch gives an empty answer
    assert shift_averaged(_pixel_net(2, 2), 1)(grid[:0], grid[:0], head[:0]).shape == (0, 2)


def test_shift_average_is_recorded_applied_and_checked(tmp_path, capsys):
    data = _synthetic_h5(tmp_path / "t.h5", n=32)
    args = ["train", str(data), "--epochs", "1", "--batch-size", "16", "--quiet"]
    assert main([*args, "-o", str(tmp_path / "d.pt")]) == 0  # the default: 3 px, inside the mirror averaging
    model, meta = load_model(tmp_path / "d.pt")
    assert meta["prediction"] == {"mirror_average": True, "shift_average_px": 3} and meta["shift_average_px"] == 3
    assert type(model.net).__name__ == "ShiftAveraged" and model.net.shift_average_px == 3
    assert main([*args, "-o", str(tmp_path / "s1.pt"), "--shift-average", "1", "--no-mirror-average"]) == 0
    model1, meta1 = load_model(tmp_path / "s1.pt")
    assert type(model1).__name__ == "ShiftAveraged" and meta1["shift_average_px"] == 1
    # the plain network's answers on the 9 translated patches, averaged, are the model's
    from gazeaug.models.preprocess import prepare_inputs

    rng = np.random.default_rng(2)
    left = rng.integers(0, 255, (3, 36, 60, 3), dtype=np.uint8)
    right = rng.integers(0, 255, (3, 36, 60, 3), dtype=np.uint8)
    head = rng.uniform(-0.3, 0.3, (3, 2))
    a, b, c = prepare_inputs(left, right, head)
    with torch.no_grad():
        answers = []
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                pad = [np.pad(x, ((0, 0), (1, 1), (1, 1), (0, 0)), mode="reflect") for x in (left, right)]
                moved = [p[:, 1 - dy : 1 - dy + 36, 1 - dx : 1 - dx + 60] for p in pad]
                answers.append(model1.net(*prepare_inputs(moved[0], moved[1], head)).numpy())
    np.testing.assert_allclose(predict_arrays(model1, left, right, head), np.mean(answers, axis=0), atol=1e-5)
    # patches of another size than the file's: refused in words
    with pytest.raises(GazeAugError, match=r"left eye patches: the model reads 60 x 36 px ones, got 1 x 1"):
        predict_arrays(model1, left[:, :1, :1], right[:, :1, :1], head)
    # a network of no recorded size (one being trained), patches no larger than the translation: refused
    # in words, not by the padding's own error
    del model1.patch_size_wh
    with pytest.raises(GazeAugError, match=r"translations of 1 px, so their sides must exceed it, got 1 x 1"):
        predict_arrays(model1, left[:, :1, :1], right[:, :1, :1], head)
    # a file from before the entry predicts unshifted; bad entries are refused in one message
    obj = torch.load(tmp_path / "s1.pt", weights_only=True)
    obj["prediction"] = {"mirror_average": False}
    torch.save(obj, tmp_path / "old.pt")
    assert load_model(tmp_path / "old.pt")[1]["shift_average_px"] == 0
    for bad, why in (
        (9, "'prediction': expected"),
        (-1, "'prediction': expected"),
        (True, "'prediction': expected"),
        (2.0, "'prediction': expected"),
    ):
        obj["prediction"] = {"mirror_average": False, "shift_average_px": bad}
        torch.save(obj, tmp_path / "bad.pt")
        with pytest.raises(GazeAugError, match=why):
            load_model(tmp_path / "bad.pt")
    obj["prediction"] = {"mirror_average": False, "shift_average_px": 8}
    obj["patch_size_wh"] = [8, 8]
    torch.save(obj, tmp_path / "small.pt")
    with pytest.raises(GazeAugError, match=r"shift_average_px 8 must be smaller than the patch's sides \[8, 8\]"):
        load_model(tmp_path / "small.pt")
    # out of range on the command line: one line, exit 2, nothing written
    capsys.readouterr()
    assert main([*args, "-o", str(tmp_path / "x.pt"), "--shift-average", "9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "shift_average_px: expected an integer from 0 to 8 pixels, got 9" in err[0]
    assert not (tmp_path / "x.pt").exists()
    # eye patches 4 px on a side take at most 3 px: refused before the training, not by the model's loader after it
    tiny = tmp_path / "tiny.h5"
    with h5py.File(data, "r") as f, h5py.File(tiny, "w") as g:
        for k in f:
            if k in ("left_eye", "right_eye"):
                g.create_dataset(k, data=f[k][:, :4, :4])
            else:
                f.copy(f[k], g, name=k)
        for k, v in f.attrs.items():
            g.attrs[k] = v
        settings = json.loads(f.attrs["settings"])
        settings["normalization"]["patch_size_wh"] = [4, 4]
        g.attrs["settings"] = json.dumps(settings)
    with pytest.raises(
        GazeAugError, match=r"shift_average_px: 4 px must be smaller than the eye patches' sides \(4 x 4"
    ):
        train(tiny, tmp_path / "y.pt", TrainSettings(epochs=1, batch_size=16, shift_average_px=4), progress=False)
    assert not (tmp_path / "y.pt").exists()


def test_a_model_of_another_signature_or_output_is_refused_before_training(tmp_path, monkeypatch):
    from gazeaug.models import MODELS, register_model

    monkeypatch.setattr(MODELS, "_entries", dict(MODELS._entries))  # the test's models leave with the test

    class TwoInputs(torch.nn.Module):  # forward(left, right): no head pose
        def __init__(self):
            super().__init__()
            self.w = torch.nn.Parameter(torch.zeros(()))

        def forward(self, left, right):
            return self.w * left.mean(dim=(1, 2, 3))[:, None].repeat(1, 2)

    class ThreeOutputs(TwoInputs):
        def forward(self, left, right, head_pose):
            return self.w * torch.cat([head_pose, head_pose[:, :1]], dim=1)

    register_model("test_two_inputs")(TwoInputs)
    register_model("test_three_outputs")(ThreeOutputs)
    data = _synthetic_h5(tmp_path / "s.h5", n=16)
    refusals = (
        ("test_two_inputs", "cannot read this set's eye patches 60 x 36 px"),
        ("test_three_outputs", "got (2, 3)"),
    )
    for name, phrase in refusals:
        with pytest.raises(GazeAugError, match=re.escape(phrase)):
            train(data, tmp_path / f"{name}.pt", TrainSettings(model=name, epochs=1, batch_size=8), progress=False)
        assert not (tmp_path / f"{name}.pt").exists()


# --------------------------------------------------------------------------- the face patch as an input


def test_a_model_that_cannot_read_the_sets_patches_is_refused_in_one_line_before_training(tmp_path):
    """face_pool 8 on a 6 x 6 face patch pools it to nothing; PyTorch's error would come mid-step."""
    data = _synthetic_h5(tmp_path / "f.h5", n=16, face_size=(6, 6))
    opts = {"face": True, "face_pool": 8}
    refused = r"cannot read this set's eye patches 60 x 36 px, face patches 6 x 6 px"
    with pytest.raises(GazeAugError, match=refused) as e:
        train(data, tmp_path / "f.pt", TrainSettings(epochs=1, batch_size=8, model_options=opts), progress=False)
    assert "\n" not in str(e.value) and "face_pool" in str(e.value)
    assert not (tmp_path / "f.pt").exists() and not (tmp_path / "f.ckpt.pt").exists()
    # the same pool on a face patch it fits trains
    fits = _synthetic_h5(tmp_path / "g.h5", n=16, face_size=(16, 16))
    train(fits, tmp_path / "g.pt", TrainSettings(epochs=1, batch_size=8, model_options=opts), progress=False)
    assert (tmp_path / "g.pt").exists()


def test_a_face_model_reads_the_face_patch(tmp_path):
    from facemesh.conventions import MIRROR_PITCHYAW, mirrored_columns
    from gazeaug.models import uses_face

    m = create_model("mobilenet_gaze", face=True, face_pool=1)
    assert uses_face(m) and not uses_face(create_model("mobilenet_gaze"))
    left, right, head, face = prepare_inputs(
        np.zeros((2, 36, 60, 3), np.uint8),
        np.zeros((2, 36, 60, 3), np.uint8),
        np.zeros((2, 2)),
        face=np.zeros((2, 48, 48, 3), np.uint8),
    )
    assert face.shape == (2, 3, 48, 48) and m(left, right, head, face).shape == (2, 2)
    with pytest.raises(GazeAugError, match="face patch"):
        m(left, right, head)
    face.requires_grad_(True)  # the face goes into the answer
    m(left, right, head, face).sum().backward()
    assert float(face.grad.abs().sum()) > 0
    with pytest.raises(GazeAugError, match="face_pool"):
        create_model("mobilenet_gaze", face=True, face_pool=0)
    # trained on a set with face patches (brightness there encodes the yaw), saved, loaded
    data = _synthetic_h5(tmp_path / "f.h5", n=32, face_size=(48, 48))
    log = train(
        data, tmp_path / "f.pt", TrainSettings(epochs=2, batch_size=16, model_options={"face": True}), progress=False
    )
    assert len(log) == 2
    model, meta = load_model(tmp_path / "f.pt")
    assert uses_face(model) and meta["normalization"]["face_patch_size_wh"] == [48, 48]
    rng = np.random.default_rng(2)
    left = rng.integers(0, 255, (4, 36, 60, 3), dtype=np.uint8)
    right = rng.integers(0, 255, (4, 36, 60, 3), dtype=np.uint8)
    face = rng.integers(0, 255, (4, 48, 48, 3), dtype=np.uint8)
    for p in (left, right, face):
        p[:, :, 0] = p[:, :, 1]  # mirroring twice gives the patch back (column 0's source lies outside)
    head = rng.uniform(-0.3, 0.3, (4, 2))
    plain = predict_arrays(model, left, right, head, face=face)
    # the mirror-averaged face model is mirror-equivariant, the face mirrored with the eyes (its face
    # reading is too weak after 2 epochs to catch an unmirrored face: the test by hand below does)
    cols, fcols = mirrored_columns(60), mirrored_columns(48)
    mirrored = predict_arrays(
        model, right[:, :, cols], left[:, :, cols], head * MIRROR_PITCHYAW, face=face[:, :, fcols]
    )
    np.testing.assert_allclose(mirrored, plain * MIRROR_PITCHYAW, atol=1e-5)
    # without a face patch, or with one of another size, it is refused
    with pytest.raises(GazeAugError, match="face patch"):
        predict_arrays(model, left, right, head)
    with pytest.raises(GazeAugError, match="face patches: the model reads 48 x 48 px ones, got 48 x 40"):
        predict_arrays(model, left, right, head, face=face[:, :40])
    # a validation set whose face camera differs from the training set's is refused before training
    with pytest.raises(GazeAugError, match="differ from the training set's"):
        train(
            data,
            tmp_path / "v.pt",
            TrainSettings(epochs=1, batch_size=16, model_options={"face": True}),
            val_path=_synthetic_h5(tmp_path / "v.h5", n=16, face_size=(40, 32)),
            progress=False,
        )
    # an eyes-only model trained on a set with face patches is not given any at test time
    from gazeaug.estimator import load_estimator
    from gazeaug.evaluate import settings_from_meta

    train(data, tmp_path / "eyes.pt", TrainSettings(epochs=1, batch_size=16), progress=False)
    eyes_only, eyes_meta = load_model(tmp_path / "eyes.pt")
    assert not eyes_meta["uses_face"] and eyes_meta["normalization"]["face_patch_size_wh"] == [48, 48]
    assert settings_from_meta(eyes_meta).face_patch_size_wh is None
    assert load_estimator(tmp_path / "eyes.pt").normalization.face_patch_size_wh is None
    assert settings_from_meta(meta).face_patch_size_wh == (48, 48)
    # a set without face patches cannot train it, nor can a file whose normalization makes none load it
    with pytest.raises(GazeAugError, match="has none"):
        train(
            _synthetic_h5(tmp_path / "e.h5", n=32),
            tmp_path / "x.pt",
            TrainSettings(epochs=1, batch_size=16, model_options={"face": True}),
            progress=False,
        )
    obj = torch.load(tmp_path / "f.pt", weights_only=True)
    obj["normalization"] = {k: v for k, v in obj["normalization"].items() if not k.startswith("face")}
    torch.save(obj, tmp_path / "stripped.pt")
    with pytest.raises(GazeAugError, match="makes none"):
        load_model(tmp_path / "stripped.pt")


def test_mirror_average_mirrors_the_face_by_hand():
    from gazeaug.models.mirror import mirror_averaged

    class FaceColumnNet(torch.nn.Module):
        """pitch 0; yaw = (the face's bright column - w / 2) / 100: it reads the face alone."""

        uses_face = True

        def forward(self, left, right, head, face):
            w = face.shape[-1]
            profile = face.mean(dim=(1, 2))
            x = (profile * torch.arange(w, dtype=face.dtype)).sum(-1) / profile.sum(-1)
            return torch.stack([torch.zeros_like(x), (x - w / 2) / 100], dim=1)

    # face 48 wide, bright column 10: plain yaw (10 - 24) / 100 = -0.14. The mirrored face has it at
    # 48 - 10 = 38 (column x from w - x): yaw +0.14, negated back -0.14; the average -0.14. Were the
    # face not mirrored, the second pass would give -0.14, negated +0.14, and the average 0.
    face = torch.zeros(1, 3, 32, 48)
    face[..., 10] = 1.0
    eyes = torch.ones(1, 3, 36, 60)
    got = mirror_averaged(FaceColumnNet())(eyes, eyes, torch.zeros(1, 2), face)
    np.testing.assert_allclose(got.numpy(), [[0.0, -0.14]], atol=1e-6)


def test_a_face_model_exports_to_onnx_with_a_face_input(tmp_path, capsys):
    pytest.importorskip("onnxruntime")
    from gazeaug.estimator import load_estimator

    data = _synthetic_h5(tmp_path / "f.h5", n=32, face_size=(40, 32))
    assert main(["train", str(data), "-o", str(tmp_path / "f.pt"), "--face", "--epochs", "1", "--quiet"]) == 0
    assert main(["export", str(tmp_path / "f.pt"), "-o", str(tmp_path / "f.onnx")]) == 0
    capsys.readouterr()
    d = H5TrainingSet(data).read(["left_eye", "right_eye", "head_pose", "face"])
    pt, ox = load_estimator(tmp_path / "f.pt"), load_estimator(tmp_path / "f.onnx")
    assert pt.uses_face and ox.uses_face
    a = pt.predict(d["left_eye"], d["right_eye"], d["head_pose"], d["face"])
    b = ox.predict(d["left_eye"], d["right_eye"], d["head_pose"], d["face"])
    np.testing.assert_allclose(a, b, atol=1e-5)
    with pytest.raises(GazeAugError, match="face patch"):
        ox.predict(d["left_eye"], d["right_eye"], d["head_pose"])
    with pytest.raises(GazeAugError, match=r"face patches: the model reads 40 x 32 px ones, got 20 x 32"):
        ox.predict(d["left_eye"], d["right_eye"], d["head_pose"], d["face"][:, :, :20])


def test_chunked_columns_read_what_h5py_reads(tmp_path):
    import zlib
    from concurrent.futures import ThreadPoolExecutor

    from gazeaug.io_h5 import ChunkedColumn

    rng = np.random.default_rng(0)
    rows = rng.integers(0, 255, (300, 6, 5, 3), dtype=np.uint8)
    path = tmp_path / "layouts.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("gzip", data=rows, chunks=(64, 6, 5, 3), compression="gzip")  # as our writer stores
        f.create_dataset("shuffled", data=rows, chunks=(64, 6, 5, 3), compression="gzip", shuffle=True)
        f.create_dataset("plain", data=rows)  # contiguous
        f.create_dataset("tiled", data=rows, chunks=(64, 3, 5, 3), compression="gzip")  # a chunk: half a row
        raw = f.create_dataset("skipped", shape=rows.shape, dtype=np.uint8, chunks=(64, 6, 5, 3), compression="gzip")
        for c in range(5):  # stored without the deflate filter (filter mask 1), as HDF5 may store a chunk
            block = np.zeros((64, 6, 5, 3), np.uint8)
            block[: len(rows[64 * c : 64 * c + 64])] = rows[64 * c : 64 * c + 64]
            raw.id.write_direct_chunk((64 * c, 0, 0, 0), block.tobytes(), filter_mask=1)
        bad = f.create_dataset("damaged", shape=rows.shape, dtype=np.uint8, chunks=(64, 6, 5, 3), compression="gzip")
        bad[...] = rows
        bad.id.write_direct_chunk((64, 0, 0, 0), b"not deflate at all")
        mangled = f.create_dataset(  # a layout h5py reads (shuffle + gzip), one chunk damaged
            "mangled", shape=rows.shape, dtype=np.uint8, chunks=(64, 6, 5, 3), compression="gzip", shuffle=True
        )
        mangled[...] = rows
        mangled.id.write_direct_chunk((64, 0, 0, 0), b"not deflate at all")
        short = f.create_dataset("short", shape=rows.shape, dtype=np.uint8, chunks=(64, 6, 5, 3), compression="gzip")
        short[...] = rows
        short.id.write_direct_chunk((0, 0, 0, 0), zlib.compress(bytes(100)))
        sparse = f.create_dataset("sparse", shape=rows.shape, dtype=np.uint8, chunks=(64, 6, 5, 3), compression="gzip")
        sparse[64:128] = rows[64:128]  # the other chunks never written: h5py gives the fill value, 0
        words = np.array([f"w{i}" * (i % 5) for i in range(300)], dtype=object)
        f.create_dataset("words", data=words, dtype=h5py.string_dtype(), chunks=(64,), compression="gzip")
    spans = [(0, 1), (5, 200), (63, 65), (128, 192), (290, 300), (0, 300), (64, 64)]
    with h5py.File(path, "r") as f, ThreadPoolExecutor(2) as pool:
        for key, direct in (("gzip", True), ("skipped", True), ("shuffled", False), ("plain", False), ("tiled", False)):
            for p in (pool, None):
                col = ChunkedColumn(f[key], p)
                assert col.direct is (direct and p is not None), key
                for (lo, hi), got in zip(spans, col.read_runs(spans)):
                    np.testing.assert_array_equal(got, rows[lo:hi], err_msg=f"{key} {lo}:{hi}")
        col = ChunkedColumn(f["sparse"], pool)
        assert col.direct
        filled = np.zeros_like(rows)
        filled[64:128] = rows[64:128]
        for (lo, hi), got in zip(spans, col.read_runs(spans)):
            np.testing.assert_array_equal(got, filled[lo:hi])
        col = ChunkedColumn(f["words"], pool)  # variable-length strings: h5py reads them
        assert not col.direct
        assert [w.decode() for w in col.read_runs([(3, 9)])[0]] == [str(w) for w in words[3:9]]
        with pytest.raises(GazeAugError, match=r"layouts\.h5: /damaged chunk 1 is damaged"):
            ChunkedColumn(f["damaged"], pool).read_runs([(60, 70)])
        with pytest.raises(GazeAugError, match=r"/short chunk 0 holds 100 bytes, expected 5760"):
            ChunkedColumn(f["short"], pool).read_runs([(0, 10)])
        for p in (pool, None):  # h5py's own error, named: the file, the dataset, the rows
            with pytest.raises(
                GazeAugError, match=r"layouts\.h5: /mangled rows 60-69: cannot be read, the file is damaged"
            ):
                ChunkedColumn(f["mangled"], p).read_runs([(0, 10), (60, 70)])


def test_a_partial_edge_chunk_stored_unfiltered_is_read_as_it_is(tmp_path):
    # HDF5 may store the last, partial chunk without its filters (H5D_CHUNK_DONT_FILTER_PARTIAL_CHUNKS)
    # while its filter mask says 0: the reader must take its bytes as they are
    from concurrent.futures import ThreadPoolExecutor

    from gazeaug.io_h5 import ChunkedColumn

    path = _synthetic_h5(tmp_path / "edge.h5", n=100)
    with h5py.File(path, "r+") as f:
        d = f["left_eye"]
        k = d.chunks[0]
        assert 100 % k and d.compression == "gzip"
        want = d[()]
        edge = np.zeros((k, *d.shape[1:]), np.uint8)
        edge[: 100 - (100 // k) * k] = want[(100 // k) * k :]
        d.id.write_direct_chunk(((100 // k) * k, 0, 0, 0), edge.tobytes(), filter_mask=0)
    with h5py.File(path, "r") as f, ThreadPoolExecutor(2) as pool:
        col = ChunkedColumn(f["left_eye"], pool)
        assert col.direct
        np.testing.assert_array_equal(np.concatenate(col.read_runs([(0, 100)])), want)
    with h5py.File(path, "r+") as g:  # a chunk that is not the edge and does not inflate is still damaged
        g["left_eye"].id.write_direct_chunk((0, 0, 0, 0), b"\x00" * 10, filter_mask=0)
    with h5py.File(path, "r") as f, ThreadPoolExecutor(2) as pool:
        with pytest.raises(GazeAugError, match="chunk 0 is damaged"):
            ChunkedColumn(f["left_eye"], pool).read_runs([(0, 10)])


def test_patches_other_than_uint8_and_absurd_sample_counts_are_refused(tmp_path):
    path = _synthetic_h5(tmp_path / "f.h5", n=40)
    with h5py.File(path, "r+") as f:
        eyes = f["right_eye"][()].astype(np.float32)
        del f["right_eye"]
        f.create_dataset("right_eye", data=eyes)
    with pytest.raises(GazeAugError, match=r"/right_eye: expected uint8 RGB patches, got float32"):
        H5TrainingSet(path)
    TrainSettings(auto_samples=10**12)
    with pytest.raises(GazeAugError, match="auto_samples: expected an integer from 1 to 1e\\+12"):
        TrainSettings(auto_samples=10**13)


def test_the_patch_size_recorded_agrees_with_the_patches(tmp_path):
    """A set whose recorded normalization makes other patches than it holds is refused before training;
    a set that records none trains with the defaults at its patches' size, and the model reads that size."""
    import h5py

    from gazeaug.io_h5 import H5Writer, Rows, read_h5

    src = read_h5(_synthetic_h5(tmp_path / "t.h5", n=32))
    arrays = {k: v for k, v in src.items() if k != "attrs"}
    for side in ("left_eye", "right_eye"):
        arrays[side] = np.pad(arrays[side], ((0, 0), (2, 2), (2, 2), (0, 0)), mode="edge")  # 64 x 40
    for name, attrs in (("recorded", {"settings": {"normalization": {"patch_size_wh": [60, 36]}}}), ("none", {})):
        w = H5Writer(tmp_path / f"{name}.h5", attrs, (64, 40))
        w.append(Rows(arrays), 31)
        w.finish()
    with h5py.File(tmp_path / "none.h5", "a") as f:  # as a user's own set: no settings attribute at all
        f.attrs.pop("settings", None)
    with pytest.raises(GazeAugError, match=r"its eye patches are 64 x 40 px, its recorded normalization makes 60 x 36"):
        train(tmp_path / "recorded.h5", tmp_path / "r.pt", TrainSettings(epochs=1, batch_size=16), progress=False)
    assert not (tmp_path / "r.pt").exists()
    train(tmp_path / "none.h5", tmp_path / "n.pt", TrainSettings(epochs=1, batch_size=16), progress=False)
    model, meta = load_model(tmp_path / "n.pt")
    assert meta["normalization"]["patch_size_wh"] == [64, 40] and model.patch_size_wh == (64, 40)
    assert predict_arrays(model, arrays["left_eye"], arrays["right_eye"], arrays["head_pose"]).shape == (32, 2)


def test_wide_model_is_the_measured_configuration_and_trains_from_the_cli(tmp_path):
    """``mobilenet_gaze_wide`` is the network docs/model.md measured (written out here), by name in a model file."""
    from gazeaug.models.mobilenet import mobilenet_gaze

    measured = dict(stem=16, hidden=256, blocks=((1, 16, 1), (4, 24, 2), (4, 32, 2), (4, 48, 1), (4, 64, 2)))
    wide = create_model("mobilenet_gaze_wide").state_dict()
    ref = mobilenet_gaze(**measured).state_dict()
    assert {k: tuple(v.shape) for k, v in wide.items()} == {k: tuple(v.shape) for k, v in ref.items()}
    assert 80_000 < sum(v.numel() for k, v in wide.items() if "running" not in k and "num_batches" not in k) < 82_000
    data = _synthetic_h5(tmp_path / "t.h5", n=64)
    out = tmp_path / "w.pt"
    assert main(["train", str(data), "-o", str(out), "--epochs", "1", "--model", "mobilenet_gaze_wide", "--quiet"]) == 0
    model, meta = load_model(out)
    assert meta["model"] == "mobilenet_gaze_wide" and meta["model_options"] == {}
    assert sum(p.numel() for p in model.parameters()) == sum(
        p.numel() for p in create_model("mobilenet_gaze_wide").parameters()
    )
    assert main(["evaluate", str(out), str(data), "-o", str(tmp_path / "ev"), "--quiet"]) == 0
