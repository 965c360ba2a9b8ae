"""UT Multiview raw reader on a miniature fixture in its layout, built from the p00 frame (real or synthetic).

The layout and the file formats are the ones the paper author's own reader and
renderer read (cedriclmenard/fastgaze ``gazeirislandmarks/datasets/utmultiview.py``
and ``utmultiview_render.py``; docs/datasets.md cites the lines), and the fixture
is written so that both those readers and HeegyoonKim/ArbGaze's
``code/preprocess_datasets.py`` read it (the tests below run their formulas,
written out by hand, on it):

- two captures x two cameras, images ``images/0000000K.jpg``;
- camera 0 is p00's calibrated camera (its image undistorted, as UT Multiview's
  images are) and the world frame is camera 0's (ArbGaze takes camera 0's
  matrix as ``K [I | 0]``); camera 1 shares its centre, turned 6 deg (its image
  is the exact homography K Q K^-1 of camera 0's); projection matrices ``K [R | t]``;
- ``headpose.txt``: header, head translation, head rotation (head -> world) in
  the head frame fastgaze's renderer needs (x toward the subject's left eye,
  y toward the chin, z into the head), header, six 3D landmarks (right eye's
  two corners, left eye's two, mouth's two), NumPy's bracketed print;
- the face mesh facemesh builds from the p00 frame, written as OBJ in world mm.
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
from gazeaug.pipeline import fit_face, mesh_for_fit
from gazeaug.render import create_renderer


def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


# camera 0 -> camera 1 (same centre); the world frame is camera 0's
Q = _rot("x", 6.0)
MONITOR_XY = ((250.0, 120.0), (40.0, 260.0))  # gaze targets on the monitor plane, one per capture
#: The six landmark rows in MediaPipe's indices: right eye's corners, left eye's, mouth's.
KEYPOINTS = (33, 133, 362, 263, 61, 291)


def _bracketed(a: np.ndarray) -> str:
    return np.array2string(np.asarray(a), precision=10, suppress_small=False, max_line_width=200)


def _headpose_text(t_head, r_head, marks) -> str:
    return f"head pose\n{_bracketed(t_head)}\n{_bracketed(r_head)}\nfeatures\n{_bracketed(marks)}\n"


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
    v_cam = np.asarray(mesh.vertices_mm)  # camera 0 = world
    g_cam = np.asarray(ann["gaze_target_3d_camera_mm"], dtype=np.float64)

    root = tmp_path_factory.mktemp("ut")
    raw = root / "s00" / "raw"
    raw.mkdir(parents=True)
    # monitor plane: axes those of camera 0 turned 180 deg about y; placed so capture 0's target is the real one
    r_m = _rot("y", 180.0)
    t_m = g_cam - r_m @ np.array([*MONITOR_XY[0], 0.0])
    (raw / "monitor.txt").write_text(f"monitor pose\n{_bracketed(t_m)}\n{_bracketed(r_m)}\n")
    (raw / "gazedata.csv").write_text("index,x,y\n" + "".join(f"{i},{x},{y}\n" for i, (x, y) in enumerate(MONITOR_XY)))
    marks_world = v_cam[list(KEYPOINTS)]
    r_head_world = np.asarray(fit.pose.rotation)
    t_head_world = np.asarray(fit.pose.translation_mm)
    tex_h, tex_w = mesh.texture.shape[:2]
    images = []
    for c in range(2):
        cap = raw / f"img{c:03d}"
        for sub in ("cparams", "images", "models"):
            (cap / sub).mkdir(parents=True)
        (cap / "headpose.txt").write_text(_headpose_text(t_head_world, r_head_world, marks_world))
        for i, (r_c, img) in enumerate(((np.eye(3), img0), (Q, img1))):
            p = k @ np.concatenate([r_c, np.zeros((3, 1))], axis=1)
            (cap / "cparams" / f"{i:08d}.txt").write_text(
                "projection matrix\n" + "\n".join(" ".join(f"{x:.10g}" for x in row) for row in p) + "\n"
            )
            path = cap / "images" / f"{i:08d}.jpg"
            cv2.imwrite(str(path), img, [cv2.IMWRITE_JPEG_QUALITY, 95])
            if c == 0:
                images.append(np.ascontiguousarray(cv2.imread(str(path))[:, :, ::-1]))
        # OBJ with texture coordinates and a material library that is not there (both ignored)
        uv = np.asarray(mesh.uv)
        lines = ["# face mesh", "mtllib face_mesh.mtl"]
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in v_cam]
        lines += [f"vt {a:.6f} {1 - b:.6f}" for a, b in uv]
        lines += ["f " + " ".join(f"{j + 1}/{j + 1}" for j in t) for t in np.asarray(mesh.triangles)]
        (cap / "models" / "face_mesh.obj").write_text("\n".join(lines) + "\n")
    truth = {
        "K": k,
        "image0": images[0],
        "image1": images[1],
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
        assert s.subject == "s00" and s.face is not None and s.face.mesh_path.name == "face_mesh.obj"
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
    expected = truth["gaze0"] + np.array([-d[0], d[1], 0.0])
    np.testing.assert_allclose(samples[2].gaze_target_mm, expected, atol=1e-4)


def _fastgaze_lines_to_array(lines: list[str]) -> np.ndarray:
    """fastgaze's ``lines_to_array`` (gazeirislandmarks/datasets/utmultiview.py lines 55-70), written out.

    It cuts NumPy's printed arrays at fixed places: the "[" before a vector ([1:-1]), the
    "[[" and " [" before a matrix's rows ([2:-1]), the "]]" after its last ([2:-2]); then
    ``np.fromstring(sep=" ")`` reads the numbers up to a "]". The asserts check the fixture
    has the characters it cuts.
    """

    def numbers(text: str) -> np.ndarray:
        return np.array(text.split("]")[0].split(), dtype=np.float64)

    if len(lines) == 1:
        assert lines[0].startswith("[") and lines[0].endswith("]\n")
        return numbers(lines[0][1:-1])
    assert lines[0].startswith("[[") and all(x.startswith(" [") for x in lines[1:]) and lines[-1].endswith("]]\n")
    rows = [numbers(lines[0][2:-1])] + [numbers(x[2:-1]) for x in lines[1:-1]] + [numbers(lines[-1][2:-2])]
    return np.stack(rows)


def _fastgaze_separate_projective_matrix2(p: np.ndarray):
    """fastgaze's ``separate_projective_matrix2`` (utmultiview.py lines 40-53), written out."""
    import scipy.linalg

    k, r = scipy.linalg.rq(p[:, :3])
    d = np.diag(np.sign(np.diag(k)))
    k, r = k @ d, d @ r
    return k, r, np.linalg.inv(k) @ p[:, 3]


