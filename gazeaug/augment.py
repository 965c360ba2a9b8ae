"""Augmenting one sample: the face mesh and its gaze turned to new head poses, each eye rendered as normalized.

Steps (the paper's 4-7):

1. the gaze label into the head frame: a target point ``T`` becomes
   ``R_h^T (T - t_h)`` (a direction ``g`` becomes ``R_h^T g``);
2. a head pose ``(yaw, pitch)`` from the application's distribution;
3. the head placed at ``R_new = R(yaw, pitch)`` (the paper's equation) with its
   eye midpoint on the application camera's optical axis, ``t_new = (0, 0, D)``
   (``D`` defaults to the source photo's distance, so the texture keeps its
   resolution); mesh and gaze move with it;
4. each eye rendered through the normalized camera that test-time
   normalization builds for that eye at this pose, with its labels: both come
   from the one kernel :func:`gazeaug.camera.normalized_views`, which
   :func:`gazeaug.normalize.normalize_image` calls for one pose and
   :func:`render_poses` for all the poses of a sample at once.

At the source pose (``R_new = R_h``, ``t_new = t_h``) the render reproduces the
normalization of the photo itself.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from facemesh.conventions import rotation_from_yaw_pitch, vector_to_pitchyaw, yaw_pitch_from_rotation
from facemesh.face_models import BUILTIN_MODELS, FaceKeypoints, builtin_face_model
from facemesh.types import FaceMesh

from .camera import NormalizedCamera, reference_points_head
from .errors import GazeAugError
from .normalize import NormalizationSettings, NormalizedSample, face_patch_camera, samples_from_views, views_at
from .render.base import RenderMesh, Scene, View, render_mesh

if TYPE_CHECKING:
    from facemesh.build import FaceFit

    from .sampling import Rig
    from .simulate import SimSettings, SimSubject

__all__ = [
    "FaceAsset",
    "face_asset",
    "HeadPlacement",
    "sampled_placement",
    "sampled_placements",
    "source_placement",
    "render_poses",
    "redirect_settings",
    "rig_looks",
    "source_eye_pitch",
    "redirect_subject",
    "render_redirected",
    "eye_softness_px",
    "EYE_SOFTNESS_SOURCE_PX",
    "TEXTURE_REACH",
    "TextureCropWarning",
    "texture_shortfall",
    "warn_texture_shortfall",
]


@dataclass(frozen=True)
class FaceAsset:
    """A face prepared for augmentation.

    Attributes:
        mesh: the textured face mesh (source camera frame).
        model_vertices_mm: (N, 3) float64, mm, head frame: the face model the pose was solved with.
        keypoints: the eye (and mouth) corner indices into the model.
        render_mesh: the mesh with its background rings, as renderers take it.
        reference_points_mm: (3, 3) float64, mm, head frame: the left eye's centre, the right
            eye's centre and the face centre (rows), as normalization defines them.
    """

    mesh: FaceMesh
    model_vertices_mm: NDArray[np.float64]
    keypoints: FaceKeypoints
    render_mesh: RenderMesh
    reference_points_mm: NDArray[np.float64]


def face_asset(mesh: FaceMesh, keypoints: FaceKeypoints | None = None) -> FaceAsset:
    """Prepare a mesh: its face model's points and key points, and the background rings.

    The model's points and key points come from the mesh (``mesh.model_vertices_mm``,
    ``mesh.model_keypoints``) or, for meshes written before those were recorded, from
    the built-in model of the same name; ``keypoints`` overrides them.

    Raises:
        GazeAugError: the face model or its key points are unknown, or do not fit each other.
    """
    model, kp = mesh.model_vertices_mm, keypoints or mesh.model_keypoints
    if model is None or kp is None:
        if model is not None and mesh.face_model_name not in BUILTIN_MODELS:
            raise GazeAugError(
                f"the mesh's face model ({mesh.face_model_name!r}, {len(model)} points) has no key points (eye and "
                "mouth corners): give them with --keypoints (a layout name or 4 or 6 indices), or build the mesh "
                "with facemesh build --keypoints"
            )
        if mesh.face_model_name not in BUILTIN_MODELS:
            raise GazeAugError(
                f"the mesh does not record its face model's points and key points, and {mesh.face_model_name!r} "
                "is not built in; rebuild it with this version of facemesh"
            )
        builtin = builtin_face_model(mesh.face_model_name)
        model = builtin.vertices_mm if model is None else model
        kp = kp or builtin.keypoints
    assert kp is not None
    model = np.asarray(model, dtype=np.float64)
    if max(kp.face_indices) >= len(model):
        raise GazeAugError(f"key point indices {kp.face_indices} do not fit a {len(model)}-point face model")
    return FaceAsset(
        mesh=mesh,
        model_vertices_mm=model,
        keypoints=kp,
        render_mesh=render_mesh(mesh),
        reference_points_mm=reference_points_head(model, kp),
    )


@dataclass(frozen=True)
class HeadPlacement:
    """Where the head is in the application camera's frame.

    Attributes:
        rotation: (3, 3) float64, head frame -> application camera frame.
        translation_mm: (3,) float64, mm: the head frame's origin (between the eyes).
        yaw_pitch_rad: (2,) the sampled (yaw, pitch) of ``R(y, p)``, or None for the source pose.
    """

    rotation: NDArray[np.float64]
    translation_mm: NDArray[np.float64]
    yaw_pitch_rad: NDArray[np.float64] | None = None


def sampled_placement(
    asset: FaceAsset, yaw_rad: float, pitch_rad: float, distance_mm: float | None = None
) -> HeadPlacement:
    """The head at ``R(yaw, pitch)``, its eye midpoint ``distance_mm`` in front of the camera on the optical axis."""
    return sampled_placements(asset, [[yaw_rad, pitch_rad]], distance_mm)[0]


def _head_distance(asset: FaceAsset, distance_mm: float | None) -> float:
    """Eye midpoint to the application camera, mm: ``distance_mm``, or the source photo's distance."""
    d = float(np.linalg.norm(asset.mesh.pose.translation_mm)) if distance_mm is None else float(distance_mm)
    if not (np.isfinite(d) and d > 0):
        raise GazeAugError(f"head distance: expected > 0 mm, got {distance_mm}")
    return d


