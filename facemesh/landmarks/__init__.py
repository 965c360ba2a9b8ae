"""Landmark models: the interface, MediaPipe Face Mesh, and user-supplied arrays."""

from .base import LandmarkModel, select_face
from .from_arrays import ArrayLandmarkModel, load_landmarks_file
from .mediapipe import MediaPipeFaceMesh

__all__ = ["LandmarkModel", "select_face", "ArrayLandmarkModel", "load_landmarks_file", "MediaPipeFaceMesh"]