def _fastgaze_labels(raw: Path) -> list[dict]:
    """What fastgaze's UTMultiviewDataset reads for each capture and camera (utmultiview.py lines 156-219)."""
    lines = (raw / "monitor.txt").open().readlines()
    monitor_t, monitor_r = _fastgaze_lines_to_array([lines[1]]), _fastgaze_lines_to_array(lines[2:])
    out = []
    for line in (raw / "gazedata.csv").open().readlines()[1:]:  # line 172: the header dropped
        data = line.split(",")
        g_w = monitor_r @ np.array([float(data[1]), float(data[2]), 0.0]) + monitor_t  # line 181
        sample_dir = raw / ("img" + data[0].zfill(3))  # line 183
        lines = (sample_dir / "headpose.txt").open().readlines()
        head_t = _fastgaze_lines_to_array([lines[1]])  # lines 187-189
        head_r = _fastgaze_lines_to_array(lines[2:5])
        features = _fastgaze_lines_to_array(lines[6:])
        for i in range(len(list((sample_dir / "cparams").glob("*.txt")))):  # fastgaze: range(8)
            lines = (sample_dir / "cparams" / ("0" * 7 + str(i) + ".txt")).open().readlines()
            camera_p = np.array([np.array(x.split(), dtype=np.float64) for x in lines[1:]])  # line 198
            c, r, t = _fastgaze_separate_projective_matrix2(camera_p)  # line 205
            out.append(
                {
                    "M": c,
                    "image": sample_dir / "images" / ("0" * 7 + str(i) + ".jpg"),  # line 211
                    "target": r @ g_w + t,  # line 212
                    "head_r": r @ head_r,  # line 213
                    "head_t": r @ head_t + t,  # line 214
                    "left_eye": r @ ((features[2] + features[3]) / 2.0) + t,  # line 218
                    "right_eye": r @ ((features[0] + features[1]) / 2.0) + t,  # line 219
                }
            )
    return out


