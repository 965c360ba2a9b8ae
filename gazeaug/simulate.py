"""Simulated subjects with known gaze: whole camera images of a face photo's mesh with 3D eyeballs.

A subject is made from one face photo: its facemesh mesh (with the background
rings of :mod:`gazeaug.render`), the eye openings cut out, and behind each
opening a 3D eyeball (sphere, 12 mm radius, its centre 10.5 mm behind the
eye contour): white, shaded sclera, an iris in the subject's iris colour
(the photo's own, measured around MediaPipe's iris landmarks, or drawn: see
:class:`SimSettings`' ``photo_iris_share``) with a darker limbus, and a pupil.
The eyeball's optical axis points at the target, offset
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
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from facemesh.conventions import look_at_rotation, rotation_from_yaw_pitch, uv_to_pixels, vector_to_pitchyaw
from facemesh.render import (
    BilinearTextureShader,
    RayCaster,
    Shader,
    TexelTable,
    camera_rays,
    import_open3d,
    shade,
)
from facemesh.types import FaceMesh

from .engine import Engine
from .errors import GazeAugError
from .sampling import Rig

#: The simulator's revision, recorded in ``simulation.json``: raised whenever a change alters the
#: images a seed gives (a drawn quantity, a shader, the order of the draws), so a set made before it
#: can be told apart (``benchmarks/generalization.py --reuse-simulated`` refuses it). 2: the sclera
#: read against the skin beyond the lid margin, the photo's iris read on pixel centres inside the
#: eye contour (sets without the field are older).
SIMULATOR_REVISION = 2

__all__ = [
    "SIMULATOR_REVISION",
    "SimSettings",
    "SubjectDraw",
    "Glasses",
    "IRIS_PALETTE",
    "draw_subject",
    "PhotoFace",
    "SimSubject",
    "SimFrame",
    "simulate",
    "eye_contours",
    "eyeball_depth_mm",
    "rig_pose",
    "eyes_only",
    "warp_texture",
    "other_photo_index",
    "face_person",
]


#: Iris colours (RGB) the identity draw picks from: dark brown, brown, amber, hazel, green, blue,
#: grey-blue, grey (each then varied by +-20 %).
IRIS_PALETTE: tuple[tuple[float, float, float], ...] = (
    (52.0, 34.0, 24.0),
    (92.0, 58.0, 34.0),
    (128.0, 88.0, 48.0),
    (108.0, 98.0, 58.0),
    (84.0, 108.0, 72.0),
    (82.0, 112.0, 148.0),
    (108.0, 122.0, 138.0),
    (98.0, 98.0, 98.0),
)


@dataclass(frozen=True)
class SimSettings:
    """How subjects are built and images varied.

    With ``vary_identity`` (the default) every simulated subject draws its own
    identity (:class:`SubjectDraw`) from the ranges below; without it every
    subject uses the fixed values (the simulator before identities: one look
    per photo, only kappa drawn).

    Attributes:
        eyeball_radius_mm: sphere radius without identity draws (default 12).
        eyeball_depth_mm: how far the sphere's centre lies behind the eye contour's centre, for a
            12 mm eyeball (default 10.5); a drawn radius moves the centre by the difference.
        iris_radius_mm: iris radius on the sphere without identity draws (default 6).
        pupil_radius_mm: pupil radius without identity draws (default 2).
        hole_scale: the eye opening is shrunk to this fraction about its centre, so that
            less sclera shows than MediaPipe's contour would (default 0.92).
        lid_follow_mm: upper-lid travel at 90 deg of vertical gaze, times sin(pitch) (default 7).
        lower_lid_follow_mm: lower-lid travel likewise (default 2).
        kappa_deg: standard deviation of the per-subject angle between visual and optical axis, per
            axis (default 2.0; 0 disables the angle, mean included). Measured angle kappa is about
            5 deg horizontally and 1-2 deg vertically on average with a spread of about 2 deg between
            people; only the spread is a per-person error a person-independent model cannot learn
            (the first simulator drew 5 deg of spread around 0: a floor of 6.3 deg of mean error).
        kappa_mean_deg: the mean (horizontal, vertical) angle (default (5.0, 1.5)), turned as
            :meth:`SimSubject.optical_axis` turns it (mirror-symmetric between the eyes).
        brightness: range of the brightness factor (default 0.8-1.2).
        blur_sigma_px: range of the Gaussian blur (default 0-1.0 px).
        noise_sigma: range of the Gaussian noise, grey levels (default 0-4).
        jpeg_quality: range of the JPEG quality (default 60-95).
        vary_identity: draw an identity per subject (default True).
        shape_sd: scale of the shape-space coefficients, N(0, shape_sd^2) each (default 1.0; see
            :mod:`facemesh.face_models.shape_space`).
        head_scale_sd: standard deviation of the overall head size factor (default 0.05).
        eyeball_radius_range_mm: drawn eyeball radius (default 11.5-13).
        iris_radius_range_mm: drawn iris radius (default 5.5-6.4).
        pupil_radius_range_mm: drawn pupil radius (default 1.3-3.2).
        hole_scale_range: drawn eye-opening scale (default 0.84-0.98).
        lid_drop_range_mm: the upper lid lowered by this much at its middle (default 0-1.8): how much
            of the iris the lid covers.
        photo_iris_share: share of subjects keeping the photo's own iris colour (default 0.3); the
            others draw from :data:`IRIS_PALETTE`.
        skin_gain_sd: standard deviation of the skin tone's log gain (default 0.15; red, green and blue
            move 0.75, 1 and 1.3 times as much), plus 0.03 per channel.
        sclera_over_skin: the sclera's brightness over the skin's around the eyes (default 1.1-1.6;
            in webcam pictures the sclera is rarely white).
        glasses_share: share of subjects with glasses (default 0.25).
        relight: re-light the face per image from the mesh normals (default True), after dividing
            the photo's own shading out as far as a low-pass model allows (``delight`` strength,
            default 0.6).
        ambient_range: the drawn ambient share of the light (default 0.35-0.8).
        specular_range: the corneal highlight's strength, grey levels (default 0-160).
        texture_mix_share: share of subjects whose face skin is mixed with another person's photo of
            the same run (default 0: off; above 0, the run needs faces of two people or more). The
            other photo's texture is carried onto this photo's through the shared topology
            (:func:`warp_texture`: the landmark triangles, so lids land on lids), each shading
            divided out first.
        texture_mix_weight: the drawn weight of the other photo's skin (default 0.25-0.6).
    """

    eyeball_radius_mm: float = 12.0
    eyeball_depth_mm: float = 10.5
    iris_radius_mm: float = 6.0
    pupil_radius_mm: float = 2.0
    hole_scale: float = 0.92
    lid_follow_mm: float = 7.0
    lower_lid_follow_mm: float = 2.0
    kappa_deg: float = 2.0
    kappa_mean_deg: tuple[float, float] = (5.0, 1.5)
    brightness: tuple[float, float] = (0.8, 1.2)
    blur_sigma_px: tuple[float, float] = (0.0, 1.0)
    noise_sigma: tuple[float, float] = (0.0, 4.0)
    jpeg_quality: tuple[int, int] = (60, 95)
    vary_identity: bool = True
    shape_sd: float = 1.0
    head_scale_sd: float = 0.05
    eyeball_radius_range_mm: tuple[float, float] = (11.5, 13.0)
    iris_radius_range_mm: tuple[float, float] = (5.5, 6.4)
    pupil_radius_range_mm: tuple[float, float] = (1.3, 3.2)
    hole_scale_range: tuple[float, float] = (0.84, 0.98)
    lid_drop_range_mm: tuple[float, float] = (0.0, 1.8)
    photo_iris_share: float = 0.3
    skin_gain_sd: float = 0.15
    sclera_over_skin: tuple[float, float] = (1.1, 1.6)
    glasses_share: float = 0.25
    relight: bool = True
    delight: float = 0.6
    ambient_range: tuple[float, float] = (0.35, 0.8)
    specular_range: tuple[float, float] = (0.0, 160.0)
    texture_mix_share: float = 0.0
    texture_mix_weight: tuple[float, float] = (0.25, 0.6)

    def __post_init__(self) -> None:
        share = self.texture_mix_share
        if not (isinstance(share, numbers.Real) and not isinstance(share, bool) and 0.0 <= share <= 1.0):
            raise GazeAugError(f"texture mix share: expected a number from 0 to 1, got {share!r}")
        w = self.texture_mix_weight
        if not (
            isinstance(w, (tuple, list))
            and len(w) == 2
            and all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in w)
            and 0.0 <= w[0] <= w[1] <= 1.0
        ):
            raise GazeAugError(f"texture mix weight: expected 0 <= low <= high <= 1, got {self.texture_mix_weight!r}")


@dataclass(frozen=True)
class Glasses:
    """A glasses frame: two rounded-rectangle rims and a bridge, in front of the eyes.

    Attributes:
        half_width_mm: half the width of one rim (default 25).
        half_height_mm: half its height (default 17).
        rim_mm: the rim's width as seen from the front.
        distance_mm: how far in front of the eye contours' centres the frame sits (head frame -z).
        drop_mm: how far below the eye centres the rims' centres lie (head frame +y).
        rgb: the frame's colour.
    """

    half_width_mm: float = 25.0
    half_height_mm: float = 17.0
    rim_mm: float = 2.5
    distance_mm: float = 14.0
    drop_mm: float = 2.0
    rgb: tuple[float, float, float] = (25.0, 22.0, 20.0)


@dataclass(frozen=True)
class SubjectDraw:
    """One simulated identity: what was drawn for it (recorded in ``simulation.jsonl``).

    Attributes:
        shape_coefficients: (K,) coefficients of the shape space (in standard deviations).
        head_scale: factor on the whole head about the eyes' midpoint.
        eyeball_radius_mm, iris_radius_mm, pupil_radius_mm: the eyes (both alike).
        hole_scale: the eye opening's scale about its centre.
        lid_drop_mm: the upper lid lowered by this much at its middle.
        kappa_deg: (horizontal, vertical) angle of the optical axis from the visual axis, degrees.
        iris_rgb: RGB of the iris, or None: the photo's own (measured per eye).
        sclera_rgb: the sclera's colour relative to the skin around the eyes (a factor per channel;
            see ``SimSettings.sclera_over_skin``).
        skin_gain: (3,) colour gains of the face's texture.
        iris_pattern: seed of the iris's radial streaks.
        glasses: the frame, or None.
        texture_mix_pick: which other photo's skin is mixed into this one's: a uniform draw in
            [0, 1) that the run maps to one of its other photos (:func:`other_photo_index`);
            None: the photo's own skin alone.
        texture_mix_weight: the other photo's share of the skin, 0 to 1.
    """

    shape_coefficients: tuple[float, ...] = ()
    head_scale: float = 1.0
    eyeball_radius_mm: float = 12.0
    iris_radius_mm: float = 6.0
    pupil_radius_mm: float = 2.0
    hole_scale: float = 0.92
    lid_drop_mm: float = 0.0
    kappa_deg: tuple[float, float] = (0.0, 0.0)
    iris_rgb: tuple[float, float, float] | None = None
    sclera_rgb: tuple[float, float, float] | None = None
    skin_gain: tuple[float, float, float] = (1.0, 1.0, 1.0)
    iris_pattern: int = 0
    glasses: Glasses | None = None
    texture_mix_pick: float | None = None
    texture_mix_weight: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        from dataclasses import asdict

        return asdict(self)


def draw_subject(settings: SimSettings, rng: np.random.Generator) -> SubjectDraw:
    """An identity drawn from ``settings``' ranges (the fixed values when ``vary_identity`` is off)."""
    s = settings
    k2 = np.asarray(s.kappa_mean_deg, dtype=np.float64) + s.kappa_deg * rng.standard_normal(2)
    kappa = (float(k2[0]), float(k2[1])) if s.kappa_deg > 0 else (0.0, 0.0)
    if not s.vary_identity:
        return SubjectDraw(
            eyeball_radius_mm=s.eyeball_radius_mm,
            iris_radius_mm=s.iris_radius_mm,
            pupil_radius_mm=s.pupil_radius_mm,
            hole_scale=s.hole_scale,
            kappa_deg=(kappa[0], kappa[1]),
        )
    from facemesh.face_models.shape_space import shape_space

    k = shape_space().num_components
    coeffs = tuple(float(v) for v in s.shape_sd * rng.standard_normal(k))
    iris: tuple[float, float, float] | None = None
    if rng.uniform() >= s.photo_iris_share:
        base = np.asarray(IRIS_PALETTE[int(rng.integers(len(IRIS_PALETTE)))])
        c = base * rng.uniform(0.8, 1.2) * rng.uniform(0.92, 1.08, 3)
        iris = (float(c[0]), float(c[1]), float(c[2]))
    sclera = np.array([1.0, 0.965, 0.93]) * rng.uniform(*s.sclera_over_skin) + rng.normal(0.0, 0.015, 3)
    # skin tone along a natural axis (darker skin loses more blue than red), plus a little per channel
    tone = rng.standard_normal()
    gain = np.exp(s.skin_gain_sd * tone * np.array([0.75, 1.0, 1.3]) + rng.normal(0.0, 0.03, 3))
    glasses = None
    if rng.uniform() < s.glasses_share:
        dark = rng.uniform() < 0.6
        rgb = rng.uniform(10, 45, 3) if dark else rng.uniform(60, 200) * rng.uniform(0.85, 1.15, 3)
        glasses = Glasses(
            half_width_mm=float(rng.uniform(21, 28)),
            half_height_mm=float(rng.uniform(13, 20)),
            rim_mm=float(rng.uniform(1.2, 4.0)),
            distance_mm=float(rng.uniform(12, 17)),
            drop_mm=float(rng.uniform(0, 4)),
            rgb=(float(rgb[0]), float(rgb[1]), float(rgb[2])),
        )
    eyeball = float(rng.uniform(*s.eyeball_radius_range_mm))
    draw = SubjectDraw(
        shape_coefficients=coeffs,
        head_scale=float(np.exp(s.head_scale_sd * rng.standard_normal())),
        eyeball_radius_mm=eyeball,
        iris_radius_mm=float(rng.uniform(*s.iris_radius_range_mm)),
        pupil_radius_mm=float(rng.uniform(*s.pupil_radius_range_mm)),
        hole_scale=float(rng.uniform(*s.hole_scale_range)),
        lid_drop_mm=float(rng.uniform(*s.lid_drop_range_mm)),
        kappa_deg=(kappa[0], kappa[1]),
        iris_rgb=iris,
        sclera_rgb=(float(sclera[0]), float(sclera[1]), float(sclera[2])),
        skin_gain=(float(gain[0]), float(gain[1]), float(gain[2])),
        iris_pattern=int(rng.integers(2**31)),
        glasses=glasses,
    )
    # drawn last, and only when asked for: every other draw of a seed stays what it was
    if s.texture_mix_share > 0 and rng.uniform() < s.texture_mix_share:
        pick = float(rng.uniform())
        draw = replace(draw, texture_mix_pick=pick, texture_mix_weight=float(rng.uniform(*s.texture_mix_weight)))
    return draw