def sampled_placements(
    asset: FaceAsset, yaw_pitch_rad: ArrayLike, distance_mm: float | None = None
) -> list[HeadPlacement]:
    """:func:`sampled_placement` for K poses at once.

    Args:
        asset: the face.
        yaw_pitch_rad: (K, 2) float radians, (yaw, pitch) rows (as :meth:`HeadPoseDistribution.sample` gives).
        distance_mm: eye midpoint to camera, mm (default: the source photo's distance).
    """
    yp = np.asarray(yaw_pitch_rad, dtype=np.float64).reshape(-1, 2)
    d = _head_distance(asset, distance_mm)
    if not np.isfinite(yp).all():
        raise GazeAugError(f"head pose: expected finite yaw and pitch, got {yp.tolist()}")
    rot = rotation_from_yaw_pitch(yp[:, 0], yp[:, 1])
    t = np.array([0.0, 0.0, d])
    return [HeadPlacement(rotation=rot[k], translation_mm=t, yaw_pitch_rad=yp[k]) for k in range(len(yp))]


def source_placement(asset: FaceAsset) -> HeadPlacement:
    """The head where the photo shows it (the ``--original-pose`` of ``gazeaug render``)."""
    return HeadPlacement(
        rotation=np.array(asset.mesh.pose.rotation), translation_mm=np.array(asset.mesh.pose.translation_mm)
    )


def _render_views(
    asset: FaceAsset,
    cameras: Sequence[Sequence[NormalizedCamera]],
    rot: NDArray[np.float64],
    trans: NDArray[np.float64],
) -> list[View]:
    """The renderer's views through each placement's cameras (``rot``, ``trans``: head -> application camera).

    ``cameras[i]`` are placement i's cameras (both eyes, or its face patch), in the application camera's frame.
    """
    r_h, t_h = asset.mesh.pose.rotation, asset.mesh.pose.translation_mm
    a = rot @ r_h.T  # mesh (source camera frame) -> application camera frame
    b = trans - np.einsum("pij,j->pi", a, t_h)
    return [View(camera=c, rotation=a[i], translation_mm=b[i]) for i in range(len(rot)) for c in cameras[i]]


def _sample_metas(placements: Sequence[HeadPlacement], meta: Mapping[str, Any] | None) -> list[dict[str, Any]]:
    """Each sample's extras: ``meta`` and, for a sampled placement, its ``yaw_pitch_deg``."""
    metas = []
    for place in placements:
        m = dict(meta or {})
        if place.yaw_pitch_rad is not None:
            m["yaw_pitch_deg"] = np.degrees(place.yaw_pitch_rad).tolist()
        metas.append(m)
    return metas


