"""Hostile inputs: huge images, broken calibrations, mismatched face models, implausible fits, native log noise.

Every bad input must end as a typed error (``InputError`` / ``PoseError`` /
``GazeAugError``, all ``FaceMeshError``) whose message names the file, and on
the command lines as exit code 2 with one ``error:`` line and no traceback.
Expected values are reasoned out here (image sizes, pixel limits, face
sizes in pixels), not read back from the code.
"""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import sys
import warnings
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from facemesh.build import build_mesh, sample_image
from facemesh.camera import default_camera, load_camera
from facemesh.face_models import builtin_face_model
from facemesh.io import load_image_rgb
from facemesh.pose import PoseError, project_points, solve_head_pose
from facemesh.types import CameraIntrinsics, FaceMeshError, FaceModel, InputError

REPO = Path(__file__).resolve().parents[1]


def _one_error_line(err: str, phrase: str) -> None:
    """stderr holds one ``error:`` line containing ``phrase``, otherwise only one-line warnings, and no traceback."""
    lines = [line for line in err.splitlines() if line.strip()]
    errors = [line for line in lines if "error:" in line]
    assert len(errors) == 1 and phrase in errors[0], err
    assert all("warning:" in line for line in lines if line not in errors), err
    assert "Traceback" not in err


def _facemesh_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    from facemesh.cli import main

    rc = main(args)
    return rc, capsys.readouterr().err


def _gazeaug_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    from gazeaug.cli import main

    rc = main(args)
    return rc, capsys.readouterr().err


# ---------------------------------------------------------------------------------------------------------------------
# 7. images above the pixel limit are refused from their header, before decoding


def _png_chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def _write_black_png(path: Path, width: int, height: int, bit_depth: int = 1) -> None:
    """A valid grey PNG of zeros, written row by row through zlib (never held whole in memory)."""
    row = bytes(1 + (width * bit_depth + 7) // 8)  # filter byte 0, then the packed zero pixels
    comp = zlib.compressobj(9)
    with path.open("wb") as fh:
        fh.write(b"\x89PNG\r\n\x1a\n")
        fh.write(_png_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, bit_depth, 0, 0, 0, 0)))
        parts = [comp.compress(row) for _ in range(height)]
        parts.append(comp.flush())
        fh.write(_png_chunk(b"IDAT", b"".join(parts)))
        fh.write(_png_chunk(b"IEND", b""))


def test_a_50000x50000_png_is_refused_from_its_header(tmp_path, capsys):
    from facemesh.io import MAX_IMAGE_PIXELS

    # 2.5 gigapixels: far above the documented limit (and above OpenCV's own, which used to raise cv2.error)
    assert MAX_IMAGE_PIXELS < 50000 * 50000
    p = tmp_path / "huge.png"
    _write_black_png(p, 50000, 50000)
    assert p.stat().st_size < 1_000_000  # small on disk: only decoding it would be a problem
    with pytest.raises(InputError) as info:
        load_image_rgb(p)
    msg = str(info.value)
    assert "huge.png" in msg and "50000x50000" in msg and "megapixel" in msg
    assert f"{MAX_IMAGE_PIXELS / 1e6:g}" in msg  # the limit is named
    rc, err = _facemesh_cli(["build", str(p), "-o", str(tmp_path / "out.glb")], capsys)
    assert rc == 2
    _one_error_line(err, "huge.png")
    assert not (tmp_path / "out.glb").exists()
    rc, err = _gazeaug_cli(["normalize", str(p), "-o", str(tmp_path / "out.npz")], capsys)
    assert rc == 2
    _one_error_line(err, "50000x50000")


def test_a_long_thin_image_is_refused_from_its_header(tmp_path, capsys):
    from facemesh.io import MAX_IMAGE_SIDE

    # 32767 x 32 is 1 megapixel, yet MediaPipe's detector aborts the process on such a side (SIGABRT)
    p = tmp_path / "strip.png"
    _write_black_png(p, 32767, 32)
    assert MAX_IMAGE_SIDE < 32767
    rc, err = _facemesh_cli(["build", str(p), "-o", str(tmp_path / "out.glb")], capsys)
    assert rc == 2
    _one_error_line(err, f"32767x32 pixels; a side above {MAX_IMAGE_SIDE} px is refused")
    assert not (tmp_path / "out.glb").exists()


