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


def _missing_shared(what: str) -> None:
    """Skip (a newcomer's clone without ../shared) or, under CI, fail: CI always has it."""
    message = f"shared test data not found ({what}; ../shared/data or $GAZEAUG_SHARED_DATA)"
    if os.environ.get("CI"):
        pytest.fail(f"{message}: CI runs beside ../shared, so its absence is an error")
    pytest.skip(message)


@pytest.fixture(scope="session")
def shared_data() -> Path:
    path = shared_data_dir()
    if path is None:
        _missing_shared("shared_data")
    assert path is not None
    return path


@pytest.fixture(scope="session")
def faces_dir(tmp_path_factory) -> Path:
    """../shared/data/faces, or without it a folder with the one photo every install has (the astronaut)."""
    path = shared_data_dir()
    if path is not None:
        return path / "faces"
    if os.environ.get("CI"):
        _missing_shared("faces")
    from facemesh.build import sample_image
    from facemesh.io import save_image_rgb

    folder = tmp_path_factory.mktemp("faces")
    save_image_rgb(folder / "astronaut.png", sample_image())  # the same picture as shared/faces/astronaut.png
    return folder


def face_photo(faces_dir: Path, name: str, *, any_face: bool = False) -> Path:
    """The photo ``name`` of :func:`faces_dir`; without ../shared, skip, or with ``any_face`` take the astronaut.

    ``any_face``: the test needs a photo with one face, not this one in particular.
    """
    path = faces_dir / name
    if not path.is_file():
        if any_face:
            return faces_dir / "astronaut.png"
        _missing_shared(f"faces/{name}")
    return path


@pytest.fixture(scope="session")
def reference_model_path(shared_data: Path) -> Path:
    path = shared_data / "reference" / "mediapipe_face_geometry" / "canonical_face_model.obj"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return path


@pytest.fixture(scope="session")
def mpii_sample(tmp_path_factory, detector) -> Path:
    """The real MPIIFaceGaze p00 frame of ../shared, or without it a synthetic one in the same layout.

    The synthetic sample (tests/helpers.py: ``synthetic_mpii_sample``) is the built-in photo on a
    1280 x 720 canvas with a synthetic calibration, the built-in model's six key points as
    ``faceModelGeneric.txt`` and MediaPipe's landmarks at them. Tests of the real frame's own
    numbers ask for :func:`real_mpii_sample` instead.
    """
    shared = shared_data_dir()
    if shared is not None:
        path = shared / "gaze" / "mpiifacegaze_p00_example"
        if not path.is_dir():
            pytest.fail(f"{path} not found in ../shared/data")
        return path
    if os.environ.get("CI"):
        _missing_shared("mpiifacegaze_p00_example")
    from helpers import synthetic_mpii_sample

    return synthetic_mpii_sample(tmp_path_factory.mktemp("mpii_synthetic"), detector)


@pytest.fixture(scope="session")
def real_mpii_sample(shared_data: Path) -> Path:
    """The real MPIIFaceGaze p00 frame (tests of its own numbers)."""
    path = shared_data / "gaze" / "mpiifacegaze_p00_example"
    if not path.is_dir():
        pytest.fail(f"{path} not found in ../shared/data")
    return path


@pytest.fixture(scope="session")
def detector():
    from facemesh.landmarks import MediaPipeFaceMesh

    det = MediaPipeFaceMesh(refine_landmarks=True)
    yield det
    det.close()


#: Single-face photos of ../shared/data/faces used for pose and fidelity checks.
SINGLE_FACE_PHOTOS = ("astronaut.png", "business-person.png", "sergey.png", "pexels/image00.jpg", "pexels/image01.jpg")
