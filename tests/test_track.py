"""`gazeaug track`: a real video (or one made from the built-in photo), folders, ONNX, rigs, bad input, Ctrl-C."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch", reason="the gaze model needs torch")

from conftest import face_photo  # noqa: E402
from helpers import synthetic_h5  # noqa: E402

from gazeaug.cli import main  # noqa: E402
from gazeaug.track import COLUMNS, RIG_COLUMNS, STAGES  # noqa: E402

STATUSES = {"ok", "no_face", "eyes_closed", "unreadable", "failed"}
RIG = Path(__file__).resolve().parents[1] / "data_samples" / "rigs" / "wheelchair_objects.yaml"


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    """A small trained model (one epoch on synthetic rows): what it predicts does not matter here."""
    from gazeaug.train import TrainSettings, train

    d = tmp_path_factory.mktemp("model")
    train(synthetic_h5(d / "t.h5", n=64), d / "m.pt", TrainSettings(epochs=1, batch_size=32), progress=False)
    return d / "m.pt"


@pytest.fixture(scope="module")
def video(faces_dir, tmp_path_factory) -> Path:
    """pexels/video00.mp4 (1280x720, a real person moving), or without ../shared a 24-frame video of the
    built-in photo drifting by a few pixels (mp4v), written here."""
    p = faces_dir / "pexels" / "video00.mp4"
    if p.is_file():
        return p
    import cv2

    from facemesh.build import sample_image

    img = cv2.cvtColor(sample_image(), cv2.COLOR_RGB2BGR)
    out = tmp_path_factory.mktemp("video") / "drift.mp4"
    w = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (512, 512))
    for i in range(24):
        w.write(np.roll(img, (i % 6) - 3, axis=1))
    w.release()
    return out


def _run(argv, capsys):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_track_video_with_a_rig(model, video, tmp_path, capsys):
    import cv2

    out = tmp_path / "t"
    code, stdout, err = _run(
        ["track", video, "-o", out, "--model", model, "--rig", RIG, "--max-frames", 24, "--quiet"], capsys
    )
    assert code == 0, err
    summary = json.loads(stdout.strip().splitlines()[-1])
    # video00's first 13 frames have a hand in front of the face
    assert summary["frames"] == 24 and summary["frames_with_face"] >= 10
    assert set(summary["ms_per_frame"]) == set(STAGES) and summary["fps"] > 0
    assert summary["latency_ms"]["median"] is not None
    rows = _rows(out / "gaze.csv")
    assert list(rows[0]) == list(COLUMNS + RIG_COLUMNS)
    assert [int(r["frame"]) for r in rows] == list(range(24))
    assert {r["status"] for r in rows} <= STATUSES
    times = [float(r["time_s"]) for r in rows]
    assert times == sorted(times) and times[1] > times[0]
    ok = [r for r in rows if r["status"] == "ok"]
    assert ok
    for r in ok:
        g = np.array([float(r["gaze_x"]), float(r["gaze_y"]), float(r["gaze_z"])])
        assert abs(np.linalg.norm(g) - 1) < 1e-5
        # pitch/yaw of the vector, conventions: y = -sin(pitch), x = -cos(pitch) sin(yaw)
        p, y = math.radians(float(r["pitch_deg"])), math.radians(float(r["yaw_deg"]))
        assert abs(-math.sin(p) - g[1]) < 1e-4 and abs(-math.cos(p) * math.sin(y) - g[0]) < 1e-4
        assert 200 < float(r["eye_z_mm"]) < 3000  # a face in front of the camera
        assert r["openness"]
    assert (out / "selections.csv").read_text().startswith("frame,time_s,target,dwell_start_s")
    assert not list(out.glob(".*part*"))
    cap = cv2.VideoCapture(str(out / "overlay.mp4"))
    n = 0
    while cap.read()[0]:
        n += 1
    assert n == 24
    assert json.loads((out / "summary.json").read_text())["frames"] == 24


def test_track_onnx_equals_pytorch(model, tmp_path, monkeypatch):
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from gazeaug.estimator import load_estimator
    from gazeaug.export import export_onnx
    from gazeaug.train import load_model

    m, meta = load_model(model)
    export_onnx(m, meta, tmp_path / "m.onnx")
    a, b = load_estimator(model), load_estimator(tmp_path / "m.onnx")
    assert (a.kind, b.kind) == ("pytorch", "onnx") and a.normalization == b.normalization
    rng = np.random.default_rng(0)
    left, right = (rng.integers(0, 256, (3, 36, 60, 3), dtype=np.uint8) for _ in range(2))
    hp = rng.normal(0, 0.3, (3, 2))
    np.testing.assert_allclose(a.predict(left, right, hp), b.predict(left, right, hp), atol=1e-4)
    # the same model with its weights in another file (external data): the estimator reads one file's
    # bytes (its digest ties calibrations to them), so it is refused in one line that says so
    import onnx

    from gazeaug.errors import GazeAugError

    onnx.save_model(
        onnx.load(tmp_path / "m.onnx"), tmp_path / "ext.onnx", save_as_external_data=True, location="ext.data"
    )
    with pytest.raises(GazeAugError, match="external data"):
        load_estimator(tmp_path / "ext.onnx")
    # also where the weights file lies in the working directory (a session built from bytes would
    # read it from there, whatever the model's folder)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(GazeAugError, match="external data"):
        load_estimator("ext.onnx")


def test_evaluate_and_predict_take_the_onnx_export_and_agree_with_the_pt(model, faces_dir, tmp_path, capsys):
    """`gazeaug evaluate` and `gazeaug predict` load an .onnx as track does: the same rows, the same gaze."""
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    import shutil

    assert main(["export", str(model), "-o", str(tmp_path / "m.onnx")]) == 0
    capsys.readouterr()
    h5 = synthetic_h5(tmp_path / "t.h5", n=40)
    photo = face_photo(faces_dir, "astronaut.png", any_face=True)
    ds = tmp_path / "ds"
    ds.mkdir()
    with open(ds / "labels.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["image", "subject", "fx", "fy", "cx", "cy", "target_x", "target_y", "target_z"])
        for i in range(2):
            shutil.copy(photo, ds / f"img{i}{photo.suffix}")
            w.writerow([f"img{i}{photo.suffix}", f"s{i}", 600, 600, 255.5, 255.5, 0, 0, 0])
    got = {}
    for kind in ("pt", "onnx"):
        m = str(model) if kind == "pt" else str(tmp_path / "m.onnx")
        for name, data in (("h5", h5), ("folder", ds)):
            rep = tmp_path / f"{name}_{kind}"
            assert main(["evaluate", m, str(data), "-o", str(rep), "--quiet"]) == 0
            got[name, kind] = json.loads((rep / "errors.json").read_text())
        assert main(["predict", m, str(photo)]) == 0
        got["predict", kind] = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for name, n in (("h5", 40), ("folder", 2)):
        a, b = got[name, "pt"], got[name, "onnx"]
        assert a["count"] == b["count"] == n and a["skipped"] == b["skipped"] == 0
        pa = np.array([[r["pred_pitch_rad"], r["pred_yaw_rad"]] for r in a["rows"]])
        pb = np.array([[r["pred_pitch_rad"], r["pred_yaw_rad"]] for r in b["rows"]])
        np.testing.assert_allclose(pb, pa, atol=1e-4)  # float32 graphs of one model: ONNX Runtime vs PyTorch
        assert abs(a["mean_deg"] - b["mean_deg"]) < 0.01
    np.testing.assert_allclose(
        got["predict", "onnx"]["gaze_vector_camera"], got["predict", "pt"]["gaze_vector_camera"], atol=1e-4
    )
    # a set normalized for another patch size is refused by both, naming the set and the model
    import h5py

    small = tmp_path / "small.h5"
    shutil.copy(h5, small)
    with h5py.File(small, "r+") as f:
        for k in ("left_eye", "right_eye"):
            cut = f[k][:, :30, :50]
            del f[k]
            f[k] = cut
    for m in (model, tmp_path / "m.onnx"):
        assert main(["evaluate", str(m), str(small), "-o", str(tmp_path / "no"), "--quiet"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "eye patches are 50 x 30 px" in err[0] and str(m) in err[0], err
    assert not (tmp_path / "no").exists()


def test_track_folder_with_a_corrupt_frame_and_closed_eyes(model, faces_dir, tmp_path, capsys):
    """A folder in name order: an undecodable file is a row marked unreadable and the run goes on;
    a face with closed eyes is flagged, not given a gaze."""
    import shutil

    src = tmp_path / "frames"
    src.mkdir()
    photo = face_photo(faces_dir, "astronaut.png", any_face=True)
    for i in range(4):
        shutil.copy(photo, src / f"{i:03d}{photo.suffix}")
    (src / "001.png").unlink(missing_ok=True)
    (src / "001.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 50)  # a PNG header and nothing else
    closed = faces_dir / "aflw_deca" / "examples_alfw1.png"  # eyes closed (openness about 0.07)
    if closed.is_file():
        shutil.copy(closed, src / "004.png")
    (src / "sequence.json").write_text('{"fps": 10}')
    out = tmp_path / "t"
    code, stdout, err = _run(["track", src, "-o", out, "--model", model, "--no-video", "--quiet", "--static"], capsys)
    assert code == 0, err
    rows = _rows(out / "gaze.csv")
    assert [r["status"] for r in rows[:4]] == ["ok", "unreadable", "ok", "ok"]
    assert [float(r["time_s"]) for r in rows[:3]] == [0.0, 0.1, 0.2]  # the folder's sequence.json: 10 fps
    assert "001.png" in rows[1]["note"] and not rows[1]["gaze_x"]
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["unreadable_frames"] == 1
    if closed.is_file():
        assert rows[4]["status"] == "eyes_closed" and rows[4]["face_found"] == "1" and not rows[4]["gaze_x"]
        assert float(rows[4]["openness"]) < 0.6 * float(rows[3]["openness"])
    assert "video" not in summary["outputs"] and not (out / "overlay.mp4").exists()
    kept = json.loads((out / "summary.json").read_text())  # the file lists itself, as the printed line does
    assert kept["outputs"] == summary["outputs"] and kept["outputs"]["summary"] == str(out / "summary.json")


def test_track_ctrl_c_keeps_complete_files(model, video, tmp_path, monkeypatch):
    """Ctrl-C mid-run: the CSV holds every frame up to the last, whole; the video is closed and playable."""
    import cv2

    from gazeaug.estimator import GazeEstimator, load_estimator
    from gazeaug.track import TrackSettings, track

    est = load_estimator(model)
    calls = {"n": 0}
    real = GazeEstimator.predict

    def predict_then_interrupt(self, *a):
        calls["n"] += 1
        if calls["n"] == 8:  # the warm-up call, then 6 frames with a gaze, then Ctrl-C
            raise KeyboardInterrupt
        return real(self, *a)

    monkeypatch.setattr(GazeEstimator, "predict", predict_then_interrupt)
    out = tmp_path / "t"
    with pytest.raises(KeyboardInterrupt):
        track(video, out, est, settings=TrackSettings(max_frames=50), progress=False)
    rows = _rows(out / "gaze.csv")
    assert 6 <= len(rows) < 50 and all(len(r) == len(COLUMNS) and None not in r.values() for r in rows)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["frames"] == len(rows)  # the frame cut short: in neither
    cap = cv2.VideoCapture(str(out / "overlay.mp4"))
    assert cap.isOpened() and cap.read()[0]
    assert not list(out.glob(".*part*"))


@pytest.mark.parametrize("case", ["missing", "not_video", "empty_folder", "bad_rig", "camera_size", "bad_model"])
def test_track_bad_input_is_one_line(case, model, video, tmp_path, capsys):
    src, extra = video, []
    if case == "missing":
        src = tmp_path / "nothing.mp4"
    elif case == "not_video":
        src = tmp_path / "x.mp4"
        src.write_text("not a video")
    elif case == "empty_folder":
        src = tmp_path / "empty"
        src.mkdir()
    elif case == "bad_rig":
        rig = tmp_path / "r.yaml"
        rig.write_text(RIG.read_text().replace("radius_mm: 50.0}", "radius_mm: -1}", 1))
        extra = ["--rig", rig]
    elif case == "camera_size":
        cam = tmp_path / "cam.yaml"
        cam.write_text(
            "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
            "   data: [ 500., 0., 100., 0., 500., 100., 0., 0., 1. ]\nimage_width: 200\nimage_height: 200\n"
        )
        extra = ["--camera", cam]
    elif case == "bad_model":
        bad = tmp_path / "m.pt"
        bad.write_bytes(b"not a model")
        model = bad
    out = tmp_path / "o"
    code, stdout, err = _run(["track", src, "-o", out, "--model", model, "--quiet", "--max-frames", 3] + extra, capsys)
    assert code == 2, (stdout, err)
    lines = [x for x in err.strip().splitlines() if "error" in x]
    assert len(lines) == 1 and "Traceback" not in err, err
    if case == "bad_rig":
        assert "line 20" in err and "radius_mm" in err
    assert not (out / "gaze.csv").exists()


def test_track_without_model_uses_the_demo_model(video, tmp_path, capsys):
    from gazeaug.models.train_demo import DEMO_CARD, DEMO_MODEL

    assert DEMO_MODEL.is_file() and DEMO_MODEL.stat().st_size < 5_000_000  # shipped, a few MB at most
    card = json.loads(DEMO_CARD.read_text())
    assert "simulated" in card["trained_on"] and card["rig"] == "wheelchair"
    code, stdout, err = _run(["track", video, "-o", tmp_path / "t", "--max-frames", 3, "--quiet", "--no-video"], capsys)
    assert code == 0, err
    assert "built-in demo model" in err and "simulated people" in err
    assert json.loads(stdout.strip().splitlines()[-1])["model"] == str(DEMO_MODEL)


def test_track_stops_early_and_replaces_older_outputs(model, faces_dir, tmp_path, capsys):
    """--max-frames short of a folder's end stops the decoding thread (no hang); a second run without a
    rig or video leaves no older selections.csv or overlay.mp4 beside its gaze.csv."""
    import shutil
    import threading

    src = tmp_path / "frames"
    src.mkdir()
    photo = face_photo(faces_dir, "astronaut.png", any_face=True)
    for i in range(8):
        shutil.copy(photo, src / f"{i:03d}{photo.suffix}")
    out = tmp_path / "t"
    result = {}

    def run(argv):
        result["code"] = main([str(a) for a in argv])

    t = threading.Thread(
        target=run, args=(["track", src, "-o", out, "--model", model, "--rig", RIG, "--max-frames", 2, "--quiet"],)
    )
    t.start()
    t.join(120)
    assert not t.is_alive() and result["code"] == 0
    assert (out / "selections.csv").is_file() and (out / "overlay.mp4").is_file()
    assert len(_rows(out / "gaze.csv")) == 2
    code, _, err = _run(["track", src, "-o", out, "--model", model, "--max-frames", 2, "--quiet", "--no-video"], capsys)
    assert code == 0, err
    assert not (out / "selections.csv").exists() and not (out / "overlay.mp4").exists()


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--margin", "30"], "--margin"),
        (["--dwell", "0"], "--dwell"),
        (["--fps", "0"], "--fps"),
    ],
)
def test_track_option_errors_name_the_option(argv, message, model, video, tmp_path, capsys):
    code, _, err = _run(["track", video, "-o", tmp_path / "o", "--model", model, "--quiet"] + argv, capsys)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1


def test_simulate_sequence_options_need_sequence(tmp_path, capsys):
    code, _, err = _run(["simulate", "--pattern", "calibration", "-o", tmp_path / "s"], capsys)
    assert code == 2 and "only with --sequence" in err


def test_track_refuses_a_broken_truth_file(model, faces_dir, tmp_path, capsys):
    import shutil

    src = tmp_path / "seq"
    src.mkdir()
    shutil.copy(face_photo(faces_dir, "astronaut.png", any_face=True), src / "00000.png")
    (src / "sequence.json").write_text('{"fps": 10}')
    (src / "truth.csv").write_text("frame,time_s\n0,zero\n")
    code, _, err = _run(["track", src, "-o", tmp_path / "o", "--model", model, "--rig", RIG, "--quiet"], capsys)
    assert code == 2 and "truth.csv, line 2" in err


def test_track_keeps_the_users_files_and_older_runs(model, video, tmp_path, capsys):
    """A folder holding a user's own gaze.csv or video is refused; the source cannot be an output file;
    a video without a decodable frame, or a folder without one, leaves an older run as it was."""
    import shutil

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "gaze.csv").write_text("my own data\n")
    code, _, err = _run(["track", video, "-o", mine, "--model", model, "--max-frames", 2, "--quiet"], capsys)
    assert code == 2 and "did not write" in err and (mine / "gaze.csv").read_text() == "my own data\n"
    out = tmp_path / "o"
    out.mkdir()
    shutil.copy(video, out / "overlay.mp4")
    code, _, err = _run(["track", out / "overlay.mp4", "-o", out, "--model", model, "--quiet"], capsys)
    assert code == 2 and "the source is one of the files" in err and (out / "overlay.mp4").stat().st_size > 0
    # an older run, then a video that opens but decodes nothing
    run = tmp_path / "run"
    code, _, err = _run(["track", video, "-o", run, "--model", model, "--max-frames", 2, "--quiet"], capsys)
    assert code == 0, err
    before = (run / "gaze.csv").read_bytes()
    tiny = tmp_path / "tiny.mp4"
    tiny.write_bytes(Path(video).read_bytes()[:20000])
    code, _, err = _run(["track", tiny, "-o", run, "--model", model, "--quiet"], capsys)
    if code == 0:  # some FFmpeg builds decode a frame from 20 kB; then the run is a new, complete one
        assert json.loads((run / "summary.json").read_text())["frames"] >= 1
    else:
        assert code == 2 and ("no frame could be read" in err or "cannot be opened as a video" in err)
        assert (run / "gaze.csv").read_bytes() == before and (run / "overlay.mp4").is_file()
    # a folder whose images all fail to decode: rows marked unreadable only, so no frame was read either
    junk = tmp_path / "junk"
    junk.mkdir()
    for k in range(3):
        (junk / f"{k:03d}.jpg").write_bytes(b"not a jpeg" * (k + 1))
    code, _, err = _run(["track", junk, "-o", run, "--model", model, "--quiet"], capsys)
    assert code == 2 and "none of the 3 images read could be decoded; nothing written" in err, err
    assert len(err.strip().splitlines()) == 1
    assert (run / "gaze.csv").read_bytes() == before and (run / "overlay.mp4").is_file()
    # into a new folder: the folders the run made are gone again ("nothing written")
    code, _, err = _run(["track", junk, "-o", tmp_path / "new" / "sub", "--model", model, "--quiet"], capsys)
    assert code == 2 and not (tmp_path / "new").exists(), err


def test_track_a_camera_that_stops_delivering(model, faces_dir, tmp_path, monkeypatch, capsys):
    """A camera that delivers frames and then none (unplugged): the run ends, the files complete."""
    import cv2

    photo = cv2.imread(str(face_photo(faces_dir, "astronaut.png", any_face=True)))

    class Camera:  # OpenCV's VideoCapture as a camera that goes away after 5 frames
        def __init__(self, index):
            self.n = 0

        def isOpened(self):
            return True

        def get(self, prop):
            return 30.0 if prop == cv2.CAP_PROP_FPS else 0.0

        def read(self):
            self.n += 1
            return (True, photo.copy()) if self.n <= 5 else (False, None)

        def release(self):
            pass

    monkeypatch.setattr(cv2, "VideoCapture", Camera)
    out = tmp_path / "t"
    code, stdout, err = _run(["track", "0", "-o", out, "--model", model, "--quiet", "--no-video"], capsys)
    assert code == 0, err
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["kind"] == "camera" and summary["frames"] == 5 and summary["unreadable_frames"] == 0
    assert len(_rows(out / "gaze.csv")) == 5
    times = [float(r["time_s"]) for r in _rows(out / "gaze.csv")]
    assert times == sorted(times)


def test_track_a_camera_file_without_an_image_size(model, video, tmp_path, capsys):
    """A calibration that gives no image size (MPIIGaze's Camera.mat, a bare OpenCV matrix) is read with
    the first frame's size (predict takes it with the image's); a bad one is still refused in one line."""
    import cv2

    cap = cv2.VideoCapture(str(video))
    w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    cap.release()
    cam = tmp_path / "cam.yaml"
    cam.write_text(
        "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        f"   data: [ {w:.1f}, 0., {(w - 1) / 2}, 0., {w:.1f}, {(h - 1) / 2}, 0., 0., 1. ]\n"
    )
    out = tmp_path / "o"
    argv = ["track", video, "-o", out, "--model", model, "--quiet", "--max-frames", 2, "--no-video"]
    code, stdout, err = _run([*argv, "--camera", cam], capsys)
    assert code == 0, err
    assert json.loads(stdout.strip().splitlines()[-1])["camera"] == str(cam)
    # a principal point far outside the first frame: refused with the frame's size named, nothing written
    cam.write_text(
        "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        f"   data: [ {w:.1f}, 0., {5.0 * w}, 0., {w:.1f}, {(h - 1) / 2}, 0., 0., 1. ]\n"
    )
    code, _, err = _run([*argv, "-o", tmp_path / "o2", "--camera", cam], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and str(cam) in err, err
    assert not (tmp_path / "o2" / "gaze.csv").exists()


def test_track_one_image_file_as_predict_reads_it(model, faces_dir, tmp_path, capsys):
    """One image file is a source of one frame, decoded as a folder's images and predict's are (not by
    FFmpeg, whose JPEG decoding differs): the same gaze as predict; an undecodable one is one line."""
    import cv2

    photo = tmp_path / "astronaut.jpg"  # a JPEG: FFmpeg's decoding of it differs from OpenCV's (a PNG's does not)
    cv2.imwrite(str(photo), cv2.imread(str(face_photo(faces_dir, "astronaut.png", any_face=True))))
    code, stdout, err = _run(["track", photo, "-o", tmp_path / "t", "--model", model, "--quiet", "--no-video"], capsys)
    assert code == 0, err
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["kind"] == "image" and summary["frames"] == 1
    row = _rows(tmp_path / "t" / "gaze.csv")[0]
    code, stdout, err = _run(["predict", model, photo], capsys)
    assert code == 0, err
    pitch, yaw = json.loads(stdout.strip().splitlines()[-1])["gaze_pitchyaw_camera_deg"]
    assert (float(row["raw_pitch_deg"]), float(row["raw_yaw_deg"])) == pytest.approx((pitch, yaw), abs=2e-3)
    fake = tmp_path / "fake.jpg"
    fake.write_text("not an image")
    code, _, err = _run(["track", fake, "-o", tmp_path / "f", "--model", model, "--quiet"], capsys)
    assert code == 2 and err.strip().endswith(f"{fake}: the image could not be decoded; nothing written"), err
    assert not (tmp_path / "f" / "gaze.csv").exists()


def test_track_overlay_keeps_frames_of_another_size(model, faces_dir, tmp_path, capsys):
    """A folder whose images differ in size: every frame is in overlay.mp4, scaled into the first's size
    (OpenCV's writer dropped the others without a word)."""
    import cv2

    photo = cv2.imread(str(face_photo(faces_dir, "astronaut.png", any_face=True)))
    src = tmp_path / "frames"
    src.mkdir()
    for i, scale in enumerate((1.0, 0.75, 1.0, 1.25)):
        cv2.imwrite(str(src / f"{i:03d}.png"), cv2.resize(photo, None, fx=scale, fy=scale))
    code, _, err = _run(["track", src, "-o", tmp_path / "t", "--model", model, "--quiet", "--static"], capsys)
    assert code == 0, err
    assert len(_rows(tmp_path / "t" / "gaze.csv")) == 4
    cap = cv2.VideoCapture(str(tmp_path / "t" / "overlay.mp4"))
    frames = []
    while True:
        ok, fr = cap.read()
        if not ok:
            break
        frames.append(fr)
    cap.release()
    assert len(frames) == 4 and {f.shape for f in frames} == {photo.shape}
    # the 0.75 frame scaled up into the first's size (a square in a square: the picture fills it)
    assert frames[1].astype(int).sum(axis=2)[:, :20].mean() > 10 and frames[1].astype(int).sum(axis=2)[:20].mean() > 10
    from gazeaug.track import _letterboxed

    wide = _letterboxed(np.full((10, 40, 3), 255, np.uint8), (40, 40))  # a wide frame in a square: bars
    assert wide[:15].max() == 0 and wide[25:].max() == 0 and wide[16:24].min() == 255


def test_track_leaves_nothing_when_the_frame_work_cannot_start(model, video, tmp_path, monkeypatch):
    """A failure after the output files were opened but before the first frame (the landmark model, the
    window): no part file, no folder the run made."""
    import gazeaug.track as track_mod
    from gazeaug.estimator import load_estimator

    def broken(*args, **kwargs):
        raise RuntimeError("no landmark model")

    monkeypatch.setattr(track_mod, "_FrameGaze", broken)
    with pytest.raises(RuntimeError, match="no landmark model"):
        track_mod.track(video, tmp_path / "new" / "o", load_estimator(model))
    assert not (tmp_path / "new").exists()


def test_ctrl_c_message_says_what_track_kept(tmp_path):
    """Ctrl-C before a frame was decoded keeps nothing (the folder made is gone): the message says so."""
    import argparse

    from gazeaug.cli import _interrupted

    args = argparse.Namespace(command="track", output=tmp_path / "o")
    assert _interrupted(args) is None  # run_command then names finished files or says nothing was written
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "summary.json").write_text("{}")
    assert _interrupted(args) == f"the outputs in {tmp_path / 'o'} are complete up to the last frame processed"
