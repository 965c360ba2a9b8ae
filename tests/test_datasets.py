"""Dataset readers on miniature fixtures in each exact format, and the augment / normalize-dataset runs."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import face_photo, shared_data_dir

from facemesh.camera import load_camera
from facemesh.outputs import OutputExistsError
from gazeaug.cli import main
from gazeaug.datasets import DatasetError, detect_format, open_dataset
from gazeaug.datasets.folder import FolderDataset
from gazeaug.datasets.mpiifacegaze import MPIIFaceGaze
from gazeaug.errors import GazeAugError
from gazeaug.io_h5 import part_path, read_h5
from gazeaug.jobs import JobSettings, run_dataset


def _p00(mpii_sample):
    """The p00 sample's annotation and calibrated camera (the real frame, or the synthetic stand-in)."""
    ann = json.loads((mpii_sample / "annotation.json").read_text())
    return ann, load_camera(mpii_sample / "cameraCalib.xml", image_size=tuple(ann["image_size_wh"]))


def _mpii_line(image, lm, rvec, tvec, fc, gt):
    vals = [image, "1200", "300"] + [f"{v:.1f}" for v in lm.ravel()] + [f"{v:.6f}" for v in (*rvec, *tvec, *fc, *gt)]
    return " ".join(vals + ["left"])


@pytest.fixture(scope="module")
def mpii_root(tmp_path_factory, mpii_sample):
    """pXX layout: two p00 frames and one image without a face; Camera.mat from the sample's calibration."""
    import scipy.io

    ann, cam = _p00(mpii_sample)
    root = tmp_path_factory.mktemp("mpii")
    (root / "p00" / "day01").mkdir(parents=True)
    (root / "p00" / "Calibration").mkdir()
    scipy.io.savemat(
        root / "p00" / "Calibration" / "Camera.mat",
        {"cameraMatrix": cam.matrix, "distCoeffs": cam.distortion.reshape(1, -1)},
    )
    for name in ("0087", "0088"):
        shutil.copy(mpii_sample / ann["image"], root / "p00" / "day01" / f"{name}.jpg")
    w, h = ann["image_size_wh"]
    cv2.imwrite(str(root / "p00" / "day01" / "0089.jpg"), np.full((h, w, 3), 128, np.uint8))
    fm = np.loadtxt(mpii_sample / "faceModelGeneric.txt")
    lm = np.array(ann["landmarks_6_px"])
    _, rvec, tvec = cv2.solvePnP(fm.T.reshape(-1, 1, 3), lm.reshape(-1, 1, 2), cam.matrix, cam.distortion)
    fc = (cv2.Rodrigues(rvec)[0] @ fm + tvec).mean(axis=1)
    gt = ann["gaze_target_3d_camera_mm"]
    lines = [_mpii_line(f"day01/{n}.jpg", lm, rvec.ravel(), tvec.ravel(), fc, gt) for n in ("0087", "0088", "0089")]
    (root / "p00" / "p00.txt").write_text("\n".join(lines) + "\n")
    return root


@pytest.fixture(scope="module")
def folder_root(tmp_path_factory, faces_dir):
    """Two photos with labels.csv, and a copy with labels.jsonl: astronaut and sergey, or the astronaut twice."""
    root = tmp_path_factory.mktemp("folder")
    rows = ["image,subject,fx,fy,cx,cy,target_x,target_y,target_z"]
    jsonl = []
    second = face_photo(faces_dir, "sergey.png", any_face=True)
    photos = {
        "astronaut.png": faces_dir / "astronaut.png",
        "sergey.png" if second.name == "sergey.png" else "copy.png": second,
    }
    names = tuple(photos)
    for i, (name, src) in enumerate(photos.items()):
        img = cv2.imread(str(src))
        h, w = img.shape[:2]
        shutil.copy(src, root / name)
        f = max(w, h)
        rows.append(f"{name},s{i},{f},{f},{w / 2 - 0.5},{h / 2 - 0.5},0,150,0")
        jsonl.append(
            {
                "image": name,
                "subject": f"s{i}",
                "fx": f,
                "fy": f,
                "cx": w / 2 - 0.5,
                "cy": h / 2 - 0.5,
                "gaze_x": 0.0,
                "gaze_y": 0.3,
                "gaze_z": -1.0,
            }
        )
    (root / "labels.csv").write_text("\n".join(rows) + "\n")
    jroot = root / "jsonl"
    jroot.mkdir()
    for name in names:
        shutil.copy(root / name, jroot / name)
    (jroot / "labels.jsonl").write_text("\n".join(json.dumps(r) for r in jsonl) + "\n")
    return root


def test_mpiifacegaze_reader(mpii_root, mpii_sample):
    ds = open_dataset(mpii_root)
    assert isinstance(ds, MPIIFaceGaze) and len(ds) == 3 and detect_format(mpii_root) == "mpiifacegaze"
    s = next(iter(ds))
    ann = json.loads((mpii_sample / "annotation.json").read_text())
    assert s.subject == "p00" and s.source_index == 0 and s.camera.image_size == tuple(ann["image_size_wh"])
    np.testing.assert_allclose(s.gaze_target_mm, ann["gaze_target_3d_camera_mm"], atol=1e-5)
    np.testing.assert_allclose(s.landmarks_px, ann["landmarks_6_px"], atol=0.05)
    assert s.camera.has_distortion and s.head_rotation.shape == (3, 3)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda t: t.replace(" left\n", "\n", 1), "line 1: expected 28 columns, found 27"),
        (lambda t: t.replace("1200", "abc", 1), "line 1: non-numeric"),
        (lambda t: t.replace("day01/0087.jpg", "day01/missing.jpg", 1), "line 1: image"),
    ],
)
def test_mpiifacegaze_bad_annotations(mpii_root, tmp_path, mutate, message):
    root = tmp_path / "m"
    shutil.copytree(mpii_root, root)
    ann = root / "p00" / "p00.txt"
    ann.write_text(mutate(ann.read_text()))
    with pytest.raises(DatasetError, match=message) as err:
        list(MPIIFaceGaze(root))
    assert "p00.txt" in str(err.value)


