"""End-to-end augmentation speed vs. decoding the images and running the landmark detector alone.

``python benchmarks/bench_augment.py [--copies 12] [--per-sample 4] [--workers 1 2]`` builds a
folder dataset from the single-face photos of ../shared/data/faces (each copied
``--copies`` times, default camera), then measures on the same images:

- ``decode+detect``: reading each image and running MediaPipe Face Mesh (model loaded beforehand);
- ``augment``: the whole run (read, landmarks, PnP, mesh, K renders of both eyes, HDF5 writing),
  with 1 and 2 worker processes (process start-up excluded: the figure is the steady rate).
  Each worker decodes its next image in a reader thread while it processes the current one,
  so with one worker the run can be faster than decode+detect done one after the other.

Prints one JSON line per measurement and the ratio end-to-end / (decode+detect) per worker.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)

from facemesh.io import load_image_rgb  # noqa: E402
from facemesh.landmarks.mediapipe import MediaPipeFaceMesh  # noqa: E402
from gazeaug.datasets import open_dataset  # noqa: E402
from gazeaug.jobs import JobSettings, run_dataset  # noqa: E402

PHOTOS = ("astronaut.png", "business-person.png", "sergey.png", "pexels/image00.jpg", "pexels/image01.jpg")


def make_folder(data: Path, root: Path, copies: int) -> int:
    """Write a folder dataset of the photos; returns its size."""
    rows = ["image,subject,fx,fy,cx,cy,target_x,target_y,target_z"]
    import cv2

    for c in range(copies):
        for i, name in enumerate(PHOTOS):
            img = cv2.imread(str(data / "faces" / name))
            h, w = img.shape[:2]
            dst = f"{c:02d}_{Path(name).name}"
            shutil.copy(data / "faces" / name, root / dst)
            f = max(w, h)
            rows.append(f"{dst},s{i},{f},{f},{(w - 1) / 2},{(h - 1) / 2},0,150,0")
    (root / "labels.csv").write_text("\n".join(rows) + "\n")
    return len(rows) - 1


def main() -> None:
    """Run the measurements."""
    ap = argparse.ArgumentParser(description=__doc__)
    add_data_option(ap)
    ap.add_argument("--copies", type=int, default=12)
    ap.add_argument("--per-sample", type=int, default=4)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = ap.parse_args()
    require_data(ap, args.data, *(f"faces/{p}" for p in PHOTOS))
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "ds"
        root.mkdir()
        n = make_folder(args.data, root, args.copies)
        samples = list(open_dataset(root))
        det = MediaPipeFaceMesh()
        det.detect(load_image_rgb(samples[0].image_path))  # model loaded
        t0 = time.perf_counter()
        for s in samples:
            det.detect(load_image_rgb(s.image_path))
        base = n / (time.perf_counter() - t0)
        print(json.dumps({"what": "decode+detect", "samples": n, "samples_per_second": round(base, 2)}))
        settings = JobSettings(kind="augment", per_sample=args.per_sample)
        # warm-up run (imports, model loading) so the timed runs measure the steady rate
        run_dataset(open_dataset(root), Path(tmp) / "warm.h5", settings, progress=False, limit=2)
        for i, w in enumerate(args.workers):
            out = Path(tmp) / f"run{i}_w{w}.h5"
            t0 = time.perf_counter()
            summary = run_dataset(open_dataset(root), out, settings, workers=w, progress=False)
            total = time.perf_counter() - t0
            rate = summary["steady_samples_per_second"]
            print(
                json.dumps(
                    {
                        "what": "augment",
                        "workers": w,
                        "per_sample": args.per_sample,
                        "samples": n,
                        "rows": summary["rows"],
                        "samples_per_second_steady": rate,
                        "samples_per_second_incl_startup": summary["samples_per_second"],
                        "wall_seconds_incl_startup": round(total, 2),
                        "per_worker_vs_decode_detect": round(rate / w / base, 3),
                    }
                ),
                flush=True,
            )


if __name__ == "__main__":
    main()
