"""Helpers shared by several test modules (not fixtures: plain functions that build small inputs)."""

from __future__ import annotations

import importlib.util
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from gazeaug.io_h5 import H5Writer, Rows


def synthetic_h5(path, n=96, subjects=("a", "b"), nan_rows=0, seed=0, face_size=None, runs=False):
    """A training set whose gaze pitch is readable from the images: brightness encodes it.

    The rows' subjects alternate, or with ``runs`` come one after another (each a run of
    ``n / len(subjects)`` rows, as augment writes them: source by source).

    With ``face_size`` (width, height) the rows carry face patches too (``face``), whose brightness
    encodes the gaze yaw, and the normalization record says so.
    """
    rng = np.random.default_rng(seed)
    gaze = rng.uniform(-0.4, 0.4, (n, 2)).astype(np.float32)
    level = (128 + 250 * gaze[:, 0]).clip(0, 255)
    eyes = (level[:, None, None, None] + rng.normal(0, 3, (n, 36, 60, 3))).clip(0, 255).astype(np.uint8)
    head = rng.uniform(-0.3, 0.3, (n, 2)).astype(np.float32)
    if nan_rows:
        gaze[:nan_rows] = np.nan
    eye3 = np.tile(np.eye(3, dtype=np.float32), (n, 1, 1))
    rows = Rows(
        {
            "left_eye": eyes,
            "right_eye": eyes,
            "head_pose": head,
            "gaze": gaze,
            "head_pose_vector": np.zeros((n, 3)),
            "gaze_vector": np.zeros((n, 3)),
            "head_pose_left": head,
            "head_pose_right": head,
            "gaze_left": gaze,
            "gaze_right": gaze,
            "R_norm_left": eye3,
            "R_norm_right": eye3,
            "R_norm_face": eye3,
            "subject": np.array(
                [subjects[i * len(subjects) // n if runs else i % len(subjects)].encode() for i in range(n)]
            ),
            "source_index": np.arange(n),
            "sampled_yaw_pitch": np.full((n, 2), np.nan),
        }
    )
    norm = {"distance_mm": 600.0, "focal_px": 650.0, "patch_size_wh": [60, 36], "antialias": True}
    if face_size is not None:
        fw, fh = face_size
        face_level = (128 + 250 * gaze[:, 1]).clip(0, 255)
        face = (face_level[:, None, None, None] + rng.normal(0, 3, (n, fh, fw, 3))).clip(0, 255).astype(np.uint8)
        rows = Rows({**rows.arrays, "face": face})
        norm.update(face_patch_size_wh=[fw, fh], face_distance_mm=600.0, face_focal_px=960.0)
    w = H5Writer(path, {"settings": {"normalization": norm}}, (60, 36), face_patch_size_wh=face_size)
    w.append(rows, n - 1)
    w.finish()
    return path


def mutations(valid: bytes, seed: int, n: int = 24) -> list[bytes]:
    """Damaged versions of a valid file: empty, truncated, random, odd tokens, flipped bytes (seeded)."""
    rng = np.random.default_rng(seed)
    out = [b"", valid[: len(valid) // 2], valid[:1], rng.bytes(64), b"\x00" * 100, b"\xff\xfe" + valid]
    text = valid.decode("utf-8", errors="replace")
    for token in ("1e308", "1e999", "-nan", "[]", "{}", '"x"', "null", "true", "9" * 400):
        out.append(text.replace("0", token, 1).encode())
    while len(out) < n:
        b = bytearray(valid)
        for _ in range(int(rng.integers(1, 6))):
            b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
        out.append(bytes(b))
    return out


def expect_typed_error(load, path: Path, data: bytes):
    """Write ``data`` to ``path`` and load it: a typed error (or success), never another exception."""
    from facemesh.types import FaceMeshError

    path.write_bytes(data)
    try:
        load(path)
    except FaceMeshError as exc:
        assert str(exc).strip(), repr(exc)  # the CLIs print it on one line
    except Exception as exc:  # pragma: no cover - the failure this test exists for
        pytest.fail(f"{path.name} with {data[:40]!r}...: {exc.__class__.__name__}: {exc}")


def is_synthetic(sample: Path) -> bool:
    """Whether an ``mpii_sample`` folder is :func:`synthetic_mpii_sample`'s stand-in, not the real p00 frame."""
    import json

    return json.loads((sample / "annotation.json").read_text())["source"].startswith("synthetic")


def synthetic_mpii_sample(folder: Path, detector) -> Path:
    """A stand-in for ../shared's MPIIFaceGaze p00 frame, in its exact layout, made from the built-in photo.

    ``day01_0087.png`` (the 512 x 512 built-in photo as it is: MediaPipe's short-range detector
    misses its face once it is a small part of a larger frame, or after JPEG coding),
    ``cameraCalib.xml`` (OpenCV FileStorage ``camera_matrix``, ``cam_distortion``: f = 600 px,
    principal point (250, 258), k1 = -0.05), ``faceModelGeneric.txt`` (3 x 6, mm: the built-in
    face model's four eye corners, image left to right, then the two mouth corners) and
    ``annotation.json`` (MediaPipe's landmarks at those six points, a gaze target in mm).
    """
    import json

    import cv2

    from facemesh.build import sample_image
    from facemesh.face_models import KEYPOINTS, builtin_face_model
    from facemesh.io import save_image_rgb

    folder.mkdir(parents=True, exist_ok=True)
    image = sample_image()
    save_image_rgb(folder / "day01_0087.png", image)
    fs = cv2.FileStorage(str(folder / "cameraCalib.xml"), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", np.array([[600.0, 0, 250], [0, 600.0, 258], [0, 0, 1]]))
    fs.write("cam_distortion", np.array([[-0.05, 0.0, 0.0, 0.0, 0.0]]))
    fs.release()
    kp = KEYPOINTS["mediapipe"]
    six = [*kp.right_eye, *kp.left_eye, *(kp.mouth or ())]  # MPII's order: eye corners left to right, mouth
    np.savetxt(folder / "faceModelGeneric.txt", builtin_face_model().vertices_mm[six].T)
    (face,) = detector.detect(image)[:1]
    annotation = {
        "source": "synthetic stand-in for the MPIIFaceGaze p00 example (tests/helpers.py)",
        "image": "day01_0087.png",
        "image_size_wh": [512, 512],
        "landmarks_6_px": np.round(face.points_px[six], 1).tolist(),
        "gaze_target_3d_camera_mm": [-60.0, 20.0, -10.0],
    }
    (folder / "annotation.json").write_text(json.dumps(annotation, indent=1))
    return folder


def unprivileged_prefix() -> list[str]:
    """A command prefix that makes file permissions bind (root ignores them), or skip the test."""
    import shutil

    if os.geteuid() != 0:
        return []
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: file permissions cannot be made to bind")
    return ["setpriv", "--bounding-set=-dac_override,-dac_read_search"]


def default_sigint() -> None:
    """``preexec_fn`` for a child a test interrupts: SIGINT delivered as a terminal's Ctrl-C delivers it.

    A suite started as a shell's background job begins with SIGINT ignored, and Python keeps an
    ignored SIGINT ignored: without this the child would finish its run instead of stopping.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def benchmark_module(name: str):
    """``benchmarks/NAME.py`` imported as a module (the scripts are not a package), its top level run once."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"bench_{name}", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
