"""UT Multiview raw reader on a miniature fixture in its layout, built from the real p00 frame.

The fixture: two captures x two cameras. Camera 0 is p00's calibrated camera
(its image undistorted, as UT Multiview's images are); camera 1 shares its
centre, turned 6 deg (its image is the exact homography K Q K^-1 of camera 0's).
The world frame is camera 0's, moved by a known rigid transform; the projection
matrices carry arbitrary scales (one negative). The face mesh is the one
facemesh builds from the p00 frame, written as OBJ in world coordinates.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from facemesh.camera import load_camera
from facemesh.conventions import angular_error_deg, pitchyaw_to_vector
from facemesh.types import CameraIntrinsics
from gazeaug.augment import face_asset, render_poses, source_placement
from gazeaug.datasets import DatasetError, detect_format, open_dataset
from gazeaug.datasets.utmultiview import UTMultiview, decompose_projection, read_number_blocks
from gazeaug.io_h5 import read_h5
from gazeaug.jobs import JobSettings, run_dataset
from gazeaug.normalize import normalize_image
from gazeaug.pipeline import dataset_mesh, fit_face, fit_from_dataset, mesh_for_fit
from gazeaug.render import create_renderer


def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


# world -> camera 0, and camera 0 -> camera 1 (same centre)
R0, T0 = _rot("y", 10.0) @ _rot("x", -4.0), np.array([20.0, -10.0, 30.0])
Q = _rot("x", 6.0)
SCALES = (2.5, -1.7)  # projection matrices are defined up to scale
MONITOR_XY = ((250.0, 120.0), (40.0, 260.0))  # gaze targets on the monitor plane, one per capture


def _bracketed(a: np.ndarray) -> str:
    return np.array2string(np.asarray(a), precision=10, suppress_small=False, max_line_width=200)


@pytest.fixture(scope="module")
def ut(tmp_path_factory, mpii_sample, detector):
    """Build ``s00/raw`` and return (root, truth)."""
    ann = json.loads((mpii_sample / "annotation.json").read_text())
    cam = load_camera(mpii_sample / "cameraCalib.xml", image_size=tuple(ann["image_size_wh"]))
    k = np.asarray(cam.matrix)
    bgr = cv2.imread(str(mpii_sample / ann["image"]))
    img0 = cv2.undistort(bgr, k, np.asarray(cam.distortion))
    h, w = img0.shape[:2]
    img1 = cv2.warpPerspective(img0, k @ Q @ np.linalg.inv(k), (w, h), flags=cv2.INTER_LINEAR)
    pinhole = CameraIntrinsics(matrix=k, distortion=np.zeros(5), image_size=(w, h))
    fit = fit_face(np.ascontiguousarray(img0[:, :, ::-1]), pinhole, detector)
    mesh = mesh_for_fit(fit)
    v_cam = np.asarray(mesh.vertices_mm)
    to_world = lambda p: (np.asarray(p) - T0) @ R0  # noqa: E731 - camera 0 -> world
    g_cam = np.asarray(ann["gaze_target_3d_camera_mm"], dtype=np.float64)

    root = tmp_path_factory.mktemp("ut")
    raw = root / "s00" / "raw"
    raw.mkdir(parents=True)
    # monitor plane: axes those of camera 0 turned 180 deg about y; placed so capture 0's target is the real one
    r_m = R0.T @ _rot("y", 180.0)
    t_m = to_world(g_cam) - r_m @ np.array([*MONITOR_XY[0], 0.0])
    (raw / "monitor.txt").write_text(f"monitor pose\n{_bracketed(t_m)}\n{_bracketed(r_m)}\n")
    (raw / "gazedata.csv").write_text("index,x,y\n" + "".join(f"{i},{x},{y}\n" for i, (x, y) in enumerate(MONITOR_XY)))
    kp = (33, 133, 362, 263, 61, 291)  # MediaPipe: right eye's corners, left eye's, mouth's
    marks_world = to_world(v_cam[list(kp)])
    r_head_world = R0.T @ np.asarray(fit.pose.rotation)
    t_head_world = to_world(np.asarray(fit.pose.translation_mm))
    tex_h, tex_w = mesh.texture.shape[:2]
    for c in range(2):
        cap = raw / f"img{c:03d}"
        for sub in ("cparams", "images", "models"):
            (cap / sub).mkdir(parents=True)
        (cap / "headpose.txt").write_text(
            "head pose\n"
            + f"{_bracketed(t_head_world)}\n{_bracketed(r_head_world)}\n"
            + "features\n"
            + f"{_bracketed(marks_world)}\n"
        )
        for i, (r_c, t_c, img) in enumerate(((R0, T0, img0), (Q @ R0, Q @ T0, img1))):
            p = SCALES[i] * k @ np.concatenate([r_c, t_c[:, None]], axis=1)
            (cap / "cparams" / f"{i:08d}.txt").write_text(
                "projection matrix\n" + "\n".join(" ".join(f"{x:.10g}" for x in row) for row in p) + "\n"
            )
            cv2.imwrite(str(cap / "images" / f"{i:08d}.png"), img)
        # OBJ with texture coordinates and a material library that is not there (both ignored)
        uv = np.asarray(mesh.uv)
        lines = ["# face mesh", "mtllib face_mesh.mtl"]
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in to_world(v_cam)]
        lines += [f"vt {a:.6f} {1 - b:.6f}" for a, b in uv]
        lines += ["f " + " ".join(f"{j + 1}/{j + 1}" for j in t) for t in np.asarray(mesh.triangles)]
        (cap / "models" / "face_mesh.obj").write_text("\n".join(lines) + "\n")
    truth = {
        "K": k,
        "image0": np.ascontiguousarray(img0[:, :, ::-1]),
        "image1": np.ascontiguousarray(img1[:, :, ::-1]),
        "gaze0": g_cam,
        "pose": fit.pose,
        "vertices": v_cam,
        "tex": (tex_w, tex_h),
    }
    return root, truth


def test_decompose_projection_recovers_k_r_t():
    k = np.array([[900.0, 0.5, 640.0], [0.0, 905.0, 360.0], [0.0, 0.0, 1.0]])
    r = _rot("z", 20.0) @ _rot("y", -35.0) @ _rot("x", 12.0)
    t = np.array([-30.0, 15.0, 700.0])
    for scale in (1.0, 3.7, -0.02):
        kk, rr, tt = decompose_projection(scale * k @ np.concatenate([r, t[:, None]], axis=1))
        np.testing.assert_allclose(kk, k, atol=1e-9)
        np.testing.assert_allclose(rr, r, atol=1e-12)
        np.testing.assert_allclose(tt, t, atol=1e-9)
    with pytest.raises(DatasetError, match="singular"):
        decompose_projection(np.zeros((3, 4)))


def test_number_blocks_read_bracketed_and_bare(tmp_path):
    f = tmp_path / "a.txt"
    f.write_text("header\n[ 1.  2.  3.]\n[[1 0 0]\n [0 1 0]\n [0 0 1]]\nnext\n4,5\n")
    blocks = read_number_blocks(f)
    assert [b[0] for b in blocks] == [2, 7]
    np.testing.assert_array_equal(blocks[0][1], [1, 2, 3, 1, 0, 0, 0, 1, 0, 0, 0, 1])
    np.testing.assert_array_equal(blocks[1][1], [4, 5])


def test_reader_gives_each_camera_its_frame(ut):
    root, truth = ut
    assert detect_format(root) == "utmultiview"
    reader = open_dataset(root)
    assert isinstance(reader, UTMultiview) and len(reader) == 4
    samples = list(reader)
    assert [s.source_index for s in samples] == [0, 1, 2, 3]
    assert [(s.extras["capture"], s.extras["camera"]) for s in samples] == [
        ("img000", 0),
        ("img000", 1),
        ("img001", 0),
        ("img001", 1),
    ]
    for s in samples:
        np.testing.assert_allclose(s.camera.matrix, truth["K"], atol=1e-6)
        assert s.camera.image_size == truth["image0"].shape[1::-1] and not s.camera.distortion.any()
        assert s.subject == "s00" and s.mesh_path is not None and s.mesh_path.name == "face_mesh.obj"
    # capture 0, camera 0: the real p00 gaze target and the pose the mesh was built at
    s0, s1 = samples[0], samples[1]
    np.testing.assert_allclose(s0.gaze_target_mm, truth["gaze0"], atol=1e-4)
    np.testing.assert_allclose(s0.head_rotation, truth["pose"].rotation, atol=1e-6)
    np.testing.assert_allclose(s0.head_translation_mm, truth["pose"].translation_mm, atol=1e-4)
    # camera 1 is camera 0 turned by Q about its centre
    np.testing.assert_allclose(s1.gaze_target_mm, Q @ truth["gaze0"], atol=1e-4)
    np.testing.assert_allclose(s1.head_rotation, Q @ truth["pose"].rotation, atol=1e-6)
    # capture 1: another point of the monitor plane, (x, y) -> (-x, y) in camera 0's axes
    d = np.array([MONITOR_XY[1][0] - MONITOR_XY[0][0], MONITOR_XY[1][1] - MONITOR_XY[0][1], 0.0])
    expected = truth["gaze0"] + R0 @ (R0.T @ _rot("y", 180.0)) @ d
    np.testing.assert_allclose(samples[2].gaze_target_mm, expected, atol=1e-4)


@pytest.mark.parametrize("index", [0, 1])
def test_dataset_mesh_renders_like_the_normalized_image(ut, index):
    """At the dataset's pose, the dataset's mesh seen through each camera reproduces that camera's image."""
    root, truth = ut
    sample = list(open_dataset(root))[index]
    image = sample.load_image()
    np.testing.assert_array_equal(image, truth[f"image{index}"])
    fit = fit_from_dataset(sample, image)
    mesh = dataset_mesh(fit, sample)
    assert mesh.num_vertices == len(truth["vertices"]) and mesh.vertex_placement == "dataset"
    real = normalize_image(
        image, fit.camera, fit.pose, fit.model.vertices_mm, fit.keypoints, gaze_target_mm=sample.gaze_target_mm
    )
    asset = face_asset(mesh)
    renderer = create_renderer("raycast")
    (rendered,) = render_poses(
        renderer.scene(asset.render_mesh), asset, [source_placement(asset)], gaze_target_mm=sample.gaze_target_mm
    )
    for side in ("left", "right"):
        a, b = real.eye(side), rendered.eye(side)
        mad = np.abs(a.image.astype(float) - b.image.astype(float)).mean()
        assert mad < 1.5, f"{side}: {mad:.2f} grey levels"
        assert angular_error_deg(pitchyaw_to_vector(a.gaze), pitchyaw_to_vector(b.gaze)) < 1e-6
        np.testing.assert_allclose(a.head_pose, b.head_pose, atol=1e-9)