def _arbgaze_labels(raw: Path) -> list[dict]:
    """What ArbGaze's preprocess_utmv reads (HeegyoonKim/ArbGaze code/preprocess_datasets.py lines 182-308)."""

    def cut(path: Path) -> list[list[str]]:  # lines 238-239
        return [x.lstrip(" [").rstrip("]\n").split() for x in path.open().readlines()]

    m = cut(raw / "monitor.txt")
    pose_t, pose_r = np.array(m[1], float), np.array(m[2:5], float)
    rows = [x.split(",") for x in (raw / "gazedata.csv").open().readlines()[1:]]  # lines 198-209: header skipped
    gt_2d = np.array([[float(r[1]), float(r[2])] for r in rows])
    world_targets = (pose_r @ np.c_[gt_2d, np.zeros(len(gt_2d))].T).T + pose_t  # lines 273-274
    out = []
    for i, folder in enumerate(sorted(raw.iterdir())[1:-1]):  # line 278: gazedata.csv, img000 ..., monitor.txt
        cparams = [
            np.array([x.split() for x in (folder / "cparams" / f).open().readlines()[1:4]], float)
            for f in sorted(p.name for p in (folder / "cparams").iterdir())
        ]
        h = cut(folder / "headpose.txt")
        head_r, ldmks = np.array(h[2:5], float), np.array(h[6:12], float)  # translation: h[1]
        k = cparams[0][:, :3]  # lines 285, 296: camera 0's matrix is K [I | 0]
        for p in cparams:
            r_t = np.linalg.inv(k) @ p  # line 298
            ldmks_3d = (r_t @ np.c_[ldmks, np.ones(6)].T).T  # line 304
            out.append(
                {
                    "target": r_t @ np.append(world_targets[i], 1.0),  # line 303
                    "head_r": r_t[:, :3] @ head_r,  # line 301
                    "right_eye": ldmks_3d[0:2].mean(axis=0),  # line 307
                    "left_eye": ldmks_3d[2:4].mean(axis=0),  # line 308
                }
            )
    return out


def test_reader_agrees_with_the_paper_authors_reader_and_arbgaze(ut):
    """Every label of every sample is what fastgaze's and ArbGaze's own UT Multiview readers compute."""
    root, _ = ut
    raw = root / "s00" / "raw"
    samples = list(open_dataset(root))
    fastgaze, arbgaze = _fastgaze_labels(raw), _arbgaze_labels(raw)
    assert len(samples) == len(fastgaze) == len(arbgaze) == 4
    for s, f, a in zip(samples, fastgaze, arbgaze):
        assert s.image_path == f["image"]
        np.testing.assert_allclose(s.camera.matrix, f["M"] / f["M"][2, 2], atol=1e-6)
        for ref in (f, a):
            np.testing.assert_allclose(s.gaze_target_mm, ref["target"], atol=1e-6)
            np.testing.assert_allclose(s.head_rotation, ref["head_r"], atol=1e-7)
            # rows 0-1 are the right eye's corners, rows 2-3 the left eye's
            np.testing.assert_allclose(s.face.landmarks_3d_mm[0:2].mean(axis=0), ref["right_eye"], atol=1e-6)
            np.testing.assert_allclose(s.face.landmarks_3d_mm[2:4].mean(axis=0), ref["left_eye"], atol=1e-6)
        np.testing.assert_allclose(s.head_translation_mm, f["head_t"], atol=1e-6)


def _obj_vertices(path: Path) -> np.ndarray:
    return np.array([x.split()[1:4] for x in path.read_text().splitlines() if x.startswith("v ")], dtype=np.float64)


