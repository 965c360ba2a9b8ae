"""The people of ``../shared/data`` who are not among the 9 training photos: test subjects for benchmarks.

``python benchmarks/people.py [--data ../shared/data] [--sheet /tmp/people_sheet.png] [--per-video 1]``
prints one JSON line per person (name, origin, crop size) and what was skipped,
and writes a contact sheet: each crop above the simulator's rendering of it
(frontal, then the head turned 25 deg), so that every face can be checked by eye.

The training photos (``benchmarks/generalization.py``): astronaut, business-person,
sergey, pexels image00/01, AFLW2000 00202, 00302, 00408, 00480. The others:

- ``grace_hopper.jpg`` of matplotlib's sample data (a dependency of the package);
- each face of ``faces/two_children.jpeg``;
- the usable faces of ``faces/pexels/image02.jpg`` (a group; its leftmost man is
  nearly in profile and MediaPipe's landmarks miss his face: not found again in
  its crop);
- one person per ``faces/pexels/video00-02.mp4`` (the most frontal usable frame
  first, see :func:`gazeaug.faces.video_face_sources`);
- ``faces/aflw_deca/examples_alfw2.png``; ``examples_alfw1.png`` is left out when
  its eyes are closed (its eye openness is about 0.07, an open eye 0.3-0.45):
  the simulator cuts the eye openings out of the photo's mesh, and a closed
  eye has none;
- ``faces/aflw_deca/AFLW2000_image00181.jpg``, a profile, left out when its head
  yaw is beyond :data:`gazeaug.faces.MAX_YAW_DEG` (its far eye is hidden: the
  simulator would texture half the face from the background) or when the
  simulator cannot build a subject from it.

Every face kept is one the simulator can use: :class:`gazeaug.simulate.SimSubject`
is built from it (with :func:`gazeaug.pipeline.default_landmark_model`); those
that fail are left out, with the reason, in ``.skipped``.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)

from gazeaug.faces import (  # noqa: E402
    MAX_YAW_DEG,
    MIN_EYE_OPENNESS,
    FaceSource,
    FaceSources,
    eye_openness,
    face_sources,
)

#: The 9 training photos, relative to ``DATA/faces``.
TRAIN_PHOTOS = (
    "astronaut.png",
    "business-person.png",
    "sergey.png",
    "pexels/image00.jpg",
    "pexels/image01.jpg",
    "aflw_deca/AFLW2000_image00202.jpg",
    "aflw_deca/AFLW2000_image00302.jpg",
    "aflw_deca/AFLW2000_image00408.jpg",
    "aflw_deca/AFLW2000_image00480.jpg",
)

#: Pictures with several people: every usable face is a person.
GROUP_PHOTOS = ("two_children.jpeg", "pexels/image02.jpg")
#: Videos: one person each.
VIDEOS = ("pexels/video00.mp4", "pexels/video01.mp4", "pexels/video02.mp4")
#: Pictures of one person (their largest face).
SINGLE_PHOTOS = ("aflw_deca/examples_alfw2.png", "aflw_deca/examples_alfw1.png", "aflw_deca/AFLW2000_image00181.jpg")
#: What :func:`other_people` reads, relative to the shared data folder (for ``require_data``: a
#: benchmark refuses a data folder that lacks one, rather than test on fewer people).
PEOPLE_FILES = tuple(f"faces/{n}" for n in (*GROUP_PHOTOS, *VIDEOS, *SINGLE_PHOTOS))
#: The 9 training photos, relative to the shared data folder.
TRAIN_FILES = tuple(f"faces/{n}" for n in TRAIN_PHOTOS)


def grace_hopper_path() -> Path | None:
    """matplotlib's ``grace_hopper.jpg`` (None when matplotlib or its sample data is missing)."""
    try:
        import matplotlib.cbook as cbook

        path = Path(cbook.get_sample_data("grace_hopper.jpg", asfileobj=False))
    except Exception:  # noqa: BLE001 - no matplotlib, or no sample data in this install
        return None
    return path if path.is_file() else None


def _fit(image: np.ndarray, detector: Any) -> Any:
    from facemesh.camera import camera_for_image
    from gazeaug.pipeline import fit_face

    h, w = image.shape[:2]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_face(image, camera_for_image(None, w, h, warn=False), detector)


