"""The facemesh CLI end to end, and every bad input the issue lists."""

import json
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import face_photo

from facemesh import load
from facemesh.cli import main


def _no_leftovers(folder: Path, name: str) -> None:
    assert not (folder / name).exists()
    assert not [p for p in folder.iterdir() if p.name.endswith(".part")], "a temporary file was left behind"


def test_build_sample_info_render_export(tmp_path, capsys):
    glb = tmp_path / "sample.glb"
    assert main(["build", "-o", str(glb), "--preview", str(tmp_path / "preview.png")]) == 0
    assert "no camera calibration" in capsys.readouterr().err
    mesh = load(glb)
    assert mesh.num_vertices == 468 and mesh.num_triangles == 898
    assert mesh.extras["source_image"] == "skimage.data.astronaut"
    preview = cv2.imread(str(tmp_path / "preview.png"))
    assert preview is not None
    # the built-in sample's face is small: its panels are enlarged so the labels fit
    assert preview.shape[0] >= 360
    assert main(["info", str(glb), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["vertices"] == 468 and info["vertex_placement"] == "backprojected"
    view = tmp_path / "view.png"
    assert main(["render", str(glb), "--yaw", "20", "--pitch", "10", "-o", str(view)]) == 0
    img = cv2.imread(str(view))
    assert img.shape[:2] == (512, 512) and img.std() > 10
    obj = tmp_path / "model.obj"
    assert main(["model", "export", "mediapipe", "-o", str(obj)]) == 0
    text = obj.read_text()
    assert text.count("\nv ") == 468 and text.count("\nf ") == 898


def _mpii_image(folder):
    """The sample's image file (the real frame's .jpg, or the synthetic stand-in's .png)."""
    return folder / json.loads((folder / "annotation.json").read_text())["image"]


def test_build_with_calibration_and_face_model_file(mpii_sample, face_model_obj, tmp_path):
    from helpers import is_synthetic

    glb = tmp_path / "mpii.glb"
    args = [
        "build",
        str(_mpii_image(mpii_sample)),
        "-o",
        str(glb),
        "--camera",
        str(mpii_sample / "cameraCalib.xml"),
    ]
    assert main(args + ["--face-model", str(face_model_obj), "--vertices", "canonical"]) == 0
    mesh = load(glb)
    assert mesh.camera.has_distortion and mesh.face_model_name == face_model_obj.name
    if not is_synthetic(mpii_sample):  # p00 sits about 0.4 m from the camera; the synthetic face about 0.9 m
        assert 350 < mesh.pose.translation_mm[2] < 550


def test_user_landmarks_with_ball_pivoting(mpii_sample, tmp_path, detector):
    # 6 MPII landmarks are too few for a surface; use MediaPipe's 468 points
    # as "a user's detector" with a points-only face model.
    from facemesh import builtin_face_model, load_image_rgb
    from facemesh.landmarks import select_face

    img = load_image_rgb(_mpii_image(mpii_sample))
    pts = select_face(detector.detect(img)).points_px[:468]
    np.save(tmp_path / "lm.npy", pts)
    np.save(tmp_path / "model.npy", builtin_face_model().vertices_mm)
    glb = tmp_path / "user.glb"
    rc = main(
        [
            "build",
            str(_mpii_image(mpii_sample)),
            "-o",
            str(glb),
            "--landmarks",
            str(tmp_path / "lm.npy"),
            "--face-model",
            str(tmp_path / "model.npy"),
            "--camera",
            str(mpii_sample / "cameraCalib.xml"),
        ]
    )
    assert rc == 0
    mesh = load(glb)
    assert mesh.reconstruction["method"] == "bpa+fill" and mesh.reconstruction["radii_mm"]
    assert mesh.landmarks.model_name == "user:lm.npy"
    # six of them are too few for Ball-Pivoting: one line, exit 2, nothing written
    six = [33, 133, 362, 263, 61, 291]
    np.save(tmp_path / "lm6.npy", pts[six])
    np.save(tmp_path / "model6.npy", builtin_face_model().vertices_mm[six])
    rc = main(
        [
            "build",
            str(_mpii_image(mpii_sample)),
            "-o",
            str(tmp_path / "six.glb"),
            "--landmarks",
            str(tmp_path / "lm6.npy"),
        ]
        + ["--face-model", str(tmp_path / "model6.npy"), "--keypoints", "mpii6", "--reconstruct", "bpa"]
    )
    assert rc == 2 and not (tmp_path / "six.glb").exists()


def _write_png(path, img):
    ok, buf = cv2.imencode(".png", img)
    assert ok
    path.write_bytes(buf.tobytes())


@pytest.fixture(scope="module")
def face_bgr(faces_dir):
    return cv2.imread(str(face_photo(faces_dir, "sergey.png", any_face=True)), cv2.IMREAD_COLOR)


def _bad(tmp_path, capsys, args, match):
    out = tmp_path / "out.glb"
    rc = main(["build", *args, "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert match in err, err
    _no_leftovers(tmp_path, "out.glb")


def test_missing_file(tmp_path, capsys):
    _bad(tmp_path, capsys, [str(tmp_path / "nope.jpg")], "nope.jpg: no such file")


def test_the_preview_never_replaces_the_input_photo(tmp_path, capsys, face_bgr):
    photo = tmp_path / "me.png"
    cv2.imwrite(str(photo), face_bgr)
    before = photo.read_bytes()
    (tmp_path / "link.png").symlink_to(photo)  # the same file under another name
    for preview in (photo, tmp_path / "link.png"):
        _bad(tmp_path, capsys, [str(photo), "--preview", str(preview)], "the preview would replace the input photo")
        assert photo.read_bytes() == before


def test_not_an_image(tmp_path, capsys):
    p = tmp_path / "text.jpg"
    p.write_text("hello, I am not a picture")
    _bad(tmp_path, capsys, [str(p)], "text.jpg: not an image")


def test_truncated_image(tmp_path, capsys, face_bgr):
    ok, buf = cv2.imencode(".jpg", face_bgr)
    p = tmp_path / "cut.jpg"
    p.write_bytes(buf.tobytes()[: len(buf) // 2])
    _bad(tmp_path, capsys, [str(p)], "cut.jpg: the image file is truncated")


def test_image_without_a_face(tmp_path, capsys):
    p = tmp_path / "wall.png"
    _write_png(p, np.full((200, 300, 3), 90, np.uint8))
    _bad(tmp_path, capsys, [str(p)], "wall.png: no face found")


def test_tiny_image(tmp_path, capsys):
    p = tmp_path / "tiny.png"
    _write_png(p, np.zeros((10, 12, 3), np.uint8))
    _bad(tmp_path, capsys, [str(p)], "tiny.png: image is 12x10 pixels")


def test_face_index_out_of_range(tmp_path, capsys, faces_dir):
    photo = face_photo(faces_dir, "sergey.png", any_face=True)
    _bad(tmp_path, capsys, [str(photo), "--face-index", "3"], "face index 3")


@pytest.mark.parametrize("kind", ["grey", "rgba", "uint16"])
def test_grey_rgba_and_16bit_images_are_handled(tmp_path, face_bgr, kind):
    if kind == "grey":
        img = cv2.cvtColor(face_bgr, cv2.COLOR_BGR2GRAY)
    elif kind == "rgba":
        img = cv2.cvtColor(face_bgr, cv2.COLOR_BGR2BGRA)
    else:
        img = face_bgr.astype(np.uint16) * 257
    p = tmp_path / f"{kind}.png"
    _write_png(p, img)
    assert main(["build", str(p), "-o", str(tmp_path / f"{kind}.glb")]) == 0
    tex = load(tmp_path / f"{kind}.glb").texture
    assert tex.dtype == np.uint8 and tex.shape[2] == 3


def test_several_faces_pick_by_index(tmp_path, two_faces_photo):
    src = str(two_faces_photo)
    assert main(["build", src, "-o", str(tmp_path / "a.glb")]) == 0
    assert main(["build", src, "-o", str(tmp_path / "b.glb"), "--face-index", "1"]) == 0
    a, b = load(tmp_path / "a.glb"), load(tmp_path / "b.glb")
    assert a.extras["num_faces_found"] == 2

    def area(m):
        x0, y0, x1, y1 = m.landmarks.bbox_px
        return (x1 - x0) * (y1 - y0)

    assert area(a) > area(b)


def test_bad_landmark_files(tmp_path, capsys, mpii_sample):
    img = str(_mpii_image(mpii_sample))
    model = str(mpii_sample / "faceModelGeneric.txt")
    wrong = tmp_path / "wrong.npy"
    np.save(wrong, np.zeros((6, 3)))
    _bad(
        tmp_path,
        capsys,
        [img, "--landmarks", str(wrong), "--face-model", model],
        "wrong.npy: expected landmarks of shape (N, 2)",
    )
    nan = tmp_path / "nan.npy"
    np.save(nan, np.array([[1.0, 2.0]] * 5 + [[np.nan, 1.0]]))
    _bad(tmp_path, capsys, [img, "--landmarks", str(nan), "--face-model", model], "nan.npy: landmark 5 is NaN")
    seven = tmp_path / "seven.npy"
    np.save(seven, np.ones((7, 2)))
    _bad(tmp_path, capsys, [img, "--landmarks", str(seven), "--face-model", model], "7 points given")
    _bad(
        tmp_path,
        capsys,
        [img, "--landmarks", str(seven)],
        "landmarks given without their face model; pass --face-model",
    )


def test_malformed_calibrations(tmp_path, capsys, faces_dir):
    img = str(face_photo(faces_dir, "sergey.png", any_face=True))
    size = cv2.imread(img).shape[:2]
    garbage = tmp_path / "calib.xml"
    garbage.write_text("<?xml version='1.0'?><opencv_storage><camera_matrix>oops")
    _bad(tmp_path, capsys, [img, "--camera", str(garbage)], "calib.xml")
    no_k = tmp_path / "nok.yml"
    no_k.write_text("%YAML:1.0\n---\nfoo: 1\n")
    _bad(tmp_path, capsys, [img, "--camera", str(no_k)], "nok.yml: no camera matrix")
    wrong_size = tmp_path / "size.yml"
    fs = cv2.FileStorage(str(wrong_size), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]))
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.release()
    _bad(
        tmp_path,
        capsys,
        [img, "--camera", str(wrong_size)],
        f"calibration is for 640x480 images, but the image is {size[1]}x{size[0]}",
    )
    _bad(tmp_path, capsys, [img, "--camera", str(tmp_path / "none.xml")], "none.xml: calibration file not found")


def test_existing_output_survives_a_failed_build(tmp_path, capsys):
    out = tmp_path / "keep.glb"
    out.write_bytes(b"precious")
    rc = main(["build", str(tmp_path / "missing.png"), "-o", str(out)])
    assert rc == 2
    assert out.read_bytes() == b"precious"
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".part")]


def test_info_on_a_file_that_is_not_ours(tmp_path, capsys):
    p = tmp_path / "x.glb"
    p.write_bytes(b"glTF" + zlib.compress(b"nonsense"))
    assert main(["info", str(p)]) == 2
    assert "x.glb" in capsys.readouterr().err
