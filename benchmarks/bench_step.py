"""Where one training step's time goes, on a device: its parts, and ways to run the whole step faster.

``python benchmarks/bench_step.py [--device cuda] [--rows 16384] [--batch-sizes 256 1024] [--steps 60] [--compile]``
holds a synthetic training set on the device (random eye patches, 36 x 60, the default
model ``mobilenet_gaze``; the speed does not depend on the pixels) and times, per batch size,
``--steps`` steps after 10 of warm-up (the device synchronised before the clock is read):

- parts, each repeated alone: ``gather`` (a batch gathered from the held rows,
  :meth:`gazeaug.train_data.ResidentSet.batches`), ``inputs`` (:func:`gazeaug.train_data.train_inputs`:
  mirror, augmentation, input scaling), ``forward_backward`` (bfloat16 autocast on CUDA, as
  :func:`gazeaug.train.train`), ``optimizer`` (AdamW, foreach, as ``train`` built it before
  2026-11-28, and a cosine step), ``optimizer_fused`` (``AdamW(fused=True)``, what ``train`` builds
  on CUDA now; CUDA only);
- whole steps: ``step`` (an eager step with the foreach AdamW), ``step_fused`` (with the fused AdamW),
  ``step_graphed`` (the model's forward and backward replayed as CUDA graphs,
  :func:`gazeaug.train_graphs.graph_model`, as training captures them; CUDA only),
  ``step_compiled`` (``torch.compile`` of the model; with ``--compile``; its compile time printed apart);
- on CUDA, one profiled ``step``: the number of device kernels and their summed time against the
  step's wall time (``gpu_busy``: under 1, the host's launching is the limit, not the GPU).

Prints one JSON line ``{"device", "torch", BATCH: {what: samples/s}, "profile": {...}}``; figures
are samples per second (a sample: one face, its two eye patches).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gazeaug.models import create_model  # noqa: E402
from gazeaug.train_augment import TrainAugment, augment_generator  # noqa: E402
from gazeaug.train_data import train_inputs  # noqa: E402
from gazeaug.train_graphs import graph_model, quiet_stream_mismatch  # noqa: E402


class _Held:
    """Rows held on the device as :class:`gazeaug.train_data.ResidentSet` holds them (uint8 HWC), gathered alike."""

    def __init__(self, rows: int, device: Any, seed: int = 0) -> None:
        import torch

        g = torch.Generator(device="cpu").manual_seed(seed)
        self.left = torch.randint(0, 256, (rows, 36, 60, 3), dtype=torch.uint8, generator=g).to(device)
        self.right = torch.randint(0, 256, (rows, 36, 60, 3), dtype=torch.uint8, generator=g).to(device)
        self.head_pose = ((torch.rand((rows, 2), generator=g) - 0.5) * 0.6).to(device)
        self.gaze = ((torch.rand((rows, 2), generator=g) - 0.5) * 0.8).to(device)
        self.device = device

    def batch(self, i: Any) -> dict[str, Any]:
        import torch

        return {
            "eyes": torch.cat([self.left.index_select(0, i), self.right.index_select(0, i)]),
            "head_pose": self.head_pose.index_select(0, i),
            "gaze": self.gaze.index_select(0, i),
        }


def _timed(fn: Callable[[int], Any], steps: int, batch: int, device: Any, warmup: int = 10) -> float:
    """Samples per second of ``fn(step)`` run ``steps`` times after ``warmup`` calls."""
    import torch

    cuda = device.type == "cuda"
    for k in range(warmup):
        fn(k)
    if cuda:
        torch.cuda.synchronize()
    t0 = time.perf_counter()
    for k in range(steps):
        fn(k)
    if cuda:
        torch.cuda.synchronize()
    return round(steps * batch / (time.perf_counter() - t0), 1)


def measure(held: _Held, batch: int, steps: int, compile_model: bool) -> dict[str, Any]:
    """Every figure for one batch size."""
    import torch

    device = held.device
    cuda = device.type == "cuda"
    rows = held.left.shape[0]
    aug = TrainAugment()
    gen = augment_generator(0, 0, device)
    index = torch.randperm(rows, device=device)
    starts = [lo for lo in range(0, rows - batch + 1, batch)]

    def index_of(k: int) -> Any:
        lo = starts[k % len(starts)]
        return index[lo : lo + batch]

    def make(fused: bool) -> tuple[Any, Any, Any]:
        torch.manual_seed(0)
        model = create_model("mobilenet_gaze").to(device).train()
        kw = {"fused": True} if fused else {}
        opt = torch.optim.AdamW(model.parameters(), lr=3e-3, weight_decay=1e-4, **kw)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=100_000, eta_min=3e-5)
        return model, opt, sched

    out: dict[str, Any] = {}
    fixed = train_inputs(held.batch(index_of(0)), device, aug, "rgb", gen)
    out["gather"] = _timed(lambda k: held.batch(index_of(k)), steps, batch, device)
    out["inputs"] = _timed(
        lambda k: train_inputs(held.batch(index_of(k)), device, aug, "rgb", gen), steps, batch, device
    )
    out["inputs"] = round(1 / (1 / out["inputs"] - 1 / out["gather"]), 1)  # the gathering taken out

    def forward_backward(model: Any, inputs: tuple[Any, ...]) -> Any:
        a, b, c, y = inputs.left, inputs.right, inputs.head_pose, inputs.gaze
        with torch.autocast("cuda", dtype=torch.bfloat16, enabled=cuda):
            pred = model(a, b, c)
        loss = (pred.float() - y).abs().mean()
        loss.backward()
        return loss

    model, opt, sched = make(False)
    out["forward_backward"] = _timed(lambda k: forward_backward(model, fixed), steps, batch, device)

    def opt_step(o: Any, s: Any) -> None:
        o.step()
        s.step()

    out["optimizer"] = _timed(lambda k: opt_step(opt, sched), steps, batch, device)
    if cuda:
        model, opt, sched = make(True)
        forward_backward(model, fixed)
        out["optimizer_fused"] = _timed(lambda k: opt_step(opt, sched), steps, batch, device)

    def whole(model: Any, opt: Any, sched: Any, call: Any = None) -> Callable[[int], Any]:
        call = call if call is not None else model  # (not `or`: a module's truth is its length)

        def step(k: int) -> Any:
            t = train_inputs(held.batch(index_of(k)), device, aug, "rgb", gen)
            a, b, c, y = t.left, t.right, t.head_pose, t.gaze
            with torch.autocast("cuda", dtype=torch.bfloat16, enabled=cuda):
                pred = call(a, b, c)
            loss = (pred.float() - y).abs().mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            return loss.detach()

        return step

    out["step"] = _timed(whole(*make(False)), steps, batch, device)
    if cuda:
        out["step_fused"] = _timed(whole(*make(True)), steps, batch, device)
        model, opt, sched = make(True)
        a, b, c, _, _ = fixed
        graphed = graph_model(model, (a, b, c))  # the capture training uses (its warning says why if it fails)
        if graphed is None:
            out["step_graphed"] = "failed: the model could not be captured"
        else:
            step = whole(model, opt, sched, graphed)

            def graphed_step(k: int) -> Any:
                with torch.autocast("cuda", dtype=torch.bfloat16, cache_enabled=False), quiet_stream_mismatch():
                    return step(k)

            out["step_graphed"] = _timed(graphed_step, steps, batch, device)
    if compile_model:
        model, opt, sched = make(cuda)
        try:
            compiled = torch.compile(model)
            t0 = time.perf_counter()
            whole(model, opt, sched, compiled)(0)
            if cuda:
                torch.cuda.synchronize()
            out["compile_seconds"] = round(time.perf_counter() - t0, 1)
            out["step_compiled"] = _timed(whole(model, opt, sched, compiled), steps, batch, device)
        except Exception as exc:
            out["step_compiled"] = f"failed: {exc.__class__.__name__}: {str(exc)[:300]}"
    if cuda:
        out["profile"] = _profile(whole(*make(False)), batch)
    return out


def _profile(step: Callable[[int], Any], batch: int, steps: int = 10) -> dict[str, Any]:
    """Kernels per step, their summed device time and the wall time per step (``steps`` steps after a warm-up)."""
    import torch
    from torch.profiler import ProfilerActivity, profile

    for k in range(5):
        step(k)
    torch.cuda.synchronize()
    with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        t0 = time.perf_counter()
        for k in range(steps):
            step(k)
        torch.cuda.synchronize()
        wall = time.perf_counter() - t0
    kernels = [e for e in prof.events() if e.device_type == torch.autograd.DeviceType.CUDA]
    busy_us = sum(e.device_time for e in kernels)  # microseconds
    top: dict[str, list[float]] = {}
    for e in kernels:
        t = top.setdefault(e.name[:60], [0, 0.0])
        t[0] += 1
        t[1] += e.device_time
    heaviest = sorted(top.items(), key=lambda kv: -kv[1][1])[:8]
    return {
        "kernels_per_step": round(len(kernels) / steps, 1),
        "kernel_ms_per_step": round(busy_us / 1000 / steps, 3),
        "wall_ms_per_step": round(wall * 1000 / steps, 3),
        "gpu_busy": round(busy_us / 1e6 / wall, 3),
        "samples_per_second_profiled": round(steps * batch / wall, 1),
        "heaviest": {name: [n // steps, round(us / 1000 / steps, 3)] for name, (n, us) in heaviest},
    }


def main(argv: list[str] | None = None) -> None:
    """Measure every batch size, print one JSON line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default=None, help="cuda when there is one, else cpu")
    p.add_argument("--rows", type=int, default=16384)
    p.add_argument("--batch-sizes", type=int, nargs="+", default=[256, 1024])
    p.add_argument("--steps", type=int, default=60)
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2)")
    p.add_argument("--compile", action="store_true", help="torch.compile the model too (slow to compile)")
    args = p.parse_args(argv)
    warnings.simplefilter("ignore")
    import torch

    torch.set_num_threads(args.threads)
    name = args.device or ("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if args.rows < max(args.batch_sizes):
        p.error(f"--rows {args.rows}: expected at least the largest batch size, {max(args.batch_sizes)}")
    held = _Held(args.rows, device)
    result: dict[str, Any] = {
        "device": torch.cuda.get_device_name(0) if device.type == "cuda" else "cpu",
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
    }
    for b in args.batch_sizes:
        result[str(b)] = measure(held, b, args.steps, args.compile)
        print(json.dumps({str(b): result[str(b)]}), file=sys.stderr, flush=True)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
