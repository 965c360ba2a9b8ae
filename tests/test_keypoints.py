"""Eye keypoints: the HDF5 column, their moves with the training-time augmentation, the head and its loss.

Expected values are derived by hand (a bright dot's new place, a mirror about the principal
point, the loss of a few numbers), never from the code's own output.
"""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import torch
from helpers import synthetic_h5

from gazeaug.errors import GazeAugError
from gazeaug.io_h5 import H5TrainingSet, H5Writer, Rows
from gazeaug.models import create_model
from gazeaug.models.keypoints import attach_keypoint_head, keypoint_loss
from gazeaug.train import TrainSettings, load_model, train
from gazeaug.train_augment import TrainAugment, augment_eyes_and_points, augment_generator, mirror_samples


def _with_keypoints(path, n, known_from=0):
    """Add ``eye_keypoints`` to a synthetic set: row i's points (i % 60, 10 + eye + point); rows < known_from NaN."""
    kp = np.zeros((n, 2, 2, 2), np.float32)
    for i in range(n):
        for e in range(2):
            for k in range(2):
                kp[i, e, k] = [i % 60, 10 + e + k]
    kp[:known_from] = np.nan
    with h5py.File(path, "a") as f:
        f.create_dataset("eye_keypoints", data=kp)
    return kp


def test_the_column_is_written_read_and_checked(tmp_path):
    src = synthetic_h5(tmp_path / "src.h5", n=10)
    with h5py.File(src, "r") as f:
        arrays = {k: f[k][()] for k in f if k != "sources"}
    kp = np.arange(10 * 8, dtype=np.float32).reshape(10, 2, 2, 2)
    kp[3] = np.nan  # a source's own row: unknown
    out = tmp_path / "kp.h5"
    w = H5Writer(out, {"settings": {}}, (60, 36), eye_keypoints=True)
    w.append(Rows({**arrays, "eye_keypoints": kp}), 9)
    w.finish()
    data = H5TrainingSet(out)
    assert data.has_eye_keypoints and not H5TrainingSet(src).has_eye_keypoints
    np.testing.assert_array_equal(data.eye_keypoints(), kp)
    # batches carry them row for row, in the order of the other columns
    keys = H5TrainingSet.batch_keys(False, keypoints=True)
    assert keys[-1] == "eye_keypoints"
    for batch in data.batches(4, np.random.default_rng(0), keys):
        for g, p in zip(batch["gaze"], batch["eye_keypoints"]):
            row = int(np.flatnonzero((arrays["gaze"] == g).all(axis=1))[0])
            np.testing.assert_array_equal(p, kp[row])
    with pytest.raises(GazeAugError, match="no eye keypoints"):
        next(H5TrainingSet(src).batches(4, None, keys))
    # a shard with them does not join an output without them
    plain = H5Writer(tmp_path / "plain.h5", {"settings": {}}, (60, 36))
    with pytest.raises(GazeAugError, match="the shard has eye keypoints, the output not"):
        plain.append_file(out)
    plain.discard()
    # a column of another shape is refused when the set is opened
    with h5py.File(src, "a") as f:
        f.create_dataset("eye_keypoints", data=np.zeros((10, 2, 2), np.float32))
    with pytest.raises(GazeAugError, match=r"/eye_keypoints: expected float \(10, 2, 2, 2\) px"):
        H5TrainingSet(src)


def test_an_older_part_file_without_the_column_is_not_resumed(tmp_path):
    out = tmp_path / "o.h5"
    w = H5Writer(out, {"settings": {"a": 1}}, (60, 36))
    w.close()  # an interrupted run of a gazeaug without the column
    with pytest.raises(GazeAugError, match=r"without the column\(s\) \['eye_keypoints'\]; delete it to start over"):
        H5Writer(out, {"settings": {"a": 1}}, (60, 36), eye_keypoints=True, resume=True)


def _dots(points, h=36, w=60):
    """(N, H, W, 3) uint8 dark patches with a white pixel at each (u, v) of ``points`` ((N, 2) whole numbers)."""
    eyes = torch.zeros((len(points), h, w, 3), dtype=torch.uint8)
    for i, (u, v) in enumerate(points):
        eyes[i, int(v), int(u)] = 255
    return eyes


def _bright_centroid(x):
    """(N, 2) (u, v): the brightness-weighted centroid of each float (N, 3, H, W) patch."""
    grey = x.mean(dim=1)
    grey = grey * (grey > 20)  # the dot, not the noise-free dark ground
    vs, us = torch.meshgrid(torch.arange(grey.shape[1]), torch.arange(grey.shape[2]), indexing="ij")
    total = grey.sum(dim=(1, 2))
    return torch.stack([(grey * us).sum(dim=(1, 2)) / total, (grey * vs).sum(dim=(1, 2)) / total], dim=1)


