"""Writing and reading a :class:`~facemesh.types.FaceMesh` as a binary glTF 2.0 file (``.glb``).

The container is written by hand (numpy, :mod:`json`, :mod:`struct`), so no
library can merge, drop or reorder vertices: vertex i of the file is vertex i
of the mesh, which is landmark i.

Layout of a file written by :func:`save_glb`
--------------------------------------------
* One mesh with one primitive. With triangles, mode 4 (TRIANGLES) and an
  ``indices`` accessor (uint16 when N <= 65535, else uint32); a mesh with no
  triangles is written as mode 0 (POINTS) without indices.
  Attributes, all tightly packed float32:

  - ``POSITION``: (N, 3) metres, glTF frame, i.e. the OpenCV camera frame
    point (x, y, z) mm written as ``(x, -y, -z) / 1000``
    (:func:`facemesh.conventions.opencv_to_gltf_points`), with ``min``/``max``.
  - ``NORMAL``: (N, 3) unit vectors, glTF frame: area-weighted vertex normals
    of the triangles (``(0, 0, 1)``, toward the camera, for a vertex no
    triangle uses). Derived data, ignored by :func:`load_glb`.
  - ``TEXCOORD_0``: (N, 2) the mesh's uv as stored (already glTF's convention).

  FaceMesh triangles are counter-clockwise seen from the camera. The axis
  change (:data:`facemesh.conventions.OPENCV_TO_GLTF`) is a proper rotation (determinant +1), so it maps
  each triangle's right-hand normal along with the points and keeps the
  winding: in glTF the triangles are still counter-clockwise seen from the
  camera at the origin looking down -Z, i.e. front faces, as glTF requires.
* One material (``pbrMetallicRoughness``: base colour texture, metallic 0,
  roughness 1; single-sided), one texture, one sampler (linear filters,
  CLAMP_TO_EDGE), one image (PNG or JPEG) stored in a bufferView.
* One scene with two nodes: node 0 holds the mesh, node 1 a perspective
  camera at the origin with identity orientation (the source camera:
  ``yfov = 2 atan(h / 2 / fy)``, ``aspectRatio = w / h``, ``znear = 0.01``).
* The root object's ``extras.facemesh`` holds everything else (camera, pose,
  landmarks, provenance), see :func:`gltf_bytes`. Floats there are written as
  the shortest repr that reads back to the same float64, so all of it comes
  back exactly.
"""

from __future__ import annotations

import json
import math
import os
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._native import native_stderr_silenced
from .conventions import gltf_to_opencv_points, opencv_to_gltf_directions, opencv_to_gltf_points
from .geometry import vertex_normals
from .io import _check_pixel_count, _header_size, atomic_write, check_input_file
from .types import CameraIntrinsics, FaceKeypoints, FaceLandmarks, FaceMesh, HeadPose, InputError

__all__ = ["FORMAT_VERSION", "save_glb", "load_glb", "gltf_bytes", "parse_glb"]

#: Version of the ``extras.facemesh`` layout this module writes (and the newest it reads).
FORMAT_VERSION = 1

_GLB_MAGIC = b"glTF"
_GLB_VERSION = 2
_CHUNK_JSON = 0x4E4F534A  # "JSON" little-endian
_CHUNK_BIN = 0x004E4942  # "BIN\0" little-endian

# glTF enums
_MODE_POINTS = 0
_MODE_TRIANGLES = 4
_UNSIGNED_SHORT = 5123
_UNSIGNED_INT = 5125
_FLOAT = 5126
_ARRAY_BUFFER = 34962
_ELEMENT_ARRAY_BUFFER = 34963
_LINEAR = 9729
_CLAMP_TO_EDGE = 33071

_COMPONENT_DTYPES: dict[int, np.dtype[Any]] = {
    5120: np.dtype("<i1"),
    5121: np.dtype("<u1"),
    5122: np.dtype("<i2"),
    _UNSIGNED_SHORT: np.dtype("<u2"),
    _UNSIGNED_INT: np.dtype("<u4"),
    _FLOAT: np.dtype("<f4"),
}
_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}

_TEXTURE_FORMATS = {"png": (".png", "image/png"), "jpeg": (".jpg", "image/jpeg"), "jpg": (".jpg", "image/jpeg")}

#: Near plane of the exported camera, metres.
_ZNEAR_M = 0.01

