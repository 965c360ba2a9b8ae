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


def test_mirror_keeps_pitch_and_negates_yaw():
    # a gaze 30 deg up and 30 deg toward the image's left: (-C30 S30, -S30, -C30 C30) = (-0.433, -0.5, -0.75);
    # in the mirrored image it points toward the image's right: (+0.433, -0.5, -0.75), i.e. (30, -30) deg
    p, y = math.radians(30), math.radians(30)
    np.testing.assert_allclose(cv.mirror_pitchyaw([p, y]), [p, -y], atol=1e-15)
    expected = [C30 * S30, -S30, -C30 * C30]
    np.testing.assert_allclose(cv.pitchyaw_to_vector(cv.mirror_pitchyaw([p, y])), expected, atol=1e-15)
    rng = np.random.default_rng(1)
    a = rng.uniform(-1.2, 1.2, size=(20, 2))
    mirrored = cv.pitchyaw_to_vector(a) * [-1.0, 1.0, 1.0]  # the camera frame's x negated
    np.testing.assert_allclose(cv.vector_to_pitchyaw(mirrored), cv.mirror_pitchyaw(a), atol=1e-12)
    np.testing.assert_array_equal(cv.mirror_pitchyaw(cv.mirror_pitchyaw(a)), a)


def test_mirrored_columns_reflect_about_the_principal_point():
    # w = 4: principal point 2.0, pixel centres 0..3; x -> 4 - x: 1 -> 3, 2 -> 2, 3 -> 1; 0 -> 4 is outside: 3
    np.testing.assert_array_equal(cv.mirrored_columns(4), [3, 3, 2, 1])
    c = cv.mirrored_columns(60)
    assert c[30] == 30 and c[1] == 59 and c[59] == 1
    with pytest.raises(ValueError, match="width"):
        cv.mirrored_columns(1)


def test_principal_point_in_grid_sample_coordinates():
    # w = 60: pixel centre 30 (the principal point) lies at (2 * 30 + 1) / 60 - 1 = 1/60; h = 36: 37/36 - 1 = 1/36
    assert cv.principal_point_grid_coordinates(60, 36) == pytest.approx((1 / 60, 1 / 36), abs=1e-15)
    # w = 4: the left edge is -1, pixel centres at -0.75, -0.25, 0.25, 0.75; the principal point 2.0 at 0.25
    assert cv.principal_point_grid_coordinates(4, 1) == pytest.approx((0.25, 1.0), abs=1e-15)
    for bad in ((0, 36), (60, 2.5), (True, 3)):
        with pytest.raises(ValueError, match="expected an integer >= 1"):
            cv.principal_point_grid_coordinates(*bad)


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


