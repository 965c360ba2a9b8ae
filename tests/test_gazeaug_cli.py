"""The gazeaug command line: outputs, recorded parameters, bad input (exit 2, nothing written)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import face_photo

from gazeaug.cli import main
from gazeaug.normalize import load_npz


@pytest.fixture(scope="module")
def glb(tmp_path_factory, faces_dir):
    from facemesh.cli import main as facemesh_main

    out = tmp_path_factory.mktemp("glb") / "face.glb"
    assert facemesh_main(["build", str(face_photo(faces_dir, "sergey.png", any_face=True)), "-o", str(out)]) == 0
    return out


def test_normalize_the_mpii_sample(mpii_sample, tmp_path, capsys):
    ann = json.loads((mpii_sample / "annotation.json").read_text())
    lm = tmp_path / "lm.json"
    lm.write_text(json.dumps(ann["landmarks_6_px"]))
    out = tmp_path / "n.npz"
    args = [
        "normalize",
        str(mpii_sample / ann["image"]),
        "--camera",
        str(mpii_sample / "cameraCalib.xml"),
        "--landmarks",
        str(lm),
        "--face-model",
        str(mpii_sample / "faceModelGeneric.txt"),
        "--keypoints",
        "mpii6",
        "--gaze-target",
        *map(str, ann["gaze_target_3d_camera_mm"]),
        "-o",
        str(out),
    ]
    without = [a for a in args if a not in ("--keypoints", "mpii6")]
    assert main(without) == 2  # a plain 6-point matrix does not say which points are the eye corners
    assert "pass --keypoints" in capsys.readouterr().err
    assert main(args) == 0
    z = load_npz(out)
    assert z["left_eye"].shape == (36, 60, 3) and "gaze_left" in z and "gaze_right" in z
    report = json.loads(capsys.readouterr().out)
    assert report["gaze_left_deg"] == pytest.approx(np.degrees(z["gaze_left"]).tolist(), abs=1e-3)
    # settings are recorded
    assert main(args[:-2] + ["--distance", "500", "--focal", "960", "--patch-size", "64", "40", "-o", str(out)]) == 0
    z = load_npz(out)
    assert float(z["distance_mm"]) == 500 and float(z["focal_px"]) == 960 and z["left_eye"].shape == (40, 64, 3)


def test_render_from_glb_and_image(glb, faces_dir, tmp_path):
    out = tmp_path / "r.npz"
    assert main(["render", str(glb), "--original-pose", "-o", str(out)]) == 0
    z = load_npz(out)
    assert str(z["source"]) == "render:raycast" and "gaze_left" not in z
    assert (
        main(["render", str(glb), "--yaw", "10", "--pitch", "30", "--gaze-target", "0", "0", "0", "-o", str(out)]) == 0
    )
    z = load_npz(out)
    assert z["meta"]["yaw_pitch_deg"] == pytest.approx([10, 30]) and "gaze_left" in z
    assert main(["render", str(glb), "--seed", "3", "--yaw-std", "10", "-o", str(out)]) == 0
    a = load_npz(out)["meta"]["yaw_pitch_deg"]
    assert main(["render", str(glb), "--seed", "3", "--yaw-std", "10", "-o", str(out)]) == 0
    assert load_npz(out)["meta"]["yaw_pitch_deg"] == a  # seeded
    assert main(["render", str(faces_dir / "astronaut.png"), "--rig", "wheelchair", "-o", str(out)]) == 0


def test_preview_writes_the_sheet_and_the_plot(glb, tmp_path):
    out = tmp_path / "sheet.png"
    assert main(["preview", str(glb), "-n", "6", "-o", str(out)]) == 0
    assert out.is_file() and (tmp_path / "sheet_distribution.png").is_file()


def test_ctrl_c_after_the_sheet_names_it_and_not_the_plot(glb, tmp_path, monkeypatch, capsys):
    """A Ctrl-C between preview's two outputs: the sheet is whole, the plot absent, and the line says so."""
    import gazeaug.viz

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(gazeaug.viz, "plot_distributions", interrupt)
    out = tmp_path / "sheet.png"
    assert main(["preview", str(glb), "-n", "2", "-o", str(out)]) == 130
    err = capsys.readouterr().err.strip()
    assert err == f"gazeaug preview: interrupted; wrote {out} whole before it; nothing else was written"
    assert out.is_file() and not (tmp_path / "sheet_distribution.png").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["sheet.png"]  # no temporary file left


