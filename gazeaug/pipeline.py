"""From an image (or a saved mesh) to what the gazeaug stages need: landmarks, pose, face model, mesh.

The input path itself (image and camera, detector, face, pose) is facemesh's
(:mod:`facemesh.build`), shared with ``facemesh build``, and so are its mesh
settings: a photo rendered directly builds the same mesh, with the same texture
margin, as the ``.glb`` that ``facemesh build`` writes of it, so the two render
alike (the margin is wide enough for the renderer's background rings:
:class:`facemesh.mesh.BuildSettings`).
"""

from __future__ import annotations

from pathlib import Path

from facemesh.build import FaceFit, fit_face, landmark_model_for, load_input
from facemesh.build import mesh_for_fit as _mesh_for_fit
from facemesh.landmarks.base import LandmarkModel
from facemesh.mesh import BuildSettings
from facemesh.types import FaceMesh

__all__ = [
    "FaceFit",
    "MESH_SETTINGS",
    "load_input",
    "landmark_model_for",
    "default_landmark_model",
    "fit_face",
    "mesh_for_fit",
    "load_mesh",
]

#: Mesh settings for augmentation: facemesh's defaults (``facemesh build``'s), so that
#: rendering a photo and rendering its ``.glb`` agree.
MESH_SETTINGS = BuildSettings()


def default_landmark_model() -> LandmarkModel:
    """MediaPipe Face Mesh, the landmark model every dataset run uses."""
    from facemesh.landmarks.mediapipe import MediaPipeFaceMesh

    return MediaPipeFaceMesh()


def mesh_for_fit(fit: FaceFit, settings: BuildSettings = MESH_SETTINGS) -> FaceMesh:
    """The textured mesh of a fitted face, at the fit's pose (not solved again), for augmentation."""
    return _mesh_for_fit(fit, settings)


def load_mesh(path: str | Path) -> FaceMesh:
    """A face mesh saved by ``facemesh build`` (.glb)."""
    from facemesh.gltf import load_glb

    return load_glb(path)
