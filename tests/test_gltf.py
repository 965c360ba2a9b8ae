"""Tests of :mod:`facemesh.gltf`: GLB writing and reading.

Expected values are derived by hand from the fixture (the OpenCV -> glTF rule
``(x, -y, -z) / 1000``, the winding, the camera's field of view) and checked
with independent readers (trimesh, a few lines of ``struct``, the Khronos
validator), never with facemesh's own conversion functions.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import struct
import subprocess
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import face_photo

from facemesh.gltf import gltf_bytes, load_glb, save_glb
from facemesh.types import CameraIntrinsics, FaceLandmarks, FaceMesh, HeadPose, InputError

REPO_ROOT = Path(__file__).resolve().parents[1]
VALIDATE_SCRIPT = REPO_ROOT / "tools" / "validate_gltf.mjs"

# A 3 x 3 grid of vertices, 80 mm wide, 500 mm in front of the camera, the
# centre vertex ("nose") pulled 30 mm toward the camera. OpenCV camera frame, mm.
GRID_XY = (-40.0, 0.0, 40.0)
VERTICES_MM = np.array([[x, y, 500.0] for y in GRID_XY for x in GRID_XY])
VERTICES_MM[4, 2] = 470.0
# Vertex r * 3 + c is row r (y grows down the image), column c (x grows right).
# Per cell, (top-left, bottom-left, bottom-right) and (top-left, bottom-right,
# top-right) run counter-clockwise as the camera sees the image.
TRIANGLES = np.array(
    [
        [0, 3, 4], [0, 4, 1],
        [1, 4, 5], [1, 5, 2],
        [3, 6, 7], [3, 7, 4],
        [4, 7, 8], [4, 8, 5],
    ]
)  # fmt: skip
# The same vertices in glTF, written out by hand: (x, -y, -z) / 1000, metres.
GOLDEN_GLTF_M = np.array(
    [
        [-0.040, 0.040, -0.500], [0.000, 0.040, -0.500], [0.040, 0.040, -0.500],
        [-0.040, 0.000, -0.500], [0.000, 0.000, -0.470], [0.040, 0.000, -0.500],
        [-0.040, -0.040, -0.500], [0.000, -0.040, -0.500], [0.040, -0.040, -0.500],
    ]
)  # fmt: skip


def make_mesh(
    *,
    vertices_mm: np.ndarray = VERTICES_MM,
    triangles: np.ndarray = TRIANGLES,
    points_3d: bool = True,
    texture: np.ndarray | None = None,
    extras: dict[str, Any] | None = None,
) -> FaceMesh:
    """A small synthetic face mesh with non-trivial metadata (12 landmarks for 9 vertices)."""
    rng = np.random.default_rng(1234)
    n = len(vertices_mm)
    num_landmarks = n + 3
    if texture is None:
        texture = rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8)
    rotation = np.asarray(cv2.Rodrigues(np.array([0.1, -0.25, 0.05]))[0], dtype=np.float64)
    return FaceMesh(
        vertices_mm=vertices_mm,
        triangles=triangles,
        uv=rng.uniform(0.0, 1.0, size=(n, 2)),
        texture=texture,
        texture_origin_px=(271, 193),
        landmarks=FaceLandmarks(
            points_px=rng.uniform(100.0, 500.0, size=(num_landmarks, 2)),
            model_name="mediapipe_face_mesh",
            points_3d=rng.normal(size=(num_landmarks, 3)) * 37.0 if points_3d else None,
        ),
        camera=CameraIntrinsics(
            matrix=np.array([[600.0 + 1 / 3, 0.0, 320.5], [0.0, 610.0, 240.25], [0.0, 0.0, 1.0]]),
            distortion=np.array([0.1, -0.05, 0.001, 0.002, 1 / 7]),
            image_size=(640, 480),
            source="calib/camera.yaml",
        ),
        pose=HeadPose(
            rotation=rotation,
            translation_mm=np.array([3.2, -5.1, 520.7 + 1 / 3]),
            reprojection_error_px=1.2345678901234567,
        ),
        face_model_name="mediapipe",
        vertex_placement="backprojected",
        reconstruction={"method": "ball_pivoting", "backend": "open3d", "radii_mm": [1.5, 3.0, 6.0 + 1 / 3]},
        extras={"source_image": "face.jpg", "nested": {"k": [1, 2.5, None, True]}} if extras is None else extras,
    )


def read_glb_json(path: Path) -> dict[str, Any]:
    """The JSON chunk of a GLB, read with nothing but struct (independent of facemesh)."""
    data = path.read_bytes()
    magic, version, total = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, total) == (b"glTF", 2, len(data))
    length, ctype = struct.unpack_from("<II", data, 12)
    assert ctype == 0x4E4F534A
    result: dict[str, Any] = json.loads(data[20 : 20 + length])
    return result


def write_glb(path: Path, gltf: dict[str, Any], binary: bytes) -> None:
    """Write a GLB from a JSON object and a BIN chunk (test-side, to craft damaged files)."""
    j = json.dumps(gltf).encode()
    j += b" " * (-len(j) % 4)
    b = binary + b"\x00" * (-len(binary) % 4)
    total = 12 + 8 + len(j) + 8 + len(b)
    path.write_bytes(
        struct.pack("<4sII", b"glTF", 2, total)
        + struct.pack("<II", len(j), 0x4E4F534A)
        + j
        + struct.pack("<II", len(b), 0x004E4942)
        + b
    )


def split_glb(path: Path) -> tuple[dict[str, Any], bytes]:
    """(JSON, BIN) of a GLB, read with struct."""
    data = path.read_bytes()
    jlen = struct.unpack_from("<I", data, 12)[0]
    blen = struct.unpack_from("<I", data, 20 + jlen)[0]
    return json.loads(data[20 : 20 + jlen]), data[28 + jlen : 28 + jlen + blen]


def assert_same_metadata(a: FaceMesh, b: FaceMesh) -> None:
    """Assert that everything but vertices, uv, triangles and texture is exactly equal."""
    assert np.array_equal(a.camera.matrix, b.camera.matrix)
    assert np.array_equal(a.camera.distortion, b.camera.distortion)
    assert a.camera.image_size == b.camera.image_size
    assert a.camera.source == b.camera.source
    assert np.array_equal(a.pose.rotation, b.pose.rotation)
    assert np.array_equal(a.pose.translation_mm, b.pose.translation_mm)
    assert a.pose.reprojection_error_px == b.pose.reprojection_error_px
    assert np.array_equal(a.landmarks.points_px, b.landmarks.points_px)
    assert a.landmarks.model_name == b.landmarks.model_name
    if a.landmarks.points_3d is None:
        assert b.landmarks.points_3d is None
    else:
        assert b.landmarks.points_3d is not None
        assert np.array_equal(a.landmarks.points_3d, b.landmarks.points_3d)
    assert a.landmarks.bbox_px == b.landmarks.bbox_px
    assert a.texture_origin_px == b.texture_origin_px
    assert a.face_model_name == b.face_model_name
    assert a.vertex_placement == b.vertex_placement
    assert a.reconstruction == b.reconstruction
    assert a.extras == b.extras


# --------------------------------------------------------------------------- round trip


@pytest.mark.parametrize("with_points_3d", [True, False])
def test_round_trip_exact(tmp_path: Path, with_points_3d: bool) -> None:
    """Save then load: float32-exact vertices and uv, exact triangles, texture and metadata."""
    mesh = make_mesh(points_3d=with_points_3d)
    path = tmp_path / "face.glb"
    save_glb(mesh, path)
    back = load_glb(path)

    # Vertices: exactly the float32 of the hand-written glTF positions, brought back by hand.
    expected_mm = GOLDEN_GLTF_M.astype(np.float32).astype(np.float64) * np.array([1.0, -1.0, -1.0]) * 1000.0
    np.testing.assert_allclose(back.vertices_mm, expected_mm, rtol=1e-12, atol=0)
    np.testing.assert_allclose(back.vertices_mm, mesh.vertices_mm, rtol=0, atol=1e-4)  # 0.1 micrometre
    # uv: exactly the float32 of what was stored.
    assert np.array_equal(back.uv, mesh.uv.astype(np.float32).astype(np.float64))
    assert back.triangles.dtype == np.int64
    assert np.array_equal(back.triangles, TRIANGLES)
    assert back.texture.dtype == np.uint8
    assert np.array_equal(back.texture, mesh.texture)
    assert back.landmarks.num_points == 12 and back.num_vertices == 9
    assert_same_metadata(mesh, back)


def test_gltf_bytes_matches_saved_file(tmp_path: Path) -> None:
    """gltf_bytes gives the bytes save_glb writes."""
    mesh = make_mesh()
    path = tmp_path / "face.glb"
    save_glb(mesh, path)
    assert path.read_bytes() == gltf_bytes(mesh)


def test_metadata_block(tmp_path: Path) -> None:
    """The extras.facemesh block holds the documented fields with float64 values."""
    path = tmp_path / "face.glb"
    save_glb(make_mesh(), path)
    meta = read_glb_json(path)["extras"]["facemesh"]
    assert meta["format_version"] == 1
    assert isinstance(meta["package_version"], str) and meta["package_version"]
    assert meta["vertex_count"] == 9
    assert len(meta["landmarks"]["points_px"]) == 12
    assert meta["camera"]["image_size"] == [640, 480]
    assert meta["camera"]["matrix"][0][0] == 600.0 + 1 / 3  # float64 repr, not float32
    assert meta["pose"]["reprojection_error_px"] == 1.2345678901234567


def test_jpeg_texture(tmp_path: Path) -> None:
    """A JPEG texture is tagged image/jpeg and decodes close to the original."""
    yy, xx = np.mgrid[0:48, 0:64]
    smooth = np.stack([xx * 4, yy * 5, (xx + yy) * 2], axis=-1).astype(np.uint8)
    mesh = make_mesh(texture=smooth)
    path = tmp_path / "face.glb"
    save_glb(mesh, path, texture_format="jpeg")
    gltf = read_glb_json(path)
    assert gltf["images"][0]["mimeType"] == "image/jpeg"
    back = load_glb(path)
    assert back.texture.shape == smooth.shape
    assert np.abs(back.texture.astype(int) - smooth.astype(int)).mean() < 3.0
    assert_same_metadata(mesh, back)


def test_mesh_without_triangles(tmp_path: Path) -> None:
    """A mesh with no triangles is written as POINTS and read back."""
    mesh = make_mesh(triangles=np.zeros((0, 3), dtype=np.int64))
    path = tmp_path / "points.glb"
    save_glb(mesh, path)
    assert read_glb_json(path)["meshes"][0]["primitives"][0]["mode"] == 0  # POINTS
    back = load_glb(path)
    assert back.triangles.shape == (0, 3)
    assert back.num_vertices == 9


def test_large_mesh_uses_uint32_indices(tmp_path: Path) -> None:
    """Over 65535 vertices, indices are uint32 and still round-trip."""
    n = 70_000
    rng = np.random.default_rng(5)
    vertices = np.column_stack([rng.uniform(-50, 50, n), rng.uniform(-50, 50, n), rng.uniform(450, 550, n)])
    triangles = np.column_stack([np.arange(n - 2), np.arange(1, n - 1), np.arange(2, n)])
    mesh = make_mesh(vertices_mm=vertices, triangles=triangles)
    path = tmp_path / "big.glb"
    save_glb(mesh, path)
    gltf = read_glb_json(path)
    index_accessor = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["indices"]]
    assert index_accessor["componentType"] == 5125  # UNSIGNED_INT
    back = load_glb(path)
    assert np.array_equal(back.triangles, triangles)
    np.testing.assert_allclose(back.vertices_mm, vertices, rtol=0, atol=1e-4)


# --------------------------------------------------------------------------- independent readers


def test_trimesh_reads_same_vertices_in_same_order(tmp_path: Path) -> None:
    """Trimesh sees the hand-converted glTF positions and our triangles, in order."""
    trimesh = pytest.importorskip("trimesh")
    path = tmp_path / "face.glb"
    save_glb(make_mesh(), path)
    loaded = trimesh.load(str(path), force="mesh", process=False)
    assert len(loaded.vertices) == 9
    np.testing.assert_allclose(np.asarray(loaded.vertices), GOLDEN_GLTF_M, rtol=0, atol=1e-7)
    assert np.array_equal(np.asarray(loaded.faces), TRIANGLES)


def test_winding_faces_the_gltf_camera(tmp_path: Path) -> None:
    """Triangles facing the OpenCV camera are glTF front faces facing the glTF camera (+Z)."""
    trimesh = pytest.importorskip("trimesh")
    # A flat square facing the camera, 2 triangles counter-clockwise as the camera sees them:
    # top-left, bottom-left, bottom-right / top-left, bottom-right, top-right.
    square = np.array([[-50.0, -50.0, 500.0], [50.0, -50.0, 500.0], [50.0, 50.0, 500.0], [-50.0, 50.0, 500.0]])
    mesh = make_mesh(vertices_mm=square, triangles=np.array([[0, 3, 2], [0, 2, 1]]))
    path = tmp_path / "square.glb"
    save_glb(mesh, path)
    loaded = trimesh.load(str(path), force="mesh", process=False)
    v = np.asarray(loaded.vertices)
    f = np.asarray(loaded.faces)
    # glTF front faces are counter-clockwise: right-hand normal (b - a) x (c - a).
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    # The square sits at z = -0.5 m; the glTF camera at the origin looks down -Z,
    # so a square facing it has normal +Z.
    np.testing.assert_allclose(normals, [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], atol=1e-12)

    # The grid with its nose: every face normal has a +Z component (toward the camera).
    path = tmp_path / "face.glb"
    save_glb(make_mesh(), path)
    loaded = trimesh.load(str(path), force="mesh", process=False)
    v, f = np.asarray(loaded.vertices), np.asarray(loaded.faces)
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(normals[:, 2] > 0)

    # Vertex normals stored in the file: unit length, toward the camera.
    gltf, binary = split_glb(path)
    acc = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["NORMAL"]]
    view = gltf["bufferViews"][acc["bufferView"]]
    stored = np.frombuffer(binary, "<f4", count=acc["count"] * 3, offset=view["byteOffset"]).reshape(-1, 3)
    np.testing.assert_allclose(np.linalg.norm(stored, axis=1), 1.0, atol=1e-6)
    assert np.all(stored[:, 2] > 0)
    np.testing.assert_allclose(stored[4], [0.0, 0.0, 1.0], atol=1e-6)  # the nose tip, by symmetry


def test_gltf_structure(tmp_path: Path) -> None:
    """Accessors, material, sampler, image and the camera node are as specified."""
    path = tmp_path / "face.glb"
    save_glb(make_mesh(), path)
    gltf = read_glb_json(path)
    assert gltf["asset"]["version"] == "2.0"
    prim = gltf["meshes"][0]["primitives"][0]
    assert prim["mode"] == 4
    pos = gltf["accessors"][prim["attributes"]["POSITION"]]
    assert (pos["type"], pos["componentType"], pos["count"]) == ("VEC3", 5126, 9)
    np.testing.assert_allclose(pos["min"], [-0.04, -0.04, -0.5], rtol=1e-6)
    np.testing.assert_allclose(pos["max"], [0.04, 0.04, -0.47], rtol=1e-6)
    uv = gltf["accessors"][prim["attributes"]["TEXCOORD_0"]]
    assert (uv["type"], uv["componentType"], uv["count"]) == ("VEC2", 5126, 9)
    material = gltf["materials"][prim["material"]]
    assert material["doubleSided"] is False
    assert material["pbrMetallicRoughness"]["metallicFactor"] == 0
    sampler = gltf["samplers"][gltf["textures"][0]["sampler"]]
    assert sampler == {"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071}
    assert gltf["images"][0]["mimeType"] == "image/png"
    # Two nodes: the mesh, and the source camera at the origin with identity orientation.
    assert sorted(gltf["scenes"][gltf["scene"]]["nodes"]) == [0, 1]
    cam_nodes = [n for n in gltf["nodes"] if "camera" in n]
    assert len(cam_nodes) == 1
    assert not {"matrix", "translation", "rotation", "scale"} & set(cam_nodes[0])
    persp = gltf["cameras"][cam_nodes[0]["camera"]]["perspective"]
    assert persp["yfov"] == pytest.approx(2 * math.atan(240.0 / 610.0), rel=1e-12)  # h / 2 / fy
    assert persp["aspectRatio"] == pytest.approx(640 / 480, rel=1e-12)
    assert persp["znear"] == 0.01


# --------------------------------------------------------------------------- bad files


def test_truncated_file(tmp_path: Path) -> None:
    """A truncated GLB raises InputError naming the file."""
    path = tmp_path / "face.glb"
    save_glb(make_mesh(), path)
    data = path.read_bytes()
    for cut in (6, len(data) // 2, len(data) - 3):
        bad = tmp_path / f"cut_{cut}.glb"
        bad.write_bytes(data[:cut])
        with pytest.raises(InputError, match=f"cut_{cut}.glb.*truncated"):
            load_glb(bad)


def test_not_a_glb(tmp_path: Path) -> None:
    """A PNG, a JSON glTF and a missing path raise InputError naming the file."""
    png = tmp_path / "image.glb"
    ok, buf = cv2.imencode(".png", np.zeros((40, 40, 3), np.uint8))
    assert ok
    png.write_bytes(buf.tobytes())
    with pytest.raises(InputError, match="image.glb.*not a binary glTF"):
        load_glb(png)
    text = tmp_path / "scene.gltf"
    text.write_text('{"asset": {"version": "2.0"}}')
    with pytest.raises(InputError, match="scene.gltf"):
        load_glb(text)
    with pytest.raises(InputError, match="missing.glb"):
        load_glb(tmp_path / "missing.glb")


def test_wrong_glb_version(tmp_path: Path) -> None:
    """A GLB version other than 2 is refused."""
    path = tmp_path / "face.glb"
    save_glb(make_mesh(), path)
    data = bytearray(path.read_bytes())
    data[4:8] = struct.pack("<I", 1)
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="face.glb.*version 1"):
        load_glb(path)


def test_glb_without_facemesh_extras(tmp_path: Path) -> None:
    """A valid GLB without the facemesh metadata is refused."""
    trimesh = pytest.importorskip("trimesh")
    path = tmp_path / "plain.glb"
    plain = trimesh.Trimesh(vertices=GOLDEN_GLTF_M, faces=TRIANGLES, process=False)
    path.write_bytes(plain.export(file_type="glb"))
    with pytest.raises(InputError, match="plain.glb.*facemesh"):
        load_glb(path)
    # Our own file with the extras stripped.
    ours = tmp_path / "stripped.glb"
    save_glb(make_mesh(), ours)
    gltf, binary = split_glb(ours)
    del gltf["extras"]
    write_glb(ours, gltf, binary)
    with pytest.raises(InputError, match="stripped.glb.*facemesh"):
        load_glb(ours)


def test_wrong_accessor_type(tmp_path: Path) -> None:
    """Accessors of the wrong type or component type are refused."""
    path = tmp_path / "face.glb"
    save_glb(make_mesh(), path)
    gltf, binary = split_glb(path)
    attrs = gltf["meshes"][0]["primitives"][0]["attributes"]
    attrs["TEXCOORD_0"] = attrs["NORMAL"]  # a VEC3 where a VEC2 belongs
    bad = tmp_path / "bad_uv.glb"
    write_glb(bad, gltf, binary)
    with pytest.raises(InputError, match="bad_uv.glb.*TEXCOORD_0.*VEC3"):
        load_glb(bad)

    gltf, binary = split_glb(path)
    gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]["componentType"] = 5121
    bad = tmp_path / "bad_pos.glb"
    write_glb(bad, gltf, binary)
    with pytest.raises(InputError, match="bad_pos.glb.*POSITION"):
        load_glb(bad)


# --------------------------------------------------------------------------- atomic writes


def test_failed_save_leaves_nothing(tmp_path: Path) -> None:
    """A failing save leaves no file, no temporary file, and an existing file untouched."""
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(InputError, match="texture_format"):
        save_glb(make_mesh(), out / "face.glb", texture_format="bmp")
    assert os.listdir(out) == []
    with pytest.raises(InputError, match="JSON"):
        save_glb(make_mesh(extras={"bad": float("nan")}), out / "face.glb")
    assert os.listdir(out) == []

    # An existing file is left untouched by a failed save.
    target = out / "face.glb"
    save_glb(make_mesh(), target)
    before = target.read_bytes()
    with pytest.raises(InputError):
        save_glb(make_mesh(extras={"bad": object()}), target)
    assert target.read_bytes() == before
    assert os.listdir(out) == ["face.glb"]


# --------------------------------------------------------------------------- Khronos validator


def _validator_dir() -> Path:
    env = os.environ.get("GLTF_VALIDATOR_DIR")
    return Path(env) if env else REPO_ROOT / ".tools" / "node" / "node_modules" / "gltf-validator"


def _reconstructed_mesh(method: str) -> FaceMesh:
    """The built-in model's 468 points 500 mm away, triangulated by a surface method (Poisson appends vertices)."""
    from facemesh import builtin_face_model
    from facemesh.reconstruct import reconstruct_surface

    pts = builtin_face_model().vertices_mm + np.array([0.0, 0.0, 500.0])
    rec = reconstruct_surface(pts, method, forward=(0.0, 0.0, -1.0))
    mesh = make_mesh(vertices_mm=np.concatenate([pts, rec.appended_vertices_mm]), triangles=rec.triangles)
    return dataclasses.replace(mesh, reconstruction=rec.as_metadata())


