"""Face sources (gazeaug.faces): pictures, one crop per face, video frames spread in head pose, errors."""

from __future__ import annotations

import hashlib
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from facemesh.build import SAMPLE_NAME, sample_image
from facemesh.types import InputError, NoFaceError
from gazeaug.faces import MIN_FACE_PX, FaceSource, face_sources

#: The built-in photo's face: a 220 px square around it (the face spans about x 178-270, y 71-177).
FACE_BOX = (14, 234, 114, 334)


def _face() -> np.ndarray:
    y0, y1, x0, x1 = FACE_BOX
    return sample_image()[y0:y1, x0:x1]


def _digests(folder: Path) -> dict[str, tuple[str, int]]:
    """Name -> (SHA-256, mtime) of every file in ``folder``: the inputs untouched, nothing left beside them."""
    return {
        p.name: (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns)
        for p in folder.iterdir()
        if p.is_file()
    }


class _Counting:
    """A detector that counts its runs on pictures of one shape (the video's frames)."""

    def __init__(self, detector, shape):
        self.detector, self.shape, self.runs = detector, shape, 0

    def detect(self, image):
        if image.shape == self.shape:
            self.runs += 1
        return self.detector.detect(image)

    def face_model(self):
        return self.detector.face_model()


class _WithTinyFace:
    """The real detector, plus on ``picture`` a made-up face: the real one's landmarks at ``scale``, at (20, 20)."""

    def __init__(self, detector, picture, scale):
        self.detector, self.picture, self.scale = detector, picture, scale

    def detect(self, image):
        faces = self.detector.detect(image)
        if image.shape == self.picture.shape and np.array_equal(image, self.picture) and faces:
            from facemesh.types import FaceLandmarks

            pts = faces[0].points_px
            tiny = (pts - pts.min(axis=0)) * self.scale + 20.0
            faces = [*faces, FaceLandmarks(points_px=tiny, model_name="tiny")]
        return faces

    def face_model(self):
        return self.detector.face_model()


# ------------------------------------------------------------------------------------------------ pictures


def test_whole_picture_and_builtin_sample(faces_dir, detector, tmp_path):
    photo = faces_dir / "astronaut.png"
    got = face_sources([photo, None], detector=detector)
    assert [s.name for s in got] == ["astronaut", "astronaut-2"]  # one stem twice: made unique
    assert [s.origin for s in got] == [str(photo), SAMPLE_NAME]
    assert [s.person for s in got] == ["astronaut", "astronaut-2"]
    np.testing.assert_array_equal(got[1].image, sample_image())  # as load_input(None, None) gives it
    assert got[0].image.shape == (512, 512, 3) and got[0].image.dtype == np.uint8
    assert got[0].region_px == (0, 0, 512, 512) and got.skipped == []
    assert face_sources(None, detector=detector)[0].origin == SAMPLE_NAME  # None alone is a list of one


def test_two_faces_give_two_crops_largest_first(two_faces_photo, detector):
    before = hashlib.sha256(two_faces_photo.read_bytes()).hexdigest(), two_faces_photo.stat().st_mtime_ns
    got = face_sources([two_faces_photo], detector=detector, all_faces=True)
    stem = two_faces_photo.stem
    assert [s.name for s in got] == [f"{stem}#face1", f"{stem}#face2"]
    assert [s.origin for s in got] == [f"{two_faces_photo}#face1", f"{two_faces_photo}#face2"]
    assert len({s.person for s in got}) == 2  # two people
    # both photos (two_children.jpeg, or the stand-in: the face beside a 0.7x copy) have the larger face on the left
    big, small = got
    assert big.region_px is not None and small.region_px is not None
    assert (big.region_px[0] + big.region_px[2]) < (small.region_px[0] + small.region_px[2])
    assert big.region_px[2] - big.region_px[0] > small.region_px[2] - small.region_px[0]
    for s in got:
        h, w, c = s.image.shape
        assert h == w and c == 3 and s.image.dtype == np.uint8
        assert 300 <= h <= 800  # the face at least 200 px wide (crop: 2.2x, or 1.6x, its box), the crop at most 800
        (face,) = detector.detect(s.image)[:1]  # the crop's largest face is centred
        x0, y0 = face.points_px.min(axis=0)
        x1, y1 = face.points_px.max(axis=0)
        assert abs((x0 + x1) / 2 - w / 2) < 0.1 * w and abs((y0 + y1) / 2 - h / 2) < 0.1 * h
    assert (hashlib.sha256(two_faces_photo.read_bytes()).hexdigest(), two_faces_photo.stat().st_mtime_ns) == before