def test_fixture_head_frame_is_the_one_fastgaze_renders(ut):
    """fastgaze's renderer fixes UT Multiview's head frame: x toward the left eye, y toward the chin, z into the head.

    Its camera for head pose (0, 0) sits at ``face - 600 mm * (0, 0, 1)`` of the head frame and
    looks along +z with its image's x along the head's x: it sees the face from the front, upright
    and unmirrored only if the head's z points into the head and y toward the chin. The fixture's
    head pose passes: the nose is nearest the camera, the mouth (rows 4-5) below the eyes, the
    left eye (rows 2-3) on the image's right.
    """
    root, _ = ut
    cap = root / "s00" / "raw" / "img000"
    lines = (cap / "headpose.txt").open().readlines()
    head_t, head_r = _fastgaze_lines_to_array([lines[1]]), _fastgaze_lines_to_array(lines[2:5])
    features = _fastgaze_lines_to_array(lines[6:])
    mesh = _obj_vertices(cap / "models" / "face_mesh.obj")
    f_h, m_h = (features - head_t) @ head_r, (mesh - head_t) @ head_r  # lines 263-272, new pose identity
    left, right = (f_h[2] + f_h[3]) / 2.0, (f_h[0] + f_h[1]) / 2.0  # lines 138-139
    face = (left + right) / 2.0  # line 145
    origin = face - 600.0 * np.array([0.0, 0.0, 1.0])  # lines 276-278: yaw_pitch_to_vector((0, 0)) = (0, 0, 1)
    forward = (face - origin) / np.linalg.norm(face - origin)  # lines 188-197, head pose identity: h_rx = (1, 0, 0)
    down = np.cross(forward, [1.0, 0.0, 0.0])
    down /= np.linalg.norm(down)
    right_axis = np.cross(down, forward)
    right_axis /= np.linalg.norm(right_axis)
    rot = np.c_[right_axis, down, forward]  # camera -> head (line 197)

    def view(points):
        c = (points - origin) @ rot  # head -> camera
        return 650.0 * c[:, 0] / c[:, 2] + 32.0, 650.0 * c[:, 1] / c[:, 2] + 32.0, c[:, 2]  # lines 57-59

    u, v, _ = view(f_h)
    assert v[4:6].mean() > v[0:4].mean() + 10  # the mouth below the eyes: upright
    assert u[2:4].mean() > u[0:2].mean() + 10  # the left eye on the image's right: not mirrored
    _, _, depth = view(m_h)
    _, _, eye_depth = view(f_h[0:4])
    assert depth.min() < eye_depth.mean() - 10  # the nose toward the camera: seen from the front


@pytest.mark.parametrize("index", [0, 1])
def test_dataset_mesh_renders_like_the_normalized_image(ut, index):
    """At the dataset's pose, the dataset's mesh seen through each camera reproduces that camera's image."""
    root, truth = ut
    sample = list(open_dataset(root))[index]
    image = sample.load_image()
    np.testing.assert_array_equal(image, truth[f"image{index}"])
    fit = sample.face.fit(sample, image)
    mesh = sample.face.mesh(fit, sample)
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
    fit_ds = sample.face.fit(sample, image)
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


def test_images_are_the_jpg_files_fastgaze_reads(ut, tmp_path):
    """fastgaze reads ``images/0000000K.jpg`` (utmultiview.py line 211): another file beside it is not the image."""
    raw = _copy(ut[0], tmp_path / "copy")
    images = raw / "img000" / "images"
    cv2.imwrite(str(images / "00000000.bmp"), np.zeros((8, 8, 3), np.uint8))
    s = next(iter(UTMultiview(tmp_path / "copy")))
    h, w = ut[1]["image0"].shape[:2]
    assert s.image_path == images / "00000000.jpg" and s.camera.image_size == (w, h)
    (images / "00000000.jpg").unlink()  # other extensions are read when there is no .jpg
    assert next(iter(UTMultiview(tmp_path / "copy"))).image_path == images / "00000000.bmp"


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


@pytest.mark.parametrize(
    "turn",
    [
        pytest.param(_rot("z", 180.0), id="x-right-y-up"),
        pytest.param(_rot("x", 180.0), id="x-left-y-up-z-out-of-the-face"),
    ],
)
def test_head_frame_of_another_convention_is_refused(ut, tmp_path, turn):
    """A head frame fastgaze's renderer would see from behind or upside down is refused, never flipped."""
    raw = _copy(ut[0], tmp_path / "copy")
    f = raw / "img000" / "headpose.txt"
    pose, marks = (b for _, b in read_number_blocks(f))
    t, r = pose[:3], pose[3:].reshape(3, 3) @ turn
    f.write_text(_headpose_text(t, r, marks.reshape(6, 3)))
    sample = next(iter(UTMultiview(tmp_path / "copy")))
    with pytest.raises(DatasetError, match="head-frame convention"):
        sample.face.fit(sample, sample.load_image())


@pytest.mark.parametrize("name", ["gazedata.csv", "monitor.txt", "img000/headpose.txt", "img000/cparams/00000001.txt"])
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


def test_redirected_eyes_refuse_the_dataset_faces_before_any_work(ut, tmp_path, capsys):
    """UT Multiview brings its own head models (no eye contours or iris points): one line, exit 2, nothing written."""
    from gazeaug.cli import main

    root, _ = ut
    out = tmp_path / "red.h5"
    assert main(["augment", str(root), "-o", str(out), "--rig", "wheelchair", "--redirect-eyes", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "redirected eyes need faces found by MediaPipe" in err[0], err
    assert not out.exists() and not out.with_name(out.name + ".part").exists()