#: (3,) float64, glTF frame: toward the source camera (OpenCV's -z), the normal of a vertex no triangle uses.
_TOWARD_CAMERA_GLTF = opencv_to_gltf_directions([0.0, 0.0, -1.0])


# --------------------------------------------------------------------------- writing


def _package_version() -> str:
    """``facemesh.__version__``, else the installed distribution's version, else ``"0+unknown"``."""
    try:
        import facemesh

        version = getattr(facemesh, "__version__", None)
        if isinstance(version, str) and version:
            return version
    except Exception:  # pragma: no cover - a broken package __init__ must not stop an export
        pass
    try:
        from importlib.metadata import PackageNotFoundError
        from importlib.metadata import version as dist_version

        return dist_version("facemesh")
    except (ImportError, PackageNotFoundError, ValueError):
        return "0+unknown"


def _json_default(obj: Any) -> Any:
    """Make numpy scalars and arrays JSON-serialisable (as Python numbers and lists)."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"object of type {type(obj).__name__} is not JSON serialisable")


def _encode_texture(texture: NDArray[np.uint8], texture_format: str) -> tuple[bytes, str]:
    """Encode an (H, W, 3) uint8 RGB texture; returns (file bytes, MIME type)."""
    import cv2

    key = texture_format.lower().lstrip(".")
    if key not in _TEXTURE_FORMATS:
        raise InputError(f"texture_format: glTF textures can be 'png' or 'jpeg', got {texture_format!r}")
    ext, mime = _TEXTURE_FORMATS[key]
    bgr = np.ascontiguousarray(texture[..., ::-1])
    params = [int(cv2.IMWRITE_JPEG_QUALITY), 95] if mime == "image/jpeg" else []
    ok, buf = cv2.imencode(ext, bgr, params)
    if not ok:
        raise InputError(f"cannot encode the texture as {texture_format!r}")
    return bytes(buf.tobytes()), mime


def _vertex_normals(positions: NDArray[np.float64], triangles: NDArray[np.int64]) -> NDArray[np.float32]:
    """Area-weighted unit vertex normals.

    Args:
        positions: (N, 3) float64, glTF frame (any unit).
        triangles: (M, 3) int64, counter-clockwise front faces.

    Returns:
        (N, 3) float32 unit vectors, same frame; toward the source camera in
        glTF axes (``(0, 0, 1)``) where no triangle (or only degenerate ones)
        touches a vertex.
    """
    return vertex_normals(positions, triangles, fallback=_TOWARD_CAMERA_GLTF).astype(np.float32)


def _metadata(mesh: FaceMesh) -> dict[str, Any]:
    """Build the ``extras.facemesh`` object: all of the mesh but positions, uv, triangles and texture pixels."""
    cam = mesh.camera
    lm = mesh.landmarks
    return {
        "format_version": FORMAT_VERSION,
        "package_version": _package_version(),
        "vertex_count": mesh.num_vertices,
        "triangle_count": mesh.num_triangles,
        "texture_size": [int(mesh.texture.shape[1]), int(mesh.texture.shape[0])],
        "texture_origin_px": [int(mesh.texture_origin_px[0]), int(mesh.texture_origin_px[1])],
        "camera": {
            "image_size": [int(cam.image_size[0]), int(cam.image_size[1])],
            "matrix": cam.matrix.tolist(),
            "distortion": cam.distortion.tolist(),
            "source": cam.source,
        },
        "pose": {
            "rotation": mesh.pose.rotation.tolist(),
            "translation_mm": mesh.pose.translation_mm.tolist(),
            "reprojection_error_px": float(mesh.pose.reprojection_error_px),
        },
        "landmarks": {
            "model_name": lm.model_name,
            "points_px": lm.points_px.tolist(),
            "points_3d": None if lm.points_3d is None else lm.points_3d.tolist(),
        },
        "face_model_name": mesh.face_model_name,
        "face_model_vertices_mm": None if mesh.model_vertices_mm is None else mesh.model_vertices_mm.tolist(),
        "face_model_keypoints": None if mesh.model_keypoints is None else mesh.model_keypoints.as_dict(),
        "vertex_placement": mesh.vertex_placement,
        "reconstruction": dict(mesh.reconstruction),
        "extras": dict(mesh.extras),
    }


class _BinWriter:
    """Accumulates bufferViews in one BIN chunk, each starting on a 4-byte boundary."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.length = 0
        self.buffer_views: list[dict[str, Any]] = []

    def add(self, data: bytes, target: int | None = None) -> int:
        pad = (-self.length) % 4
        if pad:
            self.parts.append(b"\x00" * pad)
            self.length += pad
        view: dict[str, Any] = {"buffer": 0, "byteOffset": self.length, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.parts.append(data)
        self.length += len(data)
        self.buffer_views.append(view)
        return len(self.buffer_views) - 1

    def getvalue(self) -> bytes:
        pad = (-self.length) % 4
        return b"".join(self.parts) + b"\x00" * pad


def gltf_bytes(mesh: FaceMesh, *, texture_format: str = "png") -> bytes:
    """Encode a face mesh as the bytes of a binary glTF 2.0 file (GLB).

    The file holds the mesh (vertex order kept), its texture, a camera node for
    the source camera and, in the root object's ``extras["facemesh"]``:
    ``format_version`` (1), ``package_version``, ``vertex_count``,
    ``triangle_count``, ``texture_size`` ([W, H]), ``texture_origin_px``,
    ``camera`` (``image_size``, 3x3 ``matrix``, ``distortion``, ``source``),
    ``pose`` (3x3 ``rotation``, ``translation_mm``, ``reprojection_error_px``),
    ``landmarks`` (``model_name``, ``points_px`` (L x 2), ``points_3d`` (L x 3 or
    null)), ``face_model_name``, ``face_model_vertices_mm`` (N x 3, head frame, or null),
    ``face_model_keypoints`` (``{"right_eye": [o, i], "left_eye": [i, o], "mouth": [r, l]}`` or null),
    ``vertex_placement``, ``reconstruction`` and
    ``extras``. See the module docstring for the layout.

    Args:
        mesh: the mesh to encode. ``mesh.reconstruction`` and ``mesh.extras``
            must be JSON-serialisable (numpy scalars and arrays are converted;
            tuples come back as lists).
        texture_format: ``"png"`` (lossless, the default) or ``"jpeg"``.

    Returns:
        The GLB file's bytes.

    Raises:
        InputError: the mesh has no vertices, its metadata is not
            JSON-serialisable (or holds NaN / infinity), or the texture cannot
            be encoded in ``texture_format``.
    """
    if mesh.num_vertices == 0:
        raise InputError("cannot write a glTF mesh with no vertices")
    image_bytes, mime = _encode_texture(mesh.texture, texture_format)

    positions64 = opencv_to_gltf_points(mesh.vertices_mm)  # (N, 3) float64, metres, glTF frame
    positions = positions64.astype("<f4")
    normals = _vertex_normals(positions.astype(np.float64), np.asarray(mesh.triangles)).astype("<f4")
    uv = np.asarray(mesh.uv).astype("<f4")
    n = mesh.num_vertices

    bin_writer = _BinWriter()
    accessors: list[dict[str, Any]] = []

    def add_accessor(data: NDArray[Any], gltf_type: str, component: int, target: int, **extra: Any) -> int:
        view = bin_writer.add(np.ascontiguousarray(data).tobytes(), target)
        acc: dict[str, Any] = {
            "bufferView": view,
            "componentType": component,
            "count": int(data.shape[0]),
            "type": gltf_type,
        }
        acc.update(extra)
        accessors.append(acc)
        return len(accessors) - 1

    attributes = {
        "POSITION": add_accessor(
            positions,
            "VEC3",
            _FLOAT,
            _ARRAY_BUFFER,
            min=[float(v) for v in positions.min(axis=0)],
            max=[float(v) for v in positions.max(axis=0)],
        ),
        "NORMAL": add_accessor(normals, "VEC3", _FLOAT, _ARRAY_BUFFER),
        "TEXCOORD_0": add_accessor(uv, "VEC2", _FLOAT, _ARRAY_BUFFER),
    }
    primitive: dict[str, Any] = {"attributes": attributes, "material": 0}
    if mesh.num_triangles:
        # 65535 is the primitive-restart value of uint16 and must not appear as an index.
        index_dtype, index_component = ("<u2", _UNSIGNED_SHORT) if n <= 65535 else ("<u4", _UNSIGNED_INT)
        indices = np.asarray(mesh.triangles).reshape(-1).astype(index_dtype)
        primitive["indices"] = add_accessor(indices, "SCALAR", index_component, _ELEMENT_ARRAY_BUFFER)
        primitive["mode"] = _MODE_TRIANGLES
    else:
        primitive["mode"] = _MODE_POINTS
    image_view = bin_writer.add(image_bytes)
    bin_chunk = bin_writer.getvalue()

    width, height = mesh.camera.image_size
    fy = mesh.camera.focal_px[1]
    gltf: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": f"facemesh {_package_version()}"},
        "scene": 0,
        "scenes": [{"name": "face", "nodes": [0, 1]}],
        "nodes": [
            {"name": "face", "mesh": 0},
            {"name": "source_camera", "camera": 0},
        ],
        "cameras": [
            {
                "name": "source_camera",
                "type": "perspective",
                "perspective": {
                    "yfov": 2.0 * math.atan(height / 2.0 / fy),
                    "aspectRatio": width / height,
                    "znear": _ZNEAR_M,
                },
            }
        ],
        "meshes": [{"name": "face", "primitives": [primitive]}],
        "materials": [
            {
                "name": "face",
                "pbrMetallicRoughness": {
                    "baseColorTexture": {"index": 0, "texCoord": 0},
                    "metallicFactor": 0.0,
                    "roughnessFactor": 1.0,
                },
                "doubleSided": False,
            }
        ],
        "textures": [{"sampler": 0, "source": 0}],
        "samplers": [{"magFilter": _LINEAR, "minFilter": _LINEAR, "wrapS": _CLAMP_TO_EDGE, "wrapT": _CLAMP_TO_EDGE}],
        "images": [{"name": "texture", "bufferView": image_view, "mimeType": mime}],
        "accessors": accessors,
        "bufferViews": bin_writer.buffer_views,
        "buffers": [{"byteLength": len(bin_chunk)}],
        "extras": {"facemesh": _metadata(mesh)},
    }
    try:
        json_text = json.dumps(gltf, allow_nan=False, separators=(",", ":"), default=_json_default)
    except (TypeError, ValueError) as exc:
        raise InputError(f"mesh metadata cannot be written as JSON: {exc}") from exc
    json_chunk = json_text.encode("utf-8")
    json_chunk += b" " * ((-len(json_chunk)) % 4)  # JSON chunk is padded with spaces

    total = 12 + 8 + len(json_chunk) + 8 + len(bin_chunk)
    return b"".join(
        [
            struct.pack("<4sII", _GLB_MAGIC, _GLB_VERSION, total),
            struct.pack("<II", len(json_chunk), _CHUNK_JSON),
            json_chunk,
            struct.pack("<II", len(bin_chunk), _CHUNK_BIN),
            bin_chunk,
        ]
    )


