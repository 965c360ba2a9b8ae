"""Shared fixtures: the test data in ../shared/data and one MediaPipe detector per session."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _no_debug_tracebacks(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tests see the command lines as users do: a GAZEAUG_DEBUG set in the caller's shell (which adds
    tracebacks to their one-line errors) is removed; a test that wants it sets it itself."""
    monkeypatch.delenv("GAZEAUG_DEBUG", raising=False)


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
def two_faces_photo(faces_dir, tmp_path_factory) -> Path:
    """A photo with two faces of different sizes: two_children.jpeg, or without ../shared two astronauts.

    The stand-in: the built-in photo's face (a 220 px square around it) beside a 0.7x copy, on grey,
    as PNG (MediaPipe's detector misses the astronaut's face in a larger frame or after JPEG coding).
    """
    path = faces_dir / "two_children.jpeg"
    if path.is_file():
        return path
    if os.environ.get("CI"):
        _missing_shared("faces/two_children.jpeg")
    import cv2

    from facemesh.build import sample_image
    from facemesh.io import save_image_rgb

    face = sample_image()[14:234, 114:334]  # the face spans about x 178-270, y 71-177
    small = cv2.resize(face, None, fx=0.7, fy=0.7, interpolation=cv2.INTER_AREA)
    canvas = np.full((220, 220 + small.shape[1], 3), 128, np.uint8)
    canvas[:, :220] = face
    top = (220 - small.shape[0]) // 2
    canvas[top : top + small.shape[0], 220:] = small
    path = tmp_path_factory.mktemp("two_faces") / "two_astronauts.png"
    save_image_rgb(path, canvas)
    return path


@pytest.fixture(scope="session")
def reference_model_path(shared_data: Path) -> Path:
    path = shared_data / "reference" / "mediapipe_face_geometry" / "canonical_face_model.obj"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return path


@pytest.fixture(scope="session")
def face_model_obj(tmp_path_factory) -> Path:
    """A face-model OBJ file: MediaPipe's canonical_face_model.obj of ../shared, or the built-in model exported.

    For tests that need *a* face model file; comparisons with MediaPipe's reference ask for
    :func:`reference_model_path`.
    """
    shared = shared_data_dir()
    if shared is not None:
        path = shared / "reference" / "mediapipe_face_geometry" / "canonical_face_model.obj"
        if not path.is_file():
            pytest.fail(f"{path} not found in ../shared/data")
        return path
    if os.environ.get("CI"):
        _missing_shared("canonical_face_model.obj")
    from facemesh.face_models import builtin_face_model, export_obj

    path = tmp_path_factory.mktemp("face_model") / "builtin_face_model.obj"
    path.write_text(export_obj(builtin_face_model()))
    return path


@pytest.fixture(scope="session")
def mpii_sample(tmp_path_factory, detector) -> Path:
    """The real MPIIFaceGaze p00 frame of ../shared, or without it a synthetic one in the same layout.

    The synthetic sample (tests/helpers.py: ``synthetic_mpii_sample``) is the built-in 512 x 512
    photo as PNG with a synthetic calibration, the built-in model's six key points as
    ``faceModelGeneric.txt`` and MediaPipe's landmarks at them. Its sizes come from its
    ``annotation.json`` like the real frame's; ``helpers.is_synthetic`` tells the two apart. Tests
    of the real frame's own numbers ask for :func:`real_mpii_sample` instead.
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