def test_bench_prints_one_json_line(capsys):
    assert main(["bench", "render", "--n", "4", "--per-face", "2"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    result = json.loads(line)
    assert result["renderer"] == "raycast" and result["patches"] == 8 and result["patches_per_second"] > 0


@pytest.mark.parametrize(
    "args, message",
    [
        (["render", "MISSING.png", "-o", "{out}"], "MISSING.png"),
        (["render", "{glb}", "--yaw-var", "-1", "-o", "{out}"], ">= 0"),
        (["render", "{glb}", "--yaw-var", "nan", "-o", "{out}"], "finite"),
        (["render", "{glb}", "--yaw", "10", "-o", "{out}"], "both --yaw and --pitch"),
        (["render", "{bad_glb}", "--original-pose", "-o", "{out}"], "bad.glb"),
        (["render", "{glb}", "--gaze-target", "0", "0", "nan", "-o", "{out}"], "finite"),
        (["normalize", "{glb}", "-o", "{out}"], "face.glb"),
        (["render", "{glb}", "--rig", "nowhere", "-o", "{out}"], "nowhere"),
        # options a fixed pose would silently ignore are refused
        (["render", "{glb}", "--yaw", "0", "--pitch", "30", "--rig", "wheelchair", "-o", "{out}"], "--rig: not used"),
        (["render", "{glb}", "--yaw", "0", "--pitch", "30", "--seed", "3", "-o", "{out}"], "--seed: not used"),
        (["render", "{glb}", "--original-pose", "--yaw-std", "5", "-o", "{out}"], "--yaw-std: not used"),
        (["render", "{glb}", "--original-pose", "--distance-to-camera", "500", "-o", "{out}"], "--distance-to-camera"),
    ],
)
def test_bad_input_exits_2_and_writes_nothing(glb, tmp_path, capsys, args, message):
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF not really")
    out = tmp_path / "out.npz"
    filled = [a.format(out=out, glb=glb, bad_glb=bad) for a in args]
    assert main(filled) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()
    assert not list(tmp_path.glob(".*.part")) and not list(tmp_path.glob("*.part"))


def test_render_points_only_asset_asks_for_keypoints(tmp_path, capsys, detector):
    """A .glb of a face model without key points (a sparse layout) names --keypoints, and renders with it."""
    from facemesh.build import sample_image
    from facemesh.cli import main as facemesh_main
    from facemesh.face_models.layouts import sparse_face_model
    from facemesh.io import save_image_rgb
    from facemesh.landmarks import select_face

    model, idx = sparse_face_model("dlib68")
    photo = tmp_path / "photo.png"
    save_image_rgb(photo, sample_image())
    np.save(tmp_path / "lm68.npy", select_face(detector.detect(sample_image())).points_px[idx])
    np.save(tmp_path / "model68.npy", model.vertices_mm)
    glb = tmp_path / "f68.glb"
    build = ["build", str(photo), "-o", str(glb), "--landmarks", str(tmp_path / "lm68.npy")]
    assert facemesh_main([*build, "--face-model", str(tmp_path / "model68.npy")]) == 0
    out = tmp_path / "r.npz"
    assert main(["render", str(glb), "--yaw", "0", "--pitch", "20", "-o", str(out)]) == 2
    assert "give them with --keypoints" in capsys.readouterr().err and not out.exists()
    assert main(["render", str(glb), "--yaw", "0", "--pitch", "20", "--keypoints", "dlib68", "-o", str(out)]) == 0
    assert out.is_file()


def test_an_output_that_would_replace_an_input_is_refused(tmp_path, capsys):
    """predict's picture over its own photo (also through a link), calibrate's file over its targets or
    over the source folder's sequence.json: one line, exit 2, before any work, the input unchanged."""
    photo = tmp_path / "p.png"
    photo.write_bytes(b"my photo")
    link = tmp_path / "l.png"
    link.symlink_to(photo)
    model = tmp_path / "m.pt"
    model.write_bytes(b"never read")
    seq = tmp_path / "seq"
    seq.mkdir()
    (seq / "sequence.json").write_text('{"fps": 10}')
    targets = tmp_path / "t.json"
    targets.write_text("{}")
    plot = tmp_path / "me_distribution.png"
    plot.write_bytes(b"my picture")
    cases = [
        (["predict", model, photo, "-o", photo], photo, photo),
        (["predict", model, link, "-o", photo], photo, link),
        (["calibrate", seq, "-o", seq / "sequence.json"], seq / "sequence.json", seq / "sequence.json"),
        (["calibrate", seq, "--targets", targets, "-o", targets], targets, targets),
        (["preview", plot, "-o", tmp_path / "me.png"], plot, plot),  # the sheet's plot over its input
    ]
    for argv, out, given in cases:
        before = out.read_bytes()
        assert main([str(a) for a in argv]) == 2
        err = capsys.readouterr().err
        assert err.strip() == (
            f"gazeaug {argv[0]}: error: {out}: the output would replace the input {given}; choose another -o"
        ), err
        assert out.read_bytes() == before
    # a new file beside the inputs is not refused by this check (the model is then found unreadable)
    assert main(["predict", str(model), str(photo), "-o", str(tmp_path / "new.png")]) == 2
    assert "would replace" not in capsys.readouterr().err
