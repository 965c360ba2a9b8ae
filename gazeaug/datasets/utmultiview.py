"""UT Multiview (Sugano et al., CVPR 2014), raw part: 8 calibrated cameras and a reconstructed face mesh per capture.

Layout read (per subject ``sNN``)::

    sNN/raw/gazedata.csv                      header line, then one row per capture:
                                              index, target x, target y (mm, monitor plane)
    sNN/raw/monitor.txt                       header line, translation (3), rotation (3 x 3):
                                              monitor plane -> world, ``p_w = R p_m + t``
    sNN/raw/imgNNN/headpose.txt               header, head translation (3, mm), head rotation
                                              (3 x 3; head -> world, ``p_w = R p_h + t``), header,
                                              six 3D landmarks (6 x 3, world, mm): rows 0-1 the
                                              subject's right eye's two corners, 2-3 the left
                                              eye's two, 4-5 the mouth's two
    sNN/raw/imgNNN/cparams/0000000K.txt       header, 3 x 4 projection matrix P = K [R | t]
                                              (world -> image of camera K, pixel centres at integers)
    sNN/raw/imgNNN/images/0000000K.jpg        (another of .jpeg/.png/.bmp when there is no .jpg)
    sNN/raw/imgNNN/models/face_mesh.obj       the capture's reconstructed face (world frame, mm)

Numbers may be written bare or in NumPy's bracketed style (``[ 1.  2.  3.]``).
Capture folder ``imgNNN`` is named after the row's index (zero-padded to 3).
The world frame is shared by all cameras of a capture; the images carry no lens
distortion.

Head frame: x toward the subject's left eye, y toward the chin, z into the
head (this package's head frame, :mod:`facemesh.conventions`). The dataset
documents none of this in a form we could reach; the layout, the landmark
rows, the image extension, the mesh's frame and units and the head frame are
the ones the paper author's own reader and renderer use
(cedriclmenard/fastgaze ``gazeirislandmarks/datasets/utmultiview.py`` and
``utmultiview_render.py``: its renderer looks at the face from ``-z`` of the
head frame with its image's x along the head's x, which shows the face from
the front and upright only in this frame). docs/datasets.md cites the lines.
A head rotation in another frame is refused where the pipeline uses it
(:meth:`DatasetFace.fit`), never flipped. Anything that does
not fit stops the reader with an error naming the file and line.

Each capture and camera is one :class:`~gazeaug.datasets.base.GazeSample`
whose face provider is a :class:`DatasetFace`: ``augment`` and
``normalize-dataset`` take the dataset's pose and landmarks and render the
capture's mesh (textured from the sample's own image) instead of detecting a
face and building a mesh, as the paper did for this dataset.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from facemesh.build import FaceFit
from facemesh.face_models import KEYPOINTS
from facemesh.geometry import nearest_rotation
from facemesh.pose import project_points
from facemesh.types import CameraIntrinsics, FaceLandmarks, FaceMesh, FaceModel, HeadPose

from .base import DatasetError, GazeSample, image_size, parse_numbers

__all__ = [
    "UTMultiview",
    "DatasetFace",
    "DATASET_LANDMARKS",
    "decompose_projection",
    "read_number_blocks",
    "looks_like_utmultiview",
    "load_obj_mesh",
]

_IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp")
_SUBJECT = re.compile(r"^s\d+$")


#: Capture indices are below this (the dataset has 160 per subject; folders are named imgNNN).
_MAX_CAPTURES = 100_000


def looks_like_utmultiview(path: Path) -> bool:
    """True when ``path`` (or one of its sub-folders) has ``raw/gazedata.csv``."""
    return (path / "raw" / "gazedata.csv").is_file() or any(
        (d / "raw" / "gazedata.csv").is_file() for d in path.iterdir() if d.is_dir()
    )


def read_number_blocks(path: Path) -> list[tuple[int, NDArray[np.float64]]]:
    """The runs of numeric lines of a text file, split at its text (header) lines.

    Brackets and commas are ignored, so NumPy's printed arrays read like bare numbers.

    Returns:
        ``[(first line number, (n,) float64 numbers), ...]`` in file order.

    Raises:
        DatasetError: the file is missing or unreadable.
    """
    if not path.is_file():
        raise DatasetError(f"{path}: file not found")
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read ({exc})") from exc
    blocks: list[tuple[int, list[float]]] = []
    current: list[float] | None = None
    for lineno, line in enumerate(lines, start=1):
        tokens = line.replace("[", " ").replace("]", " ").replace(",", " ").split()
        if not tokens:
            continue
        try:
            values = [float(t) for t in tokens]
        except ValueError:
            current = None  # a header line closes the block
            continue
        if current is None:
            current = []
            blocks.append((lineno, current))
        current.extend(values)
    out = []
    for lineno, values in blocks:
        arr = np.asarray(values, dtype=np.float64)
        if not np.isfinite(arr).all():
            raise DatasetError(f"{path}, line {lineno}: NaN or infinite value")
        out.append((lineno, arr))
    return out


def _blocks(path: Path, sizes: tuple[int, ...]) -> list[NDArray[np.float64]]:
    """Exactly ``len(sizes)`` numeric blocks with these sizes, or an error naming the file and line."""
    blocks = read_number_blocks(path)
    if len(blocks) != len(sizes):
        raise DatasetError(
            f"{path}: expected {len(sizes)} blocks of numbers separated by header lines "
            f"({' + '.join(map(str, sizes))} values), found {len(blocks)}"
        )
    for (lineno, values), size in zip(blocks, sizes):
        if values.size != size:
            raise DatasetError(f"{path}, line {lineno}: expected {size} numbers in this block, found {values.size}")
    return [v for _, v in blocks]


def _rotation(m: NDArray[np.float64], where: str) -> NDArray[np.float64]:
    r = m.reshape(3, 3)
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-3) or np.linalg.det(r) < 0:
        raise DatasetError(f"{where}: expected a rotation matrix (orthonormal, det +1), got {np.round(r, 4).tolist()}")
    return nearest_rotation(r)  # the printed matrix is rounded


def decompose_projection(
    p: NDArray[np.float64], where: str = "projection matrix"
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Split a 3 x 4 projection matrix ``P = s K [R | t]`` (any non-zero scale s).

    Args:
        p: (3, 4) float64, world mm -> homogeneous image pixels.
        where: the file the matrix came from, for messages.

    Returns:
        ``(K, R, t)``: (3, 3) intrinsics with positive focal lengths and ``K[2, 2] = 1``;
        (3, 3) rotation world -> camera; (3,) mm translation, so ``x_cam = R x_world + t``
        and ``P ~ K [R | t]``.

    Raises:
        DatasetError: ``P``'s left 3 x 3 block is singular.
    """
    import scipy.linalg

    p = np.asarray(p, dtype=np.float64).reshape(3, 4)
    m = p[:, :3]
    if abs(np.linalg.det(m)) < 1e-12 * max(1.0, float(np.abs(m).max()) ** 3):
        raise DatasetError(f"{where}: singular 3 x 3 block, not a camera")
    k, r = scipy.linalg.rq(m)
    d = np.diag(np.sign(np.diag(k)))
    k, r = k @ d, d @ r  # positive diagonal: k = |s| K
    t = np.linalg.solve(k, p[:, 3])
    if np.linalg.det(r) < 0:  # P had a negative overall scale s
        r, t = -r, -t
    k = k / k[2, 2]
    k[1, 0] = k[2, 0] = k[2, 1] = 0.0
    k[2, 2] = 1.0
    return k, r, t


