"""Shared fixtures: the test data in ../shared/data and one MediaPipe detector per session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path | None:
    """``$GAZEAUG_SHARED_DATA`` or ``../shared/data`` beside the repository, if it exists."""
    env = os.environ.get("GAZEAUG_SHARED_DATA")
    path = Path(env) if env else REPO.parent / "shared" / "data"
    return path if path.is_dir() else None


@pytest.fixture(scope="session")
def shared_data() -> Path:
    path = shared_data_dir()
    if path is None:
        pytest.skip("shared test data not found (../shared/data or $GAZEAUG_SHARED_DATA)")
    return path


@pytest.fixture(scope="session")
def reference_model_path(shared_data: Path) -> Path:
    path = shared_data / "reference" / "mediapipe_face_geometry" / "canonical_face_model.obj"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return path


@pytest.fixture(scope="session")
def mpii_sample(shared_data: Path) -> Path:
    path = shared_data / "gaze" / "mpiifacegaze_p00_example"
    if not path.is_dir():
        pytest.skip(f"{path} not found")
    return path


@pytest.fixture(scope="session")
def detector():
    from facemesh.landmarks import MediaPipeFaceMesh

    det = MediaPipeFaceMesh(refine_landmarks=True)
    yield det
    det.close()


#: Single-face photos of ../shared/data/faces used for pose and fidelity checks.
SINGLE_FACE_PHOTOS = ("astronaut.png", "business-person.png", "sergey.png", "pexels/image00.jpg", "pexels/image01.jpg")