def test_stand_in_two_faces_sizes(detector, tmp_path):
    """The face and a 0.7x copy, side by side: the crops' squares scale with the faces (0.7)."""
    import cv2

    from facemesh.io import save_image_rgb

    face = _face()
    small = cv2.resize(face, None, fx=0.7, fy=0.7, interpolation=cv2.INTER_AREA)
    canvas = np.full((220, 220 + small.shape[1], 3), 128, np.uint8)
    canvas[:, :220] = face
    canvas[33 : 33 + small.shape[0], 220:] = small
    path = tmp_path / "pair.png"
    save_image_rgb(path, canvas)
    got = face_sources([path], detector=detector, all_faces=True)
    assert [s.name for s in got] == ["pair#face1", "pair#face2"]
    (ax0, _, ax1, _), (bx0, _, bx1, _) = (s.region_px for s in got)
    assert (bx1 - bx0) / (ax1 - ax0) == pytest.approx(0.7, abs=0.08)
    assert (ax0 + ax1) / 2 < 220 < (bx0 + bx1) / 2  # the big face on the left, the copy on the right


def test_small_face_skipped_and_counted(faces_dir, detector):
    photo = faces_dir / "astronaut.png"
    from facemesh.io import load_image_rgb

    picture = load_image_rgb(photo)
    # the made-up face: 0.15 of the real one (inter-ocular about 43 px -> about 6.5 px, below 12)
    det = _WithTinyFace(detector, picture, 0.15)
    got = face_sources([photo], detector=det, all_faces=True)
    assert [s.name for s in got] == ["astronaut#face1"]
    assert len(got.skipped) == 1 and "#face2" in got.skipped[0] and "too small" in got.skipped[0]
    assert f"< {MIN_FACE_PX:g} px" in got.skipped[0]
    # a threshold above the real face's inter-ocular distance (about 43 px) leaves no usable face
    with pytest.raises(NoFaceError, match="no usable face"):
        face_sources([photo], detector=detector, all_faces=True, min_face_px=60)


def test_bad_entries_give_typed_errors(tmp_path, detector):
    text = tmp_path / "notes.txt"
    text.write_text("not a picture\n")
    folder = tmp_path / "folder"
    folder.mkdir()
    grey = tmp_path / "grey.png"
    from facemesh.io import save_image_rgb

    save_image_rgb(grey, np.full((200, 200, 3), 128, np.uint8))
    before = _digests(tmp_path)
    cases = [
        (text, InputError, "not an image"),
        (tmp_path / "missing.png", InputError, "no such file"),
        (folder, InputError, "folder"),
        (grey, NoFaceError, "no face"),
    ]
    for path, error, words in cases:
        with pytest.raises(error, match=words) as info:
            face_sources([path], detector=detector)
        assert str(path) in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(InputError, match="per video"):
        face_sources([None], detector=detector, per_video=0)
    assert _digests(tmp_path) == before


# ------------------------------------------------------------------------------------------------ videos

#: The test video: 480 x 360, 20 frames/s, four 2-second segments of one still picture each: the face
#: centred; moved left and turned; moved right and turned the other way; moved up and rolled.
SEGMENTS = (
    {"dx": 0, "dy": 0},
    {"dx": -130, "dy": 0, "yaw": 30},
    {"dx": 130, "dy": 0, "yaw": -30},
    {"dx": 0, "dy": -50, "roll": 25},
)
FPS, PER_SEGMENT, SIZE = 20, 40, (480, 360)


def _frame(dx=0, dy=0, yaw=0.0, pitch=0.0, roll=0.0) -> np.ndarray:
    """The face as a plane turned by (yaw, pitch, roll) deg, seen at its centre + (dx, dy) px, on grey."""
    import cv2

    face = _face()
    w, h = SIZE
    c = np.array([[-110, -110, 0], [110, -110, 0], [110, 110, 0], [-110, 110, 0]], float)
    rot = (
        cv2.Rodrigues(np.radians([0.0, 0.0, roll]))[0]
        @ cv2.Rodrigues(np.radians([pitch, 0.0, 0.0]))[0]
        @ cv2.Rodrigues(np.radians([0.0, yaw, 0.0]))[0]
    )
    p = c @ rot.T
    p[:, 2] += 440.0
    uv = p[:, :2] / p[:, 2:] * 440.0 + [w / 2 + dx, h / 2 + dy]
    hm = cv2.getPerspectiveTransform(np.float32(c[:, :2] + 110), np.float32(uv))
    return cv2.warpPerspective(face, hm, SIZE, flags=cv2.INTER_LINEAR, borderValue=(128, 128, 128))


