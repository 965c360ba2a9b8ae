"""Simulated subjects with known gaze: whole camera images of a face photo's mesh with 3D eyeballs.

A subject is made from one face photo: its facemesh mesh (with the background
rings of :mod:`gazeaug.render`), the eye openings cut out, and behind each
opening a 3D eyeball (sphere, 12 mm radius, its centre 10.5 mm behind the
eye contour): white, shaded sclera, an iris in the subject's own iris colour
(measured in the photo around MediaPipe's iris landmarks) with a darker
limbus, and a pupil. The eyeball's optical axis points at the target, offset
from the visual axis by a per-subject angle (about 5 deg, as in real eyes;
the label is the visual axis: the line to the target). The upper eyelid
follows vertical gaze (the lid contour moves by ``lid_follow_mm * sin(pitch)``
in the middle of the lid, less toward the corners), the lower lid a little.

Images are rendered by ray casting one scene (face, rings and both eyeballs:
one :class:`facemesh.render.RayCaster`) through the rig's camera; the face's
fragments are coloured by its texture
(:class:`facemesh.render.BilinearTextureShader`), each eyeball's by a
:class:`gazeaug.render.shaders.EyeballShader`, misses by a plain background;
then photometric variation (brightness, blur, noise, JPEG quality). ``gazeaug simulate`` writes a
dataset in the plain folder format (:mod:`gazeaug.datasets.folder`), plus
``simulation.jsonl`` with the ground truth (head pose, eyeball axes).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from facemesh.conventions import look_at_rotation, rotation_from_yaw_pitch, vector_to_pitchyaw
from facemesh.render import (
    BilinearTextureShader,
    RayCaster,
    Shader,
    TexelTable,
    camera_rays,
    import_open3d,
    shade,
)

from .errors import GazeAugError
from .sampling import Rig

__all__ = ["SimSettings", "SimSubject", "SimFrame", "simulate", "eye_contours"]


@dataclass(frozen=True)
class SimSettings:
    """How subjects are built and images varied.

    Attributes:
        eyeball_radius_mm: sphere radius (default 12).
        eyeball_depth_mm: how far the sphere's centre lies behind the eye contour's centre (default 10.5).
        iris_radius_mm: iris radius on the sphere (default 6).
        pupil_radius_mm: pupil radius (default 2).
        hole_scale: the eye opening is shrunk to this fraction about its centre, so that
            less sclera shows than MediaPipe's contour would (default 0.92).
        lid_follow_mm: upper-lid travel at 90 deg of vertical gaze, times sin(pitch) (default 7).
        lower_lid_follow_mm: lower-lid travel likewise (default 2).
        kappa_deg: standard deviation of the per-subject angle between visual and optical axis
            (default 5; 0 disables).
        brightness: range of the brightness factor (default 0.8-1.2).
        blur_sigma_px: range of the Gaussian blur (default 0-1.0 px).
        noise_sigma: range of the Gaussian noise, grey levels (default 0-4).
        jpeg_quality: range of the JPEG quality (default 60-95).
    """

    eyeball_radius_mm: float = 12.0
    eyeball_depth_mm: float = 10.5
    iris_radius_mm: float = 6.0
    pupil_radius_mm: float = 2.0
    hole_scale: float = 0.92
    lid_follow_mm: float = 7.0
    lower_lid_follow_mm: float = 2.0
    kappa_deg: float = 5.0
    brightness: tuple[float, float] = (0.8, 1.2)
    blur_sigma_px: tuple[float, float] = (0.0, 1.0)
    noise_sigma: tuple[float, float] = (0.0, 4.0)
    jpeg_quality: tuple[int, int] = (60, 95)


def eye_contours() -> dict[str, list[int]]:
    """MediaPipe Face Mesh eye contour loops (landmark indices, in order around each eye).

    Taken at run time from mediapipe's own ``FACEMESH_LEFT_EYE`` / ``FACEMESH_RIGHT_EYE``
    edge lists (the subject's left and right eye).
    """
    try:
        from mediapipe.python.solutions import face_mesh_connections as fmc
    except ImportError as exc:
        raise ImportError(f"the simulator needs mediapipe==0.10.21 ({exc})") from exc
    out = {}
    for side, edges in (("left", fmc.FACEMESH_LEFT_EYE), ("right", fmc.FACEMESH_RIGHT_EYE)):
        nxt: dict[int, list[int]] = {}
        for a, b in edges:
            nxt.setdefault(a, []).append(b)
            nxt.setdefault(b, []).append(a)
        start = min(nxt)
        loop, prev, cur = [start], None, start
        while True:
            cand = [v for v in nxt[cur] if v != prev]
            if not cand or cand[0] == start:
                break
            prev, cur = cur, cand[0]
            loop.append(cur)
        out[side] = loop
    return out


@dataclass(frozen=True)
class SimFrame:
    """One simulated image and its ground truth.

    Attributes:
        image: (H, W, 3) uint8 RGB.
        target_mm: (3,) float64, mm, camera frame: the point looked at.
        head_rotation: (3, 3) head frame -> camera frame (the subject's mesh head frame).
        head_translation_mm: (3,) camera frame.
        optical_axes: {"left", "right"}: (3,) camera-frame unit vectors of the rendered eyeballs.
        eyeball_centres_mm: {"left", "right"}: (3,) camera-frame centres of the eyeballs.
        coverage: fraction of pixels showing the face (the rest is background).
    """

    image: NDArray[np.uint8]
    target_mm: NDArray[np.float64]
    head_rotation: NDArray[np.float64]
    head_translation_mm: NDArray[np.float64]
    optical_axes: dict[str, NDArray[np.float64]]
    eyeball_centres_mm: dict[str, NDArray[np.float64]]
    coverage: float


class SimSubject:
    """A subject built from one face photo (see the module docstring).

    Args:
        image: (H, W, 3) uint8 RGB face photo.
        detector: a MediaPipe landmark model (478 points: the iris landmarks give the iris colour).
        name: subject id.
        settings: see :class:`SimSettings`.
        rng: random generator (the per-subject kappa offset).
        source: where the photo came from (its path), named in errors; default ``name``.
    """

    def __init__(
        self,
        image: NDArray[np.uint8],
        detector: Any,
        name: str,
        settings: SimSettings,
        rng: np.random.Generator,
        source: str | None = None,
    ):
        from facemesh.camera import camera_for_image

        from .pipeline import fit_face, mesh_for_fit
        from .render.base import render_mesh

        self.name = name
        self.settings = s = settings
        h, w = image.shape[:2]
        where = source or name
        fit = fit_face(image, camera_for_image(None, w, h, warn=False), detector, source=where)
        if fit.landmarks.num_points < 478:
            raise GazeAugError(f"{where}: the simulator needs MediaPipe's 478 landmarks (with the iris points)")
        mesh = mesh_for_fit(fit)
        rm = render_mesh(mesh)
        r, t = mesh.pose.rotation, mesh.pose.translation_mm
        head = (rm.vertices_mm - t) @ r  # every vertex (face + rings) in the head frame
        self.contours = eye_contours()
        tri = np.asarray(rm.triangles)
        drop = np.zeros(len(tri), dtype=bool)
        self.eye_centre: dict[str, NDArray[np.float64]] = {}
        self.lid_weight = np.zeros((len(head), 2))  # (upper, lower) travel weights per vertex
        for side, loop in self.contours.items():
            ids = np.asarray(loop)
            drop |= np.isin(tri, ids).all(axis=1)  # the triangles that close the eye opening
            c = head[ids].mean(axis=0)
            head[ids, :2] = c[:2] + (head[ids, :2] - c[:2]) * s.hole_scale
            self.eye_centre[side] = c + np.array([0.0, 0.0, s.eyeball_depth_mm])
            # lid weights: 1 in the middle of the lid, 0 at the corners; upper = above the corner line
            corners = head[[ids[np.argmin(head[ids, 0])], ids[np.argmax(head[ids, 0])]]]
            span = corners[1, 0] - corners[0, 0]
            for i in ids:
                u = np.clip((head[i, 0] - corners[0, 0]) / span, 0.0, 1.0)
                line_y = corners[0, 1] + u * (corners[1, 1] - corners[0, 1])
                self.lid_weight[i, 0 if head[i, 1] < line_y else 1] = math.sin(math.pi * u)
        self.head = head
        self.triangles = tri[~drop].astype(np.uint32)
        self.texture = np.ascontiguousarray(rm.texture)
        th, tw = self.texture.shape[:2]
        self.face_shader = BilinearTextureShader(self.texture, TexelTable(rm.uv, self.triangles, (tw, th)))
        self.iris_colour = {side: self._iris_colour(image, fit.landmarks.points_px, side) for side in ("left", "right")}
        k = np.radians(s.kappa_deg) * rng.standard_normal(2) if s.kappa_deg > 0 else np.zeros(2)
        self.kappa_rad = k  # (horizontal, vertical) offset of the optical axis from the visual axis
        o3d = import_open3d()
        sphere = o3d.geometry.TriangleMesh.create_sphere(radius=s.eyeball_radius_mm, resolution=24)
        self._sphere_v = np.asarray(sphere.vertices)
        self._sphere_t = np.asarray(sphere.triangles).astype(np.uint32)

    @staticmethod
    def _iris_colour(image: NDArray[np.uint8], points: NDArray[np.float64], side: str) -> NDArray[np.float64]:
        """Median colour of the iris ring (between 45% and 90% of the iris radius) in the photo."""
        centre_i, ring = (473, [474, 475, 476, 477]) if side == "left" else (468, [469, 470, 471, 472])
        c = points[centre_i]
        rad = float(np.linalg.norm(points[ring] - c, axis=1).mean())
        h, w = image.shape[:2]
        ys, xs = np.mgrid[0:h, 0:w]
        d = np.hypot(xs - c[0], ys - c[1])
        sel = (d > 0.45 * rad) & (d < 0.9 * rad)
        if sel.sum() < 4:
            return np.array([90.0, 70.0, 50.0])
        return np.median(image[sel].astype(np.float64), axis=0)

    def optical_axis(self, side: str, target_head: NDArray[np.float64]) -> NDArray[np.float64]:
        """Head-frame unit vector of an eyeball's optical axis when it fixates ``target_head`` (mm, head frame)."""
        visual = target_head - self.eye_centre[side]
        visual /= np.linalg.norm(visual)
        kh = self.kappa_rad[0] * (1.0 if side == "right" else -1.0)  # mirror-symmetric, nasal for both eyes
        turn = rotation_from_yaw_pitch(kh, self.kappa_rad[1])
        # turn the visual axis about the eye by the offset, in the frame of a level camera on the visual axis
        # looking back at the eye (the visual axis is its -z, the gaze (0, 0) of the pitch/yaw convention)
        frame = look_at_rotation(-visual, down=[0.0, 1.0, 0.0]).T  # columns: its axes in the head frame
        return frame @ (turn @ np.array([0.0, 0.0, -1.0]))

    def render(
        self,
        head_rotation: NDArray[np.float64],
        head_translation_mm: NDArray[np.float64],
        target_mm: NDArray[np.float64],
        camera_matrix: NDArray[np.float64],
        size_wh: tuple[int, int],
        rng: np.random.Generator,
    ) -> SimFrame:
        """One image: the head at the pose (head -> camera), looking at ``target_mm`` (camera frame)."""
        import cv2

        from .render.shaders import EyeballShader

        s = self.settings
        r, t = np.asarray(head_rotation), np.asarray(head_translation_mm)
        target_head = r.T @ (np.asarray(target_mm) - t)
        axes = {side: self.optical_axis(side, target_head) for side in ("left", "right")}
        # eyelids follow the vertical gaze (mean of both eyes' pitch in the head frame; y down)
        pitch = float(np.mean(vector_to_pitchyaw(np.stack([axes["left"], axes["right"]]))[:, 0]))
        v = self.head.copy()
        v[:, 1] -= math.sin(pitch) * (
            s.lid_follow_mm * self.lid_weight[:, 0] + s.lower_lid_follow_mm * self.lid_weight[:, 1]
        )
        # one scene: the face (mesh 0) and both eyeballs (meshes 1, 2), each with its shader
        caster = RayCaster([((v @ r.T + t), self.triangles)])
        shaders: dict[int, Shader] = {0: self.face_shader}
        for side in ("left", "right"):
            c = r @ self.eye_centre[side] + t
            eye_id = caster.add_mesh(self._sphere_v + c, self._sphere_t)
            shaders[eye_id] = EyeballShader(
                centre_mm=c,
                optical_axis=r @ axes[side],
                radius_mm=s.eyeball_radius_mm,
                iris_radius_mm=s.iris_radius_mm,
                pupil_radius_mm=s.pupil_radius_mm,
                iris_rgb=self.iris_colour[side],
            )
        w, h = size_wh
        rays = camera_rays(np.linalg.inv(camera_matrix), np.zeros(3), (w, h))
        fragments = caster.trace(rays)
        # background: a soft vertical gradient of a random colour
        base = rng.uniform(60, 200, 3)
        grad = np.broadcast_to(np.linspace(0.85, 1.1, h)[:, None, None] * base, (h, w, 3))
        out = shade(fragments, rays, shaders, grad)
        face = fragments.of_mesh(0)
        img: NDArray[np.float64] = out.astype(np.float64)
        # photometric variation
        img = img * rng.uniform(*s.brightness)
        sigma = rng.uniform(*s.blur_sigma_px)
        if sigma > 0.05:
            img = np.asarray(cv2.GaussianBlur(img, (0, 0), sigma), dtype=np.float64)
        img = img + rng.normal(0.0, rng.uniform(*s.noise_sigma), img.shape)
        img8: NDArray[np.uint8] = np.clip(np.round(img), 0, 255).astype(np.uint8)
        q = int(rng.integers(s.jpeg_quality[0], s.jpeg_quality[1] + 1))
        ok, enc = cv2.imencode(".jpg", cv2.cvtColor(img8, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, q])
        img8 = np.asarray(cv2.cvtColor(cv2.imdecode(enc, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB), dtype=np.uint8)
        return SimFrame(
            image=img8,
            target_mm=np.asarray(target_mm, dtype=np.float64),
            head_rotation=r,
            head_translation_mm=t,
            optical_axes={k: r @ a for k, a in axes.items()},
            eyeball_centres_mm={k: r @ c + t for k, c in self.eye_centre.items()},
            coverage=float(face.mean()),
        )


def _rig_pose(
    rig: Rig, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A head pose and a target in the rig's camera frame: (R head -> camera, t mm, target mm)."""
    r_cam = rig.camera_rotation()
    cam = np.asarray(rig.camera_position_mm)
    yaw = math.radians(rig.head_yaw_mean_deg + rig.head_yaw_std_deg * rng.standard_normal())
    pitch = math.radians(rig.head_pitch_mean_deg + rig.head_pitch_std_deg * rng.standard_normal())
    head_rig = rotation_from_yaw_pitch(yaw, pitch)
    pos = rng.normal(0.0, rig.head_position_std_mm, 3)
    lo, hi = (np.asarray(c) for c in rig.target_box_mm)
    target = rng.uniform(lo, hi)
    return r_cam @ head_rig, r_cam @ (pos - cam), r_cam @ (target - cam)


def simulate(
    faces: Sequence[str | Path | None],
    rig: Rig,
    out_dir: str | Path,
    *,
    per_face: int = 10,
    seed: int = 0,
    settings: SimSettings | None = None,
    progress: bool = True,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Write a simulated dataset in the folder format (images, ``labels.csv``, ``simulation.jsonl``).

    The dataset is written into ``OUT.part/`` and swapped in when complete: an
    existing dataset is replaced only with ``overwrite``, and a failed or
    interrupted run leaves ``out_dir`` as it was.

    Args:
        faces: face photos (None: the built-in astronaut).
        rig: the camera rig (pose, intrinsics, head motion, targets).
        out_dir: the dataset folder to create.
        per_face: images per face.
        seed: everything random derives from it (subject i, image j: ``[seed, i, j]``).
        settings: see :class:`SimSettings`.
        progress: show a progress bar.
        overwrite: replace an existing, non-empty dataset folder that ``simulate`` wrote.

    Returns:
        A summary (counts, rig, settings).

    Raises:
        OutputError: ``out_dir`` is not empty (without ``overwrite``), is a file, or another run writes it.
    """
    from facemesh.outputs import staged_folder

    s = settings or SimSettings()
    if per_face < 1:
        raise GazeAugError(f"per_face: expected an integer >= 1, got {per_face}")
    with staged_folder(out_dir, overwrite=overwrite, marker="simulation.json") as part:
        return _simulate_into(
            part, Path(out_dir), faces, rig, per_face=per_face, seed=seed, settings=s, progress=progress
        )


def _simulate_into(
    out: Path,
    final: Path,
    faces: Sequence[str | Path | None],
    rig: Rig,
    *,
    per_face: int,
    seed: int,
    settings: SimSettings,
    progress: bool,
) -> dict[str, Any]:
    from facemesh.io import atomic_write, save_image_rgb

    from .datasets.folder import write_labels_csv
    from .pipeline import default_landmark_model, load_input

    s = settings
    detector = default_landmark_model()
    w, h = rig.image_size_wh
    k = np.array([[rig.focal_px, 0.0, (w - 1) / 2.0], [0.0, rig.focal_px, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    rows, truth = [], []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(faces) * per_face, unit="image", desc="simulate", dynamic_ncols=True)
    for i, face in enumerate(faces):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            image, _, source = load_input(face, None)
        subject_id = f"sim{i:02d}"
        subj = SimSubject(image, detector, subject_id, s, np.random.default_rng([seed, i, 10**6]), source=source)
        for j in range(per_face):
            rng = np.random.default_rng([seed, i, j])
            r, t, target = _rig_pose(rig, rng)
            frame = subj.render(r, t, target, k, (w, h), rng)
            name = f"{subject_id}/{j:05d}.jpg"
            save_image_rgb(out / name, frame.image)
            rows.append(
                {
                    "image": name,
                    "subject": subject_id,
                    "fx": rig.focal_px,
                    "fy": rig.focal_px,
                    "cx": k[0, 2],
                    "cy": k[1, 2],
                    "width": w,
                    "height": h,
                    "target_x": round(float(target[0]), 4),
                    "target_y": round(float(target[1]), 4),
                    "target_z": round(float(target[2]), 4),
                }
            )
            truth.append(
                {
                    "image": name,
                    "source_face": source,
                    "head_rotation": r.tolist(),
                    "head_translation_mm": t.tolist(),
                    "target_mm": target.tolist(),
                    "optical_axes": {a: v.tolist() for a, v in frame.optical_axes.items()},
                    "eyeball_centres_mm": {a: v.tolist() for a, v in frame.eyeball_centres_mm.items()},
                    "kappa_deg": np.degrees(subj.kappa_rad).tolist(),
                    "face_coverage": frame.coverage,
                }
            )
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    write_labels_csv(out / "labels.csv", rows)
    with atomic_write(out / "simulation.jsonl") as fh:
        fh.write("".join(json.dumps(t) + "\n" for t in truth).encode("utf-8"))
    summary = {"output": str(final), "images": len(rows), "faces": len(faces), "rig": rig.as_dict(), "seed": seed}
    with atomic_write(out / "simulation.json") as fh:
        fh.write(
            json.dumps(
                {**summary, "settings": {k2: getattr(s, k2) for k2 in s.__dataclass_fields__}}, indent=1
            ).encode()
        )
    return summary