def sim_subject(src: FaceSource, detector: Any) -> Any:
    """The simulator's subject from one source (the fixed identity: ``vary_identity`` off)."""
    from gazeaug.simulate import PhotoFace, SimSettings, SimSubject, draw_subject

    settings = SimSettings(vary_identity=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        photo = PhotoFace.from_image(src.image, detector, src.name)
    return SimSubject(photo, src.name, settings, draw_subject(settings, np.random.default_rng(0)))


def usable(src: FaceSource, detector: Any) -> str | None:
    """Why the simulator cannot use ``src`` (eyes closed, a profile, no subject), or None."""
    from facemesh.conventions import rotation_to_head_pitchyaw
    from facemesh.types import FaceMeshError

    try:
        fit = _fit(src.image, detector)
    except FaceMeshError as exc:
        return f"no face fitted in the crop ({exc})"
    openness = eye_openness(fit.landmarks.points_px)
    if openness is not None and openness < MIN_EYE_OPENNESS:
        return f"eyes closed (eye openness {openness:.2f} < {MIN_EYE_OPENNESS})"
    pitch, yaw = np.degrees(rotation_to_head_pitchyaw(fit.pose.rotation))
    if abs(yaw) > MAX_YAW_DEG:
        return f"a profile (head yaw {yaw:.0f} deg, beyond {MAX_YAW_DEG:g}): its far eye and cheek are hidden"
    try:
        sim_subject(src, detector)
    except Exception as exc:  # noqa: BLE001 - whatever stops the simulator is a reason to leave the face out
        return f"the simulator cannot build a subject ({exc.__class__.__name__}: {exc})"
    return None


def other_people(
    shared_data_dir: str | Path, *, detector: Any = None, per_video: int = 1, check: bool = True
) -> FaceSources:
    """The faces of ``shared_data_dir`` (``../shared/data``) that are not the 9 training photos (module docstring).

    Args:
        shared_data_dir: the shared data folder (holding ``faces/``).
        detector: the landmark model (default: :func:`gazeaug.pipeline.default_landmark_model`).
        per_video: frames per video (each video is one person: ``FaceSource.person``).
        check: leave out what the simulator cannot use (:func:`usable`); off, only the
            crops' own checks apply.

    Returns:
        The sources, one per person (``per_video`` per video); ``.skipped`` says what was left out
        and why. Missing files are skipped (and listed), not errors.
    """
    from facemesh.types import FaceMeshError
    from gazeaug.pipeline import default_landmark_model

    faces = Path(shared_data_dir) / "faces"
    own = detector is None
    det = default_landmark_model() if own else detector
    out = FaceSources()

    def add(path: Path | None, label: str, *, largest_only: bool) -> None:
        if path is None or not path.is_file():
            out.skipped.append(f"{label}: not found")
            return
        try:
            got = face_sources([path], detector=det, all_faces=True, per_video=per_video)
        except FaceMeshError as exc:
            out.skipped.append(f"{label}: {exc}")
            return
        out.skipped.extend(got.skipped)
        kept = list(got)[:1] if largest_only else list(got)
        if largest_only and len(got) > 1:
            out.skipped.extend(f"{s.origin}: another person in the picture's background" for s in list(got)[1:])
        for src in kept:
            why = usable(src, det) if check else None
            if why is None:
                out.append(src)
            else:
                out.skipped.append(f"{src.origin}: {why}")

    try:
        add(grace_hopper_path(), "matplotlib sample_data/grace_hopper.jpg", largest_only=True)
        for name in GROUP_PHOTOS:
            add(faces / name, name, largest_only=False)
        for name in VIDEOS:
            add(faces / name, name, largest_only=False)
        for name in SINGLE_PHOTOS:
            add(faces / name, name, largest_only=True)
    finally:
        if own and hasattr(det, "close"):
            det.close()
    return out


def contact_sheet(sources: list[FaceSource], detector: Any, cell: int = 200) -> np.ndarray:
    """(H, W, 3) uint8 RGB: per source a column of its crop, its simulated frontal view and one turned 25 deg."""
    import cv2

    from facemesh.conventions import rotation_from_yaw_pitch

    cols = []
    focal, size = 1000.0, (cell, cell)
    k = np.array([[focal, 0, (cell - 1) / 2], [0, focal, (cell - 1) / 2], [0, 0, 1.0]])
    for i, src in enumerate(sources):
        tiles = [cv2.resize(src.image, (cell, cell), interpolation=cv2.INTER_AREA)]
        try:
            subject = sim_subject(src, detector)
            for yaw in (0.0, 25.0):
                r = rotation_from_yaw_pitch(np.radians(yaw), 0.0)
                t = np.array([0.0, 0.0, 1100.0])
                frame = subject.render(r, t, np.array([0.0, 0.0, 0.0]), k, size, np.random.default_rng(i))
                tiles.append(np.asarray(frame.image, dtype=np.uint8))
        except Exception as exc:  # noqa: BLE001 - shown as a grey tile with the reason printed
            print(f"{src.name}: cannot render ({exc})", file=sys.stderr)
        while len(tiles) < 3:
            tiles.append(np.full((cell, cell, 3), 128, np.uint8))
        col = np.vstack(tiles)
        label = np.full((24, cell, 3), 255, np.uint8)
        cv2.putText(label, src.name[:24], (3, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
        cols.append(np.vstack([label, col]))
    per_row = 6
    rows = []
    for j in range(0, len(cols), per_row):
        row = cols[j : j + per_row]
        row += [np.full_like(cols[0], 255)] * (per_row - len(row))
        rows.append(np.hstack(row))
    return np.vstack(rows) if rows else np.full((cell, cell, 3), 255, np.uint8)


def main() -> None:
    """List the other people and write the contact sheet."""
    import cv2

    from gazeaug.pipeline import default_landmark_model

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_data_option(ap)
    ap.add_argument("--sheet", type=Path, default=Path("/tmp/people_sheet.png"))
    ap.add_argument("--per-video", type=int, default=1)
    args = ap.parse_args()
    require_data(ap, args.data, *PEOPLE_FILES)
    det = default_landmark_model()
    people = other_people(args.data, detector=det, per_video=args.per_video)
    for s in people:
        print(json.dumps({"name": s.name, "person": s.person, "origin": s.origin, "size": list(s.image.shape[:2])}))
    print(json.dumps({"people": len({s.person for s in people}), "sources": len(people), "skipped": people.skipped}))
    sheet = contact_sheet(list(people), det)
    cv2.imwrite(str(args.sheet), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    print(f"contact sheet: {args.sheet}", file=sys.stderr)


if __name__ == "__main__":
    main()