def test_points_move_with_the_translation_and_the_zoom():
    points = torch.tensor([[20.0, 12.0], [41.0, 25.0], [30.0, 18.0], [12.0, 20.0]] * 8)
    eyes = _dots(points)
    only_moves = dict(blur_sigma=0.0, colour=0.0, contrast=0.0, brightness=0.0, gamma=0.0, noise=0.0)
    # translation alone: the dot lands exactly where the moved point says
    x, moved = augment_eyes_and_points(
        eyes, points[:, None], TrainAugment(shift_px=4, **only_moves), augment_generator(0, 0)
    )
    assert not torch.equal(moved[:, 0], points)  # it did move
    np.testing.assert_allclose(_bright_centroid(x).numpy(), moved[:, 0].numpy(), atol=1e-4)
    # with a zoom (bilinear: the dot spreads, its centroid stays within a fraction of a pixel)
    aug = TrainAugment(shift_px=3, scale=0.2, **only_moves)
    x, moved = augment_eyes_and_points(eyes, points[:, None], aug, augment_generator(1, 0))
    np.testing.assert_allclose(_bright_centroid(x).numpy(), moved[:, 0].numpy(), atol=0.35)
    # the zoom by hand: f about (30, 18), then the shift; the patches are the same with or without points
    g1, g2 = augment_generator(2, 0), augment_generator(2, 0)
    x1, moved = augment_eyes_and_points(
        eyes[:1], torch.tensor([[[40.0, 18.0]]]), TrainAugment(shift_px=0, scale=0.5), g1
    )
    x2, none = augment_eyes_and_points(eyes[:1], None, TrainAugment(shift_px=0, scale=0.5), g2)
    assert none is None and torch.equal(x1, x2)
    f = (moved[0, 0, 0] - 30.0) / 10.0
    assert 0.5 <= float(f) <= 1.5 and float(moved[0, 0, 1]) == pytest.approx(18.0)
    # NaN (unknown) stays NaN; augmentation off leaves the points
    _, moved = augment_eyes_and_points(eyes[:1], torch.full((1, 1, 2), float("nan")), aug, augment_generator(0, 0))
    assert torch.isnan(moved).all()
    _, same = augment_eyes_and_points(eyes[:4], points[:4, None], TrainAugment(enabled=False), augment_generator(0, 0))
    assert torch.equal(same[:, 0], points[:4])


def test_a_mirrored_sample_swaps_its_eyes_points_and_mirrors_u():
    # one sample: left eye points (20, 10), (25, 12); right eye (40, 11), (33, 14); mirrored about u = 30
    kp = torch.tensor([[[[20.0, 10.0], [25.0, 12.0]], [[40.0, 11.0], [33.0, 14.0]]]])
    eyes = torch.zeros((2, 36, 60, 3), dtype=torch.uint8)
    _, _, _, _, out = mirror_samples(
        eyes, torch.zeros(1, 2), torch.zeros(1, 2), TrainAugment(mirror=1.0), augment_generator(0, 0), keypoints=kp
    )
    want = torch.tensor([[[[20.0, 11.0], [27.0, 14.0]], [[40.0, 10.0], [35.0, 12.0]]]])
    assert torch.equal(out, want)
    # the dot follows: the right eye's dot at (40, 11) becomes the left patch's dot at (20, 11)
    eyes[1, 11, 40] = 255
    e, _, _, _, _ = mirror_samples(
        eyes, torch.zeros(1, 2), torch.zeros(1, 2), TrainAugment(mirror=1.0), augment_generator(0, 0)
    )
    assert e[0, 11, 20, 0] == 255
    # not mirrored: untouched
    _, _, _, _, same = mirror_samples(
        eyes, torch.zeros(1, 2), torch.zeros(1, 2), TrainAugment(mirror=0.0), augment_generator(0, 0), keypoints=kp
    )
    assert torch.equal(same, kp)


def test_the_loss_by_hand():
    pred = torch.tensor([[[1.0, 2.0], [3.0, 4.0]]])
    target = torch.tensor([[[11.0, 2.0], [float("nan"), 0.0]]])
    # known: |1 - 11|, |2 - 2|, |4 - 0| over 3 values = 14 / 3 px, in units of 10 px
    assert float(keypoint_loss(pred, target)) == pytest.approx(14 / 3 / 10)
    none = keypoint_loss(pred.requires_grad_(), torch.full_like(pred, float("nan")))
    assert float(none.detach()) == 0.0 and none.requires_grad
    with pytest.raises(GazeAugError, match="expected predictions of shape"):
        keypoint_loss(pred[..., :1], target)