@pytest.mark.parametrize("case", ["png", "jpeg", "points", "atlas", "bpa+fill", "poisson"])
def test_khronos_validator(tmp_path: Path, case: str) -> None:
    """The Khronos glTF validator reports no errors and no warnings."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed (needed to run the Khronos glTF validator)")
    vdir = _validator_dir()
    if not (vdir / "package.json").is_file():
        pytest.skip(
            f"gltf-validator not found at {vdir}; install it with "
            "`npm install --prefix .tools/node gltf-validator` or set GLTF_VALIDATOR_DIR"
        )
    path = tmp_path / f"{case}.glb"
    if case == "points":
        save_glb(make_mesh(triangles=np.zeros((0, 3), dtype=np.int64)), path)
    elif case == "atlas":
        from facemesh.atlas import atlas_mesh

        save_glb(atlas_mesh(make_mesh()), path)
    elif case in ("bpa+fill", "poisson"):
        mesh = _reconstructed_mesh(case)
        save_glb(mesh, path)
        assert load_glb(path).reconstruction == mesh.reconstruction
    else:
        save_glb(make_mesh(), path, texture_format=case)
    proc = subprocess.run(
        [node, str(VALIDATE_SCRIPT), str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "GLTF_VALIDATOR_DIR": str(vdir)},
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    issues = report["issues"]
    print(
        f"gltf-validator {report.get('validatorVersion')}: {case}: numErrors={issues['numErrors']} "
        f"numWarnings={issues['numWarnings']} numInfos={issues['numInfos']} numHints={issues['numHints']}"
    )
    problems = [m for m in issues["messages"] if m["severity"] <= 1]
    assert issues["numErrors"] == 0, problems
    assert issues["numWarnings"] == 0, problems


def test_atlas_keeps_landmark_order_and_renders_alike(tmp_path: Path, faces_dir: Path) -> None:
    """--atlas: vertex i < N is still landmark i, seam copies are appended, the view barely changes."""
    from facemesh.atlas import atlas_mesh
    from facemesh.build import build_mesh
    from facemesh.camera import camera_for_image
    from facemesh.io import load_image_rgb
    from facemesh.landmarks import MediaPipeFaceMesh
    from facemesh.render import RaycastScene

    img = load_image_rgb(face_photo(faces_dir, "sergey.png", any_face=True))
    h, w = img.shape[:2]
    cam = camera_for_image(None, w, h, warn=False)
    with MediaPipeFaceMesh() as det:
        mesh = build_mesh(img, cam, det)
    a = atlas_mesh(mesh)
    n = mesh.num_vertices
    dup = np.asarray(a.extras["atlas"]["duplicate_of"])
    assert a.num_vertices == n + len(dup) and len(dup) > 0
    np.testing.assert_array_equal(a.vertices_mm[:n], mesh.vertices_mm)
    np.testing.assert_array_equal(a.vertices_mm[n:], mesh.vertices_mm[dup])
    back = np.concatenate([np.arange(n), dup])
    np.testing.assert_array_equal(back[a.triangles], mesh.triangles)  # same triangles, same winding
    assert a.texture.shape[:2] == tuple(a.extras["atlas"]["size"][::-1])
    ra = RaycastScene.from_mesh(mesh).render(cam.matrix, (w, h)).image.astype(float)
    rb = RaycastScene.from_mesh(a).render(cam.matrix, (w, h)).image.astype(float)
    face = (ra.sum(-1) > 0) & (rb.sum(-1) > 0)
    assert np.abs(ra - rb)[face].mean() < 3.0  # two bilinear resamplings
    path = tmp_path / "atlas.glb"
    save_glb(a, path)
    b = load_glb(path)
    assert b.num_vertices == a.num_vertices and b.extras["atlas"]["duplicate_of"] == dup.tolist()
    np.testing.assert_allclose(b.uv, a.uv, atol=1e-6)