def render_poses(
    scene: Scene,
    asset: FaceAsset,
    placements: Sequence[HeadPlacement],
    *,
    gaze_target_mm: ArrayLike | None = None,
    gaze_vector: ArrayLike | None = None,
    settings: NormalizationSettings | None = None,
    renderer_name: str = "raycast",
    meta: Mapping[str, Any] | None = None,
) -> list[NormalizedSample]:
    """Render both eyes of a face at each head placement, with labels.

    Args:
        scene: the face loaded into a renderer (``renderer.scene(asset.render_mesh)``).
        asset: the face.
        placements: head poses in the application camera's frame.
        gaze_target_mm: (3,) float, mm, *source* camera frame: what the subject looked at.
        gaze_vector: (3,) float, source camera frame: the gaze direction (instead of a target).
        settings: normalization settings (must match the ones test-time normalization uses).
        renderer_name: recorded in each sample's ``source``.
        meta: extras recorded in every sample.

    Returns:
        One :class:`NormalizedSample` per placement; ``meta`` holds the sampled
        ``yaw_pitch_deg`` when the placement was sampled.
    """
    s = settings or NormalizationSettings()
    if not placements:
        return []
    if gaze_target_mm is not None and gaze_vector is not None:
        raise GazeAugError("give a gaze target or a gaze vector, not both")
    r_h, t_h = asset.mesh.pose.rotation, asset.mesh.pose.translation_mm
    rot = np.stack([p.rotation for p in placements])  # (P, 3, 3) head -> application camera
    trans = np.stack([p.translation_mm for p in placements])  # (P, 3)
    # step 1: the gaze label into the head frame, then with the head to each placement
    targets = vectors = None
    if gaze_target_mm is not None:
        t = np.asarray(gaze_target_mm, dtype=np.float64)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise GazeAugError(f"gaze target: expected finite (X, Y, Z) mm, got {t.tolist()}")
        targets = rot @ (r_h.T @ (t - t_h)) + trans
    if gaze_vector is not None:
        g = np.asarray(gaze_vector, dtype=np.float64)
        if g.shape != (3,) or not np.isfinite(g).all():
            raise GazeAugError(f"gaze vector: expected finite (3,), got {g.tolist()}")
        vectors = rot @ (r_h.T @ g)
    views = views_at(
        asset.model_vertices_mm, asset.keypoints, rot, trans, s, gaze_target_mm=targets, gaze_vector=vectors
    )
    out = scene.render(_render_views(asset, [c[:2] for c in views.cameras], rot, trans))
    h, w = s.patch_size_wh[1], s.patch_size_wh[0]
    faces = face_cover = None
    if s.face_patch_size_wh is not None:
        face = scene.render(_render_views(asset, [[face_patch_camera(c[2], s)] for c in views.cameras], rot, trans))
        faces, face_cover = np.asarray(face.images), np.asarray(face.coverage)
    metas = _sample_metas(placements, meta)
    return samples_from_views(
        views,
        np.asarray(out.images).reshape(len(rot), 2, h, w, 3),
        s,
        rot,
        f"render:{renderer_name}",
        coverage=np.asarray(out.coverage).reshape(len(rot), 2),
        metas=metas,
        face_patches=faces,
        face_coverage=face_cover,
    )


# --------------------------------------------------------------------------- gaze redirection


def rig_looks(
    asset: FaceAsset, rig: Rig, n: int, rng: np.random.Generator, distance_mm: float | None = None
) -> tuple[list[HeadPlacement], NDArray[np.float64]]:
    """``n`` head placements and the points looked at, drawn jointly as the rig draws them (``gazeaug simulate``).

    Each draw is the rig's head turn and target (:func:`gazeaug.simulate.rig_pose`);
    the head is then placed like every augmented head, its eye midpoint
    ``distance_mm`` in front of the camera on the optical axis (default: the
    source photo's distance), and the target moves with it, so the gaze keeps
    its direction in the head frame: the rig's eye-in-head gaze, not the source's.

    Returns:
        The placements (their ``yaw_pitch_rad`` that of the rotation, which may also roll) and
        (n, 3) float64 targets, mm, application camera frame.
    """
    from .simulate import rig_pose

    trans = np.array([0.0, 0.0, _head_distance(asset, distance_mm)])
    places, targets = [], []
    for _ in range(int(n)):
        r, t, target = rig_pose(rig, rng)
        places.append(HeadPlacement(rotation=r, translation_mm=trans, yaw_pitch_rad=yaw_pitch_from_rotation(r)))
        targets.append(target - t + trans)  # the head keeps its rotation and moves from t: the target with it
    return places, np.stack(targets) if targets else np.zeros((0, 3))