@pytest.mark.parametrize(("name", "map_hw"), [("mobilenet_gaze", (9, 15)), ("mobilenet_gaze_wide", (9, 15))])
def test_the_head_reads_the_encoders_stride_4_map(name, map_hw):
    torch.manual_seed(0)
    model = create_model(name)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    head, hook = attach_keypoint_head(model, (60, 36))
    assert {k: v for k, v in model.state_dict().items()}.keys() == before.keys()  # the dry pass changed nothing
    for k, v in model.state_dict().items():
        assert torch.equal(v, before[k]), k
    left, right = torch.rand(3, 3, 36, 60), torch.rand(3, 3, 36, 60)
    model(left, right, torch.zeros(3, 2))
    assert tuple(head.feature_map.shape[2:]) == map_hw
    pts = head()
    assert pts.shape == (6, 2, 2)
    # a soft-argmax over the cells' centres: inside the patch, the cells' centres at (j + 0.5) * 4 - 0.5
    assert float(head.us[0]) == pytest.approx(1.5) and float(head.us[-1]) == pytest.approx(57.5)
    assert float(head.vs[0]) == pytest.approx(1.5) and float(head.vs[-1]) == pytest.approx(33.5)
    assert bool(((pts[..., 0] >= 1.5) & (pts[..., 0] <= 57.5) & (pts[..., 1] >= 1.5) & (pts[..., 1] <= 33.5)).all())
    hook.remove()
    with pytest.raises(GazeAugError, match=r"model\.encoder\.features"):
        attach_keypoint_head(torch.nn.Linear(2, 2), (60, 36))


def test_training_with_the_loss_keeps_the_model_file_plain(tmp_path, monkeypatch):
    h5 = synthetic_h5(tmp_path / "t.h5", n=64)
    _with_keypoints(h5, 64, known_from=16)
    s = TrainSettings(epochs=2, batch_size=16, seed=1, keypoint_loss_weight=1.0)
    log = train(h5, tmp_path / "k.pt", s, progress=False)
    assert len(log) == 2 and np.isfinite(log[-1]["train_loss"])
    assert all(0 <= r["keypoint_error_px"] < 60 for r in log)
    model, meta = load_model(tmp_path / "k.pt")
    plain = create_model("mobilenet_gaze")
    assert set(torch.load(tmp_path / "k.pt", weights_only=True)["state_dict"]) == set(plain.state_dict())
    assert meta["train_settings"]["keypoint_loss_weight"] == 1.0
    ckpt = torch.load(tmp_path / "k.ckpt.pt", weights_only=True)
    assert "keypoint_head" in ckpt
    # the same run without the loss trains other weights (the head's gradient reaches the encoder)
    train(h5, tmp_path / "p.pt", TrainSettings(epochs=2, batch_size=16, seed=1), progress=False)
    a = torch.load(tmp_path / "k.pt", weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "p.pt", weights_only=True)["state_dict"]
    assert any(not torch.equal(a[k], b[k]) for k in a if k.startswith("encoder."))
    # interrupted after its first epoch and resumed: the same model as the uninterrupted run (the
    # head's weights and optimizer state come back from the checkpoint)
    import gazeaug.train as train_module

    real_save = train_module._save

    def save_then_stop(obj, path):
        real_save(obj, path)
        if obj.get("epoch") == 1:
            raise KeyboardInterrupt

    monkeypatch.setattr(train_module, "_save", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        train(h5, tmp_path / "r.pt", s, progress=False)
    monkeypatch.setattr(train_module, "_save", real_save)
    train(h5, tmp_path / "r.pt", s, progress=False, resume=True)
    r = torch.load(tmp_path / "r.pt", weights_only=True)["state_dict"]
    for k in a:
        assert torch.equal(a[k], r[k]), k


def test_the_loss_asks_for_a_set_with_keypoints(tmp_path):
    h5 = synthetic_h5(tmp_path / "t.h5", n=32)
    s = TrainSettings(epochs=1, batch_size=16, keypoint_loss_weight=0.5)
    with pytest.raises(GazeAugError, match="this set has none \\(make it with augment --redirect-eyes"):
        train(h5, tmp_path / "x.pt", s, progress=False)
    _with_keypoints(h5, 32, known_from=32)
    with pytest.raises(GazeAugError, match="every row's are unknown"):
        train(h5, tmp_path / "x.pt", s, progress=False)
    assert not (tmp_path / "x.pt").exists()
    for bad in (-1.0, 101.0, float("nan"), "1"):
        with pytest.raises(GazeAugError, match="keypoint loss weight: expected a number in \\[0, 100\\]"):
            TrainSettings(keypoint_loss_weight=bad)


def test_cli_train_keypoint_loss(tmp_path, capsys):
    from gazeaug.cli import main

    h5 = synthetic_h5(tmp_path / "t.h5", n=32)
    base = ["train", str(h5), "--epochs", "1", "--batch-size", "16", "--quiet"]
    assert main([*base, "-o", str(tmp_path / "a.pt"), "--keypoint-loss", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "eye keypoints" in err[0] and "--redirect-eyes" in err[0]
    assert main([*base, "-o", str(tmp_path / "b.pt"), "--keypoint-loss", "-1"]) == 2
    assert "keypoint loss weight" in capsys.readouterr().err
    _with_keypoints(h5, 32)
    assert main([*base, "-o", str(tmp_path / "c.pt"), "--keypoint-loss", "0.5"]) == 0
    assert load_model(tmp_path / "c.pt")[1]["train_settings"]["keypoint_loss_weight"] == 0.5
