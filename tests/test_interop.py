"""Open3D and trimesh get a facemesh ``.glb`` with vertex i = landmark i (``facemesh.load(...).to_open3d()``).

The expected values come from the file itself, read here with a few lines of
``struct``/``json``/numpy (not with facemesh's reader), and from Open3D's and
trimesh's own glTF readers (for what those libraries make of the texture
coordinates and the texture): the conversions must agree with them in
everything but the vertex order.
"""

from __future__ import annotations

import json
import re
import shutil
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest

import facemesh
import facemesh.mesh
from facemesh.types import InputError

REPO = Path(__file__).resolve().parents[1]


def read_glb_by_hand(path: Path) -> dict[str, np.ndarray]:
    """POSITION, NORMAL, TEXCOORD_0, the triangle indices and the decoded texture (RGB) of a one-primitive GLB."""
    data = path.read_bytes()
    magic, version, total = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, total) == (b"glTF", 2, len(data))
    json_len, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A
    gltf = json.loads(data[20 : 20 + json_len])
    bin_off = 20 + json_len
    bin_len, bin_type = struct.unpack_from("<II", data, bin_off)
    assert bin_type == 0x004E4942
    binary = data[bin_off + 8 : bin_off + 8 + bin_len]

    def accessor(index: int) -> np.ndarray:
        acc = gltf["accessors"][index]
        view = gltf["bufferViews"][acc["bufferView"]]
        dtype = {5126: "<f4", 5123: "<u2", 5125: "<u4"}[acc["componentType"]]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[acc["type"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        arr = np.frombuffer(binary, dtype=dtype, count=acc["count"] * width, offset=start)
        return arr.reshape(acc["count"], width) if width > 1 else arr

    prim = gltf["meshes"][0]["primitives"][0]
    image_view = gltf["bufferViews"][gltf["images"][0]["bufferView"]]
    start = image_view.get("byteOffset", 0)
    encoded = np.frombuffer(binary[start : start + image_view["byteLength"]], dtype=np.uint8)
    return {
        "positions": accessor(prim["attributes"]["POSITION"]),
        "normals": accessor(prim["attributes"]["NORMAL"]),
        "uv": accessor(prim["attributes"]["TEXCOORD_0"]),
        "triangles": accessor(prim["indices"]).astype(np.int64).reshape(-1, 3),
        "texture": cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1],
    }


@pytest.fixture(scope="module")
def sample_glb(tmp_path_factory, detector) -> Path:
    """The built-in sample's mesh (as ``facemesh build`` makes it), saved as a .glb."""
    image = facemesh.sample_image()
    camera = facemesh.default_camera(image.shape[1], image.shape[0])
    mesh = facemesh.build_mesh(image, camera, detector)
    path = tmp_path_factory.mktemp("interop") / "face.glb"
    facemesh.save(mesh, path)
    return path


@pytest.fixture(scope="module")
def raw(sample_glb):
    return read_glb_by_hand(sample_glb)


def _in_place_fraction(vertices: np.ndarray, positions: np.ndarray) -> float:
    if len(vertices) != len(positions):
        return 0.0
    return float(np.mean(np.all(vertices == positions, axis=1)))


def _match_by_position(vertices: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """For each row of ``vertices``, the index of the identical row of ``positions`` (all rows must match)."""
    index = {tuple(p): i for i, p in enumerate(positions.tolist())}
    assert len(index) == len(positions), "the file's positions are not unique"
    return np.array([index[tuple(v)] for v in vertices.tolist()])


def test_load_returns_a_face_mesh_with_the_conversions(sample_glb, raw):
    mesh = facemesh.load(sample_glb)
    assert type(mesh) is facemesh.FaceMesh  # the plain dataclass: the conversions are its methods
    assert mesh.num_vertices == len(raw["positions"]) == 468
    # vertices_mm: OpenCV camera frame, mm = the file's glTF metres (x, -y, -z) * 1000
    np.testing.assert_allclose(mesh.vertices_mm, raw["positions"] * [1000.0, -1000.0, -1000.0], rtol=0, atol=1e-9)


def test_open3d_reader_reorders_the_vertices(sample_glb, raw):
    # Why the helper exists: Open3D's own readers give the right vertices in
    # another order. (If this ever fails because Open3D keeps the order, the
    # helper is no longer needed for Open3D, but still harmless.)
    o3d = pytest.importorskip("open3d")
    positions = raw["positions"].astype(np.float64)
    plain = o3d.io.read_triangle_mesh(str(sample_glb))
    vertices = np.asarray(plain.vertices)
    assert len(vertices) == len(positions)
    where = _match_by_position(vertices, positions)  # the same 468 points ...
    assert sorted(where.tolist()) == list(range(len(positions)))
    assert _in_place_fraction(vertices, positions) < 0.05  # ... shuffled (measured: 2 of 468 in place)
    # ... and the same triangles once renumbered: only the order is lost.
    renumbered = where[np.asarray(plain.triangles)]
    assert {tuple(t) for t in renumbered.tolist()} == {tuple(t) for t in raw["triangles"].tolist()}

    model = o3d.io.read_triangle_model(str(sample_glb))
    model_vertices = np.asarray(model.meshes[0].mesh.vertices)
    assert _in_place_fraction(model_vertices, positions) < 0.05


def test_to_open3d_keeps_the_vertex_order(sample_glb, raw):
    o3d = pytest.importorskip("open3d")
    mesh = facemesh.load(sample_glb).to_open3d()
    assert isinstance(mesh, o3d.geometry.TriangleMesh)
    np.testing.assert_array_equal(np.asarray(mesh.vertices), raw["positions"].astype(np.float64))
    np.testing.assert_array_equal(np.asarray(mesh.triangles), raw["triangles"])
    np.testing.assert_allclose(np.asarray(mesh.vertex_normals), raw["normals"], rtol=0, atol=1e-6)

    # Texture coordinates and texture as Open3D's own glTF reader has them,
    # corner by corner (its triangles renumbered to the file's vertex order).
    plain = o3d.io.read_triangle_mesh(str(sample_glb))
    where = _match_by_position(np.asarray(plain.vertices), raw["positions"].astype(np.float64))
    row_of = {tuple(t): k for k, t in enumerate(raw["triangles"].tolist())}
    rows = [row_of[tuple(t)] for t in where[np.asarray(plain.triangles)].tolist()]
    ours_uv = np.asarray(mesh.triangle_uvs).reshape(-1, 3, 2)[rows]
    np.testing.assert_allclose(ours_uv, np.asarray(plain.triangle_uvs).reshape(-1, 3, 2), rtol=0, atol=1e-7)
    np.testing.assert_array_equal(np.asarray(mesh.textures[0]), np.asarray(plain.textures[0]))
    assert np.asarray(mesh.triangle_material_ids).tolist() == [0] * len(raw["triangles"])
    # Open3D's convention, from the file: (u, 1 - v) into the image flipped upside down.
    uv_corners = raw["uv"].astype(np.float64)[raw["triangles"].reshape(-1)]
    np.testing.assert_allclose(np.asarray(mesh.triangle_uvs)[:, 0], uv_corners[:, 0], rtol=0, atol=1e-7)
    np.testing.assert_allclose(np.asarray(mesh.triangle_uvs)[:, 1], 1.0 - uv_corners[:, 1], rtol=0, atol=1e-7)
    np.testing.assert_array_equal(np.asarray(mesh.textures[0])[::-1], raw["texture"])


def test_to_trimesh_keeps_the_vertex_order(sample_glb, raw):
    trimesh = pytest.importorskip("trimesh")
    mesh = facemesh.load(sample_glb).to_trimesh()
    assert isinstance(mesh, trimesh.Trimesh)
    np.testing.assert_array_equal(mesh.vertices, raw["positions"].astype(np.float64))
    np.testing.assert_array_equal(mesh.faces, raw["triangles"])
    np.testing.assert_allclose(mesh.vertex_normals, raw["normals"], rtol=0, atol=1e-6)
    assert isinstance(mesh.visual, trimesh.visual.TextureVisuals)
    # trimesh's convention, from the file: (u, 1 - v), the image top row first ...
    np.testing.assert_allclose(mesh.visual.uv[:, 0], raw["uv"][:, 0], rtol=0, atol=1e-7)
    np.testing.assert_allclose(mesh.visual.uv[:, 1], 1.0 - raw["uv"][:, 1].astype(np.float64), rtol=0, atol=1e-7)
    np.testing.assert_array_equal(np.asarray(mesh.visual.material.baseColorTexture), raw["texture"])
    # ... which is what trimesh's own glTF loader makes of the file.
    loaded = trimesh.load(sample_glb, process=False, force="mesh")
    np.testing.assert_array_equal(loaded.vertices, mesh.vertices)
    np.testing.assert_allclose(loaded.visual.uv, mesh.visual.uv, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(
        np.asarray(loaded.visual.material.baseColorTexture), np.asarray(mesh.visual.material.baseColorTexture)
    )


def test_camera_frame_option_gives_millimetres_in_the_opencv_frame(sample_glb, raw):
    pytest.importorskip("open3d")
    pytest.importorskip("trimesh")
    loaded = facemesh.load(sample_glb)
    by_hand_mm = raw["positions"].astype(np.float64) * [1000.0, -1000.0, -1000.0]  # glTF m -> OpenCV mm
    o3d_mesh = loaded.to_open3d(frame="camera")
    tm_mesh = loaded.to_trimesh(frame="camera")
    np.testing.assert_allclose(np.asarray(o3d_mesh.vertices), by_hand_mm, rtol=0, atol=1e-9)
    np.testing.assert_allclose(tm_mesh.vertices, by_hand_mm, rtol=0, atol=1e-9)
    normals_by_hand = raw["normals"] * [1.0, -1.0, -1.0]
    np.testing.assert_allclose(np.asarray(o3d_mesh.vertex_normals), normals_by_hand, rtol=0, atol=1e-6)
    np.testing.assert_allclose(tm_mesh.vertex_normals, normals_by_hand, rtol=0, atol=1e-6)
    with pytest.raises(InputError, match="frame"):
        loaded.to_open3d(frame="head")


def test_a_built_mesh_converts_like_its_file(sample_glb, raw, detector):
    # A mesh that never went through a file converts to the values its file holds,
    # with the same methods (every FaceMesh has them).
    o3d = pytest.importorskip("open3d")
    trimesh = pytest.importorskip("trimesh")
    image = facemesh.sample_image()
    built = facemesh.build_mesh(image, facemesh.default_camera(image.shape[1], image.shape[0]), detector)
    assert type(built) is facemesh.FaceMesh
    loaded = facemesh.load(sample_glb)
    positions = raw["positions"].astype(np.float64)

    o3d_built, o3d_loaded = built.to_open3d(), loaded.to_open3d()
    assert isinstance(o3d_built, o3d.geometry.TriangleMesh)
    np.testing.assert_array_equal(np.asarray(o3d_built.vertices), positions)
    np.testing.assert_array_equal(np.asarray(o3d_built.vertices), np.asarray(o3d_loaded.vertices))
    np.testing.assert_array_equal(np.asarray(o3d_built.triangles), np.asarray(o3d_loaded.triangles))
    np.testing.assert_allclose(
        np.asarray(o3d_built.triangle_uvs), np.asarray(o3d_loaded.triangle_uvs), rtol=0, atol=1e-7
    )

    tm_built, tm_loaded = built.to_trimesh(), loaded.to_trimesh()
    assert isinstance(tm_built, trimesh.Trimesh)
    np.testing.assert_array_equal(tm_built.vertices, positions)
    np.testing.assert_array_equal(tm_built.faces, tm_loaded.faces)
    np.testing.assert_allclose(tm_built.visual.uv, tm_loaded.visual.uv, rtol=0, atol=1e-7)
    # The methods are the module functions.
    np.testing.assert_array_equal(
        np.asarray(facemesh.mesh.to_open3d(built, frame="camera").vertices),
        np.asarray(built.to_open3d(frame="camera").vertices),
    )
    np.testing.assert_array_equal(facemesh.mesh.to_trimesh(built).vertices, tm_built.vertices)


def test_interop_doc_snippet_runs_as_written(sample_glb, tmp_path, monkeypatch, capsys):
    pytest.importorskip("open3d")
    pytest.importorskip("trimesh")
    text = (REPO / "docs" / "interop.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "docs/interop.md has no python snippet"
    shutil.copy(sample_glb, tmp_path / "face.glb")  # what `facemesh build -o face.glb` writes
    monkeypatch.chdir(tmp_path)
    for block in blocks:
        exec(compile(block, "docs/interop.md", "exec"), {"__name__": "__doc_snippet__"})
    assert "nose tip" in capsys.readouterr().out