def source_eye_pitch(
    asset: FaceAsset, gaze_target_mm: ArrayLike | None = None, gaze_vector: ArrayLike | None = None
) -> float:
    """The source's eye-in-head gaze pitch, radians (+ up, head frame): where its lids were photographed.

    Args:
        asset: the face at its source pose.
        gaze_target_mm: (3,) float, mm, source camera frame (seen from the eyes' midpoint); or
        gaze_vector: (3,) float, source camera frame.
    """
    r_h, t_h = asset.mesh.pose.rotation, asset.mesh.pose.translation_mm
    if gaze_target_mm is not None:
        mid = asset.reference_points_mm[:2].mean(axis=0)  # the eyes' midpoint, head frame
        g = np.asarray(gaze_target_mm, dtype=np.float64) - (r_h @ mid + t_h)
    elif gaze_vector is not None:
        g = np.asarray(gaze_vector, dtype=np.float64)
    else:
        return 0.0
    if g.shape != (3,) or not np.isfinite(g).all() or not np.linalg.norm(g) > 0:
        raise GazeAugError(f"gaze: expected a finite, non-zero (3,) vector, got {np.asarray(g).tolist()}")
    return float(vector_to_pitchyaw(r_h.T @ g)[0])


def redirect_settings() -> SimSettings:
    """The simulator's settings for redirected eyes: its defaults, so eyes and light are drawn as it draws them.

    The face is re-lit per sample as the simulator re-lights its subjects (the photo's own
    shading divided out as far as a low-pass model allows, then a light drawn in front of the
    face, mostly from above), and the eyeballs take the same light: the shading, the shadow of
    the upper lid and the corneal highlight of a lit eye.
    """
    from .simulate import SimSettings

    return SimSettings()


def redirect_subject(
    fit: FaceFit,
    asset: FaceAsset,
    rng: np.random.Generator,
    *,
    gaze_target_mm: ArrayLike | None = None,
    gaze_vector: ArrayLike | None = None,
) -> SimSubject:
    """The photo's face with 3D eyes in its eye openings, ready to look anywhere.

    The eye openings' triangles are cut out and an eyeball put behind each, as
    :class:`gazeaug.simulate.SimSubject` makes them: the eyes' sizes, lid drop,
    kappa, sclera and iris colour drawn (:func:`gazeaug.simulate.eyes_only`; the
    photo's own iris colour for ``photo_iris_share`` of the draws, 30 % by default),
    the photo's own face shape and texture. The lids follow the new gaze's pitch
    from the source's own (:func:`source_eye_pitch`).

    Raises:
        GazeAugError: the face has no MediaPipe eye contours and iris points (478 landmarks).
    """
    from .simulate import PhotoFace, SimSubject, draw_subject, eyes_only

    settings = redirect_settings()
    pitch = source_eye_pitch(asset, gaze_target_mm, gaze_vector)
    photo = PhotoFace.from_fit(fit, asset.mesh, fit.source, eye_pitch_rad=pitch, rendered=asset.render_mesh)
    return SimSubject(photo, fit.source, settings, eyes_only(draw_subject(settings, rng)))


#: The softness of a photographed eye, in source-image pixels (Gaussian sigma): the optics, the
#: demosaicing and the resampling of normalization blur a photo's eye over about a pixel, where a
#: ray-cast eyeball is sharp. A modelling choice, not a measurement.
EYE_SOFTNESS_SOURCE_PX = 0.7


def eye_softness_px(asset: FaceAsset, settings: NormalizationSettings) -> float:
    """The blur of redirected eyeballs, patch pixels: :data:`EYE_SOFTNESS_SOURCE_PX` at the patch's scale.

    A source pixel covers ``(f_n / d_n) / (f / D)`` patch pixels (``f``, ``D``: the source camera's
    focal length and the face's distance; ``f_n``, ``d_n``: the normalized camera's), at least one.
    """
    f = float(np.mean(asset.mesh.camera.focal_px))
    d = float(np.linalg.norm(asset.mesh.pose.translation_mm))
    scale = (settings.focal_px / settings.distance_mm) / (f / d)
    return EYE_SOFTNESS_SOURCE_PX * max(1.0, scale)


