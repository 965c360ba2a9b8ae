"""From landmarks to a textured face mesh: pose -> vertices -> triangles -> texture.

Vertex placement (``BuildSettings.vertex_placement``):

``canonical``
    The face model's points at the solved pose (the paper's choice). The mesh
    keeps the model's shape, so the eyes of a face whose shape differs from
    the model land away from their landmarks (measured: eyes squashed by 25-30%).
``backprojected`` (default)
    Each vertex slides along the camera ray through its detected landmark so
    that it projects exactly onto it, keeping the depth (camera z) the posed
    model gives it. The texture then lines up with the geometry everywhere.
``landmarks3d``
    Like ``backprojected``, but the depth comes from the landmark model's own
    per-face z (MediaPipe's), scaled to mm at the face's distance and centred
    on the posed model's mean depth.

Other libraries (:func:`to_open3d`, :func:`to_trimesh`, also
:meth:`FaceMesh.to_open3d <facemesh.types.FaceMesh.to_open3d>` and
:meth:`FaceMesh.to_trimesh <facemesh.types.FaceMesh.to_trimesh>`): Open3D's
glTF readers reorder a ``.glb``'s vertices (``o3d.io.read_triangle_mesh``
leaves 2 of the built-in sample's 468 in place), which breaks "vertex i =
landmark i". ``facemesh.load(path).to_open3d()`` reads the file with
:func:`facemesh.gltf.load_glb` and converts it with the order kept; a built
mesh converts the same way (docs/interop.md).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .conventions import (
    face_forward,
    gltf_to_opencv_directions,
    gltf_uv_to_bottom_left_uv,
    opencv_to_gltf_points,
    pixels_to_uv,
)
from .pose import project_points, solve_head_pose, undistort_to_rays
from .reconstruct import (
    MIN_SURFACE_POINTS,
    SURFACE_METHODS,
    BallPivotingSettings,
    PoissonSettings,
    reconstruct_surface,
)
from .types import CameraIntrinsics, FaceLandmarks, FaceMesh, FaceModel, HeadPose, InputError

if TYPE_CHECKING:  # heavy optional libraries: imported where used
    import open3d
    import trimesh

__all__ = [
    "VERTEX_PLACEMENTS",
    "TEXTURE_ALIGN",
    "INTEROP_FRAMES",
    "BuildSettings",
    "place_vertices",
    "crop_texture",
    "texture_uv",
    "build_face_mesh",
    "to_open3d",
    "to_trimesh",
]

VERTEX_PLACEMENTS = ("canonical", "backprojected", "landmarks3d")

#: The texture crop's origin is a multiple of this many pixels (2 ** 4: four pyramid levels line up).
TEXTURE_ALIGN = 16


@dataclass(frozen=True)
class BuildSettings:
    """How :func:`build_face_mesh` builds a mesh.

    Attributes:
        vertex_placement: one of :data:`VERTEX_PLACEMENTS` (default ``"backprojected"``).
        texture_margin: margin added on every side of the landmarks' bounding
            box when cropping the texture, as a fraction of the box's larger
            side (default 0.6; the outer landmarks are the face contour).
            Wide enough for the renders a mesh feeds: gazeaug's background
            rings around the contour reach 0.3-0.8 of the face's size beyond
            it, and the eye patches of heads turned up to 40 deg read them. At
            0.6 a ``.glb`` gives the eye patches the whole photo gives (within
            a few grey levels in a few pixels, on 11 test photos); at 0.15
            they differ by up to 186 (docs/face_model.md, "Texture margin").
            The crop keeps the photo's resolution: a wider margin only adds
            pixels (and file size).
        reconstruction: ``"auto"`` (default) uses the face model's triangles
            when it has them; otherwise ``"bpa+fill"`` (Ball-Pivoting, then
            its holes closed), or ``"delaunay"`` for models of fewer than
            :data:`~facemesh.reconstruct.MIN_SURFACE_POINTS` points. One of
            :data:`~facemesh.reconstruct.SURFACE_METHODS` always reconstructs
            with that method (:func:`facemesh.reconstruct.reconstruct_surface`);
            ``"ball_pivoting"`` is accepted for ``"bpa"``.
        ball_pivoting: settings of Ball-Pivoting (``bpa``, ``bpa+fill``).
        poisson: settings of ``poisson``.
    """

    vertex_placement: str = "backprojected"
    texture_margin: float = 0.6
    reconstruction: str = "auto"
    ball_pivoting: BallPivotingSettings = field(default_factory=BallPivotingSettings)
    poisson: PoissonSettings = field(default_factory=PoissonSettings)

    def __post_init__(self) -> None:
        if self.vertex_placement not in VERTEX_PLACEMENTS:
            raise InputError(f"vertex placement: expected one of {VERTEX_PLACEMENTS}, got {self.vertex_placement!r}")
        if self.reconstruction == "ball_pivoting":  # the name before the other methods existed
            object.__setattr__(self, "reconstruction", "bpa")
        if self.reconstruction not in ("auto", *SURFACE_METHODS):
            raise InputError(
                f"reconstruction: expected one of {('auto', *SURFACE_METHODS)}, got {self.reconstruction!r}"
            )
        if not (0.0 <= self.texture_margin <= 2.0):
            raise InputError(f"texture margin: expected 0..2, got {self.texture_margin}")


def place_vertices(
    placement: str,
    landmarks: FaceLandmarks,
    model: FaceModel,
    pose: HeadPose,
    camera: CameraIntrinsics,
) -> NDArray[np.float64]:
    """Mesh vertices for one face (see the module docstring for the placements).

    Returns:
        (N, 3) float64, mm, OpenCV camera frame; N = the model's point count,
        vertex i for landmark i.
    """
    n = model.num_points
    posed = pose.head_to_camera(model.vertices_mm)
    if placement == "canonical":
        return posed
    rays = undistort_to_rays(landmarks.points_px[:n], camera)
    if placement == "backprojected":
        depth = posed[:, 2]
    elif placement == "landmarks3d":
        if landmarks.points_3d is None:
            raise InputError(
                "vertex placement 'landmarks3d' needs a landmark model with 3D output; "
                f"{landmarks.model_name!r} has none"
            )
        z_rel = landmarks.points_3d[:n, 2]
        mean_depth = float(posed[:, 2].mean())
        mm_per_px = mean_depth / camera.focal_px[0]
        depth = mean_depth + (z_rel - z_rel.mean()) * mm_per_px
    else:
        raise InputError(f"vertex placement: expected one of {VERTEX_PLACEMENTS}, got {placement!r}")
    if np.any(depth <= 0):
        raise InputError("vertex placement: some vertices would lie behind the camera")
    return rays * depth[:, None]


def crop_texture(
    image_rgb: NDArray[np.uint8], points_px: ArrayLike, margin: float
) -> tuple[NDArray[np.uint8], tuple[int, int]]:
    """Crop the image to the points' bounding box plus a margin (clipped to the image).

    Args:
        image_rgb: (H, W, 3) uint8 RGB.
        points_px: (N, 2) float, pixels, image frame: what the texture must hold
            (the landmarks, or a mesh's projected vertices).
        margin: added on every side, as a fraction of the box's larger side.

    The crop's top-left corner is rounded down to a multiple of
    :data:`TEXTURE_ALIGN` pixels, so that the texture's image pyramid
    (``cv2.pyrDown`` levels, used for anti-aliased sampling) samples the same
    points as the pyramid of the whole image.

    Returns:
        ``(texture, (x0, y0))``: (h, w, 3) uint8 RGB and its top-left pixel in the image.
    """
    h, w = image_rgb.shape[:2]
    pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    (x0, y0), (x1, y1) = pts.min(axis=0), pts.max(axis=0)
    pad = margin * max(x1 - x0, y1 - y0)
    ix0 = max(0, int(math.floor(x0 - pad)) // TEXTURE_ALIGN * TEXTURE_ALIGN)
    iy0 = max(0, int(math.floor(y0 - pad)) // TEXTURE_ALIGN * TEXTURE_ALIGN)
    ix1 = min(w, int(math.ceil(x1 + pad)) + 1)
    iy1 = min(h, int(math.ceil(y1 + pad)) + 1)
    if ix1 <= ix0 or iy1 <= iy0:
        raise InputError("landmarks: the face lies outside the image")
    return np.ascontiguousarray(image_rgb[iy0:iy1, ix0:ix1]), (ix0, iy0)


def texture_uv(
    points_mm: ArrayLike, camera: CameraIntrinsics, texture_origin_px: tuple[int, int], texture_size_wh: tuple[int, int]
) -> NDArray[np.float64]:
    """GlTF texture coordinates of camera-frame points in a texture cropped from that camera's image.

    For vertices that are not landmarks (Poisson's, the renderer's background
    rings): each is textured with the photo's pixel it projects onto.

    Args:
        points_mm: (K, 3) float, mm, OpenCV camera frame of ``camera``.
        camera: the source image's camera (with its distortion).
        texture_origin_px: (x0, y0), the image pixel that is the texture's top-left.
        texture_size_wh: (width, height) of the texture, pixels.

    Returns:
        (K, 2) float64 glTF uv.
    """
    return pixels_to_uv(project_points(points_mm, camera), texture_origin_px, texture_size_wh)


def build_face_mesh(
    image_rgb: NDArray[np.uint8],
    landmarks: FaceLandmarks,
    model: FaceModel,
    camera: CameraIntrinsics,
    settings: BuildSettings | None = None,
    extras: Mapping[str, Any] | None = None,
    pose: HeadPose | None = None,
) -> FaceMesh:
    """Solve the head pose (unless given) and build the textured mesh of one face.

    Args:
        image_rgb: (H, W, 3) uint8 RGB, the image the landmarks were found in.
        landmarks: (L >= N) landmarks; the first N correspond to the model's points.
        model: the N-point face model (mm, head frame).
        camera: the image's camera.
        settings: see :class:`BuildSettings`.
        extras: JSON-serialisable metadata to carry into the asset.
        pose: the head pose already solved from these landmarks with this model and camera
            (skips solving it again).

    Raises:
        InputError: mismatched sizes or settings; PoseError: PnP failed.
    """
    s = settings or BuildSettings()
    h, w = image_rgb.shape[:2]
    if camera.image_size != (w, h):
        raise InputError(f"camera is for {camera.image_size[0]}x{camera.image_size[1]} images, the image is {w}x{h}")
    n = model.num_points
    if landmarks.num_points < n:
        raise InputError(f"landmarks: {landmarks.num_points} points, but face model {model.name!r} has {n}")
    if pose is None:
        pose = solve_head_pose(landmarks.points_px[:n], model.vertices_mm, camera)
    vertices = place_vertices(s.vertex_placement, landmarks, model, pose, camera)
    reconstruction: dict[str, Any] = {}
    appended = np.zeros((0, 3))
    if model.triangles is not None and s.reconstruction == "auto":
        triangles = np.asarray(model.triangles)
    else:
        method = s.reconstruction
        if method == "auto":
            method = SURFACE_METHODS[0] if n >= MIN_SURFACE_POINTS else "delaunay"
        rec = reconstruct_surface(
            vertices,
            method,
            viewpoint_mm=(0.0, 0.0, 0.0),
            forward=face_forward(pose.rotation),
            ball_pivoting_settings=s.ball_pivoting,
            poisson_settings=s.poisson,
        )
        triangles, appended = rec.triangles, rec.appended_vertices_mm
        reconstruction = rec.as_metadata()
    texture, origin = crop_texture(image_rgb, landmarks.points_px, s.texture_margin)
    uv = pixels_to_uv(landmarks.points_px[:n], origin, (texture.shape[1], texture.shape[0]))
    if len(appended):  # vertices the surface added after the landmarks' own: textured where they project
        vertices = np.concatenate([vertices, appended])
        uv = np.concatenate([uv, texture_uv(appended, camera, origin, (texture.shape[1], texture.shape[0]))])
    return FaceMesh(
        vertices_mm=vertices,
        triangles=triangles,
        uv=uv,
        texture=texture,
        texture_origin_px=origin,
        landmarks=landmarks,
        camera=camera,
        pose=pose,
        face_model_name=model.name,
        vertex_placement=s.vertex_placement,
        reconstruction=reconstruction,
        extras=dict(extras or {}),
        model_vertices_mm=model.vertices_mm,
        model_keypoints=model.keypoints,
    )


# --------------------------------------------------------------------------- other libraries: Open3D, trimesh

#: Frames :func:`to_open3d` and :func:`to_trimesh` can give the vertices in
#: (names as in :mod:`facemesh.conventions`).
INTEROP_FRAMES = ("gltf", "camera")


def _interop_geometry(
    mesh: FaceMesh, frame: str
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Vertices, vertex normals and the glTF uv of ``mesh`` for another library.

    Returns:
        ``(vertices, normals, uv)``: (N, 3) float64 vertices in ``frame``
        (``"gltf"``: metres, glTF frame, the float32 values a ``.glb`` of this
        mesh stores, exactly; ``"camera"``: ``mesh.vertices_mm`` as they are,
        millimetres, OpenCV camera frame); (N, 3) float64 unit area-weighted
        vertex normals in the same frame (the ``.glb``'s ``NORMAL`` values);
        (N, 2) float64 glTF uv (origin top-left).

    Raises:
        InputError: ``frame`` is not one of :data:`INTEROP_FRAMES`.
    """
    from .gltf import _vertex_normals  # the writer's own normals: the file's NORMAL accessor

    if frame not in INTEROP_FRAMES:
        raise InputError(f"frame: expected one of {INTEROP_FRAMES}, got {frame!r}")
    # As save_glb writes them: glTF frame, metres, rounded to float32.
    gltf_m = opencv_to_gltf_points(mesh.vertices_mm).astype(np.float32).astype(np.float64)
    normals = _vertex_normals(gltf_m, np.asarray(mesh.triangles)).astype(np.float64)
    if frame == "gltf":
        return gltf_m, normals, np.asarray(mesh.uv, dtype=np.float64)
    # The axis change is its own inverse and a rotation: normals map like points.
    return np.array(mesh.vertices_mm, dtype=np.float64), gltf_to_opencv_directions(normals), np.asarray(mesh.uv)


def to_open3d(mesh: FaceMesh, *, frame: str = "gltf") -> open3d.geometry.TriangleMesh:
    """The mesh as an Open3D ``TriangleMesh`` whose vertex i is ``mesh`` vertex i (landmark i).

    What Open3D's own glTF reader (``o3d.io.read_triangle_mesh``) builds from
    this mesh's ``.glb``, in the file's vertex order instead of a shuffled one:

    * ``vertices``: (N, 3) float64. ``frame="gltf"`` (default): metres, glTF
      frame (x right, y up, z toward the viewer; :mod:`facemesh.conventions`),
      exactly the float32 values of the ``.glb``'s ``POSITION`` accessor.
      ``frame="camera"``: millimetres, OpenCV camera frame of the source
      camera (x right, y down, z forward), exactly ``mesh.vertices_mm``.
    * ``triangles``: (M, 3) int32, ``mesh.triangles`` (same rows, same
      winding: counter-clockwise seen from the camera, so normals face it).
    * ``vertex_normals``: (N, 3) float64 unit, area-weighted, in ``frame``
      (the ``.glb``'s ``NORMAL`` values).
    * ``triangle_uvs``: (3M, 2) float64, the uv of each triangle's corners,
      in Open3D's convention (origin bottom-left, v up), as its glTF reader
      converts them: ``(u, 1 - v)`` of the glTF uv
      (:func:`~facemesh.conventions.gltf_uv_to_bottom_left_uv`), with
      ``textures[0]`` the texture flipped upside down
      (so both flips cancel and every corner samples the same texel).
    * ``textures``: ``[o3d.geometry.Image]``, (H, W, 3) uint8 RGB;
      ``triangle_material_ids``: (M,) int32 zeros.

    Args:
        mesh: any face mesh.
        frame: ``"gltf"`` or ``"camera"`` (see above).

    Raises:
        InputError: unknown ``frame``. ImportError: open3d is not installed.
    """
    import open3d as o3d

    vertices, normals, uv = _interop_geometry(mesh, frame)
    tri = np.asarray(mesh.triangles, dtype=np.int64)
    out = o3d.geometry.TriangleMesh()
    out.vertices = o3d.utility.Vector3dVector(np.ascontiguousarray(vertices))
    out.triangles = o3d.utility.Vector3iVector(np.ascontiguousarray(tri.astype(np.int32)).reshape(-1, 3))
    out.vertex_normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals))
    out.triangle_uvs = o3d.utility.Vector2dVector(np.ascontiguousarray(gltf_uv_to_bottom_left_uv(uv[tri.reshape(-1)])))
    out.triangle_material_ids = o3d.utility.IntVector(np.zeros(len(tri), dtype=np.int32))
    texture_rows_flipped: Any = np.ascontiguousarray(mesh.texture[::-1])  # Any: numpy 1 arrays are not typed as Buffer
    out.textures = [o3d.geometry.Image(texture_rows_flipped)]
    return out