def test_dataset_labels_agree_with_detected_landmarks(ut, detector):
    """The dataset path (its pose and 6 landmarks) and the MediaPipe path give the same labels on camera 1."""
    root, _ = ut
    sample = list(open_dataset(root))[1]
    image = sample.load_image()
    fit_ds = fit_from_dataset(sample, image)
    fit_mp = fit_face(image, sample.camera, detector)
    a = normalize_image(
        image,
        sample.camera,
        fit_ds.pose,
        fit_ds.model.vertices_mm,
        fit_ds.keypoints,
        gaze_target_mm=sample.gaze_target_mm,
    )
    b = normalize_image(
        image,
        sample.camera,
        fit_mp.pose,
        fit_mp.model.vertices_mm,
        fit_mp.keypoints,
        gaze_target_mm=sample.gaze_target_mm,
    )
    for side in ("left", "right"):
        assert angular_error_deg(pitchyaw_to_vector(a.eye(side).gaze), pitchyaw_to_vector(b.eye(side).gaze)) < 1.0


def test_augment_uses_the_dataset_meshes(ut, tmp_path):
    root, _ = ut
    out = tmp_path / "ut.h5"
    summary = run_dataset(open_dataset(root), out, JobSettings(kind="augment", per_sample=2, seed=1), progress=False)
    assert summary["rows"] == 8 and summary["skipped"] == 0 and summary["dataset_format"] == "utmultiview"
    d = read_h5(out)
    assert d["left_eye"].shape == (8, 36, 60, 3)
    assert list(d["source_index"]) == [0, 0, 1, 1, 2, 2, 3, 3]
    assert (d["left_eye"].reshape(8, -1).std(axis=1) > 5).all()  # textured eyes, not background
    summary = run_dataset(open_dataset(root), tmp_path / "n.h5", JobSettings(kind="normalize-dataset"), progress=False)
    assert summary["rows"] == 4 and summary["skipped"] == 0
    # the command line, two worker processes: the same rows
    from gazeaug.cli import main

    out2 = tmp_path / "ut2.h5"
    args = ["augment", str(root), "-o", str(out2), "--format", "utmultiview", "--per-sample", "2", "--seed", "1"]
    assert main([*args, "--workers", "2", "--quiet"]) == 0
    d2 = read_h5(out2)
    np.testing.assert_array_equal(d2["left_eye"], d["left_eye"])
    np.testing.assert_array_equal(d2["gaze"], d["gaze"])


