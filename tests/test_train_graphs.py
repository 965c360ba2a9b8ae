"""CUDA graphs in training (gazeaug.train_graphs): the same training as eager steps, only faster.

The CUDA tests run where there is a GPU (CI has none: they are skipped there); the fallback runs anywhere.
"""

from __future__ import annotations

import pickle
import warnings

import numpy as np
import pytest
from helpers import synthetic_h5

from gazeaug import train as train_module
from gazeaug.models import create_model
from gazeaug.train import TrainSettings, load_model, train
from gazeaug.train_graphs import graph_model, quiet_stream_mismatch

torch = pytest.importorskip("torch")
cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


def test_graph_model_refuses_inputs_off_cuda():
    """Graphs are CUDA's: inputs on the CPU are a programming error, said with the device found."""
    model = create_model("mobilenet_gaze").train()
    x = torch.rand(4, 3, 36, 60)
    with pytest.raises(ValueError, match="expected the sample inputs on a CUDA device, got them on cpu"):
        graph_model(model, (x, x, torch.zeros(4, 2)))


def test_quiet_stream_mismatch_switches_the_warning_back_on():
    """Off inside, set back after (the switch observed through a stand-in)."""
    seen = []
    real = getattr(torch.autograd.graph, "set_warn_on_accumulate_grad_stream_mismatch", None)
    if real is None:
        pytest.skip("this PyTorch has no such warning")
    import unittest.mock

    with unittest.mock.patch.object(torch.autograd.graph, "set_warn_on_accumulate_grad_stream_mismatch", seen.append):
        with quiet_stream_mismatch(False):
            pass
        assert seen == []
        with pytest.raises(KeyError), quiet_stream_mismatch():
            assert seen == [False]
            raise KeyError("inside")
    assert seen == [False, True]  # off inside, then back to what it was (on, PyTorch's default)


def test_quiet_stream_mismatch_keeps_a_users_choice():
    """A warning the user switched off stays off after the context."""
    getter = getattr(torch._C, "_warn_on_accumulate_grad_stream_mismatch", None)
    switch = getattr(torch.autograd.graph, "set_warn_on_accumulate_grad_stream_mismatch", None)
    if getter is None or switch is None:
        pytest.skip("this PyTorch cannot say the warning's state")
    switch(False)
    try:
        with quiet_stream_mismatch():
            pass
        assert getter() is False
    finally:
        switch(True)
    with quiet_stream_mismatch():
        assert getter() is False
    assert getter() is True


