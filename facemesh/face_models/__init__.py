"""3D face models: the built-in MediaPipe-topology model and loaders for other models.

The built-in model ``"mediapipe"`` (468 points, millimetres, head frame) was
derived by :mod:`facemesh.face_models.derive_mediapipe` from MediaPipe's own
3D landmark output on two public-domain photos that ship inside pip wheels;
it is *not* a copy of MediaPipe's canonical face model.

Files a user can give as ``--face-model PATH``:

``.obj``
    ``v x y z`` lines (and optional ``f`` lines, 1-based, ``a/b/c`` allowed).
    Files written by ``facemesh model export`` start with the comment
    ``# facemesh face model frame=head units=mm`` and are read as such; any
    other OBJ is read with MediaPipe's canonical convention (centimetres,
    y up, z toward the viewer), so MediaPipe's ``canonical_face_model.obj``
    loads as is.
``.pbtxt``
    MediaPipe's geometry pipeline metadata: the ``canonical_mesh`` block
    (5 floats per vertex x, y, z, u, v; centimetres; MediaPipe frame) and its
    ``index_buffer``.
``.txt`` / ``.csv``
    A plain matrix of numbers in millimetres, head frame: N x 3, or 3 x N as
    MPIIFaceGaze's ``faceModelGeneric.txt``.
``.npy``
    (N, 3) float array, millimetres, head frame.

Key points (which points are the eye and mouth corners, :class:`FaceKeypoints`)
belong to the model: the built-in model and MediaPipe's own formats carry
MediaPipe's, an OBJ written by ``facemesh model export`` records its own, and a
plain matrix gets them from the user (``keypoints=`` here, ``--keypoints`` on
the command lines: a layout name of :data:`KEYPOINTS` or indices). A model with
key points is re-centred so that the head frame's origin is the midpoint of its
four eye corners.
"""

from __future__ import annotations

import re
from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..conventions import MEDIAPIPE_CANONICAL_TO_HEAD
from ..types import FaceKeypoints, FaceModel, InputError

__all__ = [
    "BUILTIN_MODELS",
    "EYE_CORNERS",
    "FaceKeypoints",
    "KEYPOINTS",
    "parse_keypoints",
    "builtin_face_model",
    "load_face_model",
    "resolve_face_model",
    "export_obj",
    "mirror_permutation",
    "OBJ_HEADER",
]

#: Names accepted by :func:`builtin_face_model`.
BUILTIN_MODELS = ("mediapipe",)

#: MediaPipe landmark indices of the eye corners: subject's right eye (outer,
#: inner) = (33, 133), subject's left eye (inner, outer) = (362, 263). The
#: subject's right eye appears on the image's left.
EYE_CORNERS = {"right": (33, 133), "left": (362, 263)}


#: Key points of the landmark layouts the project knows, by name.
KEYPOINTS = {
    "mediapipe": FaceKeypoints(right_eye=(33, 133), left_eye=(362, 263), mouth=(61, 291)),
    # MPIIFaceGaze / Zhang et al.: four eye corners (image left to right), then two mouth corners.
    "mpii6": FaceKeypoints(right_eye=(0, 1), left_eye=(2, 3), mouth=(4, 5)),
    # dlib / iBUG 68-point layout (0-based).
    "dlib68": FaceKeypoints(right_eye=(36, 39), left_eye=(42, 45), mouth=(48, 54)),
    # ETH-XGaze's 50-point face model (dlib's 68 without the jaw but the chin, nor the inner mouth corners).
    "eth50": FaceKeypoints(right_eye=(20, 23), left_eye=(26, 29), mouth=(32, 38)),
}


def parse_keypoints(spec: str) -> FaceKeypoints:
    """Key points from a layout name (:data:`KEYPOINTS`) or indices ``"RO,RI,LI,LO[,MR,ML]"``.

    The indices are, in order: the subject's right eye's outer and inner corners,
    the left eye's inner and outer corners (image left to right for a frontal
    face), then optionally the right and left mouth corners (MPIIFaceGaze's order).

    Raises:
        InputError: an unknown name, or not 4 or 6 non-negative integers.
    """
    text = str(spec).strip()
    if text in KEYPOINTS:
        return KEYPOINTS[text]
    try:
        idx = [int(v) for v in text.split(",")]
    except ValueError:
        idx = []
    if len(idx) not in (4, 6) or min(idx) < 0:
        raise InputError(
            f"key points: expected a layout name ({', '.join(KEYPOINTS)}) or 4 or 6 indices "
            f"'RO,RI,LI,LO[,MR,ML]', got {spec!r}"
        )
    return FaceKeypoints((idx[0], idx[1]), (idx[2], idx[3]), (idx[4], idx[5]) if len(idx) == 6 else None)


