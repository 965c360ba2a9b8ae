"""`gazeaug track` speed: frames per second end to end and the latency from a frame to its gaze.

``python benchmarks/bench_track.py [--model M.pt|M.onnx] [--frames 300] [--video V.mp4 ...]``

Runs :func:`gazeaug.track.track` on 1280x720 videos of one person
(``../shared/data/faces/pexels/video00-02.mp4``) in several set-ups and prints
one JSON line each: frames per second end to end (decoding, landmarks, PnP,
normalization, the model, smoothing, the rig's point of gaze and selection,
the CSV, and the overlay video where written), milliseconds per stage, and the
latency from reading a frame to its gaze (median, 95th percentile). The
model's weights do not change its speed: without ``--model`` a default model is
trained for one epoch on random rows (``bench_model.synthetic``) and exported
to ONNX. The set-ups: ONNX and PyTorch; MediaPipe's video (tracking) mode and
its static-image mode; with and without the overlay video; all with the
``wheelchair_objects`` rig.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)


def _default_models(work: Path) -> tuple[Path, Path]:
    from bench_model import synthetic  # benchmarks/bench_model.py

    from gazeaug.export import export_onnx
    from gazeaug.train import TrainSettings, load_model, train

    pt = work / "m.pt"
    train(synthetic(work / "t.h5", 512), pt, TrainSettings(epochs=1, batch_size=64), progress=False)
    model, meta = load_model(pt)
    return pt, export_onnx(model, meta, work / "m.onnx")


def main() -> None:
    """Run it."""
    from gazeaug.estimator import load_estimator
    from gazeaug.sampling import load_rig
    from gazeaug.track import TrackSettings, track

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, action="append", help=".pt or .onnx (repeatable)")
    ap.add_argument("--frames", type=int, default=300, help="frames per video (default 300)")
    ap.add_argument("--video", type=Path, action="append", help="videos (default pexels/video00-02.mp4)")
    add_data_option(ap)
    args = ap.parse_args()
    if args.video:  # the videos given, each of them; else the shared data's three
        missing = [v for v in args.video if not v.is_file()]
        if missing:
            ap.exit(2, f"{ap.prog}: {missing[0]}: no such video file\n")
    else:
        require_data(ap, args.data, *(f"faces/pexels/video0{i}.mp4" for i in range(3)))
    videos = args.video or [args.data / "faces" / "pexels" / f"video0{i}.mp4" for i in range(3)]
    rig = load_rig(ROOT / "data_samples" / "rigs" / "wheelchair_objects.yaml")
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        models = args.model or list(_default_models(work))
        setups = []
        for m in models:
            setups.append((m, True, False))
        setups += [(models[-1], True, True), (models[-1], False, False)]
        for model, tracking, video in setups:
            est = load_estimator(model)
            frames = with_face = 0
            seconds = 0.0
            stages: dict[str, float] = {}
            lat = []
            for v in videos:
                s = TrackSettings(tracking=tracking, video=video, max_frames=args.frames)
                r = track(v, work / "out", est, rig=rig, settings=s, progress=False)
                frames += r["frames"]
                with_face += r["frames_with_face"]
                seconds += r["seconds"]
                for k, ms in r["ms_per_frame"].items():
                    stages[k] = stages.get(k, 0.0) + ms * r["frames"]
                lat.append(r["latency_ms"])
            print(
                json.dumps(
                    {
                        "model": est.kind,
                        "landmarks": "tracking" if tracking else "static",
                        "overlay_video": video,
                        "videos": len(videos),
                        "frames": frames,
                        "frames_with_face": with_face,
                        "fps": round(frames / seconds, 1),
                        "ms_per_frame": {k: round(t / frames, 2) for k, t in stages.items()},
                        "latency_ms_per_video": lat,
                    }
                ),
                flush=True,
            )


if __name__ == "__main__":
    main()
