"""facemesh: textured 3D face meshes from any landmark model, saved as glTF.

The stages compose: landmarks -> head pose -> mesh -> asset::

    import facemesh
    from facemesh.landmarks import MediaPipeFaceMesh

    image = facemesh.load_image_rgb("face.jpg")
    camera = facemesh.camera_for_image(None, image.shape[1], image.shape[0])
    with MediaPipeFaceMesh() as detector:
        mesh = facemesh.build_mesh(image, camera, detector)
    facemesh.save(mesh, "face.glb")
    same = facemesh.load("face.glb")  # a FaceMesh again: vertex i = landmark i
    o3d_mesh = same.to_open3d()  # any FaceMesh; keeps that order (Open3D's own .glb readers do not)
    tm_mesh = same.to_trimesh()

Conventions (frames, axes, angles, units) are in :mod:`facemesh.conventions`.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("gazeaug")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"

from .build import build_mesh, sample_image
from .camera import camera_for_image, default_camera, load_camera
from .face_models import builtin_face_model, load_face_model
from .gltf import load_glb as load
from .gltf import save_glb as save
from .io import load_image_rgb
from .mesh import BuildSettings, build_face_mesh
from .pose import solve_head_pose
from .types import (
    CameraIntrinsics,
    FaceLandmarks,
    FaceMesh,
    FaceMeshError,
    FaceModel,
    HeadPose,
    InputError,
    NoFaceError,
)

__all__ = [
    "__version__",
    "build_mesh",
    "sample_image",
    "camera_for_image",
    "default_camera",
    "load_camera",
    "builtin_face_model",
    "load_face_model",
    "load",
    "save",
    "load_image_rgb",
    "BuildSettings",
    "build_face_mesh",
    "solve_head_pose",
    "CameraIntrinsics",
    "FaceLandmarks",
    "FaceMesh",
    "FaceMeshError",
    "FaceModel",
    "HeadPose",
    "InputError",
    "NoFaceError",
]
