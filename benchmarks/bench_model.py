"""Gaze-model speed: training samples per second and ``predict`` images per second end to end.

``python benchmarks/bench_model.py [--data ../shared/data]`` builds a synthetic training set of 4096 rows
(random 36 x 60 patches, the default schema), trains the default model for 2
epochs (batch 256) and reports the samples per second of the second epoch; then
times ``predict`` on the photos of ../shared/data/faces (image decoding,
MediaPipe, PnP, normalization, the model, denormalization; model loading
excluded). One JSON line each.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)

from gazeaug.io_h5 import H5Writer, Rows  # noqa: E402
from gazeaug.train import TrainSettings, load_model, train  # noqa: E402

PHOTOS = ("astronaut.png", "business-person.png", "sergey.png", "pexels/image00.jpg", "pexels/image01.jpg")


def synthetic(path: Path, n: int) -> Path:
    """A schema-complete training set of random patches."""
    rng = np.random.default_rng(0)
    eyes = rng.integers(0, 255, (n, 36, 60, 3), dtype=np.uint8)
    py = rng.uniform(-0.5, 0.5, (n, 2)).astype(np.float32)
    eye3 = np.tile(np.eye(3, dtype=np.float32), (n, 1, 1))
    cols = {
        "left_eye": eyes,
        "right_eye": eyes[::-1],
        "head_pose": py,
        "gaze": py[::-1],
        "head_pose_vector": np.zeros((n, 3)),
        "gaze_vector": np.zeros((n, 3)),
        "head_pose_left": py,
        "head_pose_right": py,
        "gaze_left": py,
        "gaze_right": py,
        "R_norm_left": eye3,
        "R_norm_right": eye3,
        "R_norm_face": eye3,
        "subject": np.array([b"s"] * n),
        "source_index": np.arange(n),
        "sampled_yaw_pitch": np.zeros((n, 2)),
    }
    w = H5Writer(path, {"settings": {}}, (60, 36))
    w.append(Rows(cols), n - 1)
    w.finish()
    return path


def main() -> None:
    """Run both measurements."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_data_option(ap)
    data = ap.parse_args().data
    require_data(ap, data, *(f"faces/{p}" for p in PHOTOS))
    warnings.simplefilter("ignore")
    import torch

    with tempfile.TemporaryDirectory() as tmp:
        h5 = synthetic(Path(tmp) / "t.h5", 4096)
        log = train(h5, Path(tmp) / "m.pt", TrainSettings(epochs=2, batch_size=256), progress=False)
        print(
            json.dumps(
                {
                    "what": "train",
                    "model": "mobilenet_gaze",
                    "batch_size": 256,
                    "threads": torch.get_num_threads(),
                    "samples_per_second": log[-1]["samples_per_second"],
                }
            )
        )
        model, meta = load_model(Path(tmp) / "m.pt")
        from gazeaug.evaluate import predict_image, settings_from_meta
        from gazeaug.pipeline import default_landmark_model, fit_face, load_input

        det = default_landmark_model()
        settings = settings_from_meta(meta)
        paths = [data / "faces" / p for p in PHOTOS] * 4
        img, cam, src = load_input(paths[0], None)
        predict_image(model, img, fit_face(img, cam, det), settings)  # warm-up
        t0 = time.perf_counter()
        for p in paths:
            img, cam, src = load_input(p, None)
            predict_image(model, img, fit_face(img, cam, det, source=src), settings)
        rate = len(paths) / (time.perf_counter() - t0)
        print(json.dumps({"what": "predict", "images": len(paths), "images_per_second": round(rate, 2)}))


if __name__ == "__main__":
    main()