def _write_video(path: Path, frames) -> None:
    import cv2

    for fourcc in ("FFV1", "MJPG"):  # lossless first: MediaPipe misses the built-in face after strong JPEG coding
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), FPS, SIZE)
        if writer.isOpened():
            break
        writer.release()
    else:
        pytest.skip("OpenCV cannot write an .avi video here (no FFV1 or MJPG encoder)")
    if fourcc == "MJPG":
        writer.set(cv2.VIDEOWRITER_PROP_QUALITY, 100)
    for f in frames:
        writer.write(np.ascontiguousarray(f[..., ::-1]))
    writer.release()


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("video") / "clip.avi"
    frames = [_frame(**seg) for seg in SEGMENTS]
    _write_video(path, (f for f in frames for _ in range(PER_SEGMENT)))
    return path


def test_video_frames_spread_named_same_person(clip, detector):
    before = _digests(clip.parent)
    det = _Counting(detector, (SIZE[1], SIZE[0], 3))
    with warnings.catch_warnings():
        warnings.simplefilter(
            "error", UserWarning
        )  # none escapes (the fits' reprojection warnings are for selection only)
        got = face_sources([clip], detector=det, per_video=4)
    assert len(got) == 4
    assert all(isinstance(s, FaceSource) for s in got)
    assert {s.person for s in got} == {"clip"}  # one video, one person
    assert len({s.name for s in got}) == 4
    frames = []
    for s in got:
        m = re.fullmatch(r"clip@t=(\d+\.\d\d)s", s.name)
        assert m, s.name
        assert s.origin == f"{clip}@t={m.group(1)}s"
        assert s.time_s is not None and f"{s.time_s:.2f}" == m.group(1)
        index = round(s.time_s * FPS)
        assert index % 3 == 0  # 160 frames, at most 60 looked at: every third
        frames.append(index)
        h, w, _ = s.image.shape
        assert h == w and s.image.dtype == np.uint8
    # spread: one frame of each still segment (each segment's frames are identical, so its pose is one point)
    assert sorted(i // PER_SEGMENT for i in frames) == [0, 1, 2, 3]
    assert frames[0] // PER_SEGMENT == 0  # the most frontal first: the centred, unturned face
    assert det.runs <= 60  # bounded work: the candidate frames' fits only
    assert _digests(clip.parent) == before


def test_long_video_is_read_by_seeking(clip, detector, monkeypatch):
    """Videos with many frames are read by seeking to the candidate frames: the same frames as decoding all."""
    import gazeaug.faces as faces_module

    monkeypatch.setattr(faces_module, "_SEEK_ABOVE_FRAMES", 10)
    monkeypatch.setattr(faces_module, "MAX_VIDEO_CANDIDATES", 20)  # 160 frames: every 8th
    got = face_sources([clip], detector=detector, per_video=4)
    frames = [round(s.time_s * FPS) for s in got]
    assert all(i % 8 == 0 for i in frames) and sorted(i // PER_SEGMENT for i in frames) == [0, 1, 2, 3]


def test_video_fewer_usable_frames_than_asked(clip, detector):
    got = face_sources([clip], detector=detector, per_video=100)
    assert 4 <= len(got) <= 60 and {s.person for s in got} == {"clip"}
    assert len({s.name for s in got}) == len(got)


def test_bad_videos_give_typed_errors(tmp_path, detector):
    import cv2

    empty = tmp_path / "empty.mp4"
    empty.write_bytes(b"")
    noframes = tmp_path / "noframes.avi"
    writer = cv2.VideoWriter(str(noframes), cv2.VideoWriter_fourcc(*"MJPG"), FPS, SIZE)
    writer.release()
    junk = tmp_path / "junk.mkv"
    junk.write_bytes(b"\x1aE\xdf\xa3" + bytes(range(256)) * 4)
    noface = tmp_path / "noface.avi"
    _write_video(noface, [np.full((SIZE[1], SIZE[0], 3), v, np.uint8) for v in (90, 120, 150)])
    before = _digests(tmp_path)
    for path in (empty, noframes, junk):
        if not path.exists():
            continue  # an OpenCV that writes no file for a video without frames
        with pytest.raises(InputError, match="decod") as info:
            face_sources([path], detector=detector)
        assert str(path) in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(NoFaceError, match="no usable face in 3 frames"):
        face_sources([noface], detector=detector)
    assert _digests(tmp_path) == before