def test_mpiifacegaze_missing_calibration(mpii_root, tmp_path):
    root = tmp_path / "m"
    shutil.copytree(mpii_root, root)
    (root / "p00" / "Calibration" / "Camera.mat").unlink()
    with pytest.raises(DatasetError, match="Camera.mat"):
        list(MPIIFaceGaze(root))


def test_folder_reader_csv_and_jsonl(folder_root):
    ds = open_dataset(folder_root)
    assert isinstance(ds, FolderDataset) and len(ds) == 2
    a, b = list(ds)
    assert a.subject == "s0" and a.camera.image_size == (512, 512) and a.gaze_target_mm.tolist() == [0, 150, 0]
    j = list(open_dataset(folder_root / "jsonl"))
    np.testing.assert_allclose(j[1].gaze_vector, np.array([0, 0.3, -1]) / np.linalg.norm([0, 0.3, -1]))


@pytest.mark.parametrize(
    "text, message",
    [
        ("image,fx,fy,cx,cy\nastronaut.png,1,1,1,1\n", "line 1: missing columns: target_x"),
        ("image,target_x,target_y,target_z\nastronaut.png,0,0,0\n", "line 1: missing columns: fx"),
        ("image,fx,fy,cx,cy,target_x,target_y,target_z\nastronaut.png,512,x,256,256,0,0,0\n", "line 2: column 'fy'"),
        ("image,fx,fy,cx,cy,target_x,target_y,target_z\nnope.png,512,512,256,256,0,0,0\n", "line 2: image"),
        ("image,fx,fy,cx,cy,target_x,target_y,target_z\nastronaut.png,512,512,256\n", "line 2: expected 8 columns"),
        ("image,fx,fy,cx,cy,gaze_x,gaze_y,gaze_z\nastronaut.png,512,512,256,256,0,0,0\n", "zero gaze"),
        ("image,fx,fy,cx,cy,target_x,target_y,target_z\nastronaut.png,-5,512,256,256,0,0,0\n", "line 2: camera"),
    ],
)
def test_folder_bad_labels(folder_root, tmp_path, text, message):
    shutil.copy(folder_root / "astronaut.png", tmp_path / "astronaut.png")
    (tmp_path / "labels.csv").write_text(text)
    with pytest.raises(DatasetError, match=message) as err:
        list(FolderDataset(tmp_path))
    assert "labels.csv" in str(err.value)


def test_format_detection(tmp_path):
    with pytest.raises(DatasetError, match="cannot tell"):
        detect_format(tmp_path)
    with pytest.raises(DatasetError, match="not a folder"):
        detect_format(tmp_path / "nothing")


def test_augment_writes_the_schema_and_skips_faceless_images(mpii_root, tmp_path):
    out = tmp_path / "aug.h5"
    settings = JobSettings(kind="augment", per_sample=2, seed=5)
    summary = run_dataset(open_dataset(mpii_root), out, settings, progress=False)
    assert summary["rows"] == 4 and summary["skipped"] == 1
    assert summary["skipped_samples"][0]["source_index"] == 2 and "no face" in summary["skipped_samples"][0]["reason"]
    d = read_h5(out)
    assert d["left_eye"].shape == (4, 36, 60, 3) and d["left_eye"].dtype == np.uint8
    assert d["head_pose"].shape == (4, 2) and d["gaze_vector"].shape == (4, 3)
    assert d["source_index"].tolist() == [0, 0, 1, 1] and d["subject"].tolist() == [b"p00"] * 4
    assert d["attrs"]["complete"] and d["attrs"]["settings"]["per_sample"] == 2 and d["attrs"]["settings"]["seed"] == 5
    # the drawn head poses come out around the paper's pitch of 30 deg (face frame)
    assert 20 < np.degrees(d["head_pose"][:, 0]).mean() < 40
    # rows 0-1 and 2-3 come from the same image but different seeds [seed, index]
    assert not np.allclose(d["sampled_yaw_pitch"][0], d["sampled_yaw_pitch"][2])
    summary_file = json.loads(out.with_suffix(".summary.json").read_text())
    assert summary_file["distributions"]["before"]["head_pose"]["count"] == 2
    assert out.with_suffix(".distribution.png").is_file() and not part_path(out).exists()


def test_same_output_whatever_the_workers(mpii_root, tmp_path):
    settings = JobSettings(kind="augment", per_sample=2, seed=1)
    run_dataset(open_dataset(mpii_root), tmp_path / "w1.h5", settings, progress=False)
    run_dataset(open_dataset(mpii_root), tmp_path / "w2.h5", settings, workers=2, progress=False)
    a, b = read_h5(tmp_path / "w1.h5"), read_h5(tmp_path / "w2.h5")
    for k in a:
        if k != "attrs":
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)


class _Interrupting:
    """A reader that is killed (KeyboardInterrupt) after ``n`` samples."""

    def __init__(self, inner, n):
        self.inner, self.n, self.name, self.root = inner, n, inner.name, inner.root

    def __len__(self):
        return len(self.inner)

    def __iter__(self):
        for i, s in enumerate(self.inner):
            if i == self.n:
                raise KeyboardInterrupt
            yield s