@dataclass(frozen=True)
class _Capture:
    subject: str
    folder: Path
    target_world_mm: NDArray[np.float64]
    where: str  # gazedata.csv line, for messages


class UTMultiview:
    """Reader of UT Multiview's raw part (see the module docstring).

    Args:
        root: the folder holding ``s00`` ... ``s49`` (or any subset), or one subject folder.
        subjects: only these subjects (default: every subject folder with ``raw/gazedata.csv``).
        cameras: only these camera numbers (default: all eight, 0-7).
    """

    name = "utmultiview"

    def __init__(self, root: str | Path, subjects: list[str] | None = None, cameras: list[int] | None = None):
        self.root = Path(root)
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: not a folder")
        if (self.root / "raw" / "gazedata.csv").is_file():
            folders = [self.root]
        else:
            folders = sorted(d for d in self.root.iterdir() if d.is_dir() and (d / "raw" / "gazedata.csv").is_file())
        found = {d.name: d for d in folders}
        if subjects is not None:
            missing = sorted(set(subjects) - set(found))
            if missing:
                raise DatasetError(f"{self.root}: no raw/gazedata.csv for subjects {missing}")
            found = {k: v for k, v in found.items() if k in subjects}
        if not found:
            raise DatasetError(f"{self.root}: no sNN/raw/gazedata.csv (not a UT Multiview folder)")
        self.subjects = sorted(found)
        self.cameras = None if cameras is None else sorted(int(c) for c in cameras)
        self._captures: list[_Capture] = []
        for name in self.subjects:
            self._captures.extend(self._read_subject(name, found[name] / "raw"))
        first = self._captures[0].folder
        self._per_capture = len(self._camera_numbers(first))
        if self._per_capture == 0:
            raise DatasetError(f"{first / 'cparams'}: no camera parameter files (0000000K.txt)")

    def _read_subject(self, subject: str, raw: Path) -> list[_Capture]:
        (pose_m,) = _blocks(raw / "monitor.txt", (12,))
        t_m, r_m = pose_m[:3], _rotation(pose_m[3:], f"{raw / 'monitor.txt'}: rotation")
        gaze = raw / "gazedata.csv"
        lines = gaze.read_text(encoding="utf-8", errors="replace").splitlines()
        captures = []
        for lineno, line in enumerate(lines, start=1):
            cells = [c.strip() for c in line.split(",")]
            if not line.strip() or (lineno == 1 and not _is_number(cells[0])):
                continue  # the header
            where = f"{gaze}, line {lineno}"
            if len(cells) < 3:
                raise DatasetError(f"{where}: expected at least 3 columns (index, x, y), found {len(cells)}")
            values = parse_numbers(cells[:3], where)
            if not 0 <= values[0] < _MAX_CAPTURES or values[0] != int(values[0]):
                raise DatasetError(
                    f"{where}: capture index must be an integer from 0 to {_MAX_CAPTURES - 1}, got {cells[0]!r}"
                )
            index = int(values[0])
            folder = raw / f"img{index:03d}"
            if not folder.is_dir():
                raise DatasetError(f"{where}: capture folder {folder} not found")
            target_world = r_m @ np.array([values[1], values[2], 0.0]) + t_m
            captures.append(_Capture(subject, folder, target_world, where))
        if not captures:
            raise DatasetError(f"{gaze}: no capture rows")
        return captures

    def _camera_numbers(self, folder: Path) -> list[int]:
        found = sorted(int(p.stem) for p in (folder / "cparams").glob("*.txt") if p.stem.isdigit())
        if self.cameras is not None:
            missing = sorted(set(self.cameras) - set(found))
            if missing:
                raise DatasetError(f"{folder / 'cparams'}: no parameters for cameras {missing}")
            return [c for c in found if c in self.cameras]
        return found

    def __len__(self) -> int:
        return len(self._captures) * self._per_capture

    def __iter__(self) -> Iterator[GazeSample]:
        index = 0
        for cap in self._captures:
            cams = self._camera_numbers(cap.folder)
            if len(cams) != self._per_capture:
                raise DatasetError(
                    f"{cap.folder / 'cparams'}: {len(cams)} cameras, but the first capture has {self._per_capture}"
                )
            head_file = cap.folder / "headpose.txt"
            pose_h, marks = _blocks(head_file, (12, 18))
            t_h, r_h = pose_h[:3], _rotation(pose_h[3:], f"{head_file}: head rotation")
            marks = marks.reshape(6, 3)
            mesh = cap.folder / "models" / "face_mesh.obj"
            if not mesh.is_file():
                raise DatasetError(f"{mesh}: the capture's face mesh is missing")
            for cam in cams:
                yield self._sample(cap, cam, index, r_h, t_h, marks, mesh)
                index += 1

    def _sample(
        self,
        cap: _Capture,
        cam: int,
        index: int,
        r_head: NDArray[np.float64],
        t_head: NDArray[np.float64],
        marks: NDArray[np.float64],
        mesh: Path,
    ) -> GazeSample:
        pfile = cap.folder / "cparams" / f"{cam:08d}.txt"
        (p,) = _blocks(pfile, (12,))
        k, r, t = decompose_projection(p.reshape(3, 4), str(pfile))
        images = [cap.folder / "images" / f"{cam:08d}.jpg"]  # the paper author's reader reads this one
        if not images[0].is_file():
            images = [
                q for q in sorted((cap.folder / "images").glob(f"{cam:08d}.*")) if q.suffix.lower() in _IMAGE_SUFFIXES
            ]
        if not images:
            raise DatasetError(f"{cap.folder / 'images'}: no image {cam:08d}.jpg/.png/.bmp for {pfile.name}")
        w, h = image_size(images[0])
        camera = CameraIntrinsics(matrix=k, distortion=np.zeros(5), image_size=(w, h), source=str(pfile))
        world_to_cam = np.concatenate([r, t[:, None]], axis=1)
        return GazeSample(
            image_path=images[0],
            camera=camera,
            subject=cap.subject,
            source_index=index,
            gaze_target_mm=r @ cap.target_world_mm + t,
            head_rotation=r @ r_head,
            head_translation_mm=r @ t_head + t,
            face=DatasetFace(landmarks_3d_mm=marks @ r.T + t, mesh_path=mesh, mesh_to_camera=world_to_cam),
            extras={"capture": cap.folder.name, "camera": cam, "gazedata": cap.where},
        )


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