@cuda
def test_graphed_training_equals_eager_training(tmp_path, monkeypatch):
    """Graphs on and off: the same log and weights (to floating point), the same BatchNorm step count.

    600 rows at batch 256: two full batches (replayed) and one of 88 rows (eager) per epoch, so
    each BatchNorm counts 3 epochs x 3 steps = 9 training forward passes; the capture's warm-up
    passes must not count (nor move the running statistics).
    """
    h5 = synthetic_h5(tmp_path / "t.h5", n=600)
    made = []

    def spy(model, args):
        g = graph_model(model, args)
        made.append(g)
        return g

    monkeypatch.setattr(train_module, "graph_model", spy)
    s = TrainSettings(epochs=3, batch_size=256, device="cuda", seed=3)
    logs, states = {}, {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for graphs in (True, False):
            out = tmp_path / f"m_{graphs}.pt"
            logs[graphs] = train(h5, out, s, progress=False, cuda_graphs=graphs)
            states[graphs] = load_model(out)[0].state_dict()
    assert not [w for w in caught if "AccumulateGrad" in str(w.message)]  # the intended mismatch is not warned of
    assert len(made) == 1 and made[0] is not None  # captured once, in the graphed run only
    for a, b in zip(logs[True], logs[False], strict=True):
        assert a["train_loss"] == pytest.approx(b["train_loss"], rel=2e-2)
        assert a["train_error_deg"] == pytest.approx(b["train_error_deg"], rel=2e-2, abs=0.2)
    for k, v in states[False].items():
        g = states[True][k]
        if k.endswith("num_batches_tracked"):
            assert int(g) == int(v) == 9, k
        else:
            scale = float(v.float().abs().max()) + 1e-3
            assert float((g.float() - v.float()).abs().max()) <= 2e-2 * scale, k


@cuda
def test_graphed_face_model_trains(tmp_path):
    """A model reading the face patch too (four inputs) is captured and trains to a finite loss."""
    h5 = synthetic_h5(tmp_path / "f.h5", n=300, face_size=(64, 64))
    s = TrainSettings(epochs=2, batch_size=128, device="cuda", model_options={"face": True})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = train(h5, tmp_path / "f.pt", s, progress=False)
    assert not [w for w in caught if "without CUDA graphs" in str(w.message)]  # no fallback to eager
    assert np.isfinite([r["train_loss"] for r in log]).all()


@cuda
def test_streamed_training_is_captured(tmp_path, monkeypatch):
    """Streamed from the file (a reading thread pinning memory): the capture, made before the
    epoch's reader starts, holds (made once, no fallback), and trains to a finite loss."""
    h5 = synthetic_h5(tmp_path / "s.h5", n=600)
    made = []

    def spy(model, args):
        made.append(graph_model(model, args))
        return made[-1]

    monkeypatch.setattr(train_module, "graph_model", spy)
    s = TrainSettings(epochs=2, batch_size=128, device="cuda", seed=1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = train(h5, tmp_path / "s.pt", s, progress=False, preload="no")
    assert not [w for w in caught if "without CUDA graphs" in str(w.message)]
    assert len(made) == 1 and made[0] is not None
    assert np.isfinite([r["train_loss"] for r in log]).all()


@pytest.mark.parametrize("face", [False, True])
@pytest.mark.parametrize("preload", ["yes", "no"])
@pytest.mark.parametrize("augmented", [False, True])
def test_placeholder_batch_is_shaped_as_a_real_one(tmp_path, face, preload, augmented):
    """The capture's placeholder is a real full batch's shapes, dtypes and strides (what a graph
    fixes), and so are the model inputs made of it, for held and streamed sets, with a face patch
    and without, augmented (mirrored too) or not."""
    from gazeaug.train_augment import TrainAugment, augment_generator
    from gazeaug.train_data import epoch_batches, hold_rows, placeholder_batch, train_inputs

    h5 = synthetic_h5(tmp_path / "p.h5", n=70, face_size=(20, 16) if face else None)
    data = train_module.H5TrainingSet(h5)
    cpu = torch.device("cpu")
    resident = hold_rows(data, cpu, face, preload)
    assert (resident is None) is (preload == "no")
    augment = TrainAugment(mirror=0.5) if augmented else TrainAugment(enabled=False)
    real = next(iter(epoch_batches(data, resident, 32, np.random.default_rng(0), face=face)))
    fake = placeholder_batch(data, 32, face=face)
    assert set(fake) == set(real) and not torch.count_nonzero(fake["eyes"])
    for k, w in real.items():
        g = fake[k]
        assert (g.shape, g.dtype, g.stride(), g.device) == (w.shape, w.dtype, w.stride(), w.device), k
    want = train_inputs(real, cpu, augment, "rgb", augment_generator(0, 0))
    got = train_inputs(fake, cpu, augment, "rgb", torch.Generator())
    assert (want.face is None) is (got.face is None) is (not face)
    assert want.eye_keypoints is None and got.eye_keypoints is None
    for w, g in zip(want, got, strict=True):
        if w is not None:
            assert (g.shape, g.dtype, g.stride()) == (w.shape, w.dtype, w.stride())


def test_placeholder_batch_refuses_a_face_the_set_lacks(tmp_path):
    from gazeaug.errors import GazeAugError
    from gazeaug.train_data import placeholder_batch

    data = train_module.H5TrainingSet(synthetic_h5(tmp_path / "n.h5", n=8))
    with pytest.raises(GazeAugError, match="expected face patches for a face model's batch, the set has none"):
        placeholder_batch(data, 4, face=True)


@cuda
def test_graph_model_falls_back_with_a_warning_and_leaves_the_model_as_it_was():
    """A model that cannot be captured (a host sync in its forward) gives None and one warning.

    The capture's warm-up passes ran (they moved its BatchNorm statistics): those are put back.
    The last CUDA test in this file: a failed capture is the one that could disturb the others.
    """

    class Syncing(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.bn = torch.nn.BatchNorm2d(3)
            self.fc = torch.nn.Linear(3, 2)

        def forward(self, a, b, c):
            x = self.bn(a).mean((2, 3))
            if float(x.sum()) > 1e9:  # reads the value on the host: not allowed while a graph is captured
                x = x * 2
            return self.fc(x)

    model = Syncing().cuda().train()
    before = {k: v.clone() for k, v in model.state_dict().items()}
    x = torch.rand(4, 3, 36, 60, device="cuda") * 50
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert graph_model(model, (x, x, torch.zeros(4, 2, device="cuda"))) is None
    assert len([w for w in caught if "without CUDA graphs" in str(w.message)]) == 1
    for k, v in model.state_dict().items():
        assert torch.equal(v, before[k]), k
    assert torch.cuda.current_stream() == torch.cuda.default_stream()  # the capture's stream is not left current
    y = model(x, x, None)  # the model still runs eagerly, backward too
    y.sum().backward()
    assert torch.isfinite(y).all()


def test_cli_no_cuda_graphs_reaches_train(tmp_path, monkeypatch):
    """``gazeaug train --no-cuda-graphs`` trains without graphs; the default trains with them (on CUDA)."""
    import gazeaug.train as gt
    from gazeaug.cli import main

    seen = []
    real = gt.train

    def spy(*args, **kwargs):
        seen.append(kwargs["cuda_graphs"])
        return real(*args, **kwargs)

    monkeypatch.setattr(gt, "train", spy)
    h5 = synthetic_h5(tmp_path / "t.h5", n=32)
    for extra in ([], ["--no-cuda-graphs"]):
        out = tmp_path / f"m{len(extra)}.pt"
        assert main(["train", str(h5), "-o", str(out), "--epochs", "1", "--quiet", "--device", "cpu", *extra]) == 0
    assert seen == [True, False]


def test_resume_takes_this_devices_optimizer_kernel(tmp_path, monkeypatch):
    """A checkpoint written on CUDA (fused AdamW recorded in its groups) resumes on the CPU without the fused kernel."""
    h5 = synthetic_h5(tmp_path / "t.h5", n=64)
    s = TrainSettings(epochs=2, batch_size=32, device="cpu")
    real_save = train_module._save

    def save_then_die(obj, path):
        real_save(obj, path)
        raise KeyboardInterrupt

    monkeypatch.setattr(train_module, "_save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        train(h5, tmp_path / "r.pt", s, progress=False)
    monkeypatch.setattr(train_module, "_save", real_save)
    ckpt = tmp_path / "r.ckpt.pt"
    ck = torch.load(ckpt, weights_only=True)
    for g in ck["optimizer"]["param_groups"]:
        g["fused"] = True  # as a CUDA run writes it
    torch.save(ck, ckpt)
    flags = []
    real_step = torch.optim.AdamW.step

    def step(self, *args, **kwargs):
        flags.append(self.param_groups[0]["fused"])
        return real_step(self, *args, **kwargs)

    monkeypatch.setattr(torch.optim.AdamW, "step", step)
    log = train(h5, tmp_path / "r.pt", s, resume=True, progress=False)
    assert [r["epoch"] for r in log] == [1, 2]
    assert flags == [False, False]  # epoch 2's two steps, with the CPU's kernel


def test_out_of_memory_is_one_line_that_says_what_to_change(tmp_path, monkeypatch, capsys):
    """The device out of memory mid-run (epoch 2): exit 2, one line saying what needs less and where
    epoch 1 is kept; no model file; the run resumes from that checkpoint with the same settings."""
    from gazeaug.cli import main

    h5 = synthetic_h5(tmp_path / "t.h5", n=64)
    out = tmp_path / "m.pt"
    real_step = torch.optim.AdamW.step
    steps = []

    def step(self, *args, **kwargs):
        steps.append(1)
        if len(steps) == 3:  # the first step of epoch 2 (2 steps an epoch)
            raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB")
        return real_step(self, *args, **kwargs)

    monkeypatch.setattr(torch.optim.AdamW, "step", step)
    argv = ["train", str(h5), "-o", str(out), "--epochs", "2", "--batch-size", "32", "--device", "cpu", "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "out of memory while training (CUDA out of memory. Tried to allocate 2.00 GiB)" in err[0]
    assert f"kept in {out.with_suffix('.ckpt.pt')}" in err[0] and "pass a smaller --batch-size" in err[0]
    assert not out.exists()
    assert int(torch.load(out.with_suffix(".ckpt.pt"), weights_only=True)["epoch"]) == 1
    monkeypatch.setattr(torch.optim.AdamW, "step", real_step)
    assert main([*argv, "--resume"]) == 0 and out.exists()


def test_out_of_memory_keeps_where_it_was_raised(tmp_path, monkeypatch, capsys):
    """The out of memory is raised after its handler (so the failed run's frames are freed), yet
    its traceback is kept as text: the typed error's cause for API callers, and, with
    GAZEAUG_DEBUG=1, printed by the command line before its one line (exit still 2)."""
    from gazeaug.cli import main
    from gazeaug.errors import GazeAugError, TracebackText

    def allocate_a_lot(self, *args, **kwargs):  # a name to find in the kept traceback
        raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 3.00 GiB")

    monkeypatch.setattr(torch.optim.AdamW, "step", allocate_a_lot)
    h5 = synthetic_h5(tmp_path / "t.h5", n=64)
    with pytest.raises(GazeAugError, match="out of memory while training") as caught:
        train(h5, tmp_path / "m.pt", TrainSettings(epochs=1, batch_size=32), progress=False)
    cause = caught.value.__cause__
    assert isinstance(cause, TracebackText) and cause.__traceback__ is None  # text, no frames
    assert "in allocate_a_lot" in cause.text
    assert cause.text.endswith("OutOfMemoryError: CUDA out of memory. Tried to allocate 3.00 GiB")
    copied = pickle.loads(pickle.dumps(cause))  # a worker's error crosses processes by pickle
    assert isinstance(copied, TracebackText) and copied.text == cause.text

    argv = ["train", str(h5), "-o", str(tmp_path / "n.pt"), "--epochs", "1", "--device", "cpu", "--quiet"]
    assert main(argv) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1  # without the switch: one line
    monkeypatch.setenv("GAZEAUG_DEBUG", "0")
    assert main(argv) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1  # "0" is off
    monkeypatch.setenv("GAZEAUG_DEBUG", "1")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("gazeaug train: error: out of memory while training (CUDA out of memory.")
    text = "\n".join(err[:-1])
    assert "in allocate_a_lot" in text and "GazeAugError: out of memory while training" in text


@pytest.mark.parametrize(
    "error",
    [
        RuntimeError("[enforce fail at alloc_cpu.cpp:117] DefaultCPUAllocator: can't allocate memory: 8 GB"),
        RuntimeError("CUDA error: CUBLAS_STATUS_ALLOC_FAILED when calling `cublasCreate(handle)`"),
        MemoryError(),
    ],
)
def test_out_of_memory_raised_as_plain_errors_is_said_so(tmp_path, monkeypatch, error):
    """The host's allocator and cuBLAS say 'out of memory' in RuntimeErrors of their own: the same
    typed error (remedy 'memory'), in the first epoch (no checkpoint to name)."""
    from gazeaug.errors import GazeAugError

    def fail(self, *args, **kwargs):
        raise error

    monkeypatch.setattr(torch.optim.AdamW, "step", fail)
    with pytest.raises(GazeAugError, match="out of memory while training") as caught:
        train(
            synthetic_h5(tmp_path / "t.h5", n=64),
            tmp_path / "m.pt",
            TrainSettings(epochs=1, batch_size=32),
            progress=False,
        )
    assert caught.value.remedy == "memory" and "kept in" not in str(caught.value)


def test_other_runtime_errors_pass_through_unchanged(tmp_path, monkeypatch):
    error = RuntimeError("mat1 and mat2 shapes cannot be multiplied (32x7 and 8x2)")

    def fail(self, *args, **kwargs):
        raise error

    monkeypatch.setattr(torch.optim.AdamW, "step", fail)
    with pytest.raises(RuntimeError) as caught:
        train(
            synthetic_h5(tmp_path / "t.h5", n=64),
            tmp_path / "m.pt",
            TrainSettings(epochs=1, batch_size=32),
            progress=False,
        )
    assert caught.value is error


def test_out_of_memory_in_the_fit_check_is_not_called_a_misfit(tmp_path, monkeypatch):
    """The host out of memory in the model's first call (the two-sample fit check before training)
    is said as out of memory, not as a model that cannot read the set's patches."""
    from gazeaug.errors import GazeAugError

    def forward(*args, **kwargs):
        raise RuntimeError("[enforce fail at alloc_cpu.cpp:117] DefaultCPUAllocator: can't allocate memory: 8 GB")

    def create(name, **options):
        model = create_model(name, **options)
        model.forward = forward  # an instance attribute: nn.Module's call finds it first
        return model

    monkeypatch.setattr(train_module, "create_model", create)
    with pytest.raises(GazeAugError, match="out of memory while training") as caught:
        train(synthetic_h5(tmp_path / "t.h5", n=64), tmp_path / "m.pt", TrainSettings(epochs=1), progress=False)
    assert "cannot read" not in str(caught.value)


def test_validation_reads_in_the_training_batch_size(tmp_path, monkeypatch):
    """The validation after each epoch runs at the training's batch size, so ``--batch-size``, the
    remedy an out of memory names, bounds it too (it read 512 rows at a time whatever the batch)."""
    seen = []
    real = train_module._evaluate_set

    def spy(model, data, batch_size):
        seen.append(batch_size)
        return real(model, data, batch_size)

    monkeypatch.setattr(train_module, "_evaluate_set", spy)
    h5 = synthetic_h5(tmp_path / "t.h5", n=64)
    log = train(h5, tmp_path / "m.pt", TrainSettings(epochs=2, batch_size=8), val_subjects=["b"], progress=False)
    assert seen == [8, 8]
    assert all(r["val_error_deg"] is not None for r in log)
