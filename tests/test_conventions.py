"""Every convention pinned to values derived by hand (see facemesh/conventions.py)."""

import math

import numpy as np
import pytest

from facemesh import conventions as cv

S30, C30 = 0.5, math.sqrt(3) / 2


def test_pitchyaw_zero_looks_into_the_camera():
    np.testing.assert_allclose(cv.pitchyaw_to_vector([0.0, 0.0]), [0, 0, -1], atol=1e-15)


def test_positive_pitch_looks_up_and_positive_yaw_looks_to_image_left():
    # pitch 30 deg: x = 0, y = -sin 30, z = -cos 30 (y points down, so up is -y)
    np.testing.assert_allclose(cv.pitchyaw_to_vector([math.radians(30), 0.0]), [0, -S30, -C30], atol=1e-15)
    # yaw 90 deg: x = -1 (image left)
    np.testing.assert_allclose(cv.pitchyaw_to_vector([0.0, math.pi / 2]), [-1, 0, 0], atol=1e-15)


def test_vector_to_pitchyaw_hand_values():
    # (0, -1, -1): 45 deg up, straight ahead
    np.testing.assert_allclose(cv.vector_to_pitchyaw([0.0, -1.0, -1.0]), [math.pi / 4, 0.0], atol=1e-15)
    # (1, 0, -1): 45 deg toward the image's right = yaw -45 deg
    np.testing.assert_allclose(cv.vector_to_pitchyaw([1.0, 0.0, -1.0]), [0.0, -math.pi / 4], atol=1e-15)


def test_pitchyaw_round_trip_batched():
    rng = np.random.default_rng(0)
    a = rng.uniform(-1.2, 1.2, size=(50, 2))
    np.testing.assert_allclose(cv.vector_to_pitchyaw(cv.pitchyaw_to_vector(a)), a, atol=1e-12)


def test_vector_to_pitchyaw_rejects_zero():
    with pytest.raises(ValueError):
        cv.vector_to_pitchyaw([0.0, 0.0, 0.0])


def test_head_pose_of_identity_is_frontal():
    np.testing.assert_allclose(cv.rotation_to_head_pitchyaw(np.eye(3)), [0, 0], atol=1e-15)


def test_wheelchair_camera_below_looking_up_gives_positive_pitch():
    # World: y down. A level head looks along world -z toward a camera in front
    # of it; its head frame equals the world frame. The camera sits below,
    # pitched up 30 deg: its z axis is (0, -sin30, cos30) in the world, its y
    # axis (0, cos30, sin30), its x axis (1, 0, 0). World -> camera rotation
    # has these axes as rows; the head's rotation in the camera is that matrix.
    r_cam_from_world = np.array([[1, 0, 0], [0, C30, S30], [0, -S30, C30]])
    np.testing.assert_allclose(np.degrees(cv.rotation_to_head_pitchyaw(r_cam_from_world)), [30, 0], atol=1e-12)


def test_rotation_pitch_and_yaw_hand_matrices():
    np.testing.assert_allclose(cv.rotation_pitch(math.radians(30)), [[1, 0, 0], [0, C30, S30], [0, -S30, C30]])
    np.testing.assert_allclose(cv.rotation_yaw(math.radians(30)), [[C30, 0, S30], [0, 1, 0], [-S30, 0, C30]])


def test_paper_rotation_order_and_face_direction():
    y, p = math.radians(30), math.radians(20)
    r = cv.rotation_from_yaw_pitch(y, p)
    np.testing.assert_allclose(r, cv.rotation_pitch(p) @ cv.rotation_yaw(y))
    # face direction -R[:, 2] = (-sin y, -sin p cos y, -cos p cos y), derived by hand
    expected = [-math.sin(y), -math.sin(p) * math.cos(y), -math.cos(p) * math.cos(y)]
    np.testing.assert_allclose(-r[:, 2], expected, atol=1e-15)
    # pure pitch and pure yaw give exactly that head pose
    np.testing.assert_allclose(cv.rotation_to_head_pitchyaw(cv.rotation_from_yaw_pitch(0, p)), [p, 0], atol=1e-15)
    np.testing.assert_allclose(cv.rotation_to_head_pitchyaw(cv.rotation_from_yaw_pitch(y, 0)), [0, y], atol=1e-15)