def test_resume_after_an_interruption(mpii_root, tmp_path):
    from gazeaug.normalize import NormalizationSettings

    # with face patches: every column, the optional one too, resumes where the last flush left it
    settings = JobSettings(
        kind="augment", per_sample=2, seed=2, normalization=NormalizationSettings(face_patch_size_wh=(24, 24))
    )
    out = tmp_path / "r.h5"
    with pytest.raises(KeyboardInterrupt):
        run_dataset(_Interrupting(open_dataset(mpii_root), 1), out, settings, progress=False, flush_every=1)
    assert part_path(out).exists() and not out.exists()  # a killed run never looks complete
    with pytest.raises(GazeAugError, match="an interrupted run left it") as exc:
        run_dataset(open_dataset(mpii_root), out, settings, progress=False)
    assert exc.value.remedy == "resume"  # the CLI says --resume
    with pytest.raises(GazeAugError, match="other settings"):
        run_dataset(
            open_dataset(mpii_root), out, JobSettings(kind="augment", per_sample=3), resume=True, progress=False
        )
    run_dataset(open_dataset(mpii_root), out, settings, resume=True, progress=False)
    run_dataset(open_dataset(mpii_root), tmp_path / "straight.h5", settings, progress=False)
    a, b = read_h5(out), read_h5(tmp_path / "straight.h5")
    assert a["face"].shape == (4, 24, 24, 3)
    for k in a:
        if k != "attrs":
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)  # nothing lost, nothing duplicated
    with pytest.raises(OutputExistsError, match="exists and is complete") as exc:
        run_dataset(open_dataset(mpii_root), out, settings, progress=False)
    assert exc.value.remedy == "overwrite"  # the CLI says --overwrite


def test_normalize_dataset_rows_are_the_normalized_images(mpii_root, tmp_path, detector):
    from facemesh.io import load_image_rgb
    from gazeaug.normalize import normalize_image
    from gazeaug.pipeline import fit_face

    out = tmp_path / "n.h5"
    summary = run_dataset(open_dataset(mpii_root), out, JobSettings(kind="normalize-dataset"), progress=False)
    assert summary["rows"] == 2 and summary["skipped"] == 1
    d = read_h5(out)
    s = next(iter(open_dataset(mpii_root)))
    fit = fit_face(load_image_rgb(s.image_path), s.camera, detector)
    ref = normalize_image(
        fit.image, s.camera, fit.pose, fit.model.vertices_mm, fit.keypoints, gaze_target_mm=s.gaze_target_mm
    )
    np.testing.assert_array_equal(d["left_eye"][0], ref.left.image)
    np.testing.assert_allclose(d["gaze"][0], ref.face.gaze, atol=1e-6)
    assert np.isnan(d["sampled_yaw_pitch"]).all()


def test_face_patches_travel_through_the_training_set(mpii_root, tmp_path, detector):
    from facemesh.io import load_image_rgb
    from gazeaug.io_h5 import H5TrainingSet, H5Writer
    from gazeaug.normalize import NormalizationSettings, normalize_image
    from gazeaug.pipeline import fit_face

    norm = NormalizationSettings(face_patch_size_wh=(48, 40))
    out = tmp_path / "f.h5"
    run_dataset(open_dataset(mpii_root), out, JobSettings(kind="normalize-dataset", normalization=norm), progress=False)
    d = read_h5(out)
    assert d["face"].shape == (2, 40, 48, 3) and d["face"].dtype == np.uint8
    assert d["attrs"]["settings"]["normalization"]["face_patch_size_wh"] == [48, 40]
    s = next(iter(open_dataset(mpii_root)))
    fit = fit_face(load_image_rgb(s.image_path), s.camera, detector)
    ref = normalize_image(
        fit.image,
        s.camera,
        fit.pose,
        fit.model.vertices_mm,
        fit.keypoints,
        gaze_target_mm=s.gaze_target_mm,
        settings=norm,
    )
    np.testing.assert_array_equal(d["face"][0], ref.face.image)
    np.testing.assert_array_equal(d["left_eye"][0], ref.left.image)  # the eyes as without a face patch
    ts = H5TrainingSet(out)
    assert ts.face_patch_size_wh == (48, 40)
    [batch] = list(ts.batches(8, keys=("face", "gaze")))
    assert sorted(batch) == ["face", "gaze"] and batch["face"].shape == (2, 40, 48, 3)
    # a shard with face patches goes into an output that has them, not into one without
    merged = H5Writer(tmp_path / "m.h5", {"settings": {}}, (60, 36), face_patch_size_wh=(48, 40))
    assert merged.append_file(out) == 2
    merged.finish()
    np.testing.assert_array_equal(read_h5(tmp_path / "m.h5")["face"], d["face"])
    plain = H5Writer(tmp_path / "p.h5", {"settings": {}}, (60, 36))
    with pytest.raises(GazeAugError, match="face patches"):
        plain.append_file(out)
    plain.discard()
    # a set made without face patches says so when asked for them
    run_dataset(open_dataset(mpii_root), tmp_path / "n.h5", JobSettings(kind="normalize-dataset"), progress=False)
    without = H5TrainingSet(tmp_path / "n.h5")
    assert without.face_patch_size_wh is None and "face" not in read_h5(tmp_path / "n.h5")
    with pytest.raises(GazeAugError, match="no face patches"):
        next(without.batches(8, keys=("face",)))