def to_trimesh(mesh: FaceMesh, *, frame: str = "gltf") -> trimesh.Trimesh:
    """The mesh as a ``trimesh.Trimesh`` whose vertex i is ``mesh`` vertex i (landmark i).

    Built with ``process=False, maintain_order=True``: no vertex is merged,
    dropped or moved.

    * ``vertices``: (N, 3) float64, in ``frame`` as for :func:`to_open3d`
      (default ``"gltf"``: metres, glTF frame, the ``.glb``'s float32
      ``POSITION`` values exactly; ``"camera"``: millimetres, OpenCV camera
      frame, ``mesh.vertices_mm``).
    * ``faces``: (M, 3) int64, ``mesh.triangles`` (counter-clockwise seen from
      the camera).
    * ``vertex_normals``: (N, 3) float64 unit, area-weighted, in ``frame``.
    * ``visual``: ``trimesh.visual.TextureVisuals`` with ``uv`` (N, 2) float64
      in trimesh's convention, as its glTF loader converts them: ``(u, 1 - v)``
      of the glTF uv (origin at the bottom-left, v up;
      :func:`~facemesh.conventions.gltf_uv_to_bottom_left_uv`); its material a
      ``PBRMaterial`` (base colour texture: the (H, W, 3) uint8 RGB texture as
      a PIL image, top row first; metallic 0, roughness 1), like the ``.glb``'s.

    Args:
        mesh: any face mesh.
        frame: ``"gltf"`` or ``"camera"``.

    Raises:
        InputError: unknown ``frame``. ImportError: trimesh or Pillow is not installed.
    """
    import trimesh as tm
    from PIL import Image

    vertices, normals, uv = _interop_geometry(mesh, frame)
    material = tm.visual.material.PBRMaterial(
        name="face",
        baseColorTexture=Image.fromarray(np.ascontiguousarray(mesh.texture), mode="RGB"),
        metallicFactor=0.0,
        roughnessFactor=1.0,
    )
    visual = tm.visual.TextureVisuals(uv=gltf_uv_to_bottom_left_uv(uv), material=material)
    return tm.Trimesh(
        vertices=vertices,
        faces=np.asarray(mesh.triangles, dtype=np.int64),
        vertex_normals=normals,
        visual=visual,
        process=False,
        maintain_order=True,
    )