def save_glb(mesh: FaceMesh, path: str | os.PathLike[str], *, texture_format: str = "png") -> None:
    """Write a face mesh as a binary glTF 2.0 file (``.glb``), atomically.

    The file is first written beside ``path`` and renamed onto it only when
    complete: on any error ``path`` is left as it was and no temporary file
    remains. See :func:`gltf_bytes` for the content.

    Args:
        mesh: the mesh to write.
        path: output file (parent folders are created).
        texture_format: ``"png"`` (lossless, the default) or ``"jpeg"``.

    Raises:
        InputError: see :func:`gltf_bytes`.
    """
    with atomic_write(path) as fh:
        fh.write(gltf_bytes(mesh, texture_format=texture_format))


# --------------------------------------------------------------------------- reading


def parse_glb(data: bytes, name: str = "<bytes>") -> tuple[dict[str, Any], bytes]:
    """Split GLB bytes into the parsed JSON chunk and the BIN chunk.

    Checks the header (magic ``glTF``, version 2, total length) and the chunk
    layout (a JSON chunk first, an optional BIN chunk second, unknown chunks
    ignored as the specification asks).

    Args:
        data: the file's bytes.
        name: what to call the file in error messages.

    Returns:
        (glTF JSON object, BIN chunk bytes; ``b""`` when the file has none).

    Raises:
        InputError: the bytes are not a GLB 2.0 file, or are truncated or damaged.
    """
    if len(data) < 12 or data[:4] != _GLB_MAGIC:
        if data[:4] == _GLB_MAGIC:
            raise InputError(f"{name}: truncated GLB file ({len(data)} bytes, header needs 12)")
        raise InputError(f"{name}: not a binary glTF (GLB) file (no 'glTF' magic)")
    _, version, total = struct.unpack_from("<4sII", data, 0)
    if version != _GLB_VERSION:
        raise InputError(f"{name}: GLB version {version} is not supported (expected 2)")
    if total > len(data):
        raise InputError(f"{name}: truncated GLB file (header says {total} bytes, file has {len(data)})")
    if total < len(data):
        raise InputError(f"{name}: damaged GLB file (header says {total} bytes, file has {len(data)})")

    chunks: list[tuple[int, bytes]] = []
    offset = 12
    while offset < total:
        if offset + 8 > total:
            raise InputError(f"{name}: truncated GLB chunk header at byte {offset}")
        length, ctype = struct.unpack_from("<II", data, offset)
        start, end = offset + 8, offset + 8 + length
        if end > total:
            raise InputError(f"{name}: truncated GLB chunk at byte {offset} ({length} bytes announced)")
        chunks.append((ctype, data[start:end]))
        offset = end + (-length) % 4
    if not chunks or chunks[0][0] != _CHUNK_JSON:
        raise InputError(f"{name}: damaged GLB file (the first chunk is not JSON)")
    try:
        gltf = json.loads(chunks[0][1].decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise InputError(f"{name}: damaged GLB file (JSON chunk does not parse: {exc})") from exc
    if not isinstance(gltf, dict):
        raise InputError(f"{name}: damaged GLB file (JSON chunk is not an object)")
    binary = b""
    if len(chunks) > 1 and chunks[1][0] == _CHUNK_BIN:
        binary = chunks[1][1]
    return gltf, binary


def _get(obj: Any, key: Any, name: str, what: str) -> Any:
    """``obj[key]`` or an InputError naming the file and the missing item."""
    try:
        return obj[key]
    except (KeyError, IndexError, TypeError):
        raise InputError(f"{name}: {what} is missing or malformed") from None


def _read_accessor(
    gltf: Mapping[str, Any],
    binary: bytes,
    index: Any,
    name: str,
    what: str,
    gltf_type: str,
    components: tuple[int, ...],
) -> NDArray[Any]:
    """Read one accessor as a (count,) or (count, k) array, checking its type, component type and bounds."""
    if not isinstance(index, int) or isinstance(index, bool):
        raise InputError(f"{name}: {what} accessor index is missing or malformed")
    acc = _get(_get(gltf, "accessors", name, "'accessors'"), index, name, f"{what} accessor {index}")
    if acc.get("type") != gltf_type or acc.get("componentType") not in components:
        raise InputError(
            f"{name}: {what} accessor has type {acc.get('type')}/{acc.get('componentType')}, "
            f"expected {gltf_type} of component type {' or '.join(map(str, components))}"
        )
    if "sparse" in acc or acc.get("normalized", False):
        raise InputError(f"{name}: {what} accessor is sparse or normalized, which facemesh files never are")
    count = acc.get("count")
    if not isinstance(count, int) or count < 1:
        raise InputError(f"{name}: {what} accessor has an invalid count {count!r}")
    view = _get(_get(gltf, "bufferViews", name, "'bufferViews'"), acc.get("bufferView"), name, f"{what} bufferView")
    if view.get("buffer") != 0:
        raise InputError(f"{name}: {what} data is not in the GLB's binary chunk")
    dtype = _COMPONENT_DTYPES[acc["componentType"]]
    k = _TYPE_SIZES[gltf_type]
    elem = dtype.itemsize * k
    stride = view.get("byteStride", elem)
    if stride != elem:
        raise InputError(f"{name}: {what} data is interleaved (byteStride {stride}), which facemesh files never are")
    start = int(view.get("byteOffset", 0)) + int(acc.get("byteOffset", 0))
    end = start + count * elem
    view_end = int(view.get("byteOffset", 0)) + int(_get(view, "byteLength", name, f"{what} bufferView length"))
    if start < 0 or end > view_end or view_end > len(binary):
        raise InputError(f"{name}: {what} data runs past the end of its buffer (file truncated or damaged)")
    arr = np.frombuffer(binary, dtype=dtype, count=count * k, offset=start)
    return arr.reshape(count, k) if k > 1 else arr


def _read_image(gltf: Mapping[str, Any], binary: bytes, primitive: Mapping[str, Any], name: str) -> NDArray[np.uint8]:
    """Decode the base colour texture of a primitive's material as (H, W, 3) uint8 RGB."""
    import cv2

    material = _get(gltf.get("materials"), primitive.get("material"), name, "the mesh's material")
    tex_index = _get(
        _get(
            _get(material, "pbrMetallicRoughness", name, "the material's pbrMetallicRoughness"),
            "baseColorTexture",
            name,
            "the material's baseColorTexture",
        ),
        "index",
        name,
        "the baseColorTexture index",
    )
    texture = _get(gltf.get("textures"), tex_index, name, f"texture {tex_index}")
    image = _get(gltf.get("images"), texture.get("source"), name, "the texture's image")
    view = _get(gltf.get("bufferViews"), image.get("bufferView"), name, "the image's bufferView")
    start = int(view.get("byteOffset", 0))
    end = start + int(_get(view, "byteLength", name, "the image's bufferView length"))
    if view.get("buffer") != 0 or end > len(binary):
        raise InputError(f"{name}: the texture image runs past the end of the binary chunk (truncated?)")
    encoded = np.frombuffer(binary, dtype=np.uint8, count=end - start, offset=start)
    size = _header_size(encoded, Path(name))
    if size is not None:  # refused from its header, before decoding, as load_image_rgb refuses an image
        _check_pixel_count(Path(f"{name}: the texture"), *size)
    try:
        with native_stderr_silenced():  # libpng and libjpeg print to descriptor 2 from C; our error names the file
            bgr = cv2.imdecode(encoded, cv2.IMREAD_COLOR)
    except cv2.error as exc:  # sizes beyond OpenCV's limits, or a decoder assertion
        raise InputError(f"{name}: the texture image cannot be decoded ({exc.__class__.__name__})") from exc
    if bgr is None:
        raise InputError(f"{name}: the texture image ({image.get('mimeType', 'unknown type')}) cannot be decoded")
    return np.ascontiguousarray(bgr[..., ::-1])


def load_glb(path: str | os.PathLike[str]) -> FaceMesh:
    """Read a face mesh written by :func:`save_glb`.

    Vertices come back in the OpenCV camera frame in millimetres (exact up to
    the file's float32), uv exact up to float32, triangles and a PNG texture
    exactly, and all metadata (camera, pose, landmarks, names, extras) exactly.

    Args:
        path: a ``.glb`` file written by :func:`save_glb`.

    Returns:
        The mesh.

    Raises:
        InputError: the file is missing or cannot be read (permissions, I/O
            error), is not a GLB 2.0 file, is truncated or damaged, lacks the
            ``extras.facemesh`` metadata (it was not written by facemesh), has
            accessors of unexpected types, or its pose puts the head at or
            behind the camera (translation z <= 0 mm). The message names the file.
    """
    p = Path(path)
    name = str(p)
    try:
        check_input_file(p)  # "no such file", or "not a file" for a folder
        data = p.read_bytes()
    except OSError as exc:
        raise InputError(f"{name}: cannot read the file ({exc.strerror or exc.__class__.__name__})") from exc
    gltf, binary = parse_glb(data, name)

    meta = (gltf.get("extras") or {}).get("facemesh") if isinstance(gltf.get("extras"), dict) else None
    if meta is None and isinstance(gltf.get("asset"), dict) and isinstance(gltf["asset"].get("extras"), dict):
        meta = gltf["asset"]["extras"].get("facemesh")
    if not isinstance(meta, dict):
        raise InputError(f"{name}: no 'facemesh' metadata in the glTF extras (the file was not written by facemesh)")
    fmt = meta.get("format_version")
    if not isinstance(fmt, int) or fmt < 1 or fmt > FORMAT_VERSION:
        raise InputError(
            f"{name}: facemesh format version {fmt!r} is not supported (this reader knows 1..{FORMAT_VERSION})"
        )

    try:
        mesh = _build_mesh(gltf, binary, meta, name)
    except InputError as exc:
        if str(exc).startswith(name):
            raise
        raise InputError(f"{name}: {exc}") from exc
    except (AttributeError, KeyError, IndexError, TypeError, ValueError) as exc:
        raise InputError(f"{name}: the glTF content or facemesh metadata is malformed ({exc!r})") from exc
    z = float(mesh.pose.translation_mm[2])
    if not z > 0:  # every renderer looks down +z: a head at or behind the camera centre shows nothing
        raise InputError(
            f"{name}: the head is behind the camera (z = {z:g} mm; expected the pose's translation z > 0 mm)"
        )
    return mesh


def _build_mesh(gltf: Mapping[str, Any], binary: bytes, meta: Mapping[str, Any], name: str) -> FaceMesh:
    """Rebuild the FaceMesh from a parsed facemesh GLB (errors are wrapped by :func:`load_glb`)."""
    mesh_index = 0
    for node in gltf.get("nodes") or []:
        if isinstance(node, dict) and "mesh" in node:
            mesh_index = node["mesh"]
            break
    gmesh = _get(gltf.get("meshes"), mesh_index, name, f"mesh {mesh_index}")
    primitives = _get(gmesh, "primitives", name, "the mesh's primitives")
    if not isinstance(primitives, list) or len(primitives) != 1:
        found = len(primitives) if isinstance(primitives, list) else 0
        raise InputError(f"{name}: expected one mesh primitive, found {found}")
    prim = primitives[0]
    attributes = _get(prim, "attributes", name, "the primitive's attributes")
    positions = _read_accessor(gltf, binary, attributes.get("POSITION"), name, "POSITION", "VEC3", (_FLOAT,))
    uv = _read_accessor(gltf, binary, attributes.get("TEXCOORD_0"), name, "TEXCOORD_0", "VEC2", (_FLOAT,))
    n = len(positions)
    if len(uv) != n or meta.get("vertex_count") != n:
        raise InputError(
            f"{name}: vertex counts disagree (POSITION {n}, TEXCOORD_0 {len(uv)}, "
            f"metadata {meta.get('vertex_count')!r})"
        )
    mode = prim.get("mode", _MODE_TRIANGLES)
    if "indices" in prim:
        if mode != _MODE_TRIANGLES:
            raise InputError(f"{name}: primitive mode {mode} is not TRIANGLES (4)")
        idx = _read_accessor(
            gltf, binary, prim["indices"], name, "indices", "SCALAR", (_UNSIGNED_SHORT, _UNSIGNED_INT, 5121)
        )
        if len(idx) % 3:
            raise InputError(f"{name}: {len(idx)} triangle indices is not a multiple of 3")
        triangles = idx.astype(np.int64).reshape(-1, 3)
    elif mode == _MODE_POINTS:
        triangles = np.zeros((0, 3), dtype=np.int64)
    else:
        raise InputError(f"{name}: the primitive has no indices (facemesh files always index triangles)")

    texture = _read_image(gltf, binary, prim, name)
    tex_w, tex_h = (int(v) for v in meta["texture_size"])
    if texture.shape[:2] != (tex_h, tex_w):
        raise InputError(f"{name}: texture is {texture.shape[1]}x{texture.shape[0]}, metadata says {tex_w}x{tex_h}")

    cam_meta, pose_meta, lm_meta = meta["camera"], meta["pose"], meta["landmarks"]
    camera = CameraIntrinsics(
        matrix=np.array(cam_meta["matrix"], dtype=np.float64),
        distortion=np.array(cam_meta["distortion"], dtype=np.float64),
        image_size=(int(cam_meta["image_size"][0]), int(cam_meta["image_size"][1])),
        source=str(cam_meta["source"]),
    )
    pose = HeadPose(
        rotation=np.array(pose_meta["rotation"], dtype=np.float64),
        translation_mm=np.array(pose_meta["translation_mm"], dtype=np.float64),
        reprojection_error_px=float(pose_meta["reprojection_error_px"]),
    )
    points_3d = lm_meta.get("points_3d")
    landmarks = FaceLandmarks(
        points_px=np.array(lm_meta["points_px"], dtype=np.float64),
        model_name=str(lm_meta["model_name"]),
        points_3d=None if points_3d is None else np.array(points_3d, dtype=np.float64),
    )
    origin = meta["texture_origin_px"]
    model_vertices = meta.get("face_model_vertices_mm")
    model_keypoints = meta.get("face_model_keypoints")
    return FaceMesh(
        vertices_mm=gltf_to_opencv_points(positions.astype(np.float64)),
        triangles=triangles,
        uv=uv.astype(np.float64),
        texture=texture,
        texture_origin_px=(int(origin[0]), int(origin[1])),
        landmarks=landmarks,
        camera=camera,
        pose=pose,
        face_model_name=str(meta["face_model_name"]),
        vertex_placement=str(meta["vertex_placement"]),
        reconstruction=dict(meta.get("reconstruction") or {}),
        extras=dict(meta.get("extras") or {}),
        model_vertices_mm=None if model_vertices is None else np.array(model_vertices, dtype=np.float64),
        model_keypoints=None if model_keypoints is None else FaceKeypoints.from_dict(model_keypoints),
    )
