"""Every frame, axis, angle and unit convention of the project, in one place.

Nothing outside this module flips a sign or swaps an axis. Each function
names the convention it converts from and to; the tests in
``tests/test_conventions.py`` pin every one of them to values derived by hand.

Frames
------
OpenCV camera frame (``camera``)
    Origin at the camera centre; x to the right of the image, y down the
    image, z forward along the optical axis. Millimetres.
Image frame (``px``)
    Pixel coordinates as OpenCV uses them: x = column, y = row, the centre of
    the top-left pixel at (0, 0).
Head frame (``head``), also the frame of every face model
    Origin at the midpoint of the two eye centres (each eye centre the mean of
    that eye's two corners). x points toward the subject's *left* ear (so it
    matches the image's x for a face looking into the camera), y toward the
    chin, z from the face into the head. A face looking straight into a camera
    in front of it has rotation identity. Millimetres.
glTF frame (``gltf``)
    glTF 2.0: right-handed, +Y up, a camera looks down -Z; metres. An OpenCV
    camera frame point (x, y, z) mm is ``(x, -y, -z) / 1000`` in glTF, so a
    glTF camera at the origin with identity orientation sees what the real
    camera saw.
Texture coordinates (``uv``)
    glTF's: u to the right, v down, (0, 0) the top-left *corner* of the
    texture image and (1, 1) the bottom-right corner. Pixel centre (i, j) of a
    W x H texture sits at ((i + 0.5) / W, (j + 0.5) / H). Open3D and trimesh
    use the other common convention (origin at the bottom-left corner, v up):
    :func:`gltf_uv_to_bottom_left_uv` converts.
Rig frame (``rig``), gazeaug's applications (:class:`gazeaug.sampling.Rig`)
    The head frame of the user sitting still and looking straight ahead:
    origin between the eyes, x toward the user's left, y down, z from the
    face back into the head (the space in front of the face has negative z).
    Millimetres. A rig's camera sits at ``c`` (rig frame) with the rotation
    ``R`` (rig -> camera, rows the camera's axes in the rig frame), so a
    point is ``p_cam = R (p_rig - c)`` and ``p_rig = R^T p_cam + c``
    (:func:`camera_to_rig_points`, :func:`rig_to_camera_points`); a
    direction is ``R^T v`` (:func:`camera_to_rig_directions`).
OpenGL (``opengl``): Filament's and pyrender's cameras
    A camera's axes are glTF's (x right, y up, looking down -z; the same
    ``diag(1, -1, -1)`` from OpenCV's, :func:`opencv_to_opengl_camera_pose`),
    and pixel centres sit at half integers: OpenCV's pixel (i, j) is OpenGL's
    (i + 0.5, j + 0.5) (:func:`opencv_to_opengl_pixels`).

Angles
------
Directions (gaze, and the direction the face points) are (pitch, yaw) in
radians with the MPIIGaze / ETH-XGaze convention::

    x = -cos(pitch) sin(yaw),  y = -sin(pitch),  z = -cos(pitch) cos(yaw)

so (0, 0) looks straight into the camera, positive pitch looks *up* and
positive yaw looks toward the image's left (the subject's right).

The head pose as (pitch, yaw) is this convention applied to the direction the
face points, ``-R[:, 2]`` (the opposite of the head frame's z axis):
``pitch = asin(R[1, 2])``, ``yaw = atan2(R[0, 2], R[2, 2])`` as in MPIIGaze.
A head pose pitch of +30 deg means the face points 30 deg above the camera's
axis, which is how a camera *below* the face, looking up at it, sees a level
head (the paper's wheelchair example).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "OPENCV_TO_GLTF",
    "MEDIAPIPE_CANONICAL_TO_HEAD",
    "opencv_to_gltf_points",
    "gltf_to_opencv_points",
    "pixels_to_uv",
    "uv_to_pixels",
    "gltf_uv_to_bottom_left_uv",
    "opencv_to_gltf_directions",
    "gltf_to_opencv_directions",
    "homogeneous_pixel_centres",
    "mediapipe_normalized_to_pixels",
    "opencv_to_opengl_pixels",
    "opencv_to_opengl_camera_pose",
    "look_at_rotation",
    "camera_to_rig_points",
    "camera_to_rig_directions",
    "rig_to_camera_points",
    "pitchyaw_to_vector",
    "vector_to_pitchyaw",
    "MIRROR_PITCHYAW",
    "mirror_pitchyaw",
    "mirrored_columns",
    "principal_point_grid_coordinates",
    "rotation_to_head_pitchyaw",
    "face_forward",
    "frontal_coordinates",
    "rotation_yaw",
    "rotation_pitch",
    "rotation_from_yaw_pitch",
    "yaw_pitch_from_rotation",
    "angular_error_deg",
]

#: (3, 3) float64: axis change from the OpenCV camera frame to glTF axes
#: (x kept, y and z negated). Its own inverse.
OPENCV_TO_GLTF: NDArray[np.float64] = np.diag([1.0, -1.0, -1.0])

#: (3, 3) float64: axis change from MediaPipe's canonical face model frame
#: (x toward the subject's left, y up, z toward the viewer) to the head frame.
MEDIAPIPE_CANONICAL_TO_HEAD: NDArray[np.float64] = np.diag([1.0, -1.0, -1.0])

_MM_PER_M = 1000.0


def _as_points(points: ArrayLike, dim: int, name: str) -> NDArray[np.float64]:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim < 1 or arr.shape[-1] != dim:
        raise ValueError(f"{name}: expected shape (..., {dim}), got {arr.shape}")
    return arr


def opencv_to_gltf_points(points_camera_mm: ArrayLike) -> NDArray[np.float64]:
    """OpenCV camera frame, mm -> glTF axes, metres.

    Args:
        points_camera_mm: (..., 3) float, millimetres, OpenCV camera frame.

    Returns:
        (..., 3) float64, metres, glTF frame.
    """
    p = _as_points(points_camera_mm, 3, "points_camera_mm")
    return (p @ OPENCV_TO_GLTF.T) / _MM_PER_M


def gltf_to_opencv_points(points_gltf_m: ArrayLike) -> NDArray[np.float64]:
    """GlTF axes, metres -> OpenCV camera frame, mm (inverse of :func:`opencv_to_gltf_points`).

    Args:
        points_gltf_m: (..., 3) float, metres, glTF frame.

    Returns:
        (..., 3) float64, millimetres, OpenCV camera frame.
    """
    p = _as_points(points_gltf_m, 3, "points_gltf_m")
    return (p @ OPENCV_TO_GLTF.T) * _MM_PER_M


def pixels_to_uv(points_px: ArrayLike, origin_px: tuple[float, float], size_wh: tuple[int, int]) -> NDArray[np.float64]:
    """Image pixel coordinates -> glTF texture coordinates of a cropped texture.

    Args:
        points_px: (..., 2) float, pixels, image frame of the full image.
        origin_px: (x0, y0) integer pixel of the full image that is the
            crop's top-left pixel.
        size_wh: (width, height) of the crop in pixels.

    Returns:
        (..., 2) float64 uv: ``u = (x - x0 + 0.5) / W``, ``v = (y - y0 + 0.5) / H``.
    """
    p = _as_points(points_px, 2, "points_px")
    w, h = size_wh
    if w <= 0 or h <= 0:
        raise ValueError(f"size_wh: expected positive sizes, got {size_wh}")
    out = np.empty_like(p)
    out[..., 0] = (p[..., 0] - origin_px[0] + 0.5) / w
    out[..., 1] = (p[..., 1] - origin_px[1] + 0.5) / h
    return out


def uv_to_pixels(uv: ArrayLike, size_wh: tuple[int, int]) -> NDArray[np.float64]:
    """Texture coordinates (glTF) -> pixel coordinates in the texture image.

    The inverse of :func:`pixels_to_uv` with origin (0, 0).

    Args:
        uv: (..., 2) float, glTF texture coordinates.
        size_wh: (width, height) of the texture in pixels.

    Returns:
        (..., 2) float64 pixels, image frame of the texture (pixel centres at integers).
    """
    t = _as_points(uv, 2, "uv")
    out = np.empty_like(t)
    out[..., 0] = t[..., 0] * size_wh[0] - 0.5
    out[..., 1] = t[..., 1] * size_wh[1] - 0.5
    return out


def gltf_uv_to_bottom_left_uv(uv: ArrayLike) -> NDArray[np.float64]:
    """GlTF texture coordinates (origin top-left, v down) -> origin bottom-left, v up.

    Convention: glTF puts (0, 0) at the top-left corner of the texture image
    with v growing down the image; OpenGL, and with it Open3D's and trimesh's
    glTF readers, put (0, 0) at the bottom-left corner with v growing up. u
    (to the right) is the same in both, so ``(u, v) -> (u, 1 - v)``: the
    top-left corner (0, 0) becomes (0, 1), the bottom-left corner (0, 1)
    becomes (0, 0). The conversion is its own inverse.

    Args:
        uv: (K, 2) float, glTF texture coordinates (any (..., 2) shape works).

    Returns:
        (K, 2) float64 (same shape as ``uv``), texture coordinates with the
        origin at the bottom-left corner, v up: ``(u, 1 - v)``.
    """
    t = _as_points(uv, 2, "uv")
    out = np.array(t, dtype=np.float64, copy=True)
    out[..., 1] = 1.0 - t[..., 1]
    return out


def pitchyaw_to_vector(pitchyaw_rad: ArrayLike) -> NDArray[np.float64]:
    """(pitch, yaw) radians -> unit direction vector, MPIIGaze convention.

    Args:
        pitchyaw_rad: (..., 2) float, radians, (pitch, yaw).

    Returns:
        (..., 3) float64 unit vectors in the camera frame the angles refer to:
        ``(-cos p sin y, -sin p, -cos p cos y)``.

    Examples (hand-derived: (0, 0) looks into the camera, along -z; pitch +90 deg
    looks up, -y in a y-down frame; yaw +90 deg looks toward the image's left, -x):

    >>> pitchyaw_to_vector([0.0, 0.0]).round(12) + 0.0
    array([ 0.,  0., -1.])
    >>> pitchyaw_to_vector([[np.pi / 2, 0.0], [0.0, np.pi / 2]]).round(12) + 0.0
    array([[ 0., -1.,  0.],
           [-1.,  0.,  0.]])
    """
    a = _as_points(pitchyaw_rad, 2, "pitchyaw_rad")
    p, y = a[..., 0], a[..., 1]
    return np.stack([-np.cos(p) * np.sin(y), -np.sin(p), -np.cos(p) * np.cos(y)], axis=-1)


def vector_to_pitchyaw(vectors: ArrayLike) -> NDArray[np.float64]:
    """Direction vector (any length > 0) -> (pitch, yaw) radians, MPIIGaze convention.

    Args:
        vectors: (..., 3) float, any non-zero length, camera frame.

    Returns:
        (..., 2) float64 radians, (pitch, yaw); pitch in [-pi/2, pi/2], yaw in (-pi, pi].

    Examples (a gaze 45 deg up, straight ahead; any length):

    >>> np.degrees(vector_to_pitchyaw([0.0, -2.0, -2.0])).round(12) + 0.0
    array([45.,  0.])
    """
    v = _as_points(vectors, 3, "vectors")
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n == 0) or not np.all(np.isfinite(n)):
        raise ValueError("vectors: expected finite, non-zero vectors")
    u = v / n
    pitch = np.arcsin(np.clip(-u[..., 1], -1.0, 1.0))
    yaw = np.arctan2(-u[..., 0], -u[..., 2])
    return np.stack([pitch, yaw], axis=-1)


#: (2,) float64: the factors a left-right mirror of an image (its camera frame's x negated) applies
#: to a (pitch, yaw) pair of the MPIIGaze convention: pitch kept, yaw negated (see :func:`mirror_pitchyaw`).
MIRROR_PITCHYAW: NDArray[np.float64] = np.array([1.0, -1.0])


def mirror_pitchyaw(pitchyaw_rad: ArrayLike) -> NDArray[np.float64]:
    """(pitch, yaw) of a direction seen in a left-right mirrored image (the camera frame's x negated).

    Convention: MPIIGaze (pitch, yaw), as :func:`pitchyaw_to_vector`. The vector
    ``(-cos p sin y, -sin p, -cos p cos y)`` with x negated is
    ``(cos p sin y, -sin p, -cos p cos y)``, the vector of ``(p, -y)``: the pitch is
    kept and the yaw negated, for a gaze and for a head pose (the head's forward
    direction) alike. A mirrored left eye patch is a right eye's.

    Args:
        pitchyaw_rad: (..., 2) float, radians.

    Returns:
        (..., 2) float64 radians, ``pitchyaw_rad * MIRROR_PITCHYAW``.
    """
    return _as_points(pitchyaw_rad, 2, "pitchyaw_rad") * MIRROR_PITCHYAW


def mirrored_columns(width: int) -> NDArray[np.int64]:
    """Source column of each column of a left-right mirrored normalized patch.

    Convention: the normalized camera's principal point is ``(w / 2, h / 2)`` with pixel
    centres at whole numbers (:func:`homogeneous_pixel_centres`), so mirroring the scene
    about the optical axis maps column ``x`` to ``w - x`` (not ``w - 1 - x``, the plain
    flip, which would shift the mirrored patch by one pixel). Column 0 has no source
    (``w`` lies outside) and repeats its neighbour's.

    Args:
        width: w, the patch's width in pixels (>= 2).

    Returns:
        (w,) int64: ``[w - 1, w - 1, w - 2, ..., 1]``: ``out[x] = w - x`` for x >= 1.
    """
    if not (isinstance(width, (int, np.integer)) and width >= 2):
        raise ValueError(f"width: expected an integer >= 2, got {width!r}")
    cols = int(width) - np.arange(int(width), dtype=np.int64)
    cols[0] = int(width) - 1
    return cols


def principal_point_grid_coordinates(width: int, height: int) -> tuple[float, float]:
    """The normalized camera's principal point in PyTorch's ``grid_sample`` coordinates.

    Convention: the principal point is ``(w / 2, h / 2)`` with pixel centres at whole
    numbers (:func:`mirrored_columns`); ``grid_sample`` with ``align_corners=False`` puts
    the patch's left edge at -1 and its right edge at +1, so pixel centre ``x`` lies at
    ``(2 x + 1) / w - 1`` and the principal point at ``(1 / w, 1 / h)``, half a pixel
    right of and below the patch's geometric centre. Zooming a patch by ``f`` about this
    point (output position ``q`` reads input ``c + (q - c) / f``) is the same normalized
    camera with focal length ``f f_n``: the gaze and head-pose labels stay as they are.

    Args:
        width: w, the patch's width in pixels (>= 1).
        height: h, the patch's height in pixels (>= 1).

    Returns:
        (x, y), floats in grid_sample's normalized units (x right, y down).
    """
    for name, v in (("width", width), ("height", height)):
        if not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1):
            raise ValueError(f"{name}: expected an integer >= 1, got {v!r}")
    return 1.0 / int(width), 1.0 / int(height)


def rotation_to_head_pitchyaw(rotation_head_to_camera: ArrayLike) -> NDArray[np.float64]:
    """Head rotation -> head pose (pitch, yaw) radians (MPIIGaze: from the third column).

    Args:
        rotation_head_to_camera: (..., 3, 3) float, rotation taking head frame
            vectors into the camera frame.

    Returns:
        (..., 2) float64 radians: ``pitch = asin(R[1, 2])``, ``yaw = atan2(R[0, 2], R[2, 2])``.
    """
    return vector_to_pitchyaw(face_forward(rotation_head_to_camera))


def face_forward(rotation_head_to_camera: ArrayLike) -> NDArray[np.float64]:
    """The direction the face points, in the camera frame: ``-R[:, 2]`` (the head frame's -z axis).

    Convention: the head frame's z axis points into the head (see the module
    docstring), so the face looks along -z; the identity rotation gives
    ``(0, 0, -1)``, a face looking into the camera.

    Args:
        rotation_head_to_camera: (..., 3, 3) float, head frame -> camera frame.

    Returns:
        (..., 3) float64 unit vectors, camera frame.

    >>> face_forward(np.eye(3))
    array([-0., -0., -1.])
    """
    r = np.asarray(rotation_head_to_camera, dtype=np.float64)
    if r.shape[-2:] != (3, 3):
        raise ValueError(f"rotation_head_to_camera: expected shape (..., 3, 3), got {r.shape}")
    return np.asarray(-r[..., :, 2])


def frontal_coordinates(points: ArrayLike, forward: ArrayLike) -> NDArray[np.float64]:
    """Points seen from the front: orthographic projection along ``forward`` onto 2D axes ``(e1, e2)``.

    Convention: ``e1`` and ``e2`` are orthonormal, perpendicular to
    ``forward`` and right-handed with it (``e1 x e2 = forward / |forward|``);
    ``e1`` is the frame's x axis made perpendicular to ``forward`` (its y axis
    when x is within 1e-6 of parallel). So a triangle whose right-hand normal
    points along ``forward`` (toward a viewer in front of the face) has a
    positive signed area in these coordinates, and for ``forward = (0, 0, -1)``
    (:func:`face_forward` of a face looking into the camera) ``(e1, e2) = (x, -y)``.

    Args:
        points: (N, 3) float, any unit, any frame.
        forward: (3,) float, same frame: where the face looks (any length > 0).

    Returns:
        (N, 2) float64, the unit of ``points``.

    Raises:
        ValueError: ``forward`` is not 3 finite numbers with a length > 0.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(forward, dtype=np.float64).reshape(-1)
    norm = float(np.linalg.norm(f)) if f.shape == (3,) and np.all(np.isfinite(f)) else 0.0
    if not norm > 0:
        raise ValueError(f"forward: expected 3 finite numbers, not all zero, got {np.asarray(forward).tolist()}")
    f = f / norm
    ref = np.array([1.0, 0.0, 0.0]) if abs(f[0]) < 1.0 - 1e-6 else np.array([0.0, 1.0, 0.0])
    e1 = ref - (ref @ f) * f
    e1 /= np.linalg.norm(e1)
    e2 = _cross3(f, e1)
    return p @ np.stack([e1, e2], axis=1)


def _rotations(
    c: NDArray[np.float64], s: NDArray[np.float64], rows: tuple[tuple[str, ...], ...]
) -> NDArray[np.float64]:
    """(..., 3, 3) matrices whose entries are "1", "0", "c", "s" or "-s" per ``rows``."""
    values = {"1": np.ones_like(c), "0": np.zeros_like(c), "c": c, "s": s, "-s": -s}
    return np.stack([np.stack([values[e] for e in row], axis=-1) for row in rows], axis=-2)


def rotation_yaw(yaw_rad: ArrayLike) -> NDArray[np.float64]:
    """Rotation about the camera's y axis that turns a face pointing along -z to yaw ``yaw_rad``.

    ``[[cos, 0, sin], [0, 1, 0], [-sin, 0, cos]]`` (right-handed about +y).
    ``yaw_rad``: a float, or an array of shape (...,) for (..., 3, 3) matrices.
    """
    y = np.asarray(yaw_rad, dtype=np.float64)
    return _rotations(np.cos(y), np.sin(y), (("c", "0", "s"), ("0", "1", "0"), ("-s", "0", "c")))


def rotation_pitch(pitch_rad: ArrayLike) -> NDArray[np.float64]:
    """Rotation about the camera's x axis that turns a face pointing along -z to pitch ``pitch_rad`` (up for > 0).

    It is the right-handed rotation about +x by ``-pitch_rad``:
    ``[[1, 0, 0], [0, cos, sin], [0, -sin, cos]]``.
    ``pitch_rad``: a float, or an array of shape (...,) for (..., 3, 3) matrices.
    """
    p = np.asarray(pitch_rad, dtype=np.float64)
    return _rotations(np.cos(p), np.sin(p), (("1", "0", "0"), ("0", "c", "s"), ("0", "-s", "c")))


def rotation_from_yaw_pitch(yaw_rad: ArrayLike, pitch_rad: ArrayLike) -> NDArray[np.float64]:
    """The paper's head rotation ``R(y, p) = R_pitch(p) @ R_yaw(y)``: yaw first, then pitch.

    Applied to a frontal face (pointing along -z) it gives a face pointing to
    ``(-sin y, -sin p cos y, -cos p cos y)``: exactly pitch p for y = 0 and
    exactly yaw y for p = 0.

    Args:
        yaw_rad: float, or an array (...,) for many rotations at once.
        pitch_rad: float, or an array of the same shape.

    Returns:
        (3, 3) (or (..., 3, 3)) float64 rotation, camera frame.
    """
    return rotation_pitch(pitch_rad) @ rotation_yaw(yaw_rad)


def yaw_pitch_from_rotation(rotation: ArrayLike) -> NDArray[np.float64]:
    """Inverse of :func:`rotation_from_yaw_pitch` for the direction the face points.

    The (yaw, pitch) whose ``R(y, p)`` turns a frontal face to point where
    ``rotation`` makes it point (``-rotation[:, 2]``); roll is not represented.
    ``yaw = asin(R[0, 2])``, ``pitch = atan2(R[1, 2], R[2, 2])``.

    Args:
        rotation: (3, 3) float, head frame -> camera frame.

    Returns:
        (2,) float64 radians, (yaw, pitch): note the order, the paper's ``R(y, p)``.
    """
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3):
        raise ValueError(f"rotation: expected shape (3, 3), got {r.shape}")
    return np.array([np.arcsin(np.clip(r[0, 2], -1.0, 1.0)), np.arctan2(r[1, 2], r[2, 2])])