def _copy(root: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(root, dst)
    return dst / "s00" / "raw"


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda raw: (raw / "img000" / "cparams" / "00000001.txt").write_text("P\n1 2 3 4\n5 6 7 8\n9 10 11\n"),
            r"00000001.txt, line 2: expected 12 numbers",
        ),
        (lambda raw: (raw / "img001" / "models" / "face_mesh.obj").unlink(), r"img001/models/face_mesh.obj: .*missing"),
        (
            lambda raw: (raw / "gazedata.csv").write_text("index,x,y\n0,1\n"),
            r"gazedata.csv, line 2: expected at least 3",
        ),
        (lambda raw: (raw / "gazedata.csv").write_text("index,x,y\n7,1,2\n"), r"gazedata.csv, line 2: capture folder"),
        (lambda raw: (raw / "monitor.txt").write_text("m\n1 2 3\n1 0 0 0 2 0 0 0 1\n"), r"monitor.txt: rotation"),
        (
            lambda raw: (raw / "img000" / "headpose.txt").write_text("h\n1 2 3\n1 0 0 0 1 0 0 0 1\n"),
            r"headpose.txt: expected 2 blocks",
        ),
        (lambda raw: [p.unlink() for p in (raw / "img000" / "images").glob("00000000.*")], r"no image 00000000"),
    ],
)
def test_bad_files_name_file_and_line(ut, tmp_path, edit, message):
    raw = _copy(ut[0], tmp_path / "copy")
    edit(raw)
    with pytest.raises(DatasetError, match=message):
        list(UTMultiview(tmp_path / "copy"))