def eyeball_depth_mm(base_depth_mm: float, eyeball_radius_mm: float) -> float:
    """How far an eyeball's centre lies behind its eye contour's centre, mm (head frame +z).

    Args:
        base_depth_mm: the depth for a 12 mm eyeball (:attr:`SimSettings.eyeball_depth_mm`).
        eyeball_radius_mm: the eyeball's radius, mm; a larger sphere sits deeper by the
            difference, so that its front stays where a 12 mm one's would.

    Returns:
        The depth, mm. The contour's centre is the eyeball centre moved by it along the head
        frame's -z (towards the face's front): ``centre_cam - R_head @ (0, 0, depth)``.
    """
    return float(base_depth_mm) + (float(eyeball_radius_mm) - 12.0)


def eyes_only(draw: SubjectDraw) -> SubjectDraw:
    """The eyes of an identity draw, for a photo's own face (gaze redirection, :mod:`gazeaug.augment`).

    Keeps the drawn eyeball, iris and pupil sizes, eye opening, lid drop, kappa,
    sclera, iris colour (the photo's own for ``photo_iris_share`` of the draws,
    otherwise one of :data:`IRIS_PALETTE`) and iris pattern; drops the face shape,
    head size, skin gain and glasses.

    The iris colour is drawn, not always the photo's: a model trained on a few
    photos' own irises (measured through lids and shadow, often muddy) met other
    people's irises as a new domain. On issue 13's benchmark (9 photos x 40,
    wheelchair rig, new people) drawn colours took the error from 18.2 to 13.6 deg
    (docs/simulation.md).
    """
    from dataclasses import replace

    return replace(draw, shape_coefficients=(), head_scale=1.0, skin_gain=(1.0, 1.0, 1.0), glasses=None)


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
        light: the image's light (camera frame direction toward the light, ambient share, specular
            strength), or None when unlit.
    """

    image: NDArray[np.uint8]
    target_mm: NDArray[np.float64]
    head_rotation: NDArray[np.float64]
    head_translation_mm: NDArray[np.float64]
    optical_axes: dict[str, NDArray[np.float64]]
    eyeball_centres_mm: dict[str, NDArray[np.float64]]
    coverage: float
    light: dict[str, Any] | None = None

    def truth(self) -> dict[str, Any]:
        """The pose, the gaze and the eyes as ``simulation.jsonl`` records them (lists, camera frame)."""
        return {
            "head_rotation": self.head_rotation.tolist(),
            "head_translation_mm": self.head_translation_mm.tolist(),
            "target_mm": self.target_mm.tolist(),
            "optical_axes": {a: v.tolist() for a, v in self.optical_axes.items()},
            "eyeball_centres_mm": {a: v.tolist() for a, v in self.eyeball_centres_mm.items()},
        }


def label_row(image: str, subject: str, rig: Rig, target_mm: NDArray[np.float64]) -> dict[str, Any]:
    """One ``labels.csv`` row of the folder format for an image the rig's camera took.

    Its intrinsics and the point looked at (camera frame, mm, rounded to 0.1 um).
    """
    k = rig.camera().matrix
    w, h = rig.image_size_wh
    return {
        "image": image,
        "subject": subject,
        "fx": rig.focal_px,
        "fy": rig.focal_px,
        "cx": k[0, 2],
        "cy": k[1, 2],
        "width": w,
        "height": h,
        "target_x": round(float(target_mm[0]), 4),
        "target_y": round(float(target_mm[1]), 4),
        "target_z": round(float(target_mm[2]), 4),
    }


@dataclass(frozen=True)
class PhotoFace:
    """What one face photo gives every identity drawn from it (built once per photo).

    Attributes:
        source: the photo's name (its path), named in errors and in ``simulation.jsonl``.
        head_mm: (V, 3) float64, mm, head frame: the photo's mesh with its background rings
            (the first ``num_face_vertices`` are the landmarks, vertex index = landmark index).
        triangles: (M, 3) uint32: the mesh's triangles without those closing the eye openings.
        uv: (V, 2) float64 glTF texture coordinates.
        texture: (h, w, 3) uint8 RGB: the photo's texture.
        num_face_vertices: N, the landmark vertices.
        ring_parent: (V - N,) int64: the face vertex each ring vertex follows.
        iris_rgb: {"left", "right"}: (3,) float64 RGB measured in the photo.
        eye_pitch_rad: the photo's own eye-in-head pitch (radians, + up, head frame), the gaze its
            lids were photographed at: the rendered lids follow the difference (0 for photos
            without a gaze label, as the simulator's).
    """

    source: str
    head_mm: NDArray[np.float64]
    triangles: NDArray[np.uint32]
    uv: NDArray[np.float64]
    texture: NDArray[np.uint8]
    num_face_vertices: int
    ring_parent: NDArray[np.int64]
    iris_rgb: dict[str, NDArray[np.float64]]
    eye_pitch_rad: float = 0.0

    @classmethod
    def from_image(cls, image: NDArray[np.uint8], detector: Any, source: str = "image") -> PhotoFace:
        """Detect, fit and mesh the largest face of ``image`` ((H, W, 3) uint8 RGB).

        Raises:
            GazeAugError: fewer than MediaPipe's 478 landmarks (the iris points are needed);
            the errors of :func:`gazeaug.pipeline.fit_face`.
        """
        from facemesh.camera import camera_for_image

        from .pipeline import fit_face, mesh_for_fit

        h, w = image.shape[:2]
        fit = fit_face(image, camera_for_image(None, w, h, warn=False), detector, source=source)
        return cls.from_fit(fit, mesh_for_fit(fit), source)

    @classmethod
    def from_fit(
        cls, fit: Any, mesh: FaceMesh, source: str, eye_pitch_rad: float = 0.0, *, rendered: Any = None
    ) -> PhotoFace:
        """A fitted face (:class:`facemesh.build.FaceFit`) and its mesh at the fit's pose.

        ``rendered``: ``mesh`` with its background rings (:func:`gazeaug.render.base.render_mesh`)
        when the caller has it already (an augmentation's :class:`~gazeaug.augment.FaceAsset`); built here otherwise.

        Raises:
            GazeAugError: fewer than MediaPipe's 478 landmarks (the eye contours and iris points are needed).
        """
        from .render.base import render_mesh

        if fit.landmarks.num_points < 478 or mesh.num_vertices < 468:
            raise GazeAugError(
                f"{source}: 3D eyes need MediaPipe's 478 landmarks (eye contours and iris points), "
                f"got {fit.landmarks.num_points} from {mesh.face_model_name!r}"
            )
        rm = render_mesh(mesh) if rendered is None else rendered
        r, t = mesh.pose.rotation, mesh.pose.translation_mm
        head = (rm.vertices_mm - t) @ r  # every vertex (face + rings) in the head frame
        tri = np.asarray(rm.triangles)
        n = rm.num_face_vertices
        drop = np.zeros(len(tri), dtype=bool)
        for loop in eye_contours().values():
            drop |= np.isin(tri, np.asarray(loop)).all(axis=1)  # the triangles that close the eye opening
        iris = {side: _iris_colour(fit.image, fit.landmarks.points_px, side) for side in ("left", "right")}
        return cls(
            source,
            head,
            tri[~drop].astype(np.uint32),
            np.asarray(rm.uv),
            np.ascontiguousarray(rm.texture),
            n,
            rm.ring_parent,
            iris,
            float(eye_pitch_rad),
        )


def _iris_colour(image: NDArray[np.uint8], points: NDArray[np.float64], side: str) -> NDArray[np.float64]:
    """Median colour of the visible iris ring in the photo ((3,) float64 RGB, 0-255).

    The ring lies between 45 % and 90 % of the iris radius (MediaPipe's iris points, ``points``:
    (478, 2) image pixels); only its pixels inside the eye contour count, so the lids, lashes and
    their shadow do not darken it (the whole ring when fewer than 4 pixels are inside).
    """
    import cv2

    centre_i, ring = (473, [474, 475, 476, 477]) if side == "left" else (468, [469, 470, 471, 472])
    c = points[centre_i]
    rad = float(np.linalg.norm(points[ring] - c, axis=1).mean())
    h, w = image.shape[:2]
    x0, x1 = max(0, int(c[0] - rad) - 1), min(w, int(c[0] + rad) + 2)
    y0, y1 = max(0, int(c[1] - rad) - 1), min(h, int(c[1] + rad) + 2)
    if y1 - y0 < 2 or x1 - x0 < 2:
        return np.array([90.0, 70.0, 50.0])
    ys, xs = np.mgrid[y0:y1, x0:x1]
    d = np.hypot(xs - c[0], ys - c[1])
    sel = (d > 0.45 * rad) & (d < 0.9 * rad)
    contour = np.asarray(points[eye_contours()[side]], dtype=np.float32).reshape(-1, 1, 2)
    inside = sel.copy()
    for y, x in zip(*np.nonzero(sel), strict=True):  # pixel centres strictly inside the contour
        inside[y, x] = cv2.pointPolygonTest(contour, (float(xs[y, x]), float(ys[y, x])), False) > 0
    if inside.sum() >= 4:
        sel = inside
    if sel.sum() < 4:
        return np.array([90.0, 70.0, 50.0])
    return np.asarray(np.median(image[y0:y1, x0:x1][sel].astype(np.float64), axis=0))


#: Rec. 601 luma weights of (R, G, B): the grey of a colour, as the simulator reads skin and shading.
_LUMA = np.array([0.299, 0.587, 0.114])

#: Where the skin around an eye is read: the eye contour scaled about its centre by these factors
#: (in the texture), beyond the lid margin and lashes and short of the brow (see ``skin_around_eyes``).
SKIN_RING_SCALES = (1.4, 1.6, 1.8)


def skin_around_eyes(texture: NDArray[np.uint8], uv: NDArray[np.float64], contours: dict[str, list[int]]) -> float:
    """Median luminance (grey levels, 0-255) of the skin around both eyes in a face texture.

    Read on the eye contours scaled about their centres by :data:`SKIN_RING_SCALES`
    (texture pixels), not on the contours themselves: there the lid margin, the
    lashes and their shadow read 0.37-1.10 of the skin (median 0.62, on the 18
    faces of ``benchmarks/generalization.py``), which made a sclera of
    ``skin x 1.1-1.6`` darker than the skin beside it.

    Args:
        texture: (h, w, 3) uint8 RGB.
        uv: (V, 2) float64 glTF texture coordinates of the mesh's vertices.
        contours: :func:`eye_contours`.
    """
    th, tw = texture.shape[:2]
    values = []
    for loop in contours.values():
        px = uv_to_pixels(uv[np.asarray(loop)], (tw, th))
        c = px.mean(axis=0)
        for k in SKIN_RING_SCALES:
            q = c + (px - c) * k
            xi = np.clip(np.round(q[:, 0]).astype(int), 0, tw - 1)
            yi = np.clip(np.round(q[:, 1]).astype(int), 0, th - 1)
            values.append(texture[yi, xi].astype(np.float64) @ _LUMA)
    return float(np.median(np.concatenate(values)))


def _delit(texture: NDArray[np.uint8], strength: float) -> NDArray[np.float64]:
    """The texture divided by its low-pass luminance (relative to the median) to the power ``strength``.

    A simple model of the photo's baked shading: broad light and shadow are
    low-frequency in luminance; dividing them out leaves the skin's colour and
    detail, which the simulator re-lights per image.
    """
    import cv2

    tex = texture.astype(np.float64)
    if strength <= 0:
        return tex
    y = tex @ _LUMA
    sigma = 0.08 * max(texture.shape[:2])
    low = np.asarray(cv2.GaussianBlur(y, (0, 0), sigma), dtype=np.float64)
    shading = np.clip(low / max(float(np.median(low)), 1.0), 0.35, 2.5)
    return np.asarray(np.clip(tex / shading[..., None] ** strength, 0.0, 255.0))


def other_photo_index(index: int, persons: Sequence[str], pick: float) -> int:
    """The face a subject of face ``index`` mixes its skin with: one of the run's faces of another person.

    Args:
        index: the subject's own face, 0 to ``len(persons) - 1``.
        persons: who each face of the run shows (the frames of one video are one person).
        pick: :attr:`SubjectDraw.texture_mix_pick`, in [0, 1): the faces of other persons in
            their order, each an equal share of [0, 1).

    Raises:
        GazeAugError: no face of another person; ``index`` or ``pick`` out of range.
    """
    if not 0 <= index < len(persons):
        raise GazeAugError(f"face index: expected 0 to {len(persons) - 1}, got {index}")
    if not 0.0 <= pick < 1.0:
        raise GazeAugError(f"texture mix pick: expected a number in [0, 1), got {pick!r}")
    others = [k for k, p in enumerate(persons) if p != persons[index]]
    if not others:
        raise GazeAugError(
            f"texture mixing needs a face of another person; every face of the run shows {persons[index]}"
        )
    return others[min(int(pick * len(others)), len(others) - 1)]


def face_person(face: Any) -> str:
    """Who a face of the run shows, without reading it: a FaceSource's person, else the photo's stem."""
    from .faces import FaceSource

    if isinstance(face, FaceSource):
        return face.person or face.name
    return "<built-in>" if face is None else Path(str(face)).stem


def warp_texture(
    source_texture: NDArray[Any],
    source_uv: NDArray[np.float64],
    target_uv: NDArray[np.float64],
    triangles: NDArray[Any],
    target_size_wh: tuple[int, int],
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Carry one mesh's texture onto another mesh's texture layout, triangle by triangle.

    Both meshes share the topology (vertex index = landmark index): each target
    texture pixel inside a triangle reads the source texture at the same
    barycentric point of the source's triangle (bilinear, edge pixels repeated).

    Convention: glTF texture coordinates (origin at the image's top-left
    corner, v down), turned into pixels by :func:`facemesh.conventions.uv_to_pixels`
    (pixel centres at integers).

    Args:
        source_texture: (hs, ws, C) source texture, any numeric dtype.
        source_uv: (V, 2) float64 glTF texture coordinates of the source's vertices.
        target_uv: (V, 2) float64 glTF texture coordinates of the target's vertices.
        triangles: (M, 3) integer vertex indices shared by both.
        target_size_wh: (w, h) of the target texture, pixels.

    Returns:
        ((h, w, C) float32 the source's texture in the target's layout, (h, w) bool the pixels a
        triangle covers; the rest are 0).
    """
    import cv2

    w, h = target_size_wh
    tri = np.asarray(triangles, dtype=np.int64)
    hs, ws = source_texture.shape[:2]
    src = uv_to_pixels(np.asarray(source_uv, dtype=np.float64), (ws, hs))[tri]  # (M, 3, 2)
    dst = uv_to_pixels(np.asarray(target_uv, dtype=np.float64), (w, h))[tri]
    # per triangle the affine map target px -> source px: S = A [D; 1]  =>  A = S [D; 1]^-1
    d = np.concatenate([dst.transpose(0, 2, 1), np.ones((len(tri), 1, 3))], axis=1)  # (M, 3, 3)
    ok = np.abs(np.linalg.det(d)) > 1e-9  # triangles of no area cover no pixel
    ids = np.zeros((h, w), dtype=np.int32)  # 0: none; m + 1: triangle m
    scale = 16  # 4 fractional bits: corners placed to 1/16 px
    for m in np.flatnonzero(ok):
        pts = np.round(dst[m] * scale).astype(np.int32).reshape(3, 2)
        cv2.fillPoly(ids, [pts], (float(m + 1),), lineType=cv2.LINE_8, shift=4)
    covered = ids > 0
    a = np.zeros((len(tri), 2, 3))
    a[ok] = src.transpose(0, 2, 1)[ok] @ np.linalg.inv(d[ok])
    yy, xx = np.nonzero(covered)
    am = a[ids[yy, xx] - 1]  # (P, 2, 3)
    map_xy = np.zeros((h, w, 2), dtype=np.float32)
    map_xy[yy, xx] = (am[:, :, 0] * xx[:, None] + am[:, :, 1] * yy[:, None] + am[:, :, 2]).astype(np.float32)
    tex = np.asarray(source_texture, dtype=np.float32)
    out = cv2.remap(tex, map_xy[..., 0], map_xy[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out = np.asarray(out, dtype=np.float32).reshape(h, w, -1)
    out[~covered] = 0.0
    return out, covered


def _mixed_skin(
    own: NDArray[np.float64], photo: PhotoFace, other: PhotoFace, other_delit: NDArray[np.float64], weight: float
) -> NDArray[np.float64]:
    """``own`` (``photo``'s de-lit texture) with ``weight`` of ``other``'s de-lit skin, over the face's triangles.

    The other photo's share fades to 0 at the face's outline (over 2 % of the texture), so no seam shows
    where the face meets the rings (hair, background), which stay ``photo``'s.
    """
    import cv2

    n = photo.num_face_vertices
    if other.num_face_vertices != n:
        raise GazeAugError(
            f"texture mixing: {other.source} has {other.num_face_vertices} landmark vertices, {photo.source} {n}"
        )
    face_tri = photo.triangles[(photo.triangles < n).all(axis=1)]
    th, tw = own.shape[:2]
    warped, covered = warp_texture(other_delit, other.uv, photo.uv, face_tri, (tw, th))
    # 0 at the outline, 1 from a ramp's width inside it (2 % of the texture, at least 2 texels)
    ramp = max(2.0, 0.02 * max(tw, th))
    inside = np.asarray(cv2.distanceTransform(covered.astype(np.uint8), cv2.DIST_L2, 5), dtype=np.float64)
    share = weight * np.clip(inside / ramp, 0.0, 1.0)
    return np.asarray(own * (1.0 - share[..., None]) + warped.astype(np.float64) * share[..., None])


def _glasses_mesh(
    eye_centres: dict[str, NDArray[np.float64]], g: Glasses
) -> tuple[NDArray[np.float64], NDArray[np.uint32]]:
    """(V, 3) float64 head-frame vertices (mm) and (M, 3) triangles of a glasses frame (rims and bridge)."""
    m = 48
    ang = np.linspace(0.0, 2 * np.pi, m, endpoint=False)
    cos, sin = np.cos(ang), np.sin(ang)
    # a superellipse (exponent 4): a rounded rectangle
    ux = np.sign(cos) * np.abs(cos) ** 0.5
    uy = np.sign(sin) * np.abs(sin) ** 0.5
    verts, tris = [], []
    base = 0
    for c in eye_centres.values():
        centre = np.array([c[0], c[1] + g.drop_mm, c[2] - g.distance_mm])
        for a, b in ((g.half_width_mm, g.half_height_mm), (g.half_width_mm + g.rim_mm, g.half_height_mm + g.rim_mm)):
            verts.append(centre + np.stack([a * ux, b * uy, np.zeros(m)], axis=1))
        i = base + np.arange(m)
        o = base + m + np.arange(m)
        tris += [np.stack([i, np.roll(i, -1), np.roll(o, -1)], 1), np.stack([i, np.roll(o, -1), o], 1)]
        base += 2 * m
    cs = sorted(eye_centres.values(), key=lambda c: float(c[0]))
    x0 = cs[0][0] + g.half_width_mm + g.rim_mm / 2
    x1 = cs[1][0] - g.half_width_mm - g.rim_mm / 2
    y = 0.5 * (cs[0][1] + cs[1][1]) + g.drop_mm - 0.35 * g.half_height_mm
    z = 0.5 * (cs[0][2] + cs[1][2]) - g.distance_mm
    if x1 > x0:
        verts.append(np.array([[x0, y, z], [x1, y, z], [x1, y + g.rim_mm, z], [x0, y + g.rim_mm, z]]))
        tris.append(np.array([[base, base + 1, base + 2], [base, base + 2, base + 3]]))
    return np.concatenate(verts), np.concatenate(tris).astype(np.uint32)


@dataclass(frozen=True)
class _PosedScene:
    """A subject posed in a camera's frame.

    The caster (face = mesh 0, then eyeballs, glasses), the shaders by mesh id,
    each eye's optical axis (head frame) and the light (None: unlit).
    """

    caster: RayCaster
    shaders: dict[int, Shader]
    axes: dict[str, NDArray[np.float64]]
    light: Any


class SimSubject:
    """A simulated subject: one photo's face (:class:`PhotoFace`) with one identity (:class:`SubjectDraw`).

    The drawn shape (the shape space's offset, then the head scale about the
    eyes' midpoint) moves every vertex, the rings with the contour vertex they
    follow; the texture stays the photo's (through the shared topology), with
    the photo's shading divided out (``settings.delight``) and the skin gain,
    and with ``draw.texture_mix_weight`` of ``mix_with``'s skin mixed in when given.
    :attr:`mixed_with` names that photo (None: none).

    Args:
        photo: the photo's face.
        name: subject id.
        settings: see :class:`SimSettings`.
        draw: the identity (see :func:`draw_subject`).
        mix_with: the photo whose skin ``draw.texture_mix_weight`` of is mixed into ``photo``'s
            (the run's choice by ``draw.texture_mix_pick``; None: ``photo``'s skin alone).
    """

    def __init__(
        self, photo: PhotoFace, name: str, settings: SimSettings, draw: SubjectDraw, mix_with: PhotoFace | None = None
    ):
        from facemesh.face_models.shape_space import shape_space

        self.name = name
        self.photo = photo
        self.settings = s = settings
        self.draw = d = draw
        n = photo.num_face_vertices
        head = photo.head_mm.copy()
        if d.shape_coefficients:
            offset = shape_space().offset_mm(np.asarray(d.shape_coefficients))
            if len(offset) == n:
                head[:n] += offset
                head[n:] += offset[photo.ring_parent]
        head *= d.head_scale
        self.contours = eye_contours()
        self.eye_centre: dict[str, NDArray[np.float64]] = {}
        self.lid_weight = np.zeros((len(head), 2))  # (upper, lower) travel weights per vertex
        depth = eyeball_depth_mm(s.eyeball_depth_mm, d.eyeball_radius_mm)
        for side, loop in self.contours.items():
            ids = np.asarray(loop)
            c = head[ids].mean(axis=0)
            head[ids, :2] = c[:2] + (head[ids, :2] - c[:2]) * d.hole_scale
            self.eye_centre[side] = c + np.array([0.0, 0.0, depth])
            # lid weights: 1 in the middle of the lid, 0 at the corners; upper = above the corner line
            corners = head[[ids[np.argmin(head[ids, 0])], ids[np.argmax(head[ids, 0])]]]
            span = corners[1, 0] - corners[0, 0]
            for i in ids:
                u = np.clip((head[i, 0] - corners[0, 0]) / span, 0.0, 1.0)
                line_y = corners[0, 1] + u * (corners[1, 1] - corners[0, 1])
                self.lid_weight[i, 0 if head[i, 1] < line_y else 1] = math.sin(math.pi * u)
        head[:, 1] += d.lid_drop_mm * self.lid_weight[:, 0]  # a lower upper lid covers more of the iris
        # a blink: the upper lid's travel to close the opening (its height at the middle, sin-profiled)
        self.blink_travel = np.zeros(len(head))
        for loop in self.contours.values():
            ids = np.asarray(loop)
            self.blink_travel[ids] = float(np.ptp(head[ids, 1])) * self.lid_weight[ids, 0]
        self.head = head
        self.triangles = photo.triangles
        strength = s.delight if s.relight else 0.0
        tex = _delit(photo.texture, strength)
        self.mixed_with = None
        if mix_with is not None and d.texture_mix_weight > 0:
            tex = _mixed_skin(tex, photo, mix_with, _delit(mix_with.texture, strength), d.texture_mix_weight)
            self.mixed_with = mix_with.source
        tex = tex * np.asarray(d.skin_gain)
        self.texture = np.ascontiguousarray(np.clip(np.round(tex), 0, 255).astype(np.uint8))
        th, tw = self.texture.shape[:2]
        self.face_shader = BilinearTextureShader(self.texture, TexelTable(photo.uv, self.triangles, (tw, th)))
        # the sclera, relative to the skin around the eyes (beyond the lid margin)
        skin = skin_around_eyes(self.texture, photo.uv, self.contours)
        if d.sclera_rgb is None:
            self.sclera_rgb: tuple[float, float, float] = (232.0, 226.0, 220.0)
        else:
            sc = np.clip(skin * np.asarray(d.sclera_rgb), 60.0, 240.0)
            self.sclera_rgb = (float(sc[0]), float(sc[1]), float(sc[2]))
        self.iris_colour = {
            side: (np.asarray(d.iris_rgb, dtype=np.float64) if d.iris_rgb is not None else photo.iris_rgb[side])
            for side in ("left", "right")
        }
        self.kappa_rad = np.radians(np.asarray(d.kappa_deg, dtype=np.float64))  # (horizontal, vertical)
        o3d = import_open3d()
        sphere = o3d.geometry.TriangleMesh.create_sphere(radius=d.eyeball_radius_mm, resolution=24)
        self._sphere_v = np.asarray(sphere.vertices)
        self._sphere_t = np.asarray(sphere.triangles).astype(np.uint32)
        self.glasses = _glasses_mesh(self.eye_centre, d.glasses) if d.glasses is not None else None
        self._mip_shader: Any = None  # built on the first render_patches

    @classmethod
    def from_image(
        cls,
        image: NDArray[np.uint8],
        detector: Any,
        name: str,
        settings: SimSettings,
        rng: np.random.Generator,
        source: str | None = None,
    ) -> SimSubject:
        """A subject from a face photo ((H, W, 3) uint8 RGB), its identity drawn with ``rng``."""
        photo = PhotoFace.from_image(image, detector, source or name)
        return cls(photo, name, settings, draw_subject(settings, rng))

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

    def eye_keypoints_mm(
        self,
        head_rotation: NDArray[np.float64],
        head_translation_mm: NDArray[np.float64],
        target_mm: NDArray[np.float64],
    ) -> NDArray[np.float64]:
        """Each eye's :data:`EYE_KEYPOINTS` at a pose looking at ``target_mm``, as :meth:`render_patches` draws them.

        The iris centre is the centre of the limbus circle (the iris is painted on the eyeball
        with the angular radius ``asin(iris_radius / eyeball_radius)``), ``sqrt(R^2 - r_iris^2)``
        from the eyeball's centre along its optical axis; the eye opening's centre is the
        centre of the eye contour at rest (the eyeball's centre moved
        :func:`eyeball_depth_mm` along the head's -z; the lids' travel with the gaze moves the
        contour, not this point).

        Args:
            head_rotation: (3, 3) head frame -> camera frame.
            head_translation_mm: (3,) mm, camera frame.
            target_mm: (3,) mm, camera frame: the point both eyes fixate.

        Returns:
            (2, 2, 3) float64, mm, camera frame: axis 0 the eye (left, right), axis 1 the point
            (:data:`EYE_KEYPOINTS`: iris centre, opening centre).
        """
        s, d = self.settings, self.draw
        r, t = np.asarray(head_rotation, dtype=np.float64), np.asarray(head_translation_mm, dtype=np.float64)
        target_head = r.T @ (np.asarray(target_mm, dtype=np.float64) - t)
        depth = eyeball_depth_mm(s.eyeball_depth_mm, d.eyeball_radius_mm)
        front = math.sqrt(max(d.eyeball_radius_mm**2 - d.iris_radius_mm**2, 0.0))
        out = np.zeros((2, 2, 3))
        for e, side in enumerate(("left", "right")):
            centre = self.eye_centre[side]
            head_points = np.stack(
                [centre + front * self.optical_axis(side, target_head), centre - np.array([0.0, 0.0, depth])]
            )
            out[e] = head_points @ r.T + t
        return out

    def _posed_scene(
        self,
        head_rotation: NDArray[np.float64],
        head_translation_mm: NDArray[np.float64],
        target_mm: NDArray[np.float64],
        rng: np.random.Generator | None,
        blink: float = 0.0,
        face_shader: Shader | None = None,
        threads: int = 0,
    ) -> _PosedScene:
        """The subject at a pose (head -> camera) looking at ``target_mm`` (camera frame), as one ray-cast scene.

        ``rng`` draws the light (None: unlit, as without ``settings.relight``); ``face_shader``
        replaces the face's bilinear texture shader (same texture and triangles); ``threads``: Embree
        threads of the caster (0: all cores).
        """
        from facemesh.geometry import vertex_normals

        from .render.shaders import EyeballShader, FlatShader, Light, LitShader

        s, d = self.settings, self.draw
        r, t = np.asarray(head_rotation), np.asarray(head_translation_mm)
        target_head = r.T @ (np.asarray(target_mm) - t)
        axes = {side: self.optical_axis(side, target_head) for side in ("left", "right")}
        # eyelids follow the vertical gaze (mean of both eyes' pitch in the head frame; y down), from
        # where the photo's lids were (its own eye pitch)
        pitch = float(np.mean(vector_to_pitchyaw(np.stack([axes["left"], axes["right"]]))[:, 0]))
        v = self.head.copy()
        v[:, 1] -= (math.sin(pitch) - math.sin(self.photo.eye_pitch_rad)) * (
            s.lid_follow_mm * self.lid_weight[:, 0] + s.lower_lid_follow_mm * self.lid_weight[:, 1]
        )
        if blink > 0:
            v[:, 1] += min(float(blink), 1.0) * self.blink_travel
        light = None
        if s.relight and rng is not None:
            # camera frame (y down, z forward): a light in front of the face, mostly from above
            ldir = np.array([rng.normal(0.0, 0.6), rng.normal(-0.4, 0.4), -1.0])
            light = Light(
                ldir / np.linalg.norm(ldir),
                float(rng.uniform(*s.ambient_range)),
                specular=float(rng.uniform(*s.specular_range)),
            )
        # one scene: the face (mesh 0), both eyeballs, the glasses, each with its shader
        posed = v @ r.T + t
        caster = RayCaster([(posed, self.triangles)], threads=threads)
        shaders: dict[int, Shader] = {0: face_shader or self.face_shader}
        if light is not None:
            normals = vertex_normals(posed, self.triangles)
            if float(np.mean(np.einsum("ij,ij->i", normals, -posed))) < 0:  # point them toward the camera
                normals = -normals
            shaders[0] = LitShader(shaders[0], normals, self.triangles, light)
        up = r @ np.array([0.0, -1.0, 0.0])
        for side in ("left", "right"):
            c = r @ self.eye_centre[side] + t
            eye_id = caster.add_mesh(self._sphere_v + c, self._sphere_t)
            shaders[eye_id] = EyeballShader(
                centre_mm=c,
                optical_axis=r @ axes[side],
                radius_mm=d.eyeball_radius_mm,
                iris_radius_mm=d.iris_radius_mm,
                pupil_radius_mm=d.pupil_radius_mm,
                iris_rgb=self.iris_colour[side],
                sclera_rgb=self.sclera_rgb,
                limbus_soft_deg=3.0 if s.vary_identity else 0.0,
                iris_streaks=0.25 if s.vary_identity else 0.0,
                pattern_seed=d.iris_pattern + (side == "left"),
                up=up,
                lid_shadow=0.35 if s.vary_identity else 0.0,
                light=light,
            )
        if self.glasses is not None and d.glasses is not None:
            gv, gt = self.glasses
            gposed = gv @ r.T + t
            gid = caster.add_mesh(gposed, gt)
            frame_shader: Shader = FlatShader(d.glasses.rgb)
            if light is not None:
                gn = np.tile(-r[:, 2], (len(gv), 1))  # the frame faces forward (head -z)
                frame_shader = LitShader(frame_shader, gn, gt, light)
            shaders[gid] = frame_shader
        return _PosedScene(caster, shaders, axes, light)

    def render_patches(
        self,
        head_rotation: NDArray[np.float64],
        head_translation_mm: NDArray[np.float64],
        target_mm: NDArray[np.float64],
        cameras: Sequence[Any],
        *,
        antialias: bool = True,
        eye_blur_px: float = 0.0,
        supersample: int = 1,
        threads: int = 0,
        rng: np.random.Generator | None = None,
    ) -> tuple[NDArray[np.uint8], NDArray[np.float64]]:
        """Normalized patches of the subject at a pose looking at ``target_mm``, without photometric noise.

        Lit as :meth:`render` lights (a light drawn with ``rng``) when ``settings.relight`` and
        ``rng`` is given; otherwise unlit (the texture as it is, the eyeballs shaded by the viewing angle).

        Args:
            head_rotation: (3, 3) head frame -> camera frame.
            head_translation_mm: (3,) mm, camera frame.
            target_mm: (3,) mm, camera frame: the point both eyes fixate.
            cameras: normalized cameras (:class:`gazeaug.camera.NormalizedCamera`) in that camera's
                frame, all of one patch size.
            antialias: the face's texture read by the mip-mapped sampler normalization reads photos
                with (default), as the ``raycast`` renderer does; False reads it bilinearly.
            eye_blur_px: Gaussian sigma, patch pixels, of a blur over the eyeballs' pixels (mixing in their
                neighbours, the lids' edges): the softness of the texture around them, which went
                through a camera (default 0: as rendered).
            supersample: rays per pixel side (default 1: one ray through the pixel centre); s > 1
                averages s x s rays per pixel (over the rays that hit), so the edges of the eye
                opening, the iris and the pupil are antialiased as a camera's pixels average them.
            threads: Embree threads of the ray cast (0: all cores).
            rng: draws the light (see above); None: unlit.

        Returns:
            (C, H, W, 3) uint8 RGB patches (misses inpainted) and (C,) float64 coverage: the share of
            each patch's rays that hit the head (face, rings, eyes): of its pixels when ``supersample`` is 1.
        """
        [out] = self.render_patch_groups(
            head_rotation,
            head_translation_mm,
            target_mm,
            [(cameras, eye_blur_px)],
            antialias=antialias,
            supersample=supersample,
            threads=threads,
            rng=rng,
        )
        return out

    def render_patch_groups(
        self,
        head_rotation: NDArray[np.float64],
        head_translation_mm: NDArray[np.float64],
        target_mm: NDArray[np.float64],
        groups: Sequence[tuple[Sequence[Any], float]],
        *,
        antialias: bool = True,
        supersample: int = 1,
        threads: int = 0,
        rng: np.random.Generator | None = None,
    ) -> list[tuple[NDArray[np.uint8], NDArray[np.float64]]]:
        """:meth:`render_patches` for groups of cameras of different patch sizes, all from one posed scene.

        One light is drawn (with ``rng``) for the pose and every group is seen under it: the eye
        patches and the face patch of a sample show the same lighting.

        Args:
            head_rotation: (3, 3) head frame -> camera frame.
            head_translation_mm: (3,) mm, camera frame.
            target_mm: (3,) mm, camera frame: the point both eyes fixate.
            groups: ``(cameras, eye_blur_px)`` pairs: cameras of one patch size, and the blur over
                the eyeballs' pixels in that group's pixels (see :meth:`render_patches`).
            antialias: as :meth:`render_patches`.
            supersample: as :meth:`render_patches`.
            threads: as :meth:`render_patches`.
            rng: draws the one light of the pose (None: unlit).

        Returns:
            One ``(patches, coverage)`` pair per group, as :meth:`render_patches` returns them.
        """
        from .render.base import View, fill_misses, view_rays_packed
        from .render.shaders import MipTextureShader
        from .texture import build_pyramid

        ss = int(supersample)
        if ss < 1:
            raise GazeAugError(f"supersample: expected an integer >= 1, got {supersample!r}")
        if self._mip_shader is None or self._mip_shader.antialias != antialias:
            th, tw = self.texture.shape[:2]
            table = TexelTable(self.photo.uv, self.triangles, (tw, th))
            self._mip_shader = MipTextureShader(build_pyramid(self.texture), table, antialias=antialias)
        scene = self._posed_scene(
            head_rotation, head_translation_mm, target_mm, rng, face_shader=self._mip_shader, threads=threads
        )
        results = []
        for cameras, eye_blur_px in groups:
            views = [View(camera=c, rotation=np.eye(3), translation_mm=np.zeros(3)) for c in cameras]
            rays = view_rays_packed(views, ss)
            fragments = scene.caster.trace(rays)
            colour = shade(fragments, rays, scene.shaders)
            hit_rays, eye_rays = fragments.hit, fragments.hit & ~fragments.of_mesh(0)
            if ss == 1:
                cover, eyes = hit_rays.astype(np.float64), eye_rays
            else:  # each pixel: the mean of its s x s rays that hit something
                p, hs, ws = hit_rays.shape

                def pixels(a: NDArray[Any], p: int = p, hs: int = hs, ws: int = ws) -> NDArray[Any]:
                    return a.reshape(p, hs // ss, ss, ws // ss, ss, *a.shape[3:]).mean(axis=(2, 4))

                cover = pixels(hit_rays.astype(np.float64))
                colour = pixels(colour * hit_rays[..., None]) / np.maximum(cover, 1e-9)[..., None]
                eyes = pixels(eye_rays.astype(np.float64)) > 0
            out = fill_misses(colour, cover > 0)
            if eye_blur_px > 0:
                import cv2

                for i in np.flatnonzero(eyes.reshape(len(eyes), -1).any(axis=1)):
                    soft = cv2.GaussianBlur(out[i], (0, 0), float(eye_blur_px))
                    out[i][eyes[i]] = soft[eyes[i]]
            results.append((out, cover.reshape(len(cover), -1).mean(axis=1)))
        return results

    def render(
        self,
        head_rotation: NDArray[np.float64],
        head_translation_mm: NDArray[np.float64],
        target_mm: NDArray[np.float64],
        camera_matrix: NDArray[np.float64],
        size_wh: tuple[int, int],
        rng: np.random.Generator,
        blink: float = 0.0,
    ) -> SimFrame:
        """One image: the head at the pose (head -> camera), looking at ``target_mm`` (camera frame).

        ``blink``: 0 (open, default) to 1 (the upper lids lowered onto the lower ones).
        """
        import cv2

        s = self.settings
        r, t = np.asarray(head_rotation), np.asarray(head_translation_mm)
        scene = self._posed_scene(r, t, target_mm, rng, blink)
        caster, shaders, axes, light = scene.caster, scene.shaders, scene.axes, scene.light
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
            light=None
            if light is None
            else {"direction": light.direction.tolist(), "ambient": light.ambient, "specular": light.specular},
        )


def face_image(face: Any) -> tuple[NDArray[np.uint8], str, str]:
    """A simulated subject's face: (image (H, W, 3) uint8 RGB, source name, person).

    ``face``: a photo's path, a :class:`gazeaug.faces.FaceSource` (a crop of a picture or a video
    frame, with its person), or None (the built-in astronaut). A photo's person is its file stem.
    """
    import warnings

    from .faces import FaceSource
    from .pipeline import load_input

    if isinstance(face, FaceSource):
        return face.image, face.origin, face_person(face)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the default-camera warning: the simulator sets its own camera
        image, _, source = load_input(face, None)
    return image, source, face_person(face) if face is not None else Path(str(source)).stem


def rig_pose(
    rig: Rig, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A head pose and a target drawn as the rig draws them, in its camera's frame.

    The head turns by ``R(yaw, pitch)`` of the rig's normal distributions at a position spread by
    ``head_position_std_mm``; the target lies uniformly in ``target_box_mm``.

    Returns:
        (R (3, 3) head -> camera, t (3,) mm, target (3,) mm), camera frame.
    """
    yaw = rig.head_yaw_mean_deg + rig.head_yaw_std_deg * rng.standard_normal()
    pitch = rig.head_pitch_mean_deg + rig.head_pitch_std_deg * rng.standard_normal()
    pos = rng.normal(0.0, rig.head_position_std_mm, 3)
    lo, hi = (np.asarray(c) for c in rig.target_box_mm)
    target = rng.uniform(lo, hi)
    return _in_rig_camera(rig, yaw, pitch, pos, target)


def _in_rig_camera(
    rig: Rig,
    yaw_deg: float,
    pitch_deg: float,
    head_position_mm: NDArray[np.float64],
    target_rig_mm: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A head and a target of the rig frame as the rig's camera sees them.

    The head is turned by ``R(yaw, pitch)`` (degrees) at ``head_position_mm``; returns
    (R head -> camera, t mm, target mm), camera frame.
    """
    from facemesh.conventions import rig_to_camera_points

    r_cam = rig.camera_rotation()
    head_rig = rotation_from_yaw_pitch(math.radians(yaw_deg), math.radians(pitch_deg))
    c = rig.camera_position_mm
    return (
        r_cam @ head_rig,
        rig_to_camera_points(head_position_mm, r_cam, c),
        rig_to_camera_points(target_rig_mm, r_cam, c),
    )


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
    identities_per_face: int = 1,
    per_video: int = 8,
    all_faces: bool = False,
    engine: Engine | None = None,
) -> dict[str, Any]:
    """Write a simulated dataset in the folder format (images, ``labels.csv``, ``simulation.jsonl``).

    The dataset is written into ``OUT.part/`` and swapped in when complete: an
    existing dataset is replaced only with ``overwrite``, and a failed or
    interrupted run leaves ``out_dir`` as it was.

    Args:
        faces: face photos (None: the built-in astronaut), video files (``per_video`` frames spread
            in head pose, each a face of its own; see :func:`gazeaug.faces.face_sources`), or
            :class:`gazeaug.faces.FaceSource` pictures.
        rig: the camera rig (pose, intrinsics, head motion, targets).
        out_dir: the dataset folder to create.
        per_face: images per face.
        seed: everything random derives from it (face i, image j: ``[seed, i, j]``; the identity
            k drawn from face i: ``[seed, i, 10**6 + k]``).
        settings: see :class:`SimSettings`.
        progress: show a progress bar.
        overwrite: replace an existing, non-empty dataset folder that ``simulate`` wrote.
        identities_per_face: how many identities (:class:`SubjectDraw`) each photo gives; image j of
            face i belongs to identity ``j % identities_per_face``, subject id ``simII`` (one identity)
            or ``simIIiKK``. Each identity is a subject of its own in ``labels.csv``.
        per_video: frames taken from each video file.
        all_faces: every face of a picture with several (one crop each), not only the largest.
        engine: where the faces are rendered (default this machine; on Ray one face per block,
            the images written by the actors into the output folder, which every node must see).

    Returns:
        A summary (counts, rig, settings).

    Raises:
        InputError: a face path that is missing or not a file (before anything is written).
        OutputError: ``out_dir`` is not empty (without ``overwrite``), is a file, or another run writes it.
        GazeAugError: ``settings.texture_mix_share`` above 0 with faces of fewer than two people.
    """
    from facemesh.io import check_input_file
    from facemesh.outputs import staged_folder

    s = settings or SimSettings()
    for f in faces:  # a missing photo is named before any folder or progress bar appears
        if isinstance(f, (str, Path)):
            check_input_file(f)
    faces = _expand_faces(faces, per_video=per_video, all_faces=all_faces)
    if per_face < 1:
        raise GazeAugError(f"per_face: expected an integer >= 1, got {per_face}")
    people = len({face_person(f) for f in faces})
    if s.texture_mix_share > 0 and people < 2:
        raise GazeAugError(
            f"texture mixing mixes the skin of two people; this run's faces show {people}: "
            "give faces of more people, or no mixing"
        )
    if not 1 <= identities_per_face <= per_face:
        raise GazeAugError(
            f"identities per face: expected an integer from 1 to per_face ({per_face}), got {identities_per_face}"
        )
    with staged_folder(out_dir, overwrite=overwrite, marker="simulation.json") as part:
        return _simulate_into(
            part,
            Path(out_dir),
            faces,
            rig,
            per_face=per_face,
            seed=seed,
            settings=s,
            progress=progress,
            identities=identities_per_face,
            engine=engine,
        )


def _expand_faces(faces: Sequence[Any], *, per_video: int, all_faces: bool) -> list[Any]:
    """Videos (and, with ``all_faces``, pictures of several people) become :class:`~gazeaug.faces.FaceSource` crops."""
    from .faces import VIDEO_SUFFIXES, FaceSource, face_sources

    out: list[Any] = []
    for f in faces:
        is_video = f is not None and not isinstance(f, FaceSource) and Path(str(f)).suffix.lower() in VIDEO_SUFFIXES
        if is_video or (all_faces and f is not None and not isinstance(f, FaceSource)):
            out.extend(face_sources([f], per_video=per_video, all_faces=all_faces))
        else:
            out.append(f)
    return out


@dataclass(frozen=True)
class _FaceTask:
    """The images of one face (see :func:`_simulate_face`); ``out`` is the dataset folder being written."""

    index: int
    face: Any
    out: str
    rig: Rig
    per_face: int
    seed: int
    settings: SimSettings
    identities: int
    faces: tuple[Any, ...] = ()  # every face of the run (texture mixing reads the others)


_SIM_STATE: dict[str, Any] = {}


def _sim_setup() -> None:
    """A worker's landmark detector, built once (in a Ray actor, inside the actor)."""
    from .pipeline import default_landmark_model

    _SIM_STATE["detector"] = default_landmark_model()


def _simulate_face(
    task: _FaceTask, on_image: Callable[[], object] | None = None
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Render and save the images of face ``task.index``: its ``labels.csv`` rows and ``simulation.jsonl`` records.

    ``on_image`` is called after each image is saved (the local run's progress bar).
    """
    from facemesh.io import save_image_rgb

    s, rig, i, out = task.settings, task.rig, task.index, Path(task.out)
    w, h = rig.image_size_wh
    k = np.array(rig.camera().matrix)
    image, source, person = face_image(task.face)
    photo = PhotoFace.from_image(image, _SIM_STATE["detector"], source)
    others: dict[int, PhotoFace] = {}  # the run's other photos this face's subjects mix skin with

    persons = [face_person(f) for f in task.faces]

    def other(pick: float) -> PhotoFace:
        j = other_photo_index(i, persons, pick)
        if j not in others:
            img, src, _ = face_image(task.faces[j])
            others[j] = PhotoFace.from_image(img, _SIM_STATE["detector"], src)
        return others[j]

    subjects = []
    for kk in range(task.identities):
        sid = f"sim{i:02d}" if task.identities == 1 else f"sim{i:02d}i{kk:02d}"
        draw = draw_subject(s, np.random.default_rng([task.seed, i, 10**6 + kk]))
        mix = other(draw.texture_mix_pick) if draw.texture_mix_pick is not None and task.faces else None
        subjects.append(SimSubject(photo, sid, s, draw, mix))
    rows, truth = [], []
    for j in range(task.per_face):
        subj = subjects[j % task.identities]
        subject_id = subj.name
        rng = np.random.default_rng([task.seed, i, j])
        r, t, target = rig_pose(rig, rng)
        frame = subj.render(r, t, target, k, (w, h), rng)
        name = f"{subject_id}/{j:05d}.jpg"
        save_image_rgb(out / name, frame.image)
        rows.append(label_row(name, subject_id, rig, target))
        truth.append(
            {
                "image": name,
                "source_face": source,
                "person": person,
                **frame.truth(),
                "kappa_deg": np.degrees(subj.kappa_rad).tolist(),
                "face_coverage": frame.coverage,
                "subject": subject_id,
                "subject_draw": subj.draw.as_dict(),
                "texture_mixed_with": subj.mixed_with,
                "light": frame.light,
            }
        )
        if on_image is not None:
            on_image()
    return rows, truth


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
    identities: int = 1,
    engine: Engine | None = None,
) -> dict[str, Any]:
    from facemesh.io import atomic_write

    from .background import interrupt_between_steps
    from .datasets.folder import write_labels_csv

    s = settings
    rows: list[dict[str, Any]] = []
    truth: list[dict[str, Any]] = []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(faces) * per_face, unit="image", desc="simulate", dynamic_ncols=True)
    mixable = tuple(faces) if s.texture_mix_share > 0 else ()  # only what a task reads
    tasks = (
        (i, _FaceTask(i, face, str(out.resolve()), rig, per_face, seed, s, identities, mixable))
        for i, face in enumerate(faces)
    )

    def take(_i: int, result: tuple[list[dict[str, Any]], list[dict[str, Any]]], counted: bool = False) -> None:
        rows.extend(result[0])
        truth.extend(result[1])
        if bar is not None and not counted:  # a Ray actor's face arrives whole
            bar.update(len(result[0]))

    try:
        if engine is not None and engine.kind == "ray":
            from .engine import map_blocks

            with interrupt_between_steps() as interrupted:
                map_blocks(engine, tasks, _simulate_face, _sim_setup, on_result=take, interrupted=interrupted)
        else:
            _sim_setup()
            tick = None if bar is None else partial(bar.update, 1)  # here the bar advances image by image
            for i, task in tasks:
                take(i, _simulate_face(task, tick), counted=True)
    finally:
        if bar is not None:
            bar.close()
    write_labels_csv(out / "labels.csv", rows)
    with atomic_write(out / "simulation.jsonl") as fh:
        fh.write("".join(json.dumps(t) + "\n" for t in truth).encode("utf-8"))
    summary = {
        "output": str(final),
        "images": len(rows),
        "faces": len(faces),
        "subjects": len(faces) * identities,
        "rig": rig.as_dict(),
        "seed": seed,
        "simulator_revision": SIMULATOR_REVISION,
    }
    with atomic_write(out / "simulation.json") as fh:
        fh.write(
            json.dumps(
                {**summary, "settings": {k2: getattr(s, k2) for k2 in s.__dataclass_fields__}}, indent=1
            ).encode()
        )
    return summary
