"""Data normalization (Zhang et al. 2018) against hand computations of the same formulas."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from facemesh.camera import load_camera
from facemesh.face_models import KEYPOINTS, load_face_model
from facemesh.io import load_image_rgb
from facemesh.pose import solve_head_pose
from facemesh.types import CameraIntrinsics, HeadPose
from gazeaug.camera import normalized_camera
from gazeaug.errors import GazeAugError
from gazeaug.normalize import NormalizationSettings, load_npz, normalize_image, save_npz


def _zhang_rotation_by_hand(reference_mm, head_r):
    """Zhang's normalizing rotation, written out: z to the reference point, x levelled by the head's x axis."""
    forward = reference_mm / np.linalg.norm(reference_mm)
    down = np.cross(forward, head_r[:, 0])
    down /= np.linalg.norm(down)
    right = np.cross(down, forward)
    right /= np.linalg.norm(right)
    return np.c_[right, down, forward].T


def _zhang_by_hand(face_model_3xn, landmarks, camera_matrix, distortion, gaze_target):
    """Zhang's normalizeData, written out independently: returns per eye (R, W, gaze (p, y), head (p, y))."""
    ok, rvec, tvec = cv2.solvePnP(
        face_model_3xn.T.reshape(-1, 1, 3),
        landmarks.reshape(-1, 1, 2),
        camera_matrix,
        distortion,
        flags=cv2.SOLVEPNP_EPNP,
    )
    ok, rvec, tvec = cv2.solvePnP(
        face_model_3xn.T.reshape(-1, 1, 3), landmarks.reshape(-1, 1, 2), camera_matrix, distortion, rvec, tvec, True
    )
    head_r = cv2.Rodrigues(rvec)[0]
    fc = head_r @ face_model_3xn + tvec  # 3 x 6, camera frame
    out = {}
    for side, cols in (("right", [0, 1]), ("left", [2, 3])):
        et = fc[:, cols].mean(axis=1)
        distance = np.linalg.norm(et)
        r = _zhang_rotation_by_hand(et, head_r)
        cam_n = np.array([[650.0, 0, 30], [0, 650.0, 18], [0, 0, 1]])
        w = cam_n @ np.diag([1.0, 1.0, 600.0 / distance]) @ r @ np.linalg.inv(camera_matrix)
        g = r @ (gaze_target - et)
        g /= np.linalg.norm(g)
        gaze = np.array([np.arcsin(-g[1]), np.arctan2(-g[0], -g[2])])
        zv = (r @ head_r)[:, 2]
        head = np.array([np.arcsin(zv[1]), np.arctan2(zv[0], zv[2])])
        out[side] = (r, w, gaze, head)
    return out


@pytest.fixture(scope="module")
def mpii(mpii_sample):
    ann = json.loads((mpii_sample / "annotation.json").read_text())
    cam = load_camera(mpii_sample / "cameraCalib.xml", image_size=tuple(ann["image_size_wh"]))
    model = load_face_model(mpii_sample / "faceModelGeneric.txt")
    landmarks = np.array(ann["landmarks_6_px"], dtype=np.float64)
    image = load_image_rgb(mpii_sample / ann["image"])
    target = np.array(ann["gaze_target_3d_camera_mm"], dtype=np.float64)
    raw = np.loadtxt(mpii_sample / "faceModelGeneric.txt")
    return cam, model, landmarks, image, target, raw


