"""A training step's forward and backward replayed as CUDA graphs (:func:`graph_model`).

Why: the default gaze model is small, so on a GPU its step is bound by the host launching
about 400 kernels one by one, not by the GPU. Measured on an NVIDIA H200 (2026-11-28,
``benchmarks/bench_step.py``): at batch 256 the kernels of an eager step kept the GPU busy
12 % of the step's wall time; replaying the model's forward and backward as CUDA graphs
(``torch.cuda.make_graphed_callables``) took the whole step from 20-27k to 54-69k samples/s (2.5-3.1 x).

What is replayed: the model's forward and backward for batches of the captured shape (a full
batch), in train mode, under bfloat16 autocast. Anything else (the last, shorter batch of an
epoch, evaluation, the CPU) calls the model as usual; both share the parameters and the
BatchNorm statistics. The inputs' augmentation and the optimizer step stay eager.

Capturing runs the model's forward and backward a few times on the sample batch (the warm-up
``make_graphed_callables`` needs); the BatchNorm running statistics those passes would move are
put back, so a graphed run trains as an eager one (the same kernels; CUDA's floating point
results are not bitwise reproducible either way).

What a model of your own should know (``TrainSettings.model`` registered by you): a replay runs
the kernels the capture recorded, not the model's Python. Code in its forward that is not a CUDA
kernel (forward hooks, prints, counters, branches on a tensor's value) runs during the capture's
passes only; a branch on a value fixes the branch taken then (``train`` captures on a
placeholder batch of zeros, :func:`gazeaug.train_data.placeholder_batch`). Random operations (dropout) draw
anew at each replay (PyTorch's CUDA generator is registered with the graph). A model with such
code, or one that cannot be captured at all, trains as it should with ``cuda_graphs=False``
(``gazeaug train --no-cuda-graphs``).
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterator
from typing import Any

from .models import import_torch

__all__ = ["graph_model", "quiet_stream_mismatch"]


def graph_model(model: Any, sample_args: tuple[Any, ...]) -> Any | None:
    """``model``'s training forward and backward for inputs shaped as ``sample_args``, as CUDA graphs.

    Args:
        model: a ``torch.nn.Module`` on a CUDA device, in train mode, its parameters requiring
            gradients; not changed (its BatchNorm running statistics are restored after the capture).
        sample_args: the model's inputs of one full batch, as the training gives them (shapes,
            dtypes, memory formats and device are captured; the values are copied and only warm up).

    Raises:
        ValueError: ``sample_args`` not all on a CUDA device (a programming error: graphs are CUDA's).

    Returns:
        A callable taking inputs of exactly those shapes and dtypes (call it under
        ``torch.autocast("cuda", dtype=torch.bfloat16, cache_enabled=False)``); its outputs live in
        the graph's memory and are overwritten by the next call, so copy what is kept. None when the
        model cannot be captured (a warning says why; train eagerly then). An out-of-memory error of
        the capture is one such case: the capture holds a full batch's activations in a pool of its
        own beside the warm-up's, so eager steps may still fit (where they do not, ``train`` says so).
    """
    torch = import_torch()
    if not all(a.is_cuda for a in sample_args):
        devices = ", ".join(sorted({str(a.device) for a in sample_args}))
        raise ValueError(f"graph_model: expected the sample inputs on a CUDA device, got them on {devices}")

    class _Forward(torch.nn.Module):  # type: ignore[misc,name-defined]
        """A wrapper whose forward the capture replaces, so ``model`` itself keeps its own."""

        def __init__(self, inner: Any) -> None:
            super().__init__()
            self.inner = inner

        def forward(self, *args: Any) -> Any:
            return self.inner(*args)

    wrapper = _Forward(model)
    stream = torch.cuda.current_stream()  # a failed capture can leave its side stream current: put back
    static = tuple(a.detach().clone(memory_format=torch.preserve_format) for a in sample_args)
    saved = [b.detach().clone() for b in model.buffers()]
    try:
        # the capture's backward already meets the warm-up's gradient accumulators (another stream)
        with torch.autocast("cuda", dtype=torch.bfloat16, cache_enabled=False), quiet_stream_mismatch():
            return torch.cuda.make_graphed_callables(wrapper, static, allow_unused_input=True)
    except Exception as exc:  # an operation a graph cannot hold (a host sync, say): eager is still right
        torch.cuda.set_stream(stream)
        cause: BaseException = exc
        while cause.__context__ is not None:  # the first error, not "failed due to a previous error"
            cause = cause.__context__
        warnings.warn(
            f"training without CUDA graphs: the model could not be captured ({cause.__class__.__name__}: {cause})",
            RuntimeWarning,
            stacklevel=2,
        )
        return None
    finally:
        with torch.no_grad():
            for b, v in zip(model.buffers(), saved, strict=True):
                b.copy_(v)


@contextlib.contextmanager
def quiet_stream_mismatch(active: bool = True) -> Iterator[None]:
    """Backward passes of a run with a captured model, without PyTorch's stream-mismatch warning.

    The parameters' gradient accumulators of a captured model were made on the warm-up's side
    stream and are kept alive by the graph, so the capture's backward and every later backward
    (replayed or eager) hand them gradients from another stream: PyTorch synchronises the two,
    as it must, and warns that the mismatch may be unintended. Here it is intended (PyTorch's
    message says to switch the warning off then); the synchronisation stays, and is in the
    measured speed. Set back to what it was after (on where PyTorch cannot say).
    ``active`` False: nothing changes.
    """
    torch = import_torch()
    switch = getattr(torch.autograd.graph, "set_warn_on_accumulate_grad_stream_mismatch", None)
    if not active or switch is None:  # older PyTorch: no such warning
        yield
        return
    getter = getattr(torch._C, "_warn_on_accumulate_grad_stream_mismatch", None)
    before = bool(getter()) if getter is not None else True
    switch(False)
    try:
        yield
    finally:
        switch(before)