def test_bytes_after_the_end_marker_are_not_a_truncation(tmp_path):
    # a phone's "motion photo" appends a video after the JPEG's EOI; some writers pad a PNG after IEND
    face_bgr = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    ok, jpg = cv2.imencode(".jpg", face_bgr)
    ok2, png = cv2.imencode(".png", face_bgr)
    assert ok and ok2
    for name, data in (("motion.jpg", jpg.tobytes() + b"ftypmp42" * 512), ("padded.png", png.tobytes() + bytes(100))):
        (tmp_path / name).write_bytes(data)
        assert load_image_rgb(tmp_path / name).shape == face_bgr.shape, name
    # a JPEG cut inside its scan is still refused, though its EXIF thumbnail (before the scan) has an EOI
    from PIL import Image

    thumb = io.BytesIO()
    Image.fromarray(face_bgr[..., ::-1]).resize((32, 32)).save(thumb, "JPEG")
    app1 = b"Exif\x00\x00" + thumb.getvalue()  # an APP1 segment that holds a whole JPEG, EOI included
    whole = jpg.tobytes()
    with_thumb = whole[:2] + b"\xff\xe1" + (len(app1) + 2).to_bytes(2, "big") + app1 + whole[2:]
    (tmp_path / "thumb.jpg").write_bytes(with_thumb)
    assert load_image_rgb(tmp_path / "thumb.jpg").shape == face_bgr.shape
    (tmp_path / "cut.jpg").write_bytes(with_thumb[: len(with_thumb) - len(whole) // 2])
    with pytest.raises(InputError, match="truncated"):
        load_image_rgb(tmp_path / "cut.jpg")


def _jpeg_with_orientation(path: Path, orientation: int, order: str) -> bytes:
    """A JPEG whose APP1 holds a hand-made TIFF header: IFD0 with one entry, tag 0x0112 (SHORT)."""
    ok, jpg = cv2.imencode(".jpg", np.full((40, 60, 3), 120, np.uint8))
    assert ok
    e = "<" if order == "II" else ">"
    tiff = order.encode() + struct.pack(e + "HI", 42, 8) + struct.pack(e + "H", 1)
    tiff += struct.pack(e + "HHIH2x", 0x0112, 3, 1, orientation) + struct.pack(e + "I", 0)
    app1 = b"Exif\x00\x00" + tiff
    data = jpg.tobytes()[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpg.tobytes()[2:]
    path.write_bytes(data)
    return data


def test_an_exif_orientation_is_read_and_named_not_applied(tmp_path):
    from facemesh.build import load_input
    from facemesh.io import exif_orientation

    for order in ("II", "MM"):  # little- and big-endian TIFF headers
        for value in (1, 3, 6, 8):
            p = tmp_path / f"o{value}{order}.jpg"
            _jpeg_with_orientation(p, value, order)
            assert exif_orientation(p) == value, (order, value)
    assert exif_orientation(tmp_path / "nope.jpg") == 1
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        image, _, _ = load_input(tmp_path / "o6MM.jpg", None)
    assert image.shape[:2] == (40, 60)  # read as stored, not turned
    said = [str(w.message) for w in seen if "EXIF orientation 6" in str(w.message)]
    assert len(said) == 1 and "not applied" in said[0] and "turned 90 deg clockwise" in said[0], said
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        load_input(tmp_path / "o1II.jpg", None)
    assert not [w for w in seen if "EXIF" in str(w.message)]


def test_an_image_within_opencv_limits_but_above_ours_is_not_decoded(tmp_path, monkeypatch):
    from facemesh.io import MAX_IMAGE_PIXELS

    # 12000 x 12000 = 144 megapixels: OpenCV (limit 2^30 pixels) would decode it into 432 MB of RGB
    side = 12000
    assert side * side > MAX_IMAGE_PIXELS
    p = tmp_path / "big.png"
    _write_black_png(p, side, side)

    def _no_decoding(*args, **kwargs):
        raise AssertionError("imdecode was called on an image above the limit")

    monkeypatch.setattr(cv2, "imdecode", _no_decoding)
    with pytest.raises(InputError, match=r"big\.png.*12000x12000"):
        load_image_rgb(p)


def _jpeg_with_size(width: int, height: int) -> bytes:
    """A real 64x48 JPEG whose SOF0 header is rewritten to claim ``width`` x ``height``."""
    ok, buf = cv2.imencode(".jpg", np.full((48, 64, 3), 128, np.uint8))
    assert ok
    data = bytearray(buf.tobytes())
    sof = data.find(b"\xff\xc0")
    assert sof > 0
    # SOF0: marker, length (2), precision (1), height (2), width (2)
    assert struct.unpack(">HH", data[sof + 5 : sof + 9]) == (48, 64)
    data[sof + 5 : sof + 9] = struct.pack(">HH", height, width)
    return bytes(data)


def test_a_jpeg_claiming_60000x60000_is_refused_from_its_sof(tmp_path, capsys):
    p = tmp_path / "claims_huge.jpg"
    p.write_bytes(_jpeg_with_size(60000, 60000))
    with pytest.raises(InputError, match=r"claims_huge\.jpg.*60000x60000.*megapixel"):
        load_image_rgb(p)
    rc, err = _facemesh_cli(["build", str(p), "-o", str(tmp_path / "out.glb")], capsys)
    assert rc == 2
    _one_error_line(err, "claims_huge.jpg")


def test_opencv_errors_while_decoding_become_input_errors(tmp_path, capsys):
    # A BMP header of 2,000,000 x 40 pixels (80 megapixels: within our limit), but wider than OpenCV
    # accepts (2^20 columns): cv2.imdecode raises cv2.error, which must not escape.
    info = struct.pack("<IiiHHIIiiII", 40, 2_000_000, 40, 1, 24, 0, 0, 2835, 2835, 0, 0)
    p = tmp_path / "wide.bmp"
    p.write_bytes(b"BM" + struct.pack("<IHHI", 54, 0, 0, 54) + info)
    with pytest.raises(InputError, match=r"wide\.bmp"):
        load_image_rgb(p)
    rc, err = _facemesh_cli(["build", str(p), "-o", str(tmp_path / "out.glb")], capsys)
    assert rc == 2
    _one_error_line(err, "wide.bmp")


def test_ordinary_images_still_load(tmp_path):
    img = sample_image()
    for suffix in (".png", ".jpg", ".bmp"):
        p = tmp_path / f"astronaut{suffix}"
        assert cv2.imwrite(str(p), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        out = load_image_rgb(p)
        assert out.shape == (512, 512, 3) and out.dtype == np.uint8
        assert np.abs(out.astype(int) - img).mean() < 5  # JPEG loses a little


# ---------------------------------------------------------------------------------------------------------------------
# 8. calibration files: mismatched rows/cols and fuzzing of every format

_K = [600.0, 0.0, 319.5, 0.0, 600.0, 239.5, 0.0, 0.0, 1.0]
_D = [0.1, -0.05, 0.0, 0.0, 0.0]

_XML = """<?xml version="1.0"?>
<opencv_storage>
<image_width>{w}</image_width>
<image_height>{h}</image_height>
<camera_matrix type_id="opencv-matrix">
  <rows>{rows}</rows>
  <cols>{cols}</cols>
  <dt>{dt}</dt>
  <data>
    {kdata}</data></camera_matrix>
<dist_coeffs type_id="opencv-matrix">
  <rows>1</rows>
  <cols>{dcols}</cols>
  <dt>d</dt>
  <data>
    {ddata}</data></dist_coeffs>
</opencv_storage>
"""

_YAML = """%YAML:1.0
---
image_width: {w}
image_height: {h}
camera_matrix: !!opencv-matrix
   rows: {rows}
   cols: {cols}
   dt: {dt}
   data: [ {kdata} ]
dist_coeffs: !!opencv-matrix
   rows: 1
   cols: {dcols}
   dt: d
   data: [ {ddata} ]
"""

_JSON = """{{
    "image_width": {w},
    "image_height": {h},
    "camera_matrix": {{
        "type_id": "opencv-matrix",
        "rows": {rows},
        "cols": {cols},
        "dt": "{dt}",
        "data": [ {kdata} ]
    }},
    "dist_coeffs": {{
        "type_id": "opencv-matrix",
        "rows": 1,
        "cols": {dcols},
        "dt": "d",
        "data": [ {ddata} ]
    }}
}}
"""

_FORMATS = {".xml": (_XML, " "), ".yml": (_YAML, ", "), ".json": (_JSON, ", ")}


def _calib_text(suffix: str, **over: object) -> str:
    template, sep = _FORMATS[suffix]
    k = over.pop("k", _K)
    d = over.pop("d", _D)
    fields = {"w": 640, "h": 480, "rows": 3, "cols": 3, "dt": "d", "dcols": len(d)}
    fields["kdata"] = sep.join(str(v) for v in k)
    fields["ddata"] = sep.join(str(v) for v in d)
    fields.update(over)
    return template.format(**fields)


@pytest.mark.parametrize("suffix", sorted(_FORMATS))
def test_valid_calibrations_in_every_format_still_load(tmp_path, suffix):
    p = tmp_path / f"calib{suffix}"
    p.write_text(_calib_text(suffix))
    cam = load_camera(p)
    np.testing.assert_allclose(cam.matrix.ravel(), _K)
    np.testing.assert_allclose(cam.distortion, _D)
    assert cam.image_size == (640, 480)


def test_shared_calibrations_read_as_opencv_reads_them(shared_data):
    calibs = shared_data / "gaze" / "calibrations"
    files = sorted(calibs.glob("eth_xgaze_cams_*/cam*.xml"))
    files.append(shared_data / "gaze" / "mpiifacegaze_p00_example" / "cameraCalib.xml")
    files = [f for f in files if f.is_file()]
    if not files:
        pytest.skip("no calibration files in the shared data")
    for f in files:
        fs = cv2.FileStorage(str(f), cv2.FILE_STORAGE_READ)
        try:
            node = next(fs.getNode(k) for k in ("Camera_Matrix", "camera_matrix") if not fs.getNode(k).empty())
            expected = node.mat()  # OpenCV's own reading of these well-formed files
        finally:
            fs.release()
        cam = load_camera(f, image_size=(1280, 720))
        np.testing.assert_array_equal(cam.matrix, expected)
    for f in sorted((calibs / "mpiifacegaze_cameras").glob("Camera*.mat")):
        from scipy.io import loadmat

        cam = load_camera(f, image_size=(1280, 720))
        np.testing.assert_array_equal(cam.matrix, loadmat(str(f))["cameraMatrix"])


@pytest.mark.parametrize("suffix", sorted(_FORMATS))
@pytest.mark.parametrize(
    "rows, cols, k",
    [
        (4, 4, _K),  # says 16 values, gives 9
        (3, 3, _K[:8]),  # says 9, gives 8
        (3, 3, _K + [1.0, 2.0]),  # says 9, gives 11
        (1, 3, _K),  # says 3, gives 9
    ],
)
def test_rows_and_cols_that_disagree_with_the_data(tmp_path, capsys, suffix, rows, cols, k):
    p = tmp_path / f"calib{suffix}"
    p.write_text(_calib_text(suffix, rows=rows, cols=cols, k=k))
    with pytest.raises(InputError) as info:
        load_camera(p)
    msg = str(info.value)
    assert str(p) in msg
    assert f"{rows} x {cols}" in msg and f"{len(k)}" in msg  # what the header says and what the data holds
    rc, err = _facemesh_cli(["build", "-o", str(tmp_path / "out.glb"), "--camera", str(p)], capsys)
    assert rc == 2
    _one_error_line(err, p.name)


def _must_be_camera_or_input_error(path: Path, what: str, image_size: tuple[int, int] | None = None) -> str:
    """Load ``path``: 'ok' or 'InputError'; anything else fails the test, naming the case."""
    try:
        load_camera(path, image_size=image_size)
    except InputError as exc:
        assert str(path) in str(exc), f"{what}: the message does not name the file: {exc}"
        return "InputError"
    except BaseException as exc:  # noqa: BLE001 - the point of the test
        pytest.fail(f"{what}: {type(exc).__name__}: {exc}")
    return "ok"


@pytest.mark.parametrize("suffix", sorted(_FORMATS))
def test_fuzzed_filestorage_calibrations_raise_only_input_errors(tmp_path, suffix):
    rng = np.random.default_rng(7)
    p = tmp_path / f"fuzz{suffix}"
    cases: list[tuple[str, str | bytes]] = []
    good = _calib_text(suffix)
    # truncated anywhere
    cases += [(f"truncated at {n}", good[:n]) for n in range(0, len(good), 5)]
    # huge, NaN and non-numeric values in the matrix, the distortion and the image size
    for bad in ("nan", ".nan", "inf", "-inf", "1e400", "-1e400", "1e308", "1e30", "abc", '"x"', "0x10"):
        cases.append((f"fx={bad}", _calib_text(suffix, k=[bad] + _K[1:])))
        cases.append((f"cx={bad}", _calib_text(suffix, k=_K[:2] + [bad] + _K[3:])))
        cases.append((f"k1={bad}", _calib_text(suffix, d=[bad] + _D[1:])))
        cases.append((f"width={bad}", _calib_text(suffix, w=bad)))
        cases.append((f"rows={bad}", _calib_text(suffix, rows=bad)))
    for bad in ("-3", "0", "1000000000", "2147483648", "99999999999999999999", "3.5"):
        cases.append((f"rows={bad}", _calib_text(suffix, rows=bad)))
        cases.append((f"cols={bad}", _calib_text(suffix, cols=bad)))
        cases.append((f"height={bad}", _calib_text(suffix, h=bad)))
    for dt in ("u", "i", "f", "zz", "", "3d"):
        cases.append((f"dt={dt}", _calib_text(suffix, dt=dt)))
    # wrong shapes
    cases.append(("2x3 matrix", _calib_text(suffix, rows=2, cols=3, k=_K[:6])))
    cases.append(("9x1 matrix", _calib_text(suffix, rows=9, cols=1)))
    cases.append(("1x1 matrix", _calib_text(suffix, rows=1, cols=1, k=[600.0])))
    cases.append(("empty matrix", _calib_text(suffix, rows=0, cols=0, k=[])))
    cases.append(("3 distortion values", _calib_text(suffix, d=[0.1, 0.2, 0.3])))
    cases.append(("no distortion values", _calib_text(suffix, d=[], dcols=0)))
    cases.append(("negative focal", _calib_text(suffix, k=[-600.0] + _K[1:])))
    cases.append(("bottom row 0 0 0", _calib_text(suffix, k=_K[:8] + [0.0])))
    # random byte flips and random garbage after a valid-looking header
    raw = good.encode()
    for i in range(40):
        b = bytearray(raw)
        for pos in rng.integers(0, len(b), size=int(rng.integers(1, 8))):
            b[int(pos)] = int(rng.integers(0, 256))
        cases.append((f"flipped bytes #{i}", bytes(b)))
    for i in range(10):
        cases.append((f"garbage #{i}", raw[: int(rng.integers(5, 60))] + rng.bytes(int(rng.integers(1, 300)))))
    cases.append(("random bytes", rng.bytes(500)))
    cases.append(("empty file", b""))
    outcomes = set()
    for what, content in cases:
        if isinstance(content, str):
            p.write_text(content)
        else:
            p.write_bytes(content)
        outcomes.add(_must_be_camera_or_input_error(p, f"{suffix} {what}"))
    assert "InputError" in outcomes


@pytest.mark.parametrize("suffix", sorted(_FORMATS))
def test_implausible_numbers_are_refused(tmp_path, suffix):
    p = tmp_path / f"calib{suffix}"
    for what, text in [
        ("fx=1e300", _calib_text(suffix, k=[1e300] + _K[1:])),
        ("fy=1e30", _calib_text(suffix, k=_K[:4] + [1e30] + _K[5:])),
        ("k1=1e200", _calib_text(suffix, d=[1e200] + _D[1:])),
        ("width=1e12", _calib_text(suffix, w="1000000000000")),
        ("width=640.5", _calib_text(suffix, w="640.5")),
    ]:
        p.write_text(text)
        with pytest.raises(InputError, match=p.name):
            load_camera(p)
        assert what


def _cell(items: list[object]) -> np.ndarray:
    """A MATLAB cell array (a 1-D object array) holding ``items``."""
    out = np.empty(len(items), dtype=object)
    for i, item in enumerate(items):
        out[i] = item
    return out


def test_fuzzed_mat_calibrations_raise_only_input_errors(tmp_path):
    from scipy.io import savemat

    rng = np.random.default_rng(11)
    p = tmp_path / "Camera.mat"
    k = np.array(_K).reshape(3, 3)
    variants: list[tuple[str, dict[str, object]]] = [
        ("valid", {"cameraMatrix": k, "distCoeffs": np.array([_D])}),
        ("string matrix", {"cameraMatrix": "not a matrix"}),
        ("cell matrix", {"cameraMatrix": _cell([1.0, "a", k])}),
        ("struct matrix", {"cameraMatrix": {"fx": 600.0, "fy": 600.0}}),
        ("complex matrix", {"cameraMatrix": k + 1j}),
        ("2x3 matrix", {"cameraMatrix": k[:2]}),
        ("9-vector", {"cameraMatrix": k.ravel()}),
        ("empty", {"cameraMatrix": np.zeros((0, 0))}),
        ("NaN", {"cameraMatrix": np.where(k == 600.0, np.nan, k)}),
        ("inf", {"cameraMatrix": np.where(k == 600.0, np.inf, k)}),
        ("huge", {"cameraMatrix": np.where(k == 600.0, 1e300, k)}),
        ("bool", {"cameraMatrix": k > 0}),
        ("string distortion", {"cameraMatrix": k, "distCoeffs": "none"}),
        ("cell distortion", {"cameraMatrix": k, "distCoeffs": _cell(["a", 1.0])}),
        ("3 distortion values", {"cameraMatrix": k, "distCoeffs": np.array([0.1, 0.2, 0.3])}),
        ("NaN distortion", {"cameraMatrix": k, "distCoeffs": np.array([np.nan, 0, 0, 0, 0])}),
        ("struct distortion", {"cameraMatrix": k, "distCoeffs": {"k1": 0.1}}),
        ("no matrix", {"somethingElse": k}),
    ]
    outcomes: dict[str, str] = {}
    valid_bytes = b""
    for what, content in variants:
        savemat(str(p), content)
        if what == "valid":
            valid_bytes = p.read_bytes()
        outcomes[what] = _must_be_camera_or_input_error(p, f"mat {what}", image_size=(640, 480))
    assert outcomes["valid"] == "ok"
    assert all(v == "InputError" for w, v in outcomes.items() if w not in ("valid", "bool")), outcomes
    for n in range(0, len(valid_bytes), 11):
        p.write_bytes(valid_bytes[:n])
        _must_be_camera_or_input_error(p, f"mat truncated at {n}", image_size=(640, 480))
    for i in range(40):
        b = bytearray(valid_bytes)
        for pos in rng.integers(0, len(b), size=int(rng.integers(1, 8))):
            b[int(pos)] = int(rng.integers(0, 256))
        p.write_bytes(bytes(b))
        _must_be_camera_or_input_error(p, f"mat flipped bytes #{i}", image_size=(640, 480))
    p.write_bytes(rng.bytes(400))
    _must_be_camera_or_input_error(p, "mat random bytes", image_size=(640, 480))


def test_broken_calibrations_on_both_command_lines(tmp_path, capsys):
    from scipy.io import savemat

    mismatch = tmp_path / "mismatch.xml"
    mismatch.write_text(_calib_text(".xml", rows=4, cols=4))
    garbage = tmp_path / "garbage.yml"
    garbage.write_bytes(b"%YAML:1.0\n---\n" + bytes(range(256)) * 3)
    truncated = tmp_path / "truncated.json"
    truncated.write_text(_calib_text(".json")[:150])
    huge = tmp_path / "huge.xml"
    huge.write_text(_calib_text(".xml", k=[1e300] + _K[1:], w=512, h=512))
    cell = tmp_path / "cell.mat"
    savemat(str(cell), {"cameraMatrix": _cell(["a", 1.0])})
    for bad in (mismatch, garbage, truncated, huge, cell):
        rc, err = _facemesh_cli(["build", "-o", str(tmp_path / "out.glb"), "--camera", str(bad)], capsys)
        assert rc == 2, err
        _one_error_line(err, bad.name)
        rc, err = _gazeaug_cli(["normalize", "-o", str(tmp_path / "out.npz"), "--camera", str(bad)], capsys)
        assert rc == 2, err
        _one_error_line(err, bad.name)
    assert not (tmp_path / "out.glb").exists() and not (tmp_path / "out.npz").exists()


# ---------------------------------------------------------------------------------------------------------------------
# 13. a face model whose points do not match the landmark model's


#: A 6-point model (mm, head frame): the subject's right eye's outer and inner corners, the left eye's inner and
#: outer corners, the right and left mouth corners (MPIIFaceGaze's layout; x toward the subject's left ear, y down).
_SIX = np.array(
    [
        [-45.0, 0.0, 0.0],
        [-15.0, 0.0, 2.0],
        [15.0, 0.0, 2.0],
        [45.0, 0.0, 0.0],
        [-25.0, 70.0, -5.0],
        [25.0, 70.0, -5.0],
    ]
)


def test_a_6_point_model_is_not_paired_with_mediapipe_landmarks(detector):
    from gazeaug.pipeline import fit_face

    image = sample_image()
    cam = default_camera(512, 512)
    six = FaceModel("six.npy", _SIX)
    for run in (
        lambda: build_mesh(image, cam, detector, face_model=six, source="astronaut"),
        lambda: fit_face(image, cam, detector, face_model=six, source="astronaut"),
    ):
        with pytest.raises(FaceMeshError) as info:
            run()
        msg = str(info.value)
        # names the model's count, what the detector gives, and the way out
        assert "six.npy" in msg and "6 points" in msg and "478" in msg, msg
        assert info.value.remedy == "landmarks"  # the command lines say: pass --landmarks


def test_the_shipped_468_point_model_still_pairs_with_478_mediapipe_landmarks(detector):
    from gazeaug.pipeline import fit_face

    image = sample_image()
    cam = default_camera(512, 512)
    fit = fit_face(image, cam, detector, face_model=builtin_face_model(), source="astronaut")
    assert fit.model.num_points == 468 and fit.landmarks.num_points == 478


def test_a_6_point_face_model_without_landmarks_on_both_command_lines(tmp_path, capsys):
    six_npy = tmp_path / "six.npy"
    np.save(six_npy, _SIX)
    six_txt = tmp_path / "six.txt"
    np.savetxt(six_txt, _SIX.T)  # 3 x 6, as MPIIFaceGaze's faceModelGeneric.txt
    rc, err = _facemesh_cli(["build", "-o", str(tmp_path / "out.glb"), "--face-model", str(six_npy)], capsys)
    assert rc == 2
    _one_error_line(err, "6 points")
    assert not (tmp_path / "out.glb").exists()
    rc, err = _gazeaug_cli(["normalize", "-o", str(tmp_path / "out.npz"), "--face-model", str(six_txt)], capsys)
    assert rc == 2
    _one_error_line(err, "6 points")
    assert "--landmarks" in err


# ---------------------------------------------------------------------------------------------------------------------
# 14. principal point outside the image; landmarks far from their reprojection


@pytest.mark.parametrize("suffix", [".xml", ".yml"])
def test_principal_point_far_outside_the_image_is_refused(tmp_path, capsys, suffix):
    p = tmp_path / f"calib{suffix}"
    p.write_text(_calib_text(suffix, k=[600.0, 0.0, 2000.0, 0.0, 600.0, 239.5, 0.0, 0.0, 1.0]))
    with pytest.raises(InputError, match=r"calib.*principal point.*2000.*640x480"):
        load_camera(p)
    p.write_text(_calib_text(suffix, k=[600.0, 0.0, 319.5, 0.0, 600.0, -50.0, 0.0, 0.0, 1.0]))
    with pytest.raises(InputError, match="principal point"):
        load_camera(p)
    # the same through the command line, on the 512 x 512 sample
    p.write_text(_calib_text(suffix, w=512, h=512, k=[600.0, 0.0, 900.0, 0.0, 600.0, 255.5, 0.0, 0.0, 1.0]))
    rc, err = _facemesh_cli(["build", "-o", str(tmp_path / "out.glb"), "--camera", str(p)], capsys)
    assert rc == 2
    _one_error_line(err, "principal point")


def test_a_calibration_for_another_image_size_is_refused_by_gazeaug_too(tmp_path, capsys):
    # the calibration says 640x480; the built-in sample is 512x512: its principal point (319.5, 239.5) would pass
    p = tmp_path / "calib.xml"
    p.write_text(_calib_text(".xml"))
    rc, err = _gazeaug_cli(["normalize", "-o", str(tmp_path / "out.npz"), "--camera", str(p)], capsys)
    assert rc == 2
    _one_error_line(err, "640x480")
    rc, err = _facemesh_cli(["build", "-o", str(tmp_path / "out.glb"), "--camera", str(p)], capsys)
    assert rc == 2
    _one_error_line(err, "640x480")


def test_principal_point_just_outside_warns_and_off_centre_inside_is_fine(tmp_path):
    from facemesh.camera import PRINCIPAL_POINT_MARGIN_PX, PrincipalPointWarning

    p = tmp_path / "calib.xml"
    # pixel centres run 0..639, so the image's edge is at x = 639.5; 1 px beyond it, within the margin
    assert PRINCIPAL_POINT_MARGIN_PX >= 1.0
    p.write_text(_calib_text(".xml", k=[600.0, 0.0, 640.5, 0.0, 600.0, 239.5, 0.0, 0.0, 1.0]))
    with pytest.warns(PrincipalPointWarning, match="principal point"):
        cam = load_camera(p)
    assert cam.matrix[0, 2] == 640.5
    # far from the centre but inside: no warning
    p.write_text(_calib_text(".xml", k=[600.0, 0.0, 20.0, 0.0, 600.0, 470.0, 0.0, 0.0, 1.0]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_camera(p)


def test_principal_point_just_outside_is_one_warning_line_on_both_command_lines(tmp_path, capsys):
    p = tmp_path / "calib.xml"
    # the 512 x 512 sample's right edge is at x = 511.5: 513 is 1.5 px beyond it
    p.write_text(_calib_text(".xml", w=512, h=512, k=[512.0, 0.0, 513.0, 0.0, 512.0, 255.5, 0.0, 0.0, 1.0]))
    rc, err = _facemesh_cli(["build", "-o", str(tmp_path / "out.glb"), "--camera", str(p)], capsys)
    assert rc == 0, err
    lines = [line for line in err.splitlines() if "principal point" in line]
    assert len(lines) == 1 and "warning:" in lines[0], err
    assert "Traceback" not in err and "PrincipalPointWarning" not in err
    rc, err = _gazeaug_cli(["normalize", "-o", str(tmp_path / "out.npz"), "--camera", str(p)], capsys)
    assert rc == 0, err
    lines = [line for line in err.splitlines() if "principal point" in line]
    assert len(lines) == 1 and "warning:" in lines[0], err


def _synthetic_face(distance_mm: float = 600.0) -> tuple[np.ndarray, np.ndarray, CameraIntrinsics, float]:
    """The shipped model seen by the 512 x 512 default camera, and its size in pixels (independent of the code)."""
    model = builtin_face_model().vertices_mm
    cam = default_camera(512, 512)
    r = cv2.Rodrigues(np.array([0.1, -0.2, 0.02]))[0]
    px = project_points(model @ r.T + np.array([10.0, -5.0, distance_mm]), cam)
    # the documented face size: RMS distance of the projected model points from their centroid
    size = float(np.sqrt(np.mean(np.sum((px - px.mean(axis=0)) ** 2, axis=1))))
    return px, model, cam, size


def test_a_landmark_300_px_from_its_reprojection_is_refused():
    px, model, cam, size = _synthetic_face()
    assert 30 < size < 60  # a ~50 mm face radius at 600 mm with f = 512 px: about 43 px
    bad = px.copy()
    bad[10] += (300.0, 0.0)
    with pytest.raises(PoseError, match=r"landmark 10.*px"):
        solve_head_pose(bad, model, cam)


def test_a_landmark_off_by_three_quarters_of_the_face_size_warns():
    from facemesh.pose import (
        REPROJECTION_REFUSE_FRACTION,
        REPROJECTION_WARN_FRACTION,
        ReprojectionWarning,
    )

    assert REPROJECTION_WARN_FRACTION < 0.75 < REPROJECTION_REFUSE_FRACTION
    px, model, cam, size = _synthetic_face()
    off = px.copy()
    off[200] += (0.0, 0.75 * size)  # with 468 points the fit barely moves: its residual stays near 0.75 x size
    with pytest.warns(ReprojectionWarning, match="landmark 200"):
        pose = solve_head_pose(off, model, cam)
    assert pose.reprojection_error_px > 0
    # exact landmarks: no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        solve_head_pose(px, model, cam)


def test_six_landmarks_with_one_300_px_off_are_refused_on_the_command_line(tmp_path, capsys):
    cam = default_camera(512, 512)
    r = cv2.Rodrigues(np.array([0.05, 0.1, 0.0]))[0]
    px = project_points(_SIX @ r.T + np.array([0.0, 0.0, 450.0]), cam)
    model = tmp_path / "six.txt"
    np.savetxt(model, _SIX)
    good = tmp_path / "good.json"
    good.write_text(json.dumps(px.tolist()))
    bad_px = px.copy()
    bad_px[1] += (0.0, 300.0)
    bad_px[1, 1] = min(bad_px[1, 1], 500.0)  # stay inside the image, still ~ 200+ px off
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(bad_px.tolist()))
    out = tmp_path / "out.npz"
    common = ["--face-model", str(model), "--keypoints", "mpii6", "-o", str(out)]
    rc, err = _gazeaug_cli(["normalize", "--landmarks", str(good), *common], capsys)
    assert rc == 0, err
    assert "reprojection" not in err
    out.unlink()
    rc, err = _gazeaug_cli(["normalize", "--landmarks", str(bad), *common], capsys)
    assert rc == 2
    _one_error_line(err, "reprojection")
    assert not out.exists()
    rc, err = _facemesh_cli(
        ["build", "--landmarks", str(bad), "--face-model", str(model), "-o", str(tmp_path / "o.glb")], capsys
    )
    assert rc == 2
    _one_error_line(err, "reprojection")


def test_a_real_face_gives_no_reprojection_warning(detector):
    from gazeaug.pipeline import fit_face

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fit = fit_face(sample_image(), default_camera(512, 512), detector, source="astronaut")
    assert fit.pose.reprojection_error_px < 10


# ---------------------------------------------------------------------------------------------------------------------
# 17. MediaPipe's native log lines are silenced; stderr is always restored

_NOISE = ("XNNPACK", "absl::InitializeLog", "TensorFlow Lite", "W0000", "I0000", "inference_feedback_manager")


@pytest.mark.parametrize("static", [True, False], ids=["static", "video"])
@pytest.mark.parametrize("blank_first", [False, True], ids=["face-first", "blank-first"])
def test_mediapipe_prints_no_native_log_lines(static, blank_first):
    # blank first: the landmark calculators log when they first project a face ("W0000 ...
    # landmark_projection_calculator.cc ... NORM_RECT"), so a first image without a face must not
    # end the silence (it did: the line came out on a resumed augment whose first image had none)
    code = (
        "import os, sys\n"
        "import numpy as np\n"
        "from facemesh.build import sample_image\n"
        "from facemesh.landmarks import MediaPipeFaceMesh\n"
        f"det = MediaPipeFaceMesh(static_image_mode={static})\n"
        f"blanks = [len(det.detect(np.zeros((360, 480, 3), np.uint8))) for _ in range({int(blank_first)})]\n"
        "faces = [det.detect(sample_image()) for _ in range(3)]\n"
        "det.close()\n"
        "assert not any(blanks), blanks\n"
        "print(min(len(f) for f in faces))\n"
        "sys.stderr.write('python stderr works\\n'); sys.stderr.flush()\n"
        "os.write(2, b'fd 2 works\\n')\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("GLOG_minloglevel", "TF_CPP_MIN_LOG_LEVEL")}
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=str(REPO), env=env, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "1"
    for noise in _NOISE:
        assert noise not in proc.stderr, proc.stderr
    assert "python stderr works" in proc.stderr and "fd 2 works" in proc.stderr


def test_stderr_is_restored_when_creating_the_graph_fails(capfd, monkeypatch):
    import facemesh.landmarks.mediapipe as mp_mod

    class _Broken:
        def FaceMesh(self, **kwargs):  # noqa: N802 - MediaPipe's name
            os.write(2, b"hidden native noise\n")
            raise RuntimeError("graph creation failed")

    monkeypatch.setattr(mp_mod, "import_mediapipe_face_mesh", lambda: _Broken())
    det = mp_mod.MediaPipeFaceMesh()
    with pytest.raises(RuntimeError, match="graph creation failed"):
        det.detect(sample_image())
    os.write(2, b"visible after the failure\n")
    print("python stderr visible", file=sys.stderr)
    err = capfd.readouterr().err
    assert "visible after the failure" in err and "python stderr visible" in err
    assert "hidden native noise" not in err


def test_a_float_image_of_0_to_255_levels_is_refused_not_whitened(tmp_path):
    from facemesh.io import to_rgb_uint8

    levels = np.full((40, 60, 3), 128.0, np.float32)
    with pytest.raises(InputError, match="float pixel values up to 128; expected levels from 0 to 1"):
        to_rgb_uint8(levels, name="f.tiff")
    assert to_rgb_uint8(levels / 255.0, name="f.tiff")[0, 0, 0] == 128  # 0-1 levels as before


def test_a_failed_rename_names_the_file_asked_for(tmp_path):
    from facemesh.io import atomic_write

    target = tmp_path / "out.bin"
    target.mkdir()
    (target / "keep").write_text("x")  # a non-empty folder: the rename onto it fails
    with pytest.raises(OSError) as info:
        with atomic_write(target) as fh:
            fh.write(b"data")
    assert info.value.filename == str(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]  # no temporary file left
    assert (target / "keep").read_text() == "x"