#: Rays per pixel side of redirected eye patches (:func:`render_redirected`; default 1: one ray
#: through each pixel centre). 2 (2 x 2 rays per pixel, averaged) antialiases the edges of the eye
#: opening, the iris and the pupil as a camera's pixels do: against MPIIGaze's patches
#: (docs/simulation.md, "How real the eyes look") the share of high-frequency energy fell from 0.0231
#: to 0.0168 (real: 0.0068). On issue 13's benchmark, whose simulated test people are ray cast with
#: one ray per pixel, it cost accuracy (docs/simulation.md), so it is not the default.
REDIRECT_SUPERSAMPLE = 1


def render_redirected(
    subject: SimSubject,
    asset: FaceAsset,
    placements: Sequence[HeadPlacement],
    targets_mm: ArrayLike,
    *,
    settings: NormalizationSettings | None = None,
    meta: Mapping[str, Any] | None = None,
    threads: int = 0,
    rng: np.random.Generator | None = None,
    supersample: int | None = None,
) -> list[NormalizedSample]:
    """Both eyes at each head placement, the eyeballs turned to look at each target, with labels.

    Each eye patch records where its iris centre and eye opening's centre lie in it
    (:attr:`gazeaug.normalize.EyePatch.keypoints_px`, :meth:`SimSubject.eye_keypoints_mm`
    projected by the patch's camera).

    The gaze is redirected: the label is the line from the eyes to ``targets_mm``
    (the eyeballs' visual axes fixate it), not the source photo's gaze. Patches
    come from the subject's one ray-cast scene per placement (face textured by the
    mip-mapped sampler, eyeballs by :class:`gazeaug.render.shaders.EyeballShader`),
    through the normalized cameras of the one kernel :func:`gazeaug.camera.normalized_views`.

    Args:
        subject: :func:`redirect_subject` of the face.
        asset: the face.
        placements: head poses in the application camera's frame.
        targets_mm: (P, 3) float, mm, application camera frame: the point each placement looks at.
        settings: normalization settings (must match test time's).
        meta: extras recorded in every sample (with ``yaw_pitch_deg`` of sampled placements).
        threads: Embree threads per ray cast (0: all cores; 1 when several worker processes share them).
        rng: draws each placement's light (the subject's settings re-light); None: unlit.
        supersample: rays per pixel side (default :data:`REDIRECT_SUPERSAMPLE`).
    """
    s = settings or NormalizationSettings()
    if not placements:
        return []
    rot = np.stack([p.rotation for p in placements])
    trans = np.stack([p.translation_mm for p in placements])
    targets = np.asarray(targets_mm, dtype=np.float64)
    if targets.shape != (len(placements), 3) or not np.isfinite(targets).all():
        raise GazeAugError(f"targets: expected finite ({len(placements)}, 3) mm, got shape {targets.shape}")
    views = views_at(asset.model_vertices_mm, asset.keypoints, rot, trans, s, gaze_target_mm=targets)
    blur = eye_softness_px(asset, s)
    # the same softness at the face camera's scale (its own f_n / d_n against the photo's)
    face_blur = eye_softness_px(asset, replace(s, focal_px=s.face_focal_px, distance_mm=s.face_distance_mm))
    images, coverage, faces, face_cover = [], [], [], []
    # each eye's points, where the eyeball drawn below puts them, in its own patch
    keypoints = np.stack(
        [
            [
                cam.project(points)
                for cam, points in zip(views.cameras[i][:2], subject.eye_keypoints_mm(rot[i], trans[i], targets[i]))
            ]
            for i in range(len(placements))
        ]
    )
    for i in range(len(placements)):
        groups: list[tuple[Sequence[NormalizedCamera], float]] = [(views.cameras[i][:2], blur)]
        if s.face_patch_size_wh is not None:
            groups.append(([face_patch_camera(views.cameras[i][2], s)], face_blur))
        rendered = subject.render_patch_groups(
            rot[i],
            trans[i],
            targets[i],
            groups,
            antialias=s.antialias,
            supersample=REDIRECT_SUPERSAMPLE if supersample is None else supersample,
            threads=threads,
            rng=rng,
        )
        images.append(rendered[0][0])
        coverage.append(rendered[0][1])
        if len(rendered) > 1:
            faces.append(rendered[1][0][0])
            face_cover.append(rendered[1][1][0])
    metas = _sample_metas(placements, meta)
    return samples_from_views(
        views,
        np.stack(images),
        s,
        rot,
        "render:redirect",
        coverage=np.stack(coverage),
        metas=metas,
        face_patches=np.stack(faces) if faces else None,
        face_coverage=np.asarray(face_cover) if faces else None,
        eye_keypoints_px=keypoints,
    )