def test_cli_face_patch_options(folder_root, tmp_path, capsys):
    out = tmp_path / "a.h5"
    assert (
        main(["augment", str(folder_root), "-o", str(out), "--per-sample", "1", "--quiet", "--face-patch", "32", "32"])
        == 0
    )
    assert read_h5(out)["face"].shape == (2, 32, 32, 3)
    capsys.readouterr()
    assert main(["augment", str(folder_root), "-o", str(tmp_path / "b.h5"), "--face-focal", "500"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--face-patch" in err[0] and not (tmp_path / "b.h5").exists()
    assert main(["augment", str(folder_root), "-o", str(tmp_path / "c.h5"), "--face-patch", "32", "0"]) == 2
    assert "face patch size" in capsys.readouterr().err
    # Filament renders one image size per scene, the eye patch's: refused at once, one line
    args = ["augment", str(folder_root), "-o", str(tmp_path / "d.h5"), "--face-patch", "32", "32"]
    assert main([*args, "--renderer", "filament"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "raycast" in err[0] and not (tmp_path / "d.h5").exists()


def test_inconsistent_calibration_is_an_error_naming_the_image(mpii_root, tmp_path):
    root = tmp_path / "m"
    shutil.copytree(mpii_root, root)
    cv2.imwrite(str(root / "p00" / "day01" / "0088.jpg"), np.zeros((480, 640, 3), np.uint8))
    with pytest.raises(DatasetError, match="0088.jpg: the image is 640x480"):
        run_dataset(open_dataset(root), tmp_path / "x.h5", JobSettings(kind="normalize-dataset"), progress=False)
    assert not (tmp_path / "x.h5").exists()


def test_cli_augment_and_errors(folder_root, tmp_path, capsys):
    out = tmp_path / "a.h5"
    assert (
        main(["augment", str(folder_root), "-o", str(out), "--per-sample", "1", "--quiet", "--rig", "wheelchair"]) == 0
    )
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["rows"] == 2
    assert read_h5(out)["attrs"]["settings"]["rig"]["name"] == "wheelchair"
    assert main(["augment", str(tmp_path / "none"), "-o", str(tmp_path / "b.h5")]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert main(["augment", str(folder_root), "-o", str(tmp_path / "c.h5"), "--per-sample", "0"]) == 2
    assert not (tmp_path / "c.h5").exists() and not part_path(tmp_path / "c.h5").exists()


def _eth_calibration(path, cam):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_Width", int(cam.image_size[0]))
    fs.write("image_Height", int(cam.image_size[1]))
    fs.write("Camera_Matrix", cam.matrix)
    fs.write("Distortion_Coefficients", cam.distortion.reshape(1, -1))
    fs.release()


#: ETH-XGaze's 6 face-model rows (normalization_example.py line 192): four eye corners, then the two
#: points its normalizeData_face averages as the "mouth" (lines 37-38).
ETH_MODEL_ROWS = [20, 23, 26, 29, 15, 19]


@pytest.fixture(scope="module")
def eth_face_model(mpii_sample):
    """ETH-XGaze's six face-model rows (6 x 3, mm), or without ../shared the sample's six points.

    The stand-in is the sample's ``faceModelGeneric.txt``: four eye corners then the two mouth
    corners, the points its landmarks mark, so the PnP head pose and ETH's warp show the face.
    """
    shared = shared_data_dir()
    if shared is None:
        return np.loadtxt(mpii_sample / "faceModelGeneric.txt").T
    path = shared / "gaze" / "calibrations" / "eth_xgaze_face_model.txt"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return np.loadtxt(path)[ETH_MODEL_ROWS]


def _eth_turn(image):
    """ETH-XGaze's turn of cameras 3, 6 and 13, written out from normalization_example.py lines 266-270."""
    (h, w) = image.shape[:2]
    m = cv2.getRotationMatrix2D((w / 2, h / 2), 180, 1.0)
    return cv2.warpAffine(image, m, (w, h))


def _eth_face_warp(cam_matrix, hr, ht, face_model, focal_norm=960.0, distance_norm=300.0, size=448):
    """The image warp W of ETH-XGaze's normalizeData_face, written out (normalization_example.py lines 27-64)."""
    h_r = cv2.Rodrigues(np.asarray(hr, dtype=np.float64))[0]
    fc = h_r @ face_model.T + np.asarray(ht, dtype=np.float64).reshape(3, 1)
    two_eye_center = fc[:, 0:4].mean(axis=1)
    mouth_center = fc[:, 4:6].mean(axis=1)
    face_center = (two_eye_center + mouth_center) / 2.0
    distance = np.linalg.norm(face_center)
    cam_norm = np.array([[focal_norm, 0, size / 2], [0, focal_norm, size / 2], [0, 0, 1.0]])
    s = np.diag([1.0, 1.0, distance_norm / distance])
    forward = face_center / distance
    down = np.cross(forward, h_r[:, 0])
    down /= np.linalg.norm(down)
    right = np.cross(down, forward)
    right /= np.linalg.norm(right)
    r = np.c_[right, down, forward].T
    return cam_norm @ s @ r @ np.linalg.inv(cam_matrix)


@pytest.fixture(scope="module")
def eth_root(tmp_path_factory, mpii_sample, eth_face_model):
    """ETH-XGaze layout with the p00 frame as camera 00 and as camera 03, stored upside down.

    Camera 03's file is what ETH-XGaze's own turn (``_eth_turn``) takes back to the labelled
    picture: ETH's turn is its own inverse up to its one-pixel black border. The head pose is
    ETH's 6-point model fitted (PnP) to p00's six landmarks, so ETH's face patch shows the face.
    """
    ann, cam = _p00(mpii_sample)
    root = tmp_path_factory.mktemp("eth")
    (root / "calibration" / "cam_calibration").mkdir(parents=True)
    frame = root / "data" / "train" / "subject0000" / "frame0000"
    frame.mkdir(parents=True)
    (root / "data" / "annotation_train").mkdir(parents=True)
    img = cv2.imread(str(mpii_sample / ann["image"]))
    lm = np.array(ann["landmarks_6_px"], dtype=np.float64)
    fm = eth_face_model
    _, rvec, tvec = cv2.solvePnP(fm.reshape(-1, 1, 3), lm.reshape(-1, 1, 2), cam.matrix, cam.distortion)
    # coded as the sample's own image: the real frame's JPEG (re-encoding changes a few levels), the synthetic
    # stand-in's PNG (lossless: its first JPEG coding would change the picture far more) under ETH's .JPG name
    coding = Path(ann["image"]).suffix
    lines = []
    for cam_id, image in ((0, img), (3, _eth_turn(img))):
        _eth_calibration(root / "calibration" / "cam_calibration" / f"cam{cam_id:02d}.xml", cam)
        (frame / f"cam{cam_id:02d}.JPG").write_bytes(cv2.imencode(coding, image)[1].tobytes())
        cols = ["frame0000", f"cam{cam_id:02d}.JPG", "100", "200", *map(str, ann["gaze_target_3d_camera_mm"])]
        cols += [f"{v:.8f}" for v in (*rvec.ravel(), *tvec.ravel())] + ["300.5"] * 136
        lines.append(",".join(cols))
    (root / "data" / "annotation_train" / "subject0000.csv").write_text("\n".join(lines) + "\n")
    return root


def test_ethxgaze_reader_and_upside_down_cameras(eth_root, mpii_sample):
    ds = open_dataset(eth_root)
    assert ds.name == "ethxgaze" and len(ds) == 2 and detect_format(eth_root) == "ethxgaze"
    a, b = list(ds)
    assert a.subject == "subject0000" and not a.rotate_180 and b.rotate_180
    assert a.landmarks_px.shape == (68, 2) and a.camera.image_size == tuple(_p00(mpii_sample)[0]["image_size_wh"])
    # camera 03 turned exactly: pixel (x, y) is ETH's turned pixel (x + 1, y + 1), i.e. p00's
    # (JPEG re-encoding of the turned picture differs by a few levels)
    assert np.abs(b.load_image()[:-1, :-1].astype(float) - a.load_image()[1:, 1:]).mean() < 0.5


def test_real_ethxgaze_calibration_loads_as_it_is(shared_data):
    """An ETH-XGaze calibration file of the release (../shared) loads with its size and distortion."""
    real = load_camera(shared_data / "gaze" / "calibrations" / "eth_xgaze_cams_original" / "cam03.xml")
    assert real.image_size == (6000, 4000) and real.has_distortion


def test_ethxgaze_turned_cameras_give_eths_own_face_patch(eth_root, eth_face_model):
    """Cameras 3, 6, 13: the sample's image and camera reproduce ETH-XGaze's normalization exactly.

    ETH's code turns the stored image with ``warpAffine(getRotationMatrix2D(centre, 180))``
    (normalization_example.py lines 266-270): the exact flip moved one pixel right and down,
    used with the calibration's camera matrix unchanged (line 290). The reader turns the image
    exactly and moves the principal point (and the landmarks) by -1 px instead.
    """
    import csv

    fm = eth_face_model
    a, b = list(open_dataset(eth_root))
    rows = list(csv.reader((eth_root / "data" / "annotation_train" / "subject0000.csv").open()))
    hr, ht = np.array(rows[1][7:10], float), np.array(rows[1][10:13], float)
    fs = cv2.FileStorage(str(eth_root / "calibration" / "cam_calibration" / "cam03.xml"), cv2.FILE_STORAGE_READ)
    k = fs.getNode("Camera_Matrix").mat()  # ETH lines 183-184
    fs.release()
    raw = cv2.imread(str(eth_root / "data" / "train" / "subject0000" / "frame0000" / "cam03.JPG"))
    w_eth = _eth_face_warp(k, hr, ht, fm)
    expected = cv2.warpPerspective(_eth_turn(raw), w_eth, (448, 448)).astype(float)
    assert expected.std() > 20  # the face, not a border
    image = np.ascontiguousarray(b.load_image()[:, :, ::-1])  # RGB -> BGR, as cv2.imread
    got = cv2.warpPerspective(image, _eth_face_warp(b.camera.matrix, hr, ht, fm), (448, 448))
    diff = np.abs(got - expected)
    assert diff.mean() < 0.02 and diff.max() <= 2, (diff.mean(), diff.max())
    # an exact flip with the calibration's matrix unchanged is one pixel off ETH's patch
    off = np.abs(cv2.warpPerspective(image, w_eth, (448, 448)) - expected).mean()
    assert off > 0.2 and off > 1000 * diff.mean(), (off, diff.mean())
    # ETH's landmark pixels refer to ETH's turned image: one pixel right and down of ours
    np.testing.assert_allclose(b.landmarks_px, np.full((68, 2), 300.5 - 1.0))
    np.testing.assert_allclose(a.landmarks_px, np.full((68, 2), 300.5))
    np.testing.assert_allclose(b.camera.matrix[:2, 2], k[:2, 2] - 1.0)
    np.testing.assert_allclose(b.camera.matrix[[0, 1], [0, 1]], k[[0, 1], [0, 1]])


def test_ethxgaze_runs_and_bad_annotations(eth_root, mpii_sample, tmp_path):
    from helpers import is_synthetic

    summary = run_dataset(
        open_dataset(eth_root), tmp_path / "e.h5", JobSettings(kind="normalize-dataset"), progress=False
    )
    assert summary["rows"] == 2 and summary["skipped"] == 0
    d = read_h5(tmp_path / "e.h5")
    # the turned camera gives the same eyes (up to JPEG re-encoding, and sub-pixel landmark differences). The real
    # frame's eyes are minified about 2x into the patches; the synthetic sample's (a small face, f = 600 px) are
    # magnified about 1.6x, which makes the same landmark differences show about 3.6 times as much.
    limit = 1.5 if is_synthetic(mpii_sample) else 1.0
    assert np.abs(d["left_eye"][0].astype(float) - d["left_eye"][1]).mean() < limit
    root = tmp_path / "bad"
    shutil.copytree(eth_root, root)
    csv_path = root / "data" / "annotation_train" / "subject0000.csv"
    csv_path.write_text(csv_path.read_text().replace(",300.5\n", "\n", 1))
    with pytest.raises(DatasetError, match=r"subject0000.csv, line 1: expected 149 columns, found 148"):
        open_dataset(root)


def _eth_test_row():
    """A row of ETH-XGaze's test annotations: frame, image, head rotation (3), translation (3), 68 landmarks.

    The layout X-Shi/Data-Normalization-Gaze-Estimation's nor_eye_face_test.py reads
    (lines 256-297): no gaze columns at all, 2 + 3 + 3 + 136 = 144 columns.
    """
    return ",".join(["frame0000", "cam00.JPG", "0.1", "0.2", "0.05", "10", "20", "450"] + ["300.5"] * 136)


def test_ethxgaze_test_split_is_refused_with_the_reason(eth_root, tmp_path):
    """ETH-XGaze keeps its test labels for its leaderboard (README, FAQ; data_loader.py line 66)."""
    from gazeaug.datasets.ethxgaze import ETHXGaze

    root = tmp_path / "both"
    shutil.copytree(eth_root, root)
    (root / "data" / "annotation_test").mkdir()
    (root / "data" / "annotation_test" / "subject0001.csv").write_text(_eth_test_row() + "\n")
    with pytest.raises(DatasetError, match=r"test split.*no gaze labels.*leaderboard"):
        ETHXGaze(root, split="test")
    with pytest.raises(DatasetError, match=r"split: expected 'train', got 'val'"):
        ETHXGaze(root, split="val")
    assert len(open_dataset(root)) == 2  # the training split reads as before
    # a download of the test split alone: found as ETH-XGaze, refused with the reason
    only = tmp_path / "only_test"
    (only / "data" / "annotation_test").mkdir(parents=True)
    (only / "data" / "annotation_test" / "subject0001.csv").write_text(_eth_test_row() + "\n")
    assert detect_format(only) == "ethxgaze"
    with pytest.raises(DatasetError, match=r"only the test split.*no gaze labels") as err:
        open_dataset(only)
    assert "annotation_test" in str(err.value)
    # a test-split file among the training annotations: its layout is named
    (root / "data" / "annotation_train" / "subject0001.csv").write_text(_eth_test_row() + "\n")
    with pytest.raises(DatasetError, match=r"subject0001.csv, line 1: expected 149 columns, found 144 .*test split"):
        open_dataset(root)


@pytest.fixture(scope="module")
def gazecapture_root(tmp_path_factory, mpii_sample):
    """GazeCapture + FAZE's supplementary HDF5 in the released shape: 4 distortion values a row.

    fastgaze's reader (gazeirislandmarks/datasets/gazecapture.py lines 67 and 489) appends one
    zero to each ``distortion_parameters`` row and passes the result to
    ``cv2.initUndistortRectifyMap`` (line 495), which takes only 4, 5, 8, 12 or 14 values: the
    released rows hold k1, k2, p1, p2.
    """
    import h5py

    ann, cam = _p00(mpii_sample)
    root = tmp_path_factory.mktemp("gc")
    (root / "00002" / "frames").mkdir(parents=True)
    shutil.copy(mpii_sample / ann["image"], root / "00002" / "frames" / "00000.jpg")
    with h5py.File(root / "GazeCapture_supplementary.h5", "w") as f:
        g = f.create_group("00002")
        g["file_name"] = np.array([b"00002/frames/00000.jpg"])
        k = cam.matrix
        g["camera_parameters"] = np.array([[k[0, 0], k[1, 1], k[0, 2], k[1, 2]]])
        g["distortion_parameters"] = cam.distortion[:4].reshape(1, 4)
        g["head_pose"] = np.array([[0.1, 0.2, 0.0, 10.0, 20.0, 450.0]])
        g["3d_gaze_target"] = np.array([ann["gaze_target_3d_camera_mm"]])
    return root


def test_gazecapture_reader_and_run(gazecapture_root, mpii_sample, tmp_path):
    ds = open_dataset(gazecapture_root)
    assert ds.name == "gazecapture" and len(ds) == 1 and detect_format(gazecapture_root) == "gazecapture"
    s = next(iter(ds))
    size = tuple(_p00(mpii_sample)[0]["image_size_wh"])
    assert s.subject == "00002" and s.camera.image_size == size and s.camera.has_distortion
    summary = run_dataset(ds, tmp_path / "g.h5", JobSettings(kind="augment", per_sample=2), progress=False)
    assert summary["rows"] == 2


def test_gazecapture_distortion_as_released_and_as_five_values(gazecapture_root, tmp_path):
    import h5py

    with h5py.File(gazecapture_root / "GazeCapture_supplementary.h5", "r") as f:
        row = f["00002/distortion_parameters"][0]
    assert row.shape == (4,)
    s = next(iter(open_dataset(gazecapture_root)))
    # what fastgaze hands OpenCV (gazecapture.py line 67): the row with k3 = 0 appended
    np.testing.assert_array_equal(s.camera.distortion, np.append(row, 0))
    k = s.camera.matrix
    cv2.initUndistortRectifyMap(k, np.asarray(s.camera.distortion), None, k, s.camera.image_size, cv2.CV_32FC1)
    root = tmp_path / "gc"
    shutil.copytree(gazecapture_root, root)
    five = np.array([[-0.1, 0.2, 0.001, -0.002, 0.3]])
    with h5py.File(root / "GazeCapture_supplementary.h5", "a") as f:
        del f["00002/distortion_parameters"]
        f["00002/distortion_parameters"] = five
    np.testing.assert_array_equal(next(iter(open_dataset(root))).camera.distortion, five[0])
    with h5py.File(root / "GazeCapture_supplementary.h5", "a") as f:
        del f["00002/distortion_parameters"]
        f["00002/distortion_parameters"] = np.zeros((1, 6))
    with pytest.raises(
        DatasetError, match=r"group '00002': distortion_parameters has shape \(1, 6\), expected \(1, 4\)"
    ):
        open_dataset(root)


def test_gazecapture_bad_supplementary(gazecapture_root, tmp_path):
    import h5py

    root = tmp_path / "gc"
    shutil.copytree(gazecapture_root, root)
    with h5py.File(root / "GazeCapture_supplementary.h5", "a") as f:
        del f["00002/head_pose"]
    with pytest.raises(DatasetError, match=r"group '00002': missing datasets \['head_pose'\]"):
        open_dataset(root)
    with h5py.File(root / "GazeCapture_supplementary.h5", "a") as f:
        f["00002/head_pose"] = np.zeros((1, 5))
    with pytest.raises(DatasetError, match="head_pose has shape"):
        open_dataset(root)


def _eth_face_gaze(g):
    """ETH-XGaze's (pitch, yaw) of a gaze vector (target - face centre), normalization_example.py lines 313-315."""
    g = np.asarray(g, dtype=np.float64) / np.linalg.norm(g)
    return np.array([np.arcsin(-g[1]), np.arctan2(-g[0], -g[2])])


def _eth_normalized_file(path, patches_bgr, face_gaze):
    """A subjectXXXX.h5 with the datasets, shapes and types ETH's code writes (normalization_example.py 294-331)."""
    import h5py

    n = len(patches_bgr)
    with h5py.File(path, "w") as f:
        f["frame_index"] = np.arange(n).reshape(n, 1)
        f["cam_index"] = np.arange(n).reshape(n, 1)
        f["facial_landmarks"] = np.zeros((n, 68, 2))
        f["face_patch"] = np.asarray(patches_bgr, dtype=np.uint8)
        f["face_mat_norm"] = np.tile(np.eye(3), (n, 1, 1))
        f["face_gaze"] = np.asarray(face_gaze, dtype=np.float64)
        f["face_head_pose"] = np.zeros((n, 2))


@pytest.fixture(scope="module")
def eth_normalized_root(tmp_path_factory, faces_dir):
    """ETH-XGaze's normalized 224 release as ETH's code makes it, from a photo (sergey, or the astronaut).

    A 448 patch by normalizeData_face's warp (focal 960, 300 mm, normalization_example.py lines
    27-66; our head pose and face centre stand in for ETH's face model), resized to 224 with
    ``cv2.INTER_AREA`` (line 292), stored BGR.
    """
    from facemesh.camera import camera_for_image
    from facemesh.landmarks import MediaPipeFaceMesh
    from gazeaug.normalize import reference_points
    from gazeaug.pipeline import fit_face

    bgr = cv2.imread(str(face_photo(faces_dir, "sergey.png", any_face=True)))
    h, w = bgr.shape[:2]
    cam = camera_for_image(None, w, h, warn=False)
    with MediaPipeFaceMesh() as det:
        fit = fit_face(np.ascontiguousarray(bgr[:, :, ::-1]), cam, det)
    centre = reference_points(fit.pose.rotation, fit.pose.translation_mm, fit.model.vertices_mm, fit.keypoints)["face"]
    h_r = np.asarray(fit.pose.rotation)
    distance = np.linalg.norm(centre)
    forward = centre / distance
    down = np.cross(forward, h_r[:, 0])
    down /= np.linalg.norm(down)
    right = np.cross(down, forward)
    right /= np.linalg.norm(right)
    r = np.c_[right, down, forward].T
    cam_norm = np.array([[960.0, 0, 224.0], [0, 960.0, 224.0], [0, 0, 1.0]])
    warp = cam_norm @ np.diag([1.0, 1.0, 300.0 / distance]) @ r @ np.linalg.inv(cam.matrix)
    patch448 = cv2.warpPerspective(bgr, warp, (448, 448))
    patch224 = cv2.resize(patch448, (224, 224), interpolation=cv2.INTER_AREA)
    root = tmp_path_factory.mktemp("ethn")
    _eth_normalized_file(root / "subject0003.h5", [patch224, patch224], [[-0.1, 0.2], [0.05, -0.3]])
    return root


def test_ethxgaze_normalized_reader_and_run(eth_normalized_root, tmp_path):
    from facemesh.conventions import pitchyaw_to_vector

    ds = open_dataset(eth_normalized_root)
    assert (
        ds.name == "ethxgaze_normalized"
        and len(ds) == 2
        and detect_format(eth_normalized_root) == "ethxgaze_normalized"
    )
    a, b = list(ds)
    assert a.camera.image_size == (224, 224) and a.subject == "subject0003"
    np.testing.assert_allclose(b.gaze_vector, pitchyaw_to_vector([0.05, -0.3]), atol=1e-12)
    img = a.load_image()
    assert img.shape == (224, 224, 3) and img[..., 0].mean() != img[..., 2].mean()  # BGR turned to RGB
    summary = run_dataset(ds, tmp_path / "n.h5", JobSettings(kind="normalize-dataset"), progress=False)
    assert summary["rows"] == 2 and summary["skipped"] == 0
    d = read_h5(tmp_path / "n.h5")
    # the face-frame gaze of the training rows is the file's gaze (the virtual camera is the normalized one)
    np.testing.assert_allclose(d["gaze"], [[-0.1, 0.2], [0.05, -0.3]], atol=0.02)


def test_ethxgaze_normalized_gaze_is_eths_pitch_yaw(tmp_path):
    """face_gaze holds ETH's (pitch, yaw) of target - face centre (lines 313-315): the reader gives that vector back."""
    gazes = np.array([[0.3, -0.2, -0.93], [-0.5, 0.4, -0.77], [0.05, 0.6, -0.8]])
    _eth_normalized_file(tmp_path / "subject0000.h5", np.zeros((3, 448, 448, 3)), [_eth_face_gaze(g) for g in gazes])
    got = np.array([s.gaze_vector for s in open_dataset(tmp_path)])
    np.testing.assert_allclose(got, gazes / np.linalg.norm(gazes, axis=1, keepdims=True), atol=1e-12)


@pytest.mark.parametrize("size", [448, 224, 112])
def test_ethxgaze_normalized_camera_follows_the_inter_area_resize(tmp_path, size):
    """The virtual camera of a patch resized from ETH's 448 one: where cv2.resize puts the 448 principal point.

    ETH's 448 patch has focal 960 and principal point (224, 224) (normalization_example.py lines
    28-30, 45-49); the 224 release is that patch resized with INTER_AREA (line 292). A smooth
    blob centred on the 448 principal point is measured after the resize (its centroid), so
    the expected value comes from OpenCV, not from a formula.
    """
    yy, xx = np.mgrid[0:448, 0:448].astype(np.float64)
    blob = np.exp(-((xx - 224.0) ** 2 + (yy - 224.0) ** 2) / (2 * 6.0**2)).astype(np.float32)
    small = cv2.resize(blob, (size, size), interpolation=cv2.INTER_AREA) if size != 448 else blob
    ys, xs = np.mgrid[0:size, 0:size]
    centroid = np.array([(xs * small).sum(), (ys * small).sum()]) / small.sum()
    _eth_normalized_file(tmp_path / "subject0000.h5", np.zeros((1, size, size, 3)), [[0.0, 0.0]])
    s = next(iter(open_dataset(tmp_path)))
    np.testing.assert_allclose(s.camera.matrix[:2, 2], centroid, atol=1e-6)
    np.testing.assert_allclose(s.camera.matrix[[0, 1], [0, 1]], 960.0 * size / 448)
    if size == 224:
        np.testing.assert_allclose(centroid, [111.75, 111.75], atol=1e-6)
    # a release rendered at its own size (principal point at the centre) can be read too
    from gazeaug.datasets.ethxgaze_normalized import ETHXGazeNormalized

    t = next(iter(ETHXGazeNormalized(tmp_path, resized_from_448=False)))
    np.testing.assert_allclose(t.camera.matrix[:2, 2], [size / 2, size / 2])


def test_ethxgaze_normalized_refuses_another_normalization(tmp_path):
    """X-Shi/Data-Normalization-Gaze-Estimation's files (nor_eye_face.py lines 309, 329-333) use another camera."""
    import h5py

    _eth_normalized_file(tmp_path / "subject0000.h5", np.zeros((1, 224, 224, 3)), [[0.0, 0.0]])
    with h5py.File(tmp_path / "subject0000.h5", "a") as f:
        f["left_eye_patch"] = np.zeros((1, 224, 224, 3), np.uint8)
    with pytest.raises(DatasetError, match=r"subject0000.h5: has left_eye_patch.*nor_eye_face.py.*not supported"):
        open_dataset(tmp_path, format="ethxgaze_normalized")


def _read_all(root):
    """Open a dataset and read every sample description (images are not decoded)."""
    return [(s.subject, s.camera, s.gaze_target_mm, s.gaze_vector) for s in open_dataset(root)]


@pytest.mark.parametrize(
    "fixture, label_file",
    [
        ("mpii_root", "p00/p00.txt"),
        ("mpii_root", "p00/Calibration/Camera.mat"),
        ("eth_root", "data/annotation_train/subject0000.csv"),
        ("eth_root", "calibration/cam_calibration/cam00.xml"),
        ("gazecapture_root", "GazeCapture_supplementary.h5"),
        ("eth_normalized_root", "subject0003.h5"),
    ],
)
def test_fuzzed_label_files_of_every_reader(request, tmp_path, fixture, label_file):
    """Damaged label and calibration files: the reader's typed error (exit 2 at the CLI), never another one."""
    from helpers import expect_typed_error, mutations

    root = tmp_path / "ds"
    shutil.copytree(request.getfixturevalue(fixture), root)
    valid = (root / label_file).read_bytes()
    for data in mutations(valid, seed=len(label_file), n=20):
        expect_typed_error(lambda p: _read_all(root), root / label_file, data)


def test_with_source_adds_each_sources_normalized_row_and_leaves_the_draws_as_they_were(mpii_root, tmp_path):
    plain, both, norm = tmp_path / "a.h5", tmp_path / "b.h5", tmp_path / "n.h5"
    run_dataset(open_dataset(mpii_root), plain, JobSettings(kind="augment", per_sample=2, seed=5), progress=False)
    settings = JobSettings(kind="augment", per_sample=2, seed=5, with_source=True)
    summary = run_dataset(open_dataset(mpii_root), both, settings, progress=False)
    run_dataset(open_dataset(mpii_root), norm, JobSettings(kind="normalize-dataset"), progress=False)
    a, b, n = read_h5(plain), read_h5(both), read_h5(norm)
    assert summary["rows"] == 6 and summary["skipped"] == 1  # 2 faces x (1 source row + K = 2), the faceless skipped
    assert b["source_index"].tolist() == [0, 0, 0, 1, 1, 1]
    source_rows, drawn_rows = [0, 3], [1, 2, 4, 5]
    for k in a:
        if k != "attrs":
            np.testing.assert_array_equal(b[k][source_rows], n[k], err_msg=k)  # the row normalize-dataset writes
            np.testing.assert_array_equal(b[k][drawn_rows], a[k], err_msg=k)  # the same draws as without it
    assert np.isnan(b["sampled_yaw_pitch"][source_rows]).all()
    assert b["attrs"]["settings"]["with_source"] is True and "with_source" not in a["attrs"]["settings"]
    with pytest.raises(GazeAugError, match="with_source is an augmentation setting"):
        JobSettings(kind="normalize-dataset", with_source=True)
    with pytest.raises(GazeAugError, match="with_source: expected true or false, got 'yes'"):
        JobSettings(with_source="yes")


def test_cli_augment_with_source(folder_root, tmp_path, capsys):
    out = tmp_path / "a.h5"
    args = ["augment", str(folder_root), "-o", str(out), "--per-sample", "1", "--quiet", "--with-source"]
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["rows"] == 4  # 2 images x (source + 1)
    assert read_h5(out)["attrs"]["settings"]["with_source"] is True