#: First line of OBJ files written by :func:`export_obj`.
OBJ_HEADER = "# facemesh face model frame=head units=mm"

_DATA_FILE = "mediapipe468.npz"


@cache
def _builtin_arrays() -> dict[str, NDArray[np.generic]]:
    with resources.files(__package__).joinpath(_DATA_FILE).open("rb") as fh:
        with np.load(fh) as npz:
            return {k: npz[k] for k in npz.files}


def builtin_face_model(name: str = "mediapipe") -> FaceModel:
    """The face model shipped with the package.

    Args:
        name: one of :data:`BUILTIN_MODELS`.

    Returns:
        ``"mediapipe"``: 468 points, millimetres, head frame, 898 triangles
        (eyes and mouth closed; only the outer contour open).
    """
    if name not in BUILTIN_MODELS:
        raise InputError(f"unknown built-in face model {name!r}; expected one of {BUILTIN_MODELS}")
    arr = _builtin_arrays()
    return FaceModel(
        name=name,
        vertices_mm=np.asarray(arr["vertices_mm"], dtype=np.float64),
        triangles=np.asarray(arr["triangles"], dtype=np.int64),
        keypoints=KEYPOINTS["mediapipe"],
    )


def mirror_permutation() -> NDArray[np.int64]:
    """(468,) int64: landmark i's left-right mirror partner in the MediaPipe topology (derived with the model)."""
    return np.asarray(_builtin_arrays()["mirror"], dtype=np.int64)


def resolve_face_model(spec: str | Path, keypoints: FaceKeypoints | None = None) -> FaceModel:
    """A built-in name (``"mediapipe"``) or a path -> :class:`FaceModel`; ``keypoints`` replace the loader's."""
    if isinstance(spec, str) and spec in BUILTIN_MODELS:
        model = builtin_face_model(spec)
        return model if keypoints is None else model.with_keypoints(keypoints)
    return load_face_model(spec, keypoints=keypoints)


def load_face_model(path: str | Path, keypoints: FaceKeypoints | None = None) -> FaceModel:
    """Read a face model file (see the module docstring for the formats, units and key points).

    Key points: ``keypoints`` when given; else those the file records (an OBJ
    written by :func:`export_obj`); else MediaPipe's for MediaPipe's own formats
    (a ``.pbtxt``, or an OBJ read with MediaPipe's convention, of 468 or 478
    points); else none (give them for a plain matrix such as MPIIFaceGaze's
    ``faceModelGeneric.txt``: ``keypoints=KEYPOINTS["mpii6"]``).

    Raises:
        InputError: missing file, unknown suffix, or malformed content (the message names the file).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: face model file not found")
    suffix = p.suffix.lower()
    recorded: FaceKeypoints | None = None
    mediapipe_format = False
    try:
        if suffix == ".obj":
            verts, tris, recorded, mediapipe_format = _read_obj(p)
        elif suffix == ".pbtxt":
            (verts, tris), mediapipe_format = _read_pbtxt(p), True
        elif suffix in (".txt", ".csv"):
            verts, tris = _read_matrix(p), None
        elif suffix == ".npy":
            verts, tris = np.asarray(np.load(p, allow_pickle=False), dtype=np.float64), None
        else:
            raise InputError(f"{p}: unknown face model format {suffix!r} (expected .obj, .pbtxt, .txt, .csv or .npy)")
    except InputError:
        raise
    except (ValueError, OSError) as exc:
        raise InputError(f"{p}: cannot read face model: {exc}") from exc
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise InputError(f"{p}: expected N x 3 face model points, got shape {verts.shape}")
    mediapipe_layout = mediapipe_format and len(verts) in (468, 478)
    kp = keypoints or recorded or (KEYPOINTS["mediapipe"] if mediapipe_layout else None)
    if kp is not None and max(kp.face_indices) < len(verts):  # the head frame's origin between the eyes
        verts = verts - verts[[*kp.right_eye, *kp.left_eye]].mean(axis=0)
    try:
        return FaceModel(name=p.name, vertices_mm=verts, triangles=tris, keypoints=kp)
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from exc


_KEYPOINTS_COMMENT = "# keypoints "


def _read_obj(p: Path) -> tuple[NDArray[np.float64], NDArray[np.int64] | None, FaceKeypoints | None, bool]:
    """Vertices, triangles, the recorded key points, and whether it was read with MediaPipe's convention."""
    import json

    text = p.read_text(encoding="utf-8", errors="strict")
    ours = text.startswith(OBJ_HEADER)
    recorded = None
    for line in text.splitlines()[:5]:
        if ours and line.startswith(_KEYPOINTS_COMMENT):
            try:
                recorded = FaceKeypoints.from_dict(json.loads(line[len(_KEYPOINTS_COMMENT) :]))
            except json.JSONDecodeError as exc:
                raise InputError(f"{p}: the key points comment is not valid JSON ({exc.msg})") from exc
            except RecursionError as exc:
                raise InputError(f"{p}: the key points comment is JSON nested too deeply to read") from exc
    verts: list[list[float]] = []
    faces: list[list[int]] = []
    for lineno, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            if len(parts) < 4:
                raise InputError(f"{p}:{lineno}: a 'v' line needs 3 coordinates")
            verts.append([float(x) for x in parts[1:4]])
        elif parts[0] == "f":
            idx = [int(x.split("/")[0]) for x in parts[1:]]
            if len(idx) < 3:
                raise InputError(f"{p}:{lineno}: an 'f' line needs at least 3 vertices")
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    if not verts:
        raise InputError(f"{p}: no 'v' lines")
    v = np.asarray(verts, dtype=np.float64)
    if not ours:
        v = (v @ MEDIAPIPE_CANONICAL_TO_HEAD.T) * 10.0
    t = np.asarray(faces, dtype=np.int64) if faces else None
    return v, t, recorded, not ours