#: How far beyond a texture position the sampler's reading matters, in pixels of the coarser pyramid
#: level it reads (``2 ** ceil(lod)`` texture pixels each): that level's ``cv2.pyrDown`` 5-tap kernels
#: and its bilinear tap (their farther taps weigh little). Measured (11 photos, 56 poses up to 40 deg,
#: margins 0.15, 0.4, 0.6; docs/face_model.md, "Texture margin"): every eye patch with no pixel within
#: this reach of a cut edge is within 4 grey levels of the whole photo's render.
TEXTURE_REACH = 2.0


def texture_shortfall(
    asset: FaceAsset, placements: Sequence[HeadPlacement], settings: NormalizationSettings | None = None
) -> NDArray[np.float64]:
    """Share of each eye patch's pixels that the texture's crop may cost: (P, 2) float64, (left, right) rows.

    A pixel counts when the mesh point it shows reads the texture within
    :data:`TEXTURE_REACH` of a crop edge that the source photo goes past (the
    crop's margin cut it, not the photo's own edge): there the render reads the
    crop's replicated edge, or a pyramid level built without the photo's pixels
    beyond it, where rendering the photo with a wider margin would read the
    photo. Where no pixel counts, the render is the whole photo's (measured:
    within 4 grey levels, :data:`TEXTURE_REACH`). The geometry is the
    renderers' common :class:`RenderMesh`; the reach is the ray caster's
    sampler's. A rebuild with a wider ``texture_margin`` (``facemesh build
    --texture-margin``) brings it down. Atlas textures (``--atlas``) are no
    crop of the photo: zero.
    """
    from facemesh.render import RayCaster, TexelTable

    from .render.base import view_rays_packed
    from .texture import MAX_LEVELS, level_of_detail

    s = settings or NormalizationSettings()
    if not placements or "atlas" in asset.mesh.extras:
        return np.zeros((len(placements), 2))
    rot = np.stack([p.rotation for p in placements])
    trans = np.stack([p.translation_mm for p in placements])
    views = views_at(asset.model_vertices_mm, asset.keypoints, rot, trans, s)
    rm, mesh = asset.render_mesh, asset.mesh
    th, tw = rm.texture.shape[:2]
    fragments = RayCaster([(rm.vertices_mm, rm.triangles)]).trace(
        view_rays_packed(_render_views(asset, [c[:2] for c in views.cameras], rot, trans))
    )
    hit = fragments.hit
    px = TexelTable(rm.uv, rm.triangles, (tw, th)).texture_px(fragments)
    lod = np.minimum(level_of_detail(px, hit), np.float32(MAX_LEVELS))
    reach = TEXTURE_REACH * 2.0 ** np.ceil(lod)
    x, y = px[..., 0], px[..., 1]
    (w, h), (x0, y0) = mesh.camera.image_size, mesh.texture_origin_px
    short = np.zeros_like(hit)
    if x0 > 0:  # the photo goes on beyond the crop's left edge
        short |= x - reach < 0
    if y0 > 0:
        short |= y - reach < 0
    if x0 + tw < w:
        short |= x + reach > tw - 1
    if y0 + th < h:
        short |= y + reach > th - 1
    short &= hit
    return short.reshape(len(placements), 2, -1).mean(axis=2)


class TextureCropWarning(UserWarning):
    """A texture crop too tight for a pose: the render may differ from the photo's (:func:`texture_shortfall`)."""


def warn_texture_shortfall(
    asset: FaceAsset,
    placements: Sequence[HeadPlacement],
    settings: NormalizationSettings | None = None,
    name: str = "the mesh",
) -> float:
    """Warn (:class:`TextureCropWarning`) when :func:`texture_shortfall` finds pixels at these poses.

    For meshes read from a file (``gazeaug render face.glb``): built with a
    tighter ``--texture-margin`` than the default, their renders of turned
    heads can read the crop's edge where rendering the photo reads the photo.

    Returns:
        The largest share of one eye patch's pixels concerned (0.0: no warning).
    """
    import warnings

    from facemesh.mesh import BuildSettings

    worst = float(texture_shortfall(asset, placements, settings).max(initial=0.0))
    if worst > 0:
        warnings.warn(
            f"{name}: its texture crop is too tight for this head pose: {worst:.1%} of an eye patch's pixels read "
            "the texture at its cut edge, so the render may differ from rendering the photo itself; rebuild it "
            f"with a wider margin (facemesh build --texture-margin, default {BuildSettings.texture_margin:g})",
            TextureCropWarning,
            stacklevel=2,
        )
    return worst
