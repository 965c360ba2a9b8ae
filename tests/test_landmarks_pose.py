"""MediaPipe landmarks against MediaPipe's own expectations, user landmark files, and PnP."""

import json

import cv2
import numpy as np
import pytest
from conftest import SINGLE_FACE_PHOTOS

from facemesh import (
    CameraIntrinsics,
    InputError,
    NoFaceError,
    builtin_face_model,
    camera_for_image,
    load_camera,
    load_face_model,
    load_image_rgb,
    solve_head_pose,
)
from facemesh.conventions import angular_error_deg
from facemesh.landmarks import load_landmarks_file, select_face
from facemesh.pose import project_points, undistort_to_rays
from facemesh.types import FaceLandmarks


def _rotation_angle_deg(r1, r2):
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(r1 @ r2.T)[0])))


def test_mediapipe_matches_its_own_expected_landmarks(shared_data, detector):
    faces = shared_data / "faces"
    img = load_image_rgb(faces / "business-person.png")
    h, w = img.shape[:2]
    expected = json.loads((faces / "business-person_expected_landmarks.json").read_text())
    exp = np.asarray(expected["landmarks"], dtype=float)[:, :2]
    # Normalised (0..1, image corners) -> OpenCV pixel centres, as documented.
    exp_px = np.stack([exp[:, 0] * w - 0.5, exp[:, 1] * h - 0.5], axis=1)
    face = select_face(detector.detect(img))
    assert face.num_points == 478
    err = np.linalg.norm(face.points_px[: len(exp_px)] - exp_px, axis=1)
    assert err.mean() <= 3.0 and err.max() <= 8.0, (err.mean(), err.max())


def test_several_faces_largest_first_and_face_index(two_faces_photo, detector):
    img = load_image_rgb(two_faces_photo)
    faces = detector.detect(img)
    assert len(faces) == 2
    first, second = select_face(faces, 0), select_face(faces, 1)
    assert first.area_px >= second.area_px
    assert select_face(faces) is first
    with pytest.raises(NoFaceError, match="face index 2"):
        select_face(faces, 2)


def test_no_face_found(detector):
    grey = np.full((240, 320, 3), 127, np.uint8)
    assert detector.detect(grey) == []
    with pytest.raises(NoFaceError, match="blank"):
        select_face(detector.detect(grey), source="blank")


@pytest.mark.parametrize("suffix", [".npy", ".json", ".csv"])
def test_landmark_files(tmp_path, suffix):
    pts = np.array([[1.5, 2.0], [3.0, 4.25], [5.0, 6.0], [7.0, 8.0]])
    p = tmp_path / f"lm{suffix}"
    if suffix == ".npy":
        np.save(p, pts)
    elif suffix == ".json":
        p.write_text(json.dumps({"landmarks_px": pts.tolist()}))
    else:
        p.write_text("x,y\n" + "\n".join(f"{x},{y}" for x, y in pts))
    np.testing.assert_array_equal(load_landmarks_file(p), pts)


def test_landmark_file_errors(tmp_path):
    bad_shape = tmp_path / "a.npy"
    np.save(bad_shape, np.zeros((5, 3)))
    with pytest.raises(InputError, match=r"a\.npy.*\(N, 2\)"):
        load_landmarks_file(bad_shape)
    nan = tmp_path / "b.json"
    nan.write_text("[[1, 2], [NaN, 3], [4, 5], [6, 7]]")
    with pytest.raises(InputError, match=r"b\.json.*landmark 1 is NaN"):
        load_landmarks_file(nan)
    bad_csv = tmp_path / "c.csv"
    bad_csv.write_text("1,2\n3,oops\n")
    with pytest.raises(InputError, match=r"c\.csv:2"):
        load_landmarks_file(bad_csv)
    with pytest.raises(InputError, match="not found"):
        load_landmarks_file(tmp_path / "missing.npy")