def test_opencv_gltf_axes_and_units():
    np.testing.assert_allclose(cv.opencv_to_gltf_points([10.0, 20.0, 500.0]), [0.01, -0.02, -0.5])
    np.testing.assert_allclose(cv.gltf_to_opencv_points([0.01, -0.02, -0.5]), [10.0, 20.0, 500.0])
    assert np.linalg.det(cv.OPENCV_TO_GLTF) == pytest.approx(1.0)  # a rotation: windings survive


def test_mediapipe_canonical_to_head_axes():
    # MediaPipe: y up, z toward the viewer; head frame: y down (chin), z into the head.
    np.testing.assert_allclose(cv.MEDIAPIPE_CANONICAL_TO_HEAD @ [1.0, 2.0, 3.0], [1.0, -2.0, -3.0])


def test_pixels_to_uv_pixel_centres():
    # crop origin (10, 20), crop size 100 x 50: pixel (10, 20) is the crop's
    # first pixel, whose centre is at u = 0.5 / 100, v = 0.5 / 50.
    np.testing.assert_allclose(cv.pixels_to_uv([[10.0, 20.0]], (10, 20), (100, 50)), [[0.005, 0.01]])
    np.testing.assert_allclose(cv.pixels_to_uv([[109.5, 69.5]], (10, 20), (100, 50)), [[1.0, 1.0]])
    np.testing.assert_allclose(cv.uv_to_pixels([[0.005, 0.01]], (100, 50)), [[0.0, 0.0]])


def test_gltf_uv_to_bottom_left_uv_hand_values():
    # The texture's four corners: glTF's top-left (0, 0) is (0, 1) with the
    # origin at the bottom-left, and so on (u kept, v -> 1 - v).
    corners = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]
    out = cv.gltf_uv_to_bottom_left_uv(corners)
    assert out.dtype == np.float64 and out.shape == (4, 2)
    np.testing.assert_array_equal(out, [[0.0, 1.0], [1.0, 1.0], [0.0, 0.0], [1.0, 0.0]])
    # Centre of the top-left pixel of a 4 x 2 (W x H) texture: glTF uv
    # (0.5 / 4, 0.5 / 2) = (0.125, 0.25); seen from the bottom-left corner it
    # is 1.5 pixels of 2 up: v = 1.5 / 2 = 0.75.
    np.testing.assert_array_equal(cv.gltf_uv_to_bottom_left_uv([[0.125, 0.25]]), [[0.125, 0.75]])
    np.testing.assert_array_equal(
        cv.gltf_uv_to_bottom_left_uv(cv.pixels_to_uv([[0.0, 0.0]], (0, 0), (4, 2))), [[0.125, 0.75]]
    )


def test_gltf_uv_to_bottom_left_uv_is_its_own_inverse():
    uv = np.random.default_rng(0).uniform(0.0, 1.0, size=(20, 2)).astype(np.float32)
    before = uv.copy()
    once = cv.gltf_uv_to_bottom_left_uv(uv)
    np.testing.assert_allclose(cv.gltf_uv_to_bottom_left_uv(once), uv, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(uv, before)  # the input is not changed


def test_angular_error_hand_values():
    assert cv.angular_error_deg([1, 0, 0], [0, 1, 0]) == pytest.approx(90.0)
    assert cv.angular_error_deg([1, 0, 0], [2, 0, 0]) == pytest.approx(0.0)
    assert cv.angular_error_deg([0, 0, -1], [0, -S30, -C30]) == pytest.approx(30.0)


def test_rotation_from_yaw_pitch_batches_agree_with_the_hand_formula():
    from facemesh.conventions import rotation_from_yaw_pitch

    yaw = np.radians([0.0, 25.0, -40.0, 10.0])
    pitch = np.radians([30.0, -15.0, 5.0, 0.0])
    r = rotation_from_yaw_pitch(yaw, pitch)
    assert r.shape == (4, 3, 3)
    # the frontal face direction (0, 0, -1) goes to (-sin y, -sin p cos y, -cos p cos y)
    expected = np.stack([-np.sin(yaw), -np.sin(pitch) * np.cos(yaw), -np.cos(pitch) * np.cos(yaw)], axis=1)
    np.testing.assert_allclose(r @ [0.0, 0.0, -1.0], expected, atol=1e-15)
    for k in range(4):
        np.testing.assert_allclose(r[k], rotation_from_yaw_pitch(yaw[k], pitch[k]), atol=1e-15)