def test_mpii_labels_equal_a_hand_computation(mpii, real_mpii_sample):  # the real frame's own numbers
    cam, model, landmarks, image, target, raw = mpii
    pose = solve_head_pose(landmarks, model.vertices_mm, cam)
    sample = normalize_image(image, cam, pose, model.vertices_mm, KEYPOINTS["mpii6"], gaze_target_mm=target)
    hand = _zhang_by_hand(raw, landmarks, cam.matrix, cam.distortion, target)
    for side in ("left", "right"):
        r, w, gaze, head = hand[side]
        eye = sample.eye(side)
        np.testing.assert_allclose(eye.camera.rotation, r, atol=1e-7)
        np.testing.assert_allclose(eye.camera.warp_matrix(cam.matrix), w, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(np.degrees(eye.gaze), np.degrees(gaze), atol=1e-5)
        # the pipeline refines PnP from SQPnP's start, the hand computation (as Zhang's code) from
        # EPnP's: Levenberg-Marquardt stops within ~1e-5 deg of the same optimum from either
        np.testing.assert_allclose(np.degrees(eye.head_pose), np.degrees(head), atol=1e-4)
    # the subject's left eye is on the image's right: larger x in the camera frame
    assert sample.left.camera.reference_mm[0] > sample.right.camera.reference_mm[0]
    # plausibility: p00 looks to the image's left of the camera (target x = -128 mm): positive yaw
    assert 5 < np.degrees(sample.left.gaze[1]) < 30


def test_without_antialiasing_on_an_undistorted_camera_it_is_warp_perspective(mpii):
    cam, model, landmarks, image, target, raw = mpii
    cam0 = CameraIntrinsics(cam.matrix, np.zeros(5), cam.image_size)
    pose = solve_head_pose(landmarks, model.vertices_mm, cam0)
    s = normalize_image(
        image, cam0, pose, model.vertices_mm, KEYPOINTS["mpii6"], settings=NormalizationSettings(antialias=False)
    )
    for side in ("left", "right"):
        w = s.eye(side).camera.warp_matrix(cam0.matrix)
        expected = cv2.warpPerspective(image, w, (60, 36))
        diff = np.abs(s.eye(side).image.astype(int) - expected)
        # OpenCV's warp uses fixed-point weights: rounding may differ by one level
        assert diff.max() <= 1 and diff.mean() < 0.01


def test_antialiasing_changes_little_where_there_is_little_to_alias(mpii, real_mpii_sample):  # minified real eyes
    cam, model, landmarks, image, target, raw = mpii
    pose = solve_head_pose(landmarks, model.vertices_mm, cam)
    a = normalize_image(image, cam, pose, model.vertices_mm, KEYPOINTS["mpii6"])
    b = normalize_image(
        image, cam, pose, model.vertices_mm, KEYPOINTS["mpii6"], settings=NormalizationSettings(antialias=False)
    )
    mad = np.abs(a.left.image.astype(float) - b.left.image).mean()
    assert 0 < mad < 6  # MPII eyes are minified ~2x: a mild blur


def test_normalized_camera_by_hand():
    # an eye straight ahead of the camera, head frontal: R = I and W = C_n S C_r^-1
    cam = normalized_camera([0, 0, 300.0], np.eye(3), distance_mm=600, focal_px=650, size_wh=(60, 36))
    np.testing.assert_allclose(cam.rotation, np.eye(3), atol=1e-12)
    k = np.array([[1000.0, 0, 640], [0, 1000.0, 360], [0, 0, 1]])
    expected = np.array([[650.0, 0, 30], [0, 650, 18], [0, 0, 1]]) @ np.diag([1, 1, 2.0]) @ np.linalg.inv(k)
    np.testing.assert_allclose(cam.warp_matrix(k), expected, atol=1e-12)
    # an eye 45 deg to the right (x = z): forward = (1, 0, 1)/sqrt 2, x axis perpendicular to it in the x-z plane
    cam = normalized_camera([400.0, 0, 400.0], np.eye(3), distance_mm=600, focal_px=650, size_wh=(60, 36))
    s = np.sqrt(0.5)
    np.testing.assert_allclose(cam.rotation, [[s, 0, -s], [0, 1, 0], [s, 0, s]], atol=1e-12)
    # looking from that eye into the camera is (0, 0) in its normalized frame
    np.testing.assert_allclose(cam.gaze_pitchyaw([-400.0, 0, -400.0]), [0, 0], atol=1e-12)
    # the head, frontal to the real camera, is turned yaw = -45 deg (toward the image's right) for this camera
    np.testing.assert_allclose(np.degrees(cam.head_pose_pitchyaw(np.eye(3))), [0, -45], atol=1e-9)
    # denormalization undoes normalization
    g = np.array([0.3, -0.2, -0.93])
    np.testing.assert_allclose(cam.denormalize_vector(cam.normalize_vector(g)), g / np.linalg.norm(g), atol=1e-12)


def test_normalized_camera_projects_points_by_hand():
    # the eye 300 mm straight ahead, d_n 600: the patch sees the face as from 600 mm (S halves z)
    cam = normalized_camera([0, 0, 300.0], np.eye(3), distance_mm=600, focal_px=650, size_wh=(60, 36))
    # the reference lands on the principal point (w / 2, h / 2), pixel centres at whole numbers
    np.testing.assert_allclose(cam.project([0.0, 0.0, 300.0]), [30.0, 18.0], atol=1e-12)
    # 10 mm right and 5 mm down at the reference's depth: 650 * 10 / 600 and 650 * 5 / 600 px off it
    np.testing.assert_allclose(cam.project([10.0, 5.0, 300.0]), [30 + 650 * 10 / 600, 18 + 650 * 5 / 600], atol=1e-12)
    # 12 mm nearer the camera (288 mm): S R p = (10, 0, 576), so 650 * 10 / 576 px right
    np.testing.assert_allclose(cam.project([10.0, 0.0, 288.0]), [30 + 650 * 10 / 576, 18.0], atol=1e-12)
    # the camera turned 45 deg (eye at x = z): a point 10 mm along its x axis, at the reference
    cam = normalized_camera([400.0, 0, 400.0], np.eye(3), distance_mm=600, focal_px=650, size_wh=(60, 36))
    s = np.sqrt(0.5)
    e = np.array([400.0, 0.0, 400.0])
    x_axis = np.array([s, 0.0, -s])
    # ||e|| = 400 sqrt 2, S scales z by 600 / ||e||: the 10 mm land 650 * 10 / 600 px right
    np.testing.assert_allclose(cam.project(e + 10 * x_axis), [30 + 650 * 10 / 600, 18.0], atol=1e-9)
    # many points at once, shape (..., 3) -> (..., 2); the inverse of pixel_to_ray
    uv = np.array([[3.0, 4.0], [57.0, 30.5]])
    rays = np.c_[uv, np.ones(2)] @ cam.pixel_to_ray.T
    np.testing.assert_allclose(cam.project((rays * [[2.0], [0.5]])[None]), uv[None], atol=1e-9)
    with pytest.raises(GazeAugError, match="in front of"):
        cam.project([0.0, 0.0, -1.0])
    with pytest.raises(GazeAugError, match=r"\(\.\.\., 3\)"):
        cam.project([1.0, 2.0])


def test_bad_gaze_and_eyes_behind_the_camera(mpii):
    cam, model, landmarks, image, target, raw = mpii
    pose = solve_head_pose(landmarks, model.vertices_mm, cam)
    kp = KEYPOINTS["mpii6"]
    with pytest.raises(GazeAugError, match="finite"):
        normalize_image(image, cam, pose, model.vertices_mm, kp, gaze_target_mm=[np.nan, 0, 0])
    with pytest.raises(GazeAugError, match="zero"):
        normalize_image(image, cam, pose, model.vertices_mm, kp, gaze_vector=[0, 0, 0])
    eye = pose.head_to_camera(model.vertices_mm[[2, 3]]).mean(axis=0)
    with pytest.raises(GazeAugError, match="zero-length"):
        normalize_image(image, cam, pose, model.vertices_mm, kp, gaze_target_mm=eye)
    behind = HeadPose(pose.rotation, pose.translation_mm * np.array([1, 1, -1]))
    with pytest.raises(GazeAugError, match="behind the camera"):
        normalize_image(image, cam, behind, model.vertices_mm, kp)
    with pytest.raises(GazeAugError, match="distance_mm"):
        NormalizationSettings(distance_mm=-1)
    # bounds where the warp's numbers would overflow or vanish (a crafted model file's values)
    for field, value in (("distance_mm", 1e-300), ("distance_mm", 1e308), ("focal_px", 0.5), ("focal_px", 1e7)):
        with pytest.raises(
            GazeAugError, match=rf"normalization {field}: expected a number from 1 to (100000|1e\+06), got"
        ):
            NormalizationSettings(**{field: value})
    assert NormalizationSettings(distance_mm=1.0, focal_px=1e6).focal_px == 1e6
    with pytest.raises(GazeAugError, match="patch size"):
        NormalizationSettings(patch_size_wh=(0, 36))


def test_npz_round_trip_and_atomic_write(mpii, tmp_path):
    cam, model, landmarks, image, target, raw = mpii
    pose = solve_head_pose(landmarks, model.vertices_mm, cam)
    s = normalize_image(
        image, cam, pose, model.vertices_mm, KEYPOINTS["mpii6"], gaze_target_mm=target, meta={"input": "p00"}
    )
    out = tmp_path / "n.npz"
    save_npz(out, s)
    z = load_npz(out)
    assert z["left_eye"].shape == (36, 60, 3) and z["left_eye"].dtype == np.uint8
    np.testing.assert_array_equal(z["right_eye"], s.right.image)
    np.testing.assert_allclose(z["gaze_left"], s.left.gaze)
    np.testing.assert_allclose(z["R_norm_right"], s.right.camera.rotation)
    assert float(z["distance_mm"]) == 600 and float(z["focal_px"]) == 650
    assert z["patch_size_wh"].tolist() == [60, 36] and str(z["source"]) == "normalize"
    assert z["meta"] == {"input": "p00"}
    with pytest.raises(GazeAugError, match=".npz"):
        save_npz(tmp_path / "n.png", s)
    assert not (tmp_path / "n.png").exists()
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(GazeAugError, match="not a readable"):
        load_npz(tmp_path / "bad.npz")


def test_the_normalization_kernel_against_hand_derived_values():
    """One kernel for cameras and labels: values worked out by hand for a frontal face 500 mm away.

    Model (head frame, mm): right eye corners (-35, 0, 0), (-25, 0, 0); left (25, 0, 0), (35, 0, 0);
    mouth (-20, 60, 0), (20, 60, 0). At R = I, t = (0, 0, 500) the left eye centre is e = (30, 0, 500):
    z = e/n, y = z x (1, 0, 0) = (0, 1, 0), x = y x z = (500, 0, -30)/n, n = sqrt(250900); the head
    pose is (asin R[1,2], atan2(R[0,2], R[2,2])) = (0, atan2(-30, 500)); the gaze to the camera
    centre, R_n (-e/n) = (0, 0, -1), is (0, 0). The face centre is (0, 20, 500): x = (1, 0, 0),
    y = (0, 500, -20)/m, m = sqrt(250400); head pose (asin(-20/m), 0); gaze to the camera (0, 0).
    """
    from facemesh.conventions import rotation_yaw
    from facemesh.face_models import FaceKeypoints
    from gazeaug.camera import normalized_camera, normalized_views

    model = np.array([[-35, 0, 0], [-25, 0, 0], [25, 0, 0], [35, 0, 0], [-20, 60, 0], [20, 60, 0]], float)
    kp = FaceKeypoints(right_eye=(0, 1), left_eye=(2, 3), mouth=(4, 5))
    opts = dict(distance_mm=600.0, focal_px=650.0, size_wh=(60, 36))
    v = normalized_views(model, kp, np.eye(3)[None], np.array([[0.0, 0, 500]]), gaze_target_mm=np.zeros(3), **opts)
    n, m = np.sqrt(250900.0), np.sqrt(250400.0)
    left, right, face = v.cameras[0]
    np.testing.assert_allclose(left.rotation, [[500 / n, 0, -30 / n], [0, 1, 0], [30 / n, 0, 500 / n]], atol=1e-15)
    np.testing.assert_allclose(face.rotation, [[1, 0, 0], [0, 500 / m, -20 / m], [0, 20 / m, 500 / m]], atol=1e-15)
    np.testing.assert_allclose(v.references_mm[0], [[30, 0, 500], [-30, 0, 500], [0, 20, 500]], atol=1e-12)
    np.testing.assert_allclose(v.head_pose[0, 0], [0, np.arctan2(-30, 500)], atol=1e-15)
    np.testing.assert_allclose(v.head_pose[0, 1], [0, np.arctan2(30, 500)], atol=1e-15)
    np.testing.assert_allclose(v.head_pose[0, 2], [np.arcsin(-20 / m), 0], atol=1e-15)
    np.testing.assert_allclose(v.gaze[0], np.zeros((3, 2)), atol=1e-15)
    # a batch of poses is each pose on its own, and agrees with the camera's own label methods
    rots = np.stack([np.eye(3), rotation_yaw(0.3)])
    trans = np.array([[0.0, 0, 500], [10, -5, 400]])
    target = np.array([[5.0, 40, 0], [-50, 30, 10]])
    batch = normalized_views(model, kp, rots, trans, gaze_target_mm=target, **opts)
    for p in range(2):
        one = normalized_views(model, kp, rots[p : p + 1], trans[p : p + 1], gaze_target_mm=target[p], **opts)
        np.testing.assert_array_equal(one.head_pose[0], batch.head_pose[p])
        np.testing.assert_array_equal(one.gaze[0], batch.gaze[p])
        for j in range(3):
            cam = normalized_camera(batch.references_mm[p, j], rots[p], **opts)
            np.testing.assert_allclose(cam.rotation, batch.cameras[p][j].rotation, atol=1e-15)
            np.testing.assert_allclose(cam.head_pose_pitchyaw(rots[p]), batch.head_pose[p, j], atol=1e-14)
            g = target[p] - batch.references_mm[p, j]
            np.testing.assert_allclose(cam.gaze_pitchyaw(g), batch.gaze[p, j], atol=1e-14)
    with pytest.raises(GazeAugError, match="not both"):
        normalized_views(model, kp, rots, trans, gaze_target_mm=target, gaze_vector=[0, 0, -1], **opts)
    with pytest.raises(GazeAugError, match="zero-length"):
        normalized_views(model, kp, rots[:1], trans[:1], gaze_vector=[0, 0, 0], **opts)


def _zhang_face_warp_by_hand(face_model_3xn, head_r, head_t, camera_matrix, focal=960.0, distance_n=600.0, size=224):
    """Zhang's face normalization written out: the face centre is the mean of the six model points at the pose."""
    fc = head_r @ face_model_3xn + head_t.reshape(3, 1)
    centre = fc.mean(axis=1)
    distance = np.linalg.norm(centre)
    r = _zhang_rotation_by_hand(centre, head_r)
    cam_n = np.array([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1.0]])
    return cam_n @ np.diag([1.0, 1.0, distance_n / distance]) @ r @ np.linalg.inv(camera_matrix), r


