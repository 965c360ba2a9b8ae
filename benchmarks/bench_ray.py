"""The Ray engine against the local engine on the same machine: samples/s of ``augment``.

``python benchmarks/bench_ray.py [--copies 12] [--per-sample 4] [--actors 1 2] [--block-size 16]``
builds the folder dataset of ``bench_augment.py`` (the single-face photos of
../shared/data/faces, each copied ``--copies`` times), then augments it:

- ``local``: the local engine with 1 and 2 worker processes;
- ``ray``: a local Ray instance (started once, before timing) with 1, 2, ... actors.

For each it prints one JSON line: the steady rate (samples/s after the first result:
worker start-up and model loading excluded), the whole run's rate and seconds, and
the start-up seconds (Ray's start excluded for ``ray``: it is paid once per command), and for
Ray the driver's merge time per sample (``merge_ms``: reading a shard, appending it to the
gzip-compressed output, flushing), which bounds a cluster's rate at ``1000 / merge_ms`` samples/s.
Last, the ratio ray / local at each worker count: the issue's bar is >= 0.9 on 2 cores.
Every Ray output is checked to hold the local engine's arrays.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_augment import PHOTOS, make_folder  # noqa: E402
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)

from gazeaug.datasets import open_dataset  # noqa: E402
from gazeaug.engine import Engine  # noqa: E402
from gazeaug.io_h5 import read_h5  # noqa: E402
from gazeaug.jobs import JobSettings, run_dataset  # noqa: E402


def main() -> None:
    """Run the measurements."""
    ap = argparse.ArgumentParser(description=__doc__)
    add_data_option(ap)
    ap.add_argument("--copies", type=int, default=12)
    ap.add_argument("--per-sample", type=int, default=4)
    ap.add_argument("--actors", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--block-size", type=int, default=16)
    args = ap.parse_args()
    require_data(ap, args.data, *(f"faces/{p}" for p in PHOTOS))
    import ray

    from gazeaug.io_h5 import H5Writer

    merge_s = [0.0]  # the driver's work per shard: read it, append it (gzip) and flush
    append_file = H5Writer.append_file

    def timed_append(self, path):
        t = time.perf_counter()
        n = append_file(self, path)
        self.flush()
        merge_s[0] += time.perf_counter() - t
        return n

    H5Writer.append_file = timed_append
    settings = JobSettings(kind="augment", per_sample=args.per_sample, seed=0)
    rates: dict[tuple[str, int], float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "data"
        root.mkdir()
        n = make_folder(args.data, root, args.copies)
        outputs = {}
        for workers in args.actors:
            t0 = time.perf_counter()
            out = Path(tmp) / f"local{workers}.h5"
            s = run_dataset(open_dataset(root), out, settings, workers=workers, progress=False)
            outputs[("local", workers)] = out
            rates[("local", workers)] = s["steady_samples_per_second"]
            _report("local", workers, n, s, time.perf_counter() - t0)
        t0 = time.perf_counter()
        ray.init(address="local", include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
        ray_start = time.perf_counter() - t0
        try:
            for actors in args.actors:
                t0 = time.perf_counter()
                merge_s[0] = 0.0
                out = Path(tmp) / f"ray{actors}.h5"
                engine = Engine("ray", workers=actors, block_size=args.block_size)
                s = run_dataset(open_dataset(root), out, settings, progress=False, engine=engine)
                rates[("ray", actors)] = s["steady_samples_per_second"]
                merge_ms = round(1000 * merge_s[0] / n, 2)
                _report("ray", actors, n, s, time.perf_counter() - t0, ray_start=round(ray_start, 2), merge_ms=merge_ms)
                a, b = read_h5(out), read_h5(outputs[("local", args.actors[0])])
                same = all(np.array_equal(a[k], b[k]) for k in a if k != "attrs")
                print(json.dumps({"ray_output_equals_local": same, "actors": actors}), flush=True)
        finally:
            ray.shutdown()
    for w in args.actors:
        if rates.get(("local", w)) and rates.get(("ray", w)):
            ratio = rates[("ray", w)] / rates[("local", w)]
            print(json.dumps({"workers": w, "ray_over_local_steady": round(ratio, 3)}))


def _report(engine: str, workers: int, n: int, s: dict, wall: float, **extra: float) -> None:
    print(
        json.dumps(
            {
                "engine": engine,
                "workers": workers,
                "samples": n,
                "steady_samples_per_second": s["steady_samples_per_second"],
                "samples_per_second": s["samples_per_second"],
                "seconds": round(wall, 2),
                **extra,
            }
        ),
        flush=True,
    )


if __name__ == "__main__":
    main()