def test_pnp_recovers_a_known_pose_with_distortion():
    model = builtin_face_model()
    cam = CameraIntrinsics(
        matrix=[[900.0, 0, 640], [0, 905.0, 360], [0, 0, 1]],
        distortion=[-0.2, 0.1, 0.001, -0.002, 0.0],
        image_size=(1280, 720),
    )
    rvec = np.array([0.2, -0.3, 0.05])
    r = cv2.Rodrigues(rvec)[0]
    t = np.array([30.0, -20.0, 600.0])
    px = project_points(model.vertices_mm @ r.T + t, cam)
    pose = solve_head_pose(px, model.vertices_mm, cam)
    assert _rotation_angle_deg(pose.rotation, r) < 1e-4
    np.testing.assert_allclose(pose.translation_mm, t, atol=1e-3)
    assert pose.reprojection_error_px < 1e-4
    # undistorted rays go back through the same points
    rays = undistort_to_rays(px, cam)
    pts = model.vertices_mm @ r.T + t
    np.testing.assert_allclose(rays * pts[:, 2:3], pts, atol=1e-6)


def test_pnp_refuses_landmarks_at_one_point_or_on_one_line():
    """A landmark file of zeros (or points on a line) has no pose: one clear error, not a pose 1e16 mm away."""
    model = builtin_face_model()
    cam = CameraIntrinsics(
        matrix=[[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]], distortion=np.zeros(5), image_size=(640, 480)
    )
    n = model.num_points
    line = np.stack([np.linspace(100, 300, n), np.linspace(50, 150, n)], axis=1)  # y = x / 2
    for px in (np.zeros((n, 2)), np.full((n, 2), 200.0), line):
        with pytest.raises(InputError, match="at one point or on one line"):
            solve_head_pose(px, model.vertices_mm, cam)
    bad = np.zeros((n, 2))
    bad[3] = np.nan
    with pytest.raises(InputError, match="finite"):
        solve_head_pose(bad, model.vertices_mm, cam)


def test_pnp_on_the_calibrated_mpiifacegaze_sample(real_mpii_sample, detector):
    mpii_sample = real_mpii_sample  # the real frame's own numbers
    ann = json.loads((mpii_sample / "annotation.json").read_text())
    cam = load_camera(mpii_sample / "cameraCalib.xml", image_size=tuple(ann["image_size_wh"]))
    six = load_face_model(mpii_sample / "faceModelGeneric.txt")
    pose6 = solve_head_pose(np.array(ann["landmarks_6_px"]), six.vertices_mm, cam)
    distance = np.linalg.norm(pose6.translation_mm)
    assert 350 <= distance <= 550
    # facing the camera within 30 deg: the face direction -R[:, 2] vs the direction to the camera -t
    assert angular_error_deg(-pose6.rotation[:, 2], -pose6.translation_mm) < 30
    # the MediaPipe path on the same image agrees within a few degrees
    img = load_image_rgb(mpii_sample / ann["image"])
    face = select_face(detector.detect(img))
    model = builtin_face_model()
    pose_mp = solve_head_pose(face.points_px[:468], model.vertices_mm, cam)
    assert _rotation_angle_deg(pose_mp.rotation, pose6.rotation) < 7.0
    assert angular_error_deg(pose_mp.rotation[:, 0], pose6.rotation[:, 0]) < 2.0  # same eye line
    assert abs(np.linalg.norm(pose_mp.translation_mm) - distance) < 40


ALL_FACE_PHOTOS = SINGLE_FACE_PHOTOS + (
    "two_children.jpeg",
    "pexels/image02.jpg",
    *(f"aflw_deca/AFLW2000_image00{n}.jpg" for n in (181, 202, 302, 408, 480)),
)


@pytest.mark.parametrize("name", ALL_FACE_PHOTOS)
def test_poses_with_our_model_agree_with_the_reference_model(shared_data, reference_model_path, detector, name):
    img = load_image_rgb(shared_data / "faces" / name)
    h, w = img.shape[:2]
    cam = camera_for_image(None, w, h, warn=False)
    reference = load_face_model(reference_model_path).vertices_mm
    for face in detector.detect(img):  # every face in the photo
        ours = solve_head_pose(face.points_px[:468], builtin_face_model().vertices_mm, cam)
        ref = solve_head_pose(face.points_px[:468], reference, cam)
        assert _rotation_angle_deg(ours.rotation, ref.rotation) < 3.0


def test_face_landmarks_validation():
    with pytest.raises(InputError, match="NaN"):
        FaceLandmarks(points_px=[[0, 0], [1, np.nan], [2, 2], [3, 3]], model_name="x")
    with pytest.raises(InputError, match=r"expected shape \(N, 2\)"):
        FaceLandmarks(points_px=np.zeros((5, 3)), model_name="x")