def test_opencv_gltf_directions_keep_lengths():
    # the direction toward an OpenCV camera (0, 0, -1) is glTF's +z (toward the viewer)
    np.testing.assert_array_equal(cv.opencv_to_gltf_directions([0.0, 0.0, -1.0]), [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(cv.opencv_to_gltf_directions([[1.0, 2.0, 3.0]]), [[1.0, -2.0, -3.0]])
    np.testing.assert_array_equal(cv.gltf_to_opencv_directions([1.0, -2.0, -3.0]), [1.0, 2.0, 3.0])


def test_homogeneous_pixel_centres_hand_values():
    # 3 x 2 image: pixel (i, j) centred at (i, j)
    expected = [[[0, 0, 1], [1, 0, 1], [2, 0, 1]], [[0, 1, 1], [1, 1, 1], [2, 1, 1]]]
    out = cv.homogeneous_pixel_centres((3, 2))
    assert out.shape == (2, 3, 3) and out.dtype == np.float64
    np.testing.assert_array_equal(out, expected)
    # 2 x 2 samples per pixel of a 2 x 1 image: pixel 0 spans [-0.5, 0.5], its samples at -0.25 and 0.25;
    # pixel 1 spans [0.5, 1.5]: 0.75 and 1.25; the one row's samples at -0.25 and 0.25
    sub = cv.homogeneous_pixel_centres((2, 1), supersample=2)
    assert sub.shape == (2, 4, 3)
    np.testing.assert_array_equal(sub[0, :, 0], [-0.25, 0.25, 0.75, 1.25])
    np.testing.assert_array_equal(sub[:, 0, 1], [-0.25, 0.25])
    np.testing.assert_array_equal(sub[..., 2], 1.0)
    with pytest.raises(ValueError):
        cv.homogeneous_pixel_centres((2, 1), supersample=0)


def test_mediapipe_normalized_to_pixels_hand_values():
    # a 640 x 480 image: the top-left corner (0, 0) is half a pixel before the first pixel's centre,
    # the middle (0.5, 0.5) lies between pixels 319 and 320, 239 and 240, the far corner (1, 1) at 639.5, 479.5
    out = cv.mediapipe_normalized_to_pixels([[0.0, 0.0], [0.5, 0.5], [1.0, 1.0]], (640, 480))
    np.testing.assert_array_equal(out, [[-0.5, -0.5], [319.5, 239.5], [639.5, 479.5]])


def test_opencv_to_opengl_pixels_hand_values():
    # OpenCV's top-left pixel centre (0, 0) is OpenGL's (0.5, 0.5); the principal point of a 60 x 36
    # normalized camera (30, 18) becomes (30.5, 18.5)
    np.testing.assert_array_equal(cv.opencv_to_opengl_pixels([[0.0, 0.0], [30.0, 18.0]]), [[0.5, 0.5], [30.5, 18.5]])


def test_opencv_to_opengl_camera_pose_hand_values():
    # identity rotation, the world origin 5 mm in front of the camera: the camera sits at world z = -5,
    # its OpenGL y axis (up) is world -y and it looks down its -z, i.e. along world +z
    pose = cv.opencv_to_opengl_camera_pose(np.eye(3), [0.0, 0.0, 5.0])
    np.testing.assert_array_equal(pose, [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, -5], [0, 0, 0, 1]])
    # a camera turned 90 deg to look along world +x: rows of R are its x, y, z axes in the world,
    # x = (0, 0, -1), y = (0, 1, 0), z = (1, 0, 0); centre at world (-7, 0, 0), so t = -R c = (0, 0, 7)
    r = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    pose = cv.opencv_to_opengl_camera_pose(r, [0.0, 0.0, 7.0])
    # pose columns: OpenGL x = OpenCV x = (0, 0, -1); OpenGL y = -OpenCV y = (0, -1, 0); OpenGL z = -OpenCV z
    np.testing.assert_array_equal(pose[:3, :3], [[0, 0, -1], [0, -1, 0], [-1, 0, 0]])
    np.testing.assert_array_equal(pose[:3, 3], [-7, 0, 0])
    np.testing.assert_array_equal(pose[:3, :3] @ [0, 0, -1], [1, 0, 0])  # it looks along world +x


def test_look_at_rotation_hand_values():
    # looking along +z with the hint x: the identity
    np.testing.assert_allclose(cv.look_at_rotation([0.0, 0.0, 3.0], right=[1.0, 0.0, 0.0]), np.eye(3), atol=1e-15)
    # a camera below the eyes looking up at 45 deg: z = (0, -1, 1)/sqrt2 (up is -y), hint x = (1, 0, 0):
    # y = z x x = (0, 1, 1)/sqrt2, x = y x z = (1, 0, 0); the same as the wheelchair test's matrix at 45 deg
    h = math.sqrt(0.5)
    np.testing.assert_allclose(
        cv.look_at_rotation([0.0, -1.0, 1.0], right=[1.0, 0.0, 0.0]), [[1, 0, 0], [0, h, h], [0, -h, h]], atol=1e-15
    )
    # a hint not perpendicular to z keeps y perpendicular to it: z = +z, hint (1, 0, 1) -> x = (1, 0, 0)
    np.testing.assert_allclose(cv.look_at_rotation([0.0, 0.0, 1.0], right=[1.0, 0.0, 1.0]), np.eye(3), atol=1e-15)
    # looking along +x with the hint y = (0, 1, 0): x = y x z = (0, 0, -1), y = z x x = (0, 1, 0)
    np.testing.assert_allclose(
        cv.look_at_rotation([2.0, 0.0, 0.0], down=[0.0, 1.0, 0.0]), [[0, 0, -1], [0, 1, 0], [1, 0, 0]], atol=1e-15
    )
    # the down hint keeps x level: z = (0, -1, 1)/sqrt2, hint (0, 1, 0): x = (1, 0, 0), y = (0, 1, 1)/sqrt2
    np.testing.assert_allclose(
        cv.look_at_rotation([0.0, -1.0, 1.0], down=[0.0, 1.0, 0.0]), [[1, 0, 0], [0, h, h], [0, -h, h]], atol=1e-15
    )


def test_look_at_rotation_batches_and_refuses_degenerate_hints():
    rng = np.random.default_rng(5)
    f = rng.normal(size=(6, 3))
    hint = rng.normal(size=(6, 3))
    r = cv.look_at_rotation(f, right=hint)
    assert r.shape == (6, 3, 3)
    np.testing.assert_allclose(r @ np.transpose(r, (0, 2, 1)), np.broadcast_to(np.eye(3), (6, 3, 3)), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-14)
    np.testing.assert_allclose(r[:, 2], f / np.linalg.norm(f, axis=1, keepdims=True), atol=1e-15)
    np.testing.assert_allclose(np.einsum("ki,ki->k", r[:, 1], hint), 0.0, atol=1e-14)  # y perpendicular to the hint
    for k in range(6):
        np.testing.assert_array_equal(r[k], cv.look_at_rotation(f[k], right=hint[k]))
    with pytest.raises(ValueError, match="parallel"):
        cv.look_at_rotation([0.0, 0.0, 1.0], right=[0.0, 0.0, 2.0])
    with pytest.raises(ValueError, match="exactly one"):
        cv.look_at_rotation([0.0, 0.0, 1.0])
    with pytest.raises(ValueError):
        cv.look_at_rotation([0.0, 0.0, 0.0], down=[0.0, 1.0, 0.0])


def test_camera_rig_frames_hand_values():
    # The wheelchair rig: the camera 460 mm from the eyes, 30 deg below their line of sight,
    # c = (0, 460 sin 30, -460 cos 30) = (0, 230, -398.37) (rig frame: y down, in front z < 0),
    # looking at the eyes: its z axis (0, -230, 398.37) / 460 = (0, -1/2, sqrt3/2), x level = (1, 0, 0),
    # y = z x x = (0, sqrt3/2, 1/2).
    s3 = math.sqrt(3) / 2
    c = np.array([0.0, 230.0, -460 * s3])
    r = np.array([[1.0, 0.0, 0.0], [0.0, s3, 0.5], [0.0, -0.5, s3]])
    np.testing.assert_allclose(cv.look_at_rotation(-c, right=[1.0, 0.0, 0.0]), r, atol=1e-12)
    # the eyes are 460 mm straight ahead of the camera; the camera centre is c
    np.testing.assert_allclose(cv.camera_to_rig_points([0.0, 0.0, 460.0], r, c), [0.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(cv.camera_to_rig_points([0.0, 0.0, 0.0], r, c), c, atol=1e-12)
    # 100 mm along the camera's x (the image's right, the user's left as the camera faces them): rig +x
    np.testing.assert_allclose(cv.camera_to_rig_points([100.0, 0.0, 0.0], r, c), c + [100.0, 0.0, 0.0], atol=1e-9)
    # the camera's optical axis in the rig: up (y < 0) and back toward the user (z > 0)
    np.testing.assert_allclose(cv.camera_to_rig_directions([0.0, 0.0, 1.0], r), [0.0, -0.5, s3], atol=1e-12)
    # a user looking straight ahead (rig (0, 0, -1)) looks, for the camera, away and up in its image:
    # R (0, 0, -1) = (0, -1/2, -sqrt3/2)
    np.testing.assert_allclose(cv.camera_to_rig_directions([0.0, -0.5, -s3], r), [0.0, 0.0, -1.0], atol=1e-12)
    # round trips, batched
    pts = np.array([[1.0, 2.0, 3.0], [-40.0, 5.0, 600.0]])
    np.testing.assert_allclose(cv.rig_to_camera_points(cv.camera_to_rig_points(pts, r, c), r, c), pts, atol=1e-9)
    with pytest.raises(ValueError, match="rotation_rig_to_camera"):
        cv.camera_to_rig_points(pts, np.eye(2), c)


def test_face_forward_hand_values():
    # identity: the face looks into the camera, along -z
    np.testing.assert_allclose(cv.face_forward(np.eye(3)), [0, 0, -1], atol=0)
    # the paper's R(y, p) turns a frontal face to (-sin y, -sin p cos y, -cos p cos y)
    y, p = np.radians(20.0), np.radians(30.0)
    expected = [-np.sin(y), -np.sin(p) * np.cos(y), -np.cos(p) * np.cos(y)]
    np.testing.assert_allclose(cv.face_forward(cv.rotation_from_yaw_pitch(y, p)), expected, atol=1e-15)
    assert cv.face_forward(np.stack([np.eye(3)] * 4)).shape == (4, 3)


def test_frontal_coordinates_hand_values():
    pts = np.array([[1.0, 2.0, 3.0], [-4.0, 5.0, 6.0]])
    # a face looking into the camera: (x, -y)
    np.testing.assert_allclose(cv.frontal_coordinates(pts, (0, 0, -1)), [[1, -2], [-4, -5]], atol=1e-15)
    # seen from behind (forward +z): (x, y), the other handedness
    np.testing.assert_allclose(cv.frontal_coordinates(pts, (0, 0, 5)), [[1, 2], [-4, 5]], atol=1e-15)
    # a face looking along +x (x parallel to forward): e1 = y, e2 = x cross y = z
    np.testing.assert_allclose(cv.frontal_coordinates(pts, (2, 0, 0)), [[2, 3], [5, 6]], atol=1e-15)
    # a counter-clockwise triangle seen from the front (normal toward the viewer) has positive area
    tri = np.array([[0.0, 0, 500], [10, 0, 500], [0, -10, 500]])  # normal (b-a)x(c-a) = (0, 0, -100)
    q = cv.frontal_coordinates(tri, (0, 0, -1))
    assert (q[1] - q[0])[0] * (q[2] - q[0])[1] - (q[1] - q[0])[1] * (q[2] - q[0])[0] > 0
    for bad in ((0, 0, 0), (0, 0), (np.nan, 0, 1)):
        with pytest.raises(ValueError, match="forward"):
            cv.frontal_coordinates(pts, bad)