#: Name of the 6-point layout of the dataset's own 3D landmarks.
DATASET_LANDMARKS = "dataset6"

_OBJ_CACHE: dict[str, tuple[NDArray[np.float64], NDArray[np.int64]]] = {}


def load_obj_mesh(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Vertices and triangles of an OBJ file, in file order (nothing merged; the last file is cached).

    Returns:
        ``(vertices, triangles)``: (V, 3) float64 in the file's units and frame; (T, 3) int64.

    Raises:
        DatasetError: missing, unreadable or empty file.
    """
    key = str(path)
    if key in _OBJ_CACHE:
        return _OBJ_CACHE[key]
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"{p}: mesh file not found")
    import trimesh

    try:
        mesh = trimesh.load(p, file_type="obj", process=False, maintain_order=True, force="mesh", skip_materials=True)
    except Exception as exc:  # trimesh raises many kinds on malformed files
        raise DatasetError(f"{p}: cannot read the mesh ({exc})") from exc
    v = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    f = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(v) < 3 or len(f) < 1 or not np.isfinite(v).all():
        raise DatasetError(f"{p}: no usable triangles (vertices {len(v)}, faces {len(f)})")
    _OBJ_CACHE.clear()
    _OBJ_CACHE[key] = (v, f)
    return v, f


@dataclass(frozen=True)
class DatasetFace:
    """The face as UT Multiview describes it: a face provider (:class:`~gazeaug.datasets.base.FaceProvider`).

    Nothing is detected: the pose and the face model come from the dataset's head
    pose and six 3D landmarks, the mesh is the capture's own reconstruction
    (textured from the sample's image), as the paper did for this dataset.

    Attributes:
        landmarks_3d_mm: (6, 3) float64, mm, this camera's frame: rows 0-1 the subject's
            right eye's two corners, 2-3 the left eye's two, 4-5 the mouth's two.
        mesh_path: the capture's ``models/face_mesh.obj`` (world frame, mm).
        mesh_to_camera: (3, 4) float64 ``[R | t]``, mm: world -> this camera's frame
            (``p_cam = R p_world + t``).
    """

    landmarks_3d_mm: NDArray[np.float64]
    mesh_path: Path
    mesh_to_camera: NDArray[np.float64]

    def fit(self, sample: GazeSample, image: NDArray[np.uint8], detector: Any = None) -> FaceFit:
        """The face fitted from the dataset's head pose and 3D landmarks (``detector`` unused).

        The face model is the six landmarks in the head frame, re-centred between the
        eyes (the head frame's origin in this package), with MPIIFaceGaze's key points
        (eye corners, then mouth corners), so eye centres and normalized cameras come
        from the dataset's own landmarks.

        Raises:
            DatasetError: no head pose, or a head frame whose axes do not follow the
                convention (x toward the subject's left eye, y toward the chin).
        """
        where = f"sample {sample.source_index} ({sample.image_path})"
        if sample.head_rotation is None or sample.head_translation_mm is None:
            raise DatasetError(f"{where}: the dataset gives no head pose")
        marks = np.asarray(self.landmarks_3d_mm, dtype=np.float64)
        if marks.shape != (6, 3):
            raise DatasetError(f"{where}: 3D landmarks: expected (6, 3), got {marks.shape}")
        r, t = np.asarray(sample.head_rotation), np.asarray(sample.head_translation_mm)
        head = (marks - t) @ r  # head frame
        kp = KEYPOINTS["mpii6"]  # the six points' order: the eyes' corners, then the mouth's
        right, left = head[list(kp.right_eye)].mean(axis=0), head[list(kp.left_eye)].mean(axis=0)
        mid = 0.5 * (right + left)
        eye_line = (left - right) / max(float(np.linalg.norm(left - right)), 1e-9)
        down = head[list(kp.mouth or ())].mean(axis=0) - mid
        down /= max(float(np.linalg.norm(down)), 1e-9)
        if eye_line[0] < np.cos(np.radians(30)) or down[1] < np.cos(np.radians(45)):
            raise DatasetError(
                f"{where}: the dataset's head rotation does not follow the head-frame convention "
                f"(x toward the subject's left eye, y toward the chin): in its frame the eye line points "
                f"{np.round(eye_line, 3).tolist()} and the mouth lies toward {np.round(down, 3).tolist()}"
            )
        model = FaceModel(DATASET_LANDMARKS, head - mid, keypoints=kp)
        pose = HeadPose(r, t + r @ mid)
        landmarks = FaceLandmarks(project_points(marks, sample.camera), DATASET_LANDMARKS)
        return FaceFit(image, sample.camera, landmarks, model, pose, str(sample.image_path))

    def mesh(self, fit: FaceFit, sample: GazeSample) -> FaceMesh:
        """The capture's own mesh, moved into this camera's frame and textured from this sample's image.

        Each vertex's texture coordinate is where the camera sees it, as for meshes
        built from landmarks (parts hidden from this camera take the colour of what
        hides them).

        Raises:
            DatasetError: the mesh is missing or unreadable, or its size is not that of a face in mm.
        """
        from facemesh.conventions import pixels_to_uv
        from facemesh.mesh import crop_texture
        from facemesh.reconstruct import orient_triangles_toward

        from ..pipeline import MESH_SETTINGS

        v, tri = load_obj_mesh(self.mesh_path)
        m = np.asarray(self.mesh_to_camera)
        v = v @ m[:, :3].T + m[:, 3]
        extent = float(np.ptp(v, axis=0).max())
        if not 50.0 <= extent <= 1000.0:
            raise DatasetError(f"{self.mesh_path}: the mesh spans {extent:.3g} units; expected a face in millimetres")
        if (v[:, 2] <= 0).any():
            raise DatasetError(f"{self.mesh_path}: part of the mesh lies behind camera {sample.camera.source}")
        tri = orient_triangles_toward(v, tri, np.zeros(3))  # normals toward the camera at the origin
        px = project_points(v, sample.camera)
        texture, origin = crop_texture(fit.image, px, MESH_SETTINGS.texture_margin)
        uv = pixels_to_uv(px, origin, (texture.shape[1], texture.shape[0]))
        return FaceMesh(
            vertices_mm=v,
            triangles=tri,
            uv=uv,
            texture=texture,
            texture_origin_px=origin,
            landmarks=fit.landmarks,
            camera=fit.camera,
            pose=fit.pose,
            face_model_name=DATASET_LANDMARKS,
            vertex_placement="dataset",
            reconstruction={"method": "dataset", "mesh": str(self.mesh_path)},
            extras={"source_image": fit.source},
            model_vertices_mm=fit.model.vertices_mm,
            model_keypoints=fit.model.keypoints,
        )