def _read_pbtxt(p: Path) -> tuple[NDArray[np.float64], NDArray[np.int64] | None]:
    text = p.read_text(encoding="utf-8")
    start = text.find("canonical_mesh")
    if start < 0:
        raise InputError(f"{p}: no 'canonical_mesh' block (expected MediaPipe geometry pipeline metadata)")
    block = text[start:]
    vb = [float(x) for x in re.findall(r"vertex_buffer:\s*([-+0-9.eE]+)", block)]
    ib = [int(x) for x in re.findall(r"index_buffer:\s*(\d+)", block)]
    if not vb or len(vb) % 5:
        raise InputError(f"{p}: expected 5 floats (x, y, z, u, v) per vertex, got {len(vb)} floats")
    v = np.asarray(vb, dtype=np.float64).reshape(-1, 5)[:, :3]
    v = (v @ MEDIAPIPE_CANONICAL_TO_HEAD.T) * 10.0
    if len(ib) % 3:
        raise InputError(f"{p}: index_buffer length {len(ib)} is not a multiple of 3")
    t = np.asarray(ib, dtype=np.int64).reshape(-1, 3) if ib else None
    return v, t


def _read_matrix(p: Path) -> NDArray[np.float64]:
    delimiter = "," if p.suffix.lower() == ".csv" else None
    m = np.loadtxt(p, dtype=np.float64, delimiter=delimiter, ndmin=2)
    if m.shape[1] == 3:
        return m
    if m.shape[0] == 3:
        return m.T.copy()
    raise InputError(f"{p}: expected an N x 3 or 3 x N matrix, got {m.shape[0]} x {m.shape[1]}")


def export_obj(model: FaceModel) -> str:
    """Wavefront OBJ text of a face model: millimetres, head frame, 1-based faces.

    The first line is :data:`OBJ_HEADER`, so :func:`load_face_model` reads it back unchanged.
    """
    import json

    lines = [
        OBJ_HEADER,
        f"# name: {model.name}; {model.num_points} vertices; "
        f"{0 if model.triangles is None else len(model.triangles)} triangles",
        "# head frame: x toward the subject's left ear, y toward the chin, z into the head",
    ]
    if model.keypoints is not None:
        lines.append(_KEYPOINTS_COMMENT + json.dumps(model.keypoints.as_dict()))
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in model.vertices_mm]
    if model.triangles is not None:
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in model.triangles]
    return "\n".join(lines) + "\n"