def angular_error_deg(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Angle between direction vectors, degrees.

    Args:
        a: (..., 3) float, any non-zero length.
        b: (..., 3) float, any non-zero length, same frame as ``a``.

    Returns:
        (...,) float64 degrees in [0, 180].
    """
    u = _as_points(a, 3, "a")
    v = _as_points(b, 3, "b")
    nu = np.linalg.norm(u, axis=-1)
    nv = np.linalg.norm(v, axis=-1)
    if np.any(nu == 0) or np.any(nv == 0):
        raise ValueError("angular_error_deg: expected non-zero vectors")
    cos = np.sum(u * v, axis=-1) / (nu * nv)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def opencv_to_gltf_directions(vectors: ArrayLike) -> NDArray[np.float64]:
    """Directions (normals, axes) in the OpenCV camera frame -> glTF axes; lengths are kept.

    Convention: the axis change of :func:`opencv_to_gltf_points` without the
    unit change, ``(x, y, z) -> (x, -y, -z)``: the direction toward an OpenCV
    camera, ``(0, 0, -1)``, is glTF's ``(0, 0, 1)``. A rotation (determinant
    +1), so right-hand normals stay right-hand normals.

    Args:
        vectors: (..., 3) float, any length, OpenCV camera frame.

    Returns:
        (..., 3) float64, same lengths, glTF frame.
    """
    return _as_points(vectors, 3, "vectors") @ OPENCV_TO_GLTF.T


def gltf_to_opencv_directions(vectors: ArrayLike) -> NDArray[np.float64]:
    """Directions in glTF axes -> OpenCV camera frame (inverse of :func:`opencv_to_gltf_directions`).

    Args:
        vectors: (..., 3) float, any length, glTF frame.

    Returns:
        (..., 3) float64, same lengths, OpenCV camera frame: ``(x, -y, -z)``.
    """
    return _as_points(vectors, 3, "vectors") @ OPENCV_TO_GLTF.T


def homogeneous_pixel_centres(size_wh: tuple[int, int], supersample: int = 1) -> NDArray[np.float64]:
    """Homogeneous image positions ``(x, y, 1)`` of every pixel centre (or sub-pixel sample) of an image.

    Convention: OpenCV's, pixel (i, j) (column i, row j) is centred at (i, j),
    so the image spans [-0.5, W - 0.5] x [-0.5, H - 0.5]. With ``supersample``
    s > 1 each pixel holds s x s samples on a regular grid centred on its
    centre: sample k of pixel i (along either axis) sits at
    ``i + (k + 0.5) / s - 0.5``. A camera's pixel -> ray matrix (``K^-1``, or
    ``R^T K^-1`` for a turned camera) times these gives its rays.

    Args:
        size_wh: (W, H) image size in pixels.
        supersample: samples per pixel side, >= 1.

    Returns:
        (H * s, W * s, 3) float64; row ``j * s + kj``, column ``i * s + ki``
        is sample (ki, kj) of pixel (i, j), so ``reshape(H, s, W, s, 3)``
        groups each pixel's samples.
    """
    w, h, s = int(size_wh[0]), int(size_wh[1]), int(supersample)
    if w <= 0 or h <= 0 or s < 1:
        raise ValueError(f"size_wh and supersample: expected positive sizes and s >= 1, got {size_wh}, {supersample}")
    offsets = (np.arange(s) + 0.5) / s - 0.5
    xs = (np.arange(w)[:, None] + offsets[None, :]).ravel()
    ys = (np.arange(h)[:, None] + offsets[None, :]).ravel()
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx, gy, np.ones_like(gx)], axis=-1)


def mediapipe_normalized_to_pixels(points_normalized: ArrayLike, size_wh: tuple[int, int]) -> NDArray[np.float64]:
    """MediaPipe's normalized landmark positions -> image pixel coordinates.

    Convention: MediaPipe gives x and y as fractions of the image's width and
    height measured from the image's top-left *corner* ((0, 0) the corner,
    (1, 1) the bottom-right corner); pixel coordinates put the centre of the
    top-left pixel at (0, 0), half a pixel from the corner. So
    ``x_px = x * W - 0.5``, ``y_px = y * H - 0.5``.

    Args:
        points_normalized: (..., 2) float, MediaPipe's (x, y) fractions.
        size_wh: (W, H) of the image the landmarks were detected in, pixels.

    Returns:
        (..., 2) float64 pixels, image frame (pixel centres at integers).
    """
    p = _as_points(points_normalized, 2, "points_normalized")
    out = np.empty_like(p)
    out[..., 0] = p[..., 0] * size_wh[0] - 0.5
    out[..., 1] = p[..., 1] * size_wh[1] - 0.5
    return out


def opencv_to_opengl_pixels(points_px: ArrayLike) -> NDArray[np.float64]:
    """Image positions with pixel centres at integers (OpenCV) -> at half integers (OpenGL, Filament, pyrender).

    Convention: both measure x to the right and y down from the image's
    top-left corner side (as OpenGL intrinsics ``cx``, ``cy`` are given), but
    OpenCV puts the top-left pixel's centre at (0, 0) and OpenGL at
    (0.5, 0.5): ``(x, y) -> (x + 0.5, y + 0.5)``. Used for a principal point
    handed to an OpenGL renderer.

    Args:
        points_px: (..., 2) float, pixels, OpenCV image frame.

    Returns:
        (..., 2) float64, pixels, OpenGL pixel-centre convention.
    """
    return _as_points(points_px, 2, "points_px") + 0.5


def opencv_to_opengl_camera_pose(rotation_world_to_camera: ArrayLike, translation_mm: ArrayLike) -> NDArray[np.float64]:
    """OpenCV extrinsics -> the 4 x 4 pose (camera -> world) of the same camera with OpenGL camera axes.

    Convention: OpenCV extrinsics map a world point to the camera frame,
    ``p_cam = R p_world + t`` (x right, y down, looking along +z); an OpenGL
    camera node (pyrender, glTF) is placed by its pose, camera -> world, with
    x right, y up, looking along -z. The camera centre is ``-R^T t`` and the
    OpenGL axes are the OpenCV ones times ``diag(1, -1, -1)``
    (:data:`OPENCV_TO_GLTF`), so the pose is
    ``[[R^T diag(1, -1, -1), -R^T t], [0, 0, 0, 1]]``.

    Args:
        rotation_world_to_camera: (3, 3) float ``R``, world (scene) frame -> OpenCV camera frame.
        translation_mm: (3,) float ``t``, mm (the scene's unit).

    Returns:
        (4, 4) float64 camera -> world pose, OpenGL camera axes.
    """
    r = np.asarray(rotation_world_to_camera, dtype=np.float64)
    t = np.asarray(translation_mm, dtype=np.float64)
    if r.shape != (3, 3) or t.shape != (3,):
        raise ValueError(f"extrinsics: expected (3, 3) and (3,), got {r.shape} and {t.shape}")
    pose = np.eye(4)
    pose[:3, :3] = r.T @ OPENCV_TO_GLTF
    pose[:3, 3] = -r.T @ t
    return pose


def look_at_rotation(
    forward: ArrayLike, *, right: ArrayLike | None = None, down: ArrayLike | None = None
) -> NDArray[np.float64]:
    """The rotation of a camera looking along ``forward``, levelled by a hint for its x or its y axis.

    Convention: the rows are the camera's x (right), y (down) and z
    (forward) axes, OpenCV's, in the frame of the inputs, so the matrix maps
    that frame's vectors into the camera's. Exactly one hint:

    - ``right`` (the hint for x): ``y = normalize(z x right)``,
      ``x = normalize(y x z)``. x lies in the plane of z and the hint, y is
      perpendicular to the hint. Zhang's normalized camera (hint: the head's
      x axis) and a rig's camera (hint: the rig's x axis) are built so.
    - ``down`` (the hint for y): ``x = normalize(down x z)``,
      ``y = normalize(z x x)``. x is perpendicular to the hint (level).

    Args:
        forward: (..., 3) float, any non-zero length: the viewing direction z.
        right: (..., 3) float, broadcastable to ``forward``: hint for x.
        down: (..., 3) float, broadcastable to ``forward``: hint for y.

    Returns:
        (..., 3, 3) float64 rotation, rows (x, y, z).

    Raises:
        ValueError: not exactly one hint, a zero ``forward``, or a hint
            parallel to ``forward`` (|z x hint| < 1e-9 |hint|).
    """
    if right is not None and down is None:
        hint = _as_points(right, 3, "right")
    elif down is not None and right is None:
        hint = _as_points(down, 3, "down")
    else:
        raise ValueError("look_at_rotation: give exactly one of right= and down=")
    f = _as_points(forward, 3, "forward")
    f, hint = np.broadcast_arrays(f, hint)
    fn = np.sqrt(f[..., 0] * f[..., 0] + f[..., 1] * f[..., 1] + f[..., 2] * f[..., 2])[..., None]
    if not (np.all(np.isfinite(fn)) and np.all(fn > 0)):
        raise ValueError("look_at_rotation: forward must be finite and non-zero")
    z = f / fn
    first = _cross3(z, hint) if right is not None else _cross3(hint, z)  # y (right hint) or x (down hint)
    n = np.sqrt(np.sum(first * first, axis=-1, keepdims=True))
    if not np.all(n >= 1e-9 * np.sqrt(np.sum(hint * hint, axis=-1, keepdims=True))) or not np.all(n > 0):
        raise ValueError("look_at_rotation: the hint is parallel to the forward axis; the rotation is undefined")
    first = first / n
    second = _cross3(first, z) if right is not None else _cross3(z, first)  # x = y x z, or y = z x x
    second = second / np.sqrt(np.sum(second * second, axis=-1, keepdims=True))
    x, y = (second, first) if right is not None else (first, second)
    return np.stack([x, y, z], axis=-2)


def _rig_pose(
    rotation_rig_to_camera: ArrayLike, camera_position_rig_mm: ArrayLike | None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    r = np.asarray(rotation_rig_to_camera, dtype=np.float64)
    if r.shape != (3, 3):
        raise ValueError(f"rotation_rig_to_camera: expected a (3, 3) rotation, got shape {r.shape}")
    c = np.zeros(3) if camera_position_rig_mm is None else np.asarray(camera_position_rig_mm, dtype=np.float64)
    if c.shape != (3,):
        raise ValueError(f"camera_position_rig_mm: expected (3,) mm, got shape {c.shape}")
    return r, c


def camera_to_rig_points(
    points_camera_mm: ArrayLike, rotation_rig_to_camera: ArrayLike, camera_position_rig_mm: ArrayLike
) -> NDArray[np.float64]:
    """Points from a rig's camera frame (OpenCV, mm) into the rig frame (mm).

    Convention: ``p_rig = R^T p_cam + c``, with ``R`` the rig -> camera
    rotation (rows: the camera's x, y, z axes in the rig frame, as
    :func:`look_at_rotation` builds it) and ``c`` the camera centre in the
    rig frame. The camera centre ``(0, 0, 0)`` maps to ``c``.

    Args:
        points_camera_mm: (..., 3) float, OpenCV camera frame, mm.
        rotation_rig_to_camera: (3, 3) float.
        camera_position_rig_mm: (3,) float, rig frame, mm.

    Returns:
        (..., 3) float64, rig frame, mm.
    """
    p = _as_points(points_camera_mm, 3, "points_camera_mm")
    r, c = _rig_pose(rotation_rig_to_camera, camera_position_rig_mm)
    return p @ r + c


def rig_to_camera_points(
    points_rig_mm: ArrayLike, rotation_rig_to_camera: ArrayLike, camera_position_rig_mm: ArrayLike
) -> NDArray[np.float64]:
    """Points from the rig frame (mm) into the rig's camera frame (OpenCV, mm): ``p_cam = R (p_rig - c)``.

    The inverse of :func:`camera_to_rig_points` (same arguments, same shapes).
    """
    p = _as_points(points_rig_mm, 3, "points_rig_mm")
    r, c = _rig_pose(rotation_rig_to_camera, camera_position_rig_mm)
    return (p - c) @ r.T


def camera_to_rig_directions(vectors_camera: ArrayLike, rotation_rig_to_camera: ArrayLike) -> NDArray[np.float64]:
    """Directions (gaze vectors) from a rig's camera frame into the rig frame: ``v_rig = R^T v_cam``.

    Args:
        vectors_camera: (..., 3) float, OpenCV camera frame; any length (kept).
        rotation_rig_to_camera: (3, 3) float, as in :func:`camera_to_rig_points`.

    Returns:
        (..., 3) float64, rig frame.
    """
    v = _as_points(vectors_camera, 3, "vectors_camera")
    r, _ = _rig_pose(rotation_rig_to_camera, None)
    return v @ r


def _cross3(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cross product over the last axis of two (..., 3) arrays of one shape (without ``np.cross``'s overhead)."""
    out = np.empty(a.shape, dtype=np.float64)
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out