def test_the_face_patch_is_warp_perspective_through_zhangs_face_camera(mpii, tmp_path):
    cam, model, landmarks, image, target, raw = mpii
    cam0 = CameraIntrinsics(cam.matrix, np.zeros(5), cam.image_size)
    pose = solve_head_pose(landmarks, model.vertices_mm, cam0)
    face = NormalizationSettings(antialias=False, face_patch_size_wh=(224, 224))
    s = normalize_image(image, cam0, pose, model.vertices_mm, KEYPOINTS["mpii6"], gaze_target_mm=target, settings=face)
    w, r = _zhang_face_warp_by_hand(raw, np.asarray(pose.rotation), np.asarray(pose.translation_mm), cam0.matrix)
    np.testing.assert_allclose(s.face.camera.rotation, r, atol=1e-9)  # the patch sees the labels' frame
    expected = cv2.warpPerspective(image, w, (224, 224))
    assert s.face.image.shape == (224, 224, 3) and s.face.image.dtype == np.uint8 and expected.std() > 20
    diff = np.abs(s.face.image.astype(int) - expected)
    assert diff.max() <= 1 and diff.mean() < 0.01
    # the face patch changes no label and no eye
    plain = normalize_image(
        image,
        cam0,
        pose,
        model.vertices_mm,
        KEYPOINTS["mpii6"],
        gaze_target_mm=target,
        settings=NormalizationSettings(antialias=False),
    )
    assert plain.face.image is None
    np.testing.assert_array_equal(plain.face.gaze, s.face.gaze)
    np.testing.assert_array_equal(plain.left.image, s.left.image)
    # the face camera's own distance and focal: half the focal is half the scale about the centre
    half = NormalizationSettings(antialias=False, face_patch_size_wh=(112, 112), face_focal_px=480.0)
    h = normalize_image(image, cam0, pose, model.vertices_mm, KEYPOINTS["mpii6"], settings=half)
    w_half, _ = _zhang_face_warp_by_hand(
        raw, np.asarray(pose.rotation), np.asarray(pose.translation_mm), cam0.matrix, focal=480.0, size=112
    )
    assert np.abs(h.face.image.astype(int) - cv2.warpPerspective(image, w_half, (112, 112))).max() <= 1
    # saved with the sample
    save_npz(tmp_path / "f.npz", s)
    z = load_npz(tmp_path / "f.npz")
    np.testing.assert_array_equal(z["face"], s.face.image)
    assert z["face_patch_size_wh"].tolist() == [224, 224] and float(z["face_focal_px"]) == 960


def test_face_patch_settings_and_their_record():
    plain = NormalizationSettings()
    # without a face patch the record is the one outputs carried before face patches existed
    assert plain.as_dict() == {"distance_mm": 600.0, "focal_px": 650.0, "patch_size_wh": [60, 36], "antialias": True}
    face = NormalizationSettings(face_patch_size_wh=(224, 224))
    rec = face.as_dict()
    assert rec["face_patch_size_wh"] == [224, 224] and rec["face_focal_px"] == 960 and rec["face_distance_mm"] == 600
    assert NormalizationSettings.from_dict(rec) == face
    with pytest.raises(GazeAugError, match="face patch size"):
        NormalizationSettings(face_patch_size_wh=(224, 2000))
    with pytest.raises(GazeAugError, match="without a face patch"):
        NormalizationSettings(face_focal_px=500.0)
    with pytest.raises(GazeAugError, match="face_distance_mm"):
        NormalizationSettings(face_patch_size_wh=(224, 224), face_distance_mm=-1.0)