def test_head_frame_of_another_convention_is_refused(ut, tmp_path):
    raw = _copy(ut[0], tmp_path / "copy")
    f = raw / "img000" / "headpose.txt"
    pose, marks = (b for _, b in read_number_blocks(f))
    t, r = pose[:3], pose[3:].reshape(3, 3) @ _rot("z", 180.0)  # x toward the subject's right, y up
    f.write_text(f"h\n{_bracketed(t)}\n{_bracketed(r)}\nf\n{_bracketed(marks.reshape(6, 3))}\n")
    sample = next(iter(UTMultiview(tmp_path / "copy")))
    with pytest.raises(DatasetError, match="head-frame convention"):
        fit_from_dataset(sample, sample.load_image())


@pytest.mark.parametrize(
    "name", ["gazedata.csv", "monitor.txt", "img000/headpose.txt", "img000/cparams/00000001.txt"]
)
def test_fuzzed_files_give_typed_errors(ut, tmp_path, name):
    """Damaged files: the reader's typed error (exit 2 at the CLI), never another exception."""
    from helpers import expect_typed_error, mutations

    raw = _copy(ut[0], tmp_path / "copy")
    valid = (raw / name).read_bytes()
    root = raw.parent.parent

    def read(_):
        return [(s.subject, s.camera) for s in open_dataset(root)]

    for data in mutations(valid, seed=len(name), n=20):
        expect_typed_error(read, raw / name, data)
