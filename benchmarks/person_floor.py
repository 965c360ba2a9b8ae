"""Issue 13's test read by a model that knows its people: what knowing the face, the eyes or the photo buys.

``python benchmarks/person_floor.py -o OUT [--draw 1] [--cells own eyes photo ...] [--images 200]
[--seeds 1] [--epochs N] [--halves even odd] [--data ../shared/data]``

The test of ``benchmarks/generalization.py --seed DRAW`` (the other people of
``benchmarks/people.py``, one simulated identity each, 15 images in the ``wheelchair`` rig,
simulator seed ``DRAW + 1``) is simulated again with ``15 + --images`` images of each person:
the simulator draws image ``j`` of face ``i`` from ``[seed, i, j]``, so images 0-14 are the
test's head poses and targets and are dropped, and the others are new images of the test's
people in the test's rig. Each cell trains the wide network (``mobilenet_gaze_wide``, training
seed ``DRAW`` and then ``DRAW + 10``, ... for ``--seeds``; today's defaults otherwise) on those
images and reads the test's 135 images with and without mirror averaging:

- ``own``: the test people themselves (each person's face and eyes: the floor of this test);
- ``eyes``: each person's face (the photo, face shape, head size, skin gain, glasses) with
  eyes drawn anew for every image (eyeball, iris and pupil sizes, opening, lid drop, kappa,
  sclera and iris colour, iris pattern): a model that knows the face but not the eyes;
- ``photo``: each person's photo only, every identity parameter drawn anew for every image;
- ``others``: the 9 training photos of ``benchmarks/people.py`` instead of the test people's,
  ``--images`` images of each in the test's rig, every identity drawn anew for every image
  (simulator seed ``DRAW``, the recipe's training seed, so identity ``k`` of a photo is the
  recipe's): the ``photo`` cell's design without knowing the test photos, beside the recipe
  (``benchmarks/generalization.py``: screen-rig images, eyes redirected to the test's rig);
- ``mixed``: the ``others`` rows joined with the ``photo`` rows of half the test people (two
  models: the even-numbered people seen, then the odd-numbered), so one model reads people whose
  photo it has seen among 9 others and people whose photo it has not (printed apart as
  ``seen_deg`` and ``unseen_deg``): a photo mixed in among other training photos. To train the
  two at once, run ``--halves even`` and ``--halves odd`` as two processes, the second once the
  ``others`` and ``photo`` sets exist (once the first has written ``mixedeven_*.h5``): two
  processes would otherwise simulate the same set;
- ``frame``: the ``photo`` cell with another picture of the person where there is one: the three
  test people taken from a video (``sim05``-``sim07``) are simulated from another moment of their
  video (:data:`ENROL_FRAMES_S`), the others from their photo as in ``photo`` (the same images:
  image ``j`` of person ``i`` is drawn from ``[seed, i, j]``, so they are a control for the
  training's noise). The ``photo`` cell knows the very picture each test person was simulated
  from; a user's enrolment photo is another picture of their face: this cell measures what that
  costs (printed for the three as ``other_frame_deg``, for the rest as ``same_photo_deg``);
- ``clip``: the same with four other frames of each video person (:data:`CLIP_FRAMES_S`, the
  ``frame`` cell's among them; ``--images`` / 4 images of each frame, set ``clipframes``),
  joined with the ``photo`` rows of the other six (``other_frames_deg``, ``same_photo_deg``):
  a short clip of the user instead of one picture;
- ``mixedframe``: the ``mixed`` cell with the ``frame`` cell's rows instead of the ``photo``
  cell's: the video people seen from another frame among the training photos.

The identity of image ``j`` in ``eyes``, ``photo`` and ``others`` is the simulator's own draw ``k = j``
(``--identities-per-face`` equal to the images); ``eyes`` keeps the face fields of the
person's draw ``k = 0`` (the test's identity) by wrapping
:func:`gazeaug.simulate.draw_subject` here, in this process.

Prints one JSON line per cell, seed and reading: mean error, ratio to the constant guess, r of
pitch and yaw, the error with each person's offset removed, the standard deviation of the
per-person offsets (pitch, yaw, degrees), each person's mean error (``per_person_deg``) and the
times. Everything lands in ``OUT/``; the sets
and the trained models are kept and reused by a later run with the same ``--draw``,
``--images`` and ``--epochs`` (the file names carry them; delete a file to make it again).
Measured in docs/model.md ("a known face with unknown eyes"; ``others``: "the photo known, or
the design without it"; ``mixed``: "a photo among other photos"; ``frame``, ``clip`` and ``mixedframe``:
"another picture of the person").
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from generalization import test_people  # noqa: E402  (benchmarks/generalization.py)
from people import PEOPLE_FILES, TRAIN_FILES, TRAIN_PHOTOS, other_people  # noqa: E402  (benchmarks/people.py)
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)

#: The fields of a :class:`gazeaug.simulate.SubjectDraw` that make the face (the rest are the eyes).
FACE_FIELDS = ("shape_coefficients", "head_scale", "skin_gain", "glasses", "texture_mix_pick", "texture_mix_weight")
TEST_IMAGES = 15
#: The cells whose people are printed in two groups: (the named group's key, the rest's key).
GROUPS = {
    "mixed": ("seen_deg", "unseen_deg"),
    "mixedframe": ("seen_deg", "unseen_deg"),
    "frame": ("other_frame_deg", "same_photo_deg"),
    "clip": ("other_frames_deg", "same_photo_deg"),
}
#: The ``frame`` cell's enrolment pictures: for each test person taken from a video (the video's
#: most frontal usable frame, ``gazeaug.faces.video_face_sources``), another moment of the same
#: video, in seconds, checked by eye to show the same person: video00 6.4 s after the test's
#: frame (1.60 s), video01 5.8 s before it (7.80 s), video02 in another shot (the video shows two
#: girls; the test's girl at 4.27 s looks up, at 7.07 s she looks down with her lids lowered).
ENROL_FRAMES_S: dict[str, tuple[float, ...]] = {"video00": (8.00,), "video01": (2.00,), "video02": (7.07,)}
#: The ``clip`` cell's enrolment pictures: four frames of each test person's video, at least 1 s
#: from the test's frame, over the clip, the head within 20 deg of frontal (:data:`ENROL_FRAMES_S`'
#: among them); video02's are its test girl's (5.33 s in the test's shot, the others in the next).
CLIP_FRAMES_S: dict[str, tuple[float, ...]] = {
    "video00": (4.16, 8.00, 12.48, 16.32),
    "video01": (0.40, 1.20, 2.00, 6.40),
    "video02": (5.33, 6.00, 6.80, 7.07),
}


def _simulate(people: list[Path], folder: Path, draw: int, cell: str, images: int) -> None:
    """The cell's images of ``people`` (test people: images 0-14, the test's poses, dropped; ``others``: all kept)."""
    import numpy as np

    import gazeaug.simulate as sim
    from gazeaug.sampling import BUILTIN_RIGS

    first = 0 if cell == "others" else TEST_IMAGES  # images kept: first, first + 1, ...
    per = TEST_IMAGES if cell == "test" else first + images
    ids = 1 if cell in ("test", "own") else per
    original = sim.draw_subject

    def face_kept(settings: Any, rng: Any) -> Any:
        seed, i, _k = (int(v) for v in rng.bit_generator.seed_seq.entropy)
        new = original(settings, rng)
        own = original(settings, np.random.default_rng([seed, i, 10**6]))  # the test's identity
        return replace(new, **{f: getattr(own, f) for f in FACE_FIELDS})

    if cell == "eyes":
        sim.draw_subject = face_kept
    try:
        sim.simulate(
            people,
            BUILTIN_RIGS["wheelchair"],
            folder,
            per_face=per,
            identities_per_face=ids,
            seed=draw if cell == "others" else draw + 1,
            settings=sim.SimSettings(),
            progress=False,
            overwrite=True,
        )
    finally:
        sim.draw_subject = original
    if cell not in ("test", "others"):
        from gazeaug.datasets.folder import write_labels_csv

        labels = folder / "labels.csv"
        with labels.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
        write_labels_csv(labels, [r for r in rows if int(Path(r["image"]).stem) >= TEST_IMAGES])


def enrolment_frames(
    data: Path, people: list[Path], work: Path, times: dict[str, tuple[float, ...]]
) -> dict[int, list[Path]]:
    """Other frames of the test people taken from a video: for each, its video's frames at ``times[video]``.

    Args:
        data: the shared data folder (``../shared/data``).
        people: the test people's pictures (``generalization.test_people``), for the count.
        work: where the frames are written (PNG, ``personKK_tSS.SS.png``).
        times: per video stem, the frames' times in seconds (:data:`ENROL_FRAMES_S`, :data:`CLIP_FRAMES_S`).

    Returns:
        Per test person taken from a video (its index in ``people``), the frames' pictures in the
        order of ``times``.

    Raises:
        NoFaceError: the test people are not the ones of :func:`benchmarks.people.other_people`,
            or a video has no usable face at one of the times.
    """
    import cv2

    from facemesh.types import NoFaceError
    from gazeaug.faces import face_sources
    from gazeaug.pipeline import default_landmark_model

    sources = list(other_people(data))
    if len(sources) != len(people):
        raise NoFaceError(f"expected the {len(people)} test people, found {len(sources)} in {data}")
    out: dict[int, list[Path]] = {}
    det = default_landmark_model()
    try:
        for k, src in enumerate(sources):
            if src.person not in times or src.time_s is None:
                continue
            video = Path(src.origin.rsplit("@", 1)[0])
            found = list(face_sources([video], detector=det, per_video=100))
            out[k] = []
            for when in times[src.person]:
                frames = [f for f in found if f.time_s is not None and abs(f.time_s - when) < 0.02]
                if not frames:
                    raise NoFaceError(f"{video}: no usable face at {when:.2f} s")
                out[k].append(work / f"person{k:02d}_t{when:05.2f}.png")
                cv2.imwrite(str(out[k][-1]), cv2.cvtColor(frames[0].image, cv2.COLOR_RGB2BGR))
    finally:
        if hasattr(det, "close"):
            det.close()
    return out


def _normalize(folder: Path, out: Path) -> None:
    from gazeaug.datasets import open_dataset
    from gazeaug.jobs import JobSettings, run_dataset

    run_dataset(open_dataset(folder), out, JobSettings(kind="normalize-dataset"), progress=False, overwrite=True)


def _join(others: Path, photo: Path, seen: list[int], out: Path) -> None:
    """``others``' rows, then ``photo``'s rows of the test people ``seen`` (subjects renamed ``testNNiK``).

    The photo rows' subjects (``simNNiK``, as the others' training photos are named) get the prefix
    ``test`` and their source indices follow the others', so no subject or source is shared.
    """
    import numpy as np

    from gazeaug.io_h5 import H5Writer, Rows, read_h5

    a, b = read_h5(others), read_h5(photo)
    keys = [k for k in a if k != "attrs"]
    keep = np.array([int(s[3:5]) in seen for s in b["subject"]])
    b = {k: b[k][keep] for k in keys}
    b["subject"] = np.array([b"test" + s[3:] for s in b["subject"]])
    first = int(a["attrs"]["next_source_index"])  # the photo rows' source indices start here
    b["source_index"] = b["source_index"] + first
    h, w = a["left_eye"].shape[1:3]
    face = (a["face"].shape[2], a["face"].shape[1]) if "face" in a else None
    attrs = {
        "kind": "normalize-dataset",
        "gazeaug_version": a["attrs"].get("gazeaug_version"),
        "settings": a["attrs"]["settings"],
        "selection": {"joined": [str(others), str(photo)], "test_people_seen": seen},
    }
    writer = H5Writer(out, attrs, (w, h), face_patch_size_wh=face, overwrite=True)
    try:
        writer.append(Rows({k: a[k] for k in keys}), first - 1)
        writer.append(Rows(b), int(b["source_index"].max()))
        writer.finish()
    except BaseException:
        writer.discard()
        raise


def _read(model: Path, test: Path, mirror: bool) -> dict[str, Any]:
    import numpy as np

    from gazeaug.estimator import load_estimator
    from gazeaug.evaluate import evaluate_h5
    from gazeaug.metrics import global_offset

    res = evaluate_h5(load_estimator(model, mirror_average=mirror), test)
    m = res["metrics"]
    subj = np.array([r["subject"] for r in res["rows"]])
    pred = np.array([[r["pred_pitch_rad"], r["pred_yaw_rad"]] for r in res["rows"]])
    true = np.array([[r["true_pitch_rad"], r["true_yaw_rad"]] for r in res["rows"]])
    names = sorted(set(subj.tolist()))
    offsets = np.degrees([global_offset(pred[subj == s], true[subj == s]) for s in names])
    return {
        "mean_deg": round(res["mean_deg"], 2),
        "median_deg": round(res["median_deg"], 2),
        "constant_deg": round(m["constant_guess_deg"], 2),
        "ratio_to_constant": round(m["ratio_to_constant"], 3),
        "pearson_pitch": round(m["pearson_pitch"], 3),
        "pearson_yaw": round(m["pearson_yaw"], 3),
        "subject_offsets_removed_deg": round(m["subject_offsets_removed_deg"], 2),
        "offset_sd_pitch_yaw_deg": [round(float(v), 2) for v in offsets.std(0, ddof=1)],
        "per_person_deg": {s: round(v, 2) for s, v in m["per_subject_deg"].items()},
    }


def run() -> None:
    """Simulate, normalize, train and read each cell (module docstring)."""
    from gazeaug.train import TrainSettings, train

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", type=Path, required=True)
    add_data_option(ap)
    ap.add_argument("--draw", type=int, default=1, help="generalization.py's --seed whose test this is (default 1)")
    ap.add_argument(
        "--cells",
        nargs="+",
        choices=("own", "eyes", "photo", "others", "mixed", "frame", "clip", "mixedframe"),
        default=["own", "eyes", "photo"],
    )
    ap.add_argument("--images", type=int, default=200, help="training images of each person or photo (default 200)")
    ap.add_argument("--seeds", type=int, default=1, help="trainings per cell (seeds DRAW, DRAW + 10, ...)")
    ap.add_argument("--epochs", type=int, default=None, help="default: fitted to the set's size")
    ap.add_argument(
        "--halves",
        nargs="+",
        choices=("even", "odd"),
        default=["even", "odd"],
        help="the mixed cell's models: the even- or odd-numbered test people seen (default both; one each "
        "lets two processes train them at once)",
    )
    args = ap.parse_args()
    for name in ("draw", "images", "seeds"):
        if getattr(args, name) < (0 if name == "draw" else 1):
            ap.error(f"--{name}: expected an integer >= {0 if name == 'draw' else 1}, got {getattr(args, name)}")
    require_data(ap, args.data, *TRAIN_FILES, *PEOPLE_FILES)
    warnings.simplefilter("ignore")
    out = args.output
    people = test_people(args.data, out / "people")
    test = out / f"test_draw{args.draw}.h5"
    if not test.is_file():
        _simulate(people, out / f"test_draw{args.draw}", args.draw, "test", 0)
        _normalize(out / f"test_draw{args.draw}", test)

    def made(cell: str, faces: list[Path] | None = None, images: int = args.images) -> Path:
        """The cell's normalized set (of ``faces``, default the cell's), simulated and normalized unless made before."""
        name = f"{cell}_draw{args.draw}_{images}"
        data = out / f"{name}.h5"
        if not data.is_file():
            if faces is None:
                faces = [args.data / "faces" / n for n in TRAIN_PHOTOS] if cell == "others" else people
            _simulate(faces, out / name, args.draw, cell, images)
            _normalize(out / name, data)
        return data

    def frame_set() -> tuple[Path, list[int]]:
        """The frame cell's set and the test people it takes from another frame of their video."""
        frames = enrolment_frames(args.data, people, out / "people", ENROL_FRAMES_S)
        return made("frame", [frames[k][0] if k in frames else p for k, p in enumerate(people)]), sorted(frames)

    for cell in args.cells:
        t0 = time.perf_counter()
        if cell in ("mixed", "mixedframe"):
            others = made("others")
            photo = made("photo") if cell == "mixed" else frame_set()[0]
            halves = {f"{cell}{h}": list(range(int(h == "odd"), len(people), 2)) for h in args.halves}
            sets = {}
            for half, seen in halves.items():
                sets[half] = out / f"{half}_draw{args.draw}_{args.images}.h5"
                if not sets[half].is_file():
                    _join(others, photo, seen, sets[half])
        elif cell == "frame":
            data, replaced = frame_set()
            sets, halves = {cell: data}, {cell: replaced}
        elif cell == "clip":
            frames = enrolment_frames(args.data, people, out / "people", CLIP_FRAMES_S)
            per = len(next(iter(CLIP_FRAMES_S.values())))
            clips = made("clipframes", [p for k in sorted(frames) for p in frames[k]], args.images // per)
            photo = made("photo")
            sets = {cell: out / f"clip_draw{args.draw}_{args.images}.h5"}
            if not sets[cell].is_file():
                _join(clips, photo, [k for k in range(len(people)) if k not in frames], sets[cell])
            halves = {cell: sorted(frames)}
        else:
            halves = {cell: []}
            sets = {cell: made(cell)}
        t_set = time.perf_counter() - t0
        for half, data in sets.items():
            for k in range(args.seeds):
                seed = args.draw + 10 * k
                model = data.with_name(
                    f"{data.stem}_seed{seed}{'' if args.epochs is None else f'_epochs{args.epochs}'}.pt"
                )
                t1 = time.perf_counter()
                if not model.is_file():
                    settings = TrainSettings(seed=seed, model="mobilenet_gaze_wide", epochs=args.epochs)
                    train(data, model, settings, progress=False)
                t_train = time.perf_counter() - t1
                for mirror in (False, True):
                    row = {"cell": half, "draw": args.draw, "images": args.images, "seed": seed}
                    row.update(mirror_average=mirror, **_read(model, test, mirror))
                    if cell in GROUPS:
                        apart = {f"sim{i:02d}" for i in halves[half]}
                        per_person = row["per_person_deg"]  # the people with test rows (a face found)
                        for key, group in (
                            (GROUPS[cell][0], [v for p, v in per_person.items() if p in apart]),
                            (GROUPS[cell][1], [v for p, v in per_person.items() if p not in apart]),
                        ):
                            row[key] = round(sum(group) / len(group), 2) if group else None
                    row.update(set_s=round(t_set, 1), train_s=round(t_train, 1))
                    print(json.dumps(row), flush=True)


def main() -> None:
    """Run it: a library error or an unwritable OUT gives one line and exit 2, Ctrl-C exit 130."""
    from facemesh.types import FaceMeshError

    try:
        run()
    except (FaceMeshError, OSError) as exc:
        print(f"person_floor: {exc}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print("person_floor: interrupted", file=sys.stderr)
        sys.exit(130)


if __name__ == "__main__":
    main()
