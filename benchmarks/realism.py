"""Issue 13's realism measure: simulated eye patches beside real MPIIGaze ones.

``python benchmarks/realism.py -o /tmp/realism [--data ../shared/data] [--per-face 40]
[--video-frames 150] [--seed 0] [--reuse]``

1. Simulates the 9 single-face photos of issue 13's training set (``benchmarks/people.py``),
   ``--per-face`` images each in the ``screen`` rig (a webcam above a screen, as MPIIGaze's
   laptops), one identity per image, and makes three sets of normalized eye patches at
   MPIIGaze's normalization (f = 960 px, d = 600 mm, 60 x 36 px):
   ``people.h5`` (the simulated people themselves, ``gazeaug normalize-dataset``),
   ``redirect.h5`` (their redirected eyes, ``gazeaug augment --redirect-eyes --rig screen``: what
   the recipe trains on) and ``paper.h5`` (the paper's augmentation, the source's eyes re-rendered
   at new head poses, ``gazeaug augment --rig screen``).
2. A real anchor that is not MPIIGaze: ``--video-frames`` frames of each of the three real
   videos of ``faces/pexels`` (other people, another camera), normalized the same way
   (``real_video.npz``). How far real eyes of other people lie from MPIIGaze's says what a
   score means.
3. Compares each set with ``gaze/mpiigaze_eyes_unlabeled/test_eyes.npz``
   (:func:`gazeaug.realism.compare_patches`): classifier two-sample test (accuracy, AUC, and
   the real-vs-real floor), sharpness, high-frequency share, mean-patch difference. Prints one
   JSON line per set and a table (the held-out patches of a set with several people are whole
   people: the simulated sets' subjects, the videos); pictures in ``OUT/report/realism_SET.png``, and
   ``OUT/report/people_and_redirected.png``: simulated people's left eyes (first column) beside
   the redirected eyes made from them.

Caveat printed with the table: the 3000 MPIIGaze patches show one participant (both eyes, 1500
each), so every other set differs from them in identity too; the real video anchor measures how
much that alone counts.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from people import TRAIN_PHOTOS  # noqa: E402  (benchmarks/people.py)
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)

NORMALIZATION = ["--focal", "960", "--distance", "600", "--patch-size", "60", "36"]


def gazeaug(*argv: str) -> None:
    """Run one ``gazeaug`` command (this interpreter), quietly; stop with its message if it fails."""
    cmd = [sys.executable, "-m", "gazeaug.cli", *argv, "--quiet"]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"realism: {' '.join(argv[:1])} failed: {done.stderr.strip().splitlines()[-1:]}")


def video_patches(videos: list[Path], frames: int, out: Path, max_head_deg: float = 25.0) -> int:
    """Normalized eye patches of ``frames`` evenly spaced frames of each video -> ``out`` (.npz); rows written.

    Eyes whose normalized head pose lies beyond ``max_head_deg`` in pitch or yaw are left out (a
    turned head hides the eye; MPIIGaze's head poses lie mostly within 25 deg).
    """
    import cv2
    import numpy as np

    from facemesh.build import fit_face, landmark_model_for
    from facemesh.camera import camera_for_image
    from facemesh.io import atomic_write
    from facemesh.types import FaceMeshError
    from gazeaug.normalize import NormalizationSettings, normalize_image

    warnings.simplefilter("ignore")  # reprojection warnings of turned heads: those eyes are left out below
    settings = NormalizationSettings(focal_px=960.0, distance_mm=600.0, patch_size_wh=(60, 36))
    detector, _ = landmark_model_for(None, None)
    images, subjects = [], []
    for k, path in enumerate(videos):
        cap = cv2.VideoCapture(str(path))
        total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        for i in np.linspace(0, max(total - 1, 0), frames).astype(int):
            cap.set(cv2.CAP_PROP_POS_FRAMES, int(i))
            ok, bgr = cap.read()
            if not ok:
                continue
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            h, w = rgb.shape[:2]
            try:
                fit = fit_face(rgb, camera_for_image(None, w, h, warn=False), detector, source=str(path))
                s = normalize_image(rgb, fit.camera, fit.pose, fit.model.vertices_mm, fit.keypoints, settings=settings)
            except FaceMeshError:
                continue
            for side in ("left", "right"):
                eye = s.eye(side)
                if np.degrees(np.abs(eye.head_pose)).max() <= max_head_deg:  # MPIIGaze's range of head poses
                    images.append(eye.image)
                    subjects.append(k)
        cap.release()
    with atomic_write(out) as fh:
        np.savez(fh, images=np.stack(images), subject_id=np.asarray(subjects, dtype=np.int64))
    return len(images)


def source_sheet(people_h5: Path, redirect_h5: Path, out_png: Path, sources: int = 8) -> None:
    """Left eyes of ``sources`` simulated people (first column) beside their redirected eyes (as many as K), RGB."""
    import cv2
    import numpy as np

    from facemesh.io import save_image_rgb
    from gazeaug.io_h5 import read_h5

    p, r = (read_h5(f, ["left_eye", "source_index"]) for f in (people_h5, redirect_h5))
    pi, ri = p["source_index"], r["source_index"]
    rows = []
    for s in np.unique(pi)[np.linspace(0, len(np.unique(pi)) - 1, sources).astype(int)]:
        own = p["left_eye"][int(np.flatnonzero(pi == s)[0])]
        redirected = list(r["left_eye"][ri == s])
        gap = np.full((own.shape[0], 6, 3), 255, np.uint8)
        rows.append(np.hstack([own, gap, *redirected]))
    width = max(row.shape[1] for row in rows)
    sheet = np.vstack([np.pad(row, ((0, 0), (0, width - row.shape[1]), (0, 0)), constant_values=255) for row in rows])
    save_image_rgb(out_png, cv2.resize(sheet, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", type=Path, required=True)
    add_data_option(ap)
    ap.add_argument("--per-face", type=int, default=40)
    ap.add_argument("--video-frames", type=int, default=150, help="frames per real video (default 150)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--reuse", action="store_true", help="keep the sets an earlier run left in OUT")
    args = ap.parse_args()

    from gazeaug.realism import RealismSettings, compare_patches, read_eye_patches, realism_sheet

    real_npz = args.data / "gaze" / "mpiigaze_eyes_unlabeled" / "test_eyes.npz"
    require_data(ap, args.data, *(f"faces/{p}" for p in TRAIN_PHOTOS), str(real_npz.relative_to(args.data)))
    out = args.output
    (out / "report").mkdir(parents=True, exist_ok=True)
    faces = [str(args.data / "faces" / p) for p in TRAIN_PHOTOS]
    t0 = time.perf_counter()
    sim = out / "sim_screen"
    if not (args.reuse and sim.is_dir()):
        gazeaug(
            "simulate",
            "--faces",
            *faces,
            "--rig",
            "screen",
            "--per-face",
            str(args.per_face),
            "--identities-per-face",
            str(args.per_face),
            "--seed",
            str(args.seed),
            "-o",
            str(sim),
            "--overwrite",
        )
    steps = {
        "people": ("normalize-dataset", str(sim)),
        "redirect": ("augment", str(sim), "--redirect-eyes", "--rig", "screen", "--seed", str(args.seed)),
        "paper": ("augment", str(sim), "--rig", "screen", "--seed", str(args.seed)),
    }
    for name, argv in steps.items():
        h5 = out / f"{name}.h5"
        if not (args.reuse and h5.is_file()):
            gazeaug(*argv, *NORMALIZATION, "--workers", "2", "-o", str(h5), "--overwrite")
    video = out / "real_video.npz"
    if not (args.reuse and video.is_file()):
        video_patches(sorted((args.data / "faces" / "pexels").glob("video*.mp4")), args.video_frames, video)
    t_sets = time.perf_counter() - t0

    source_sheet(out / "people.h5", out / "redirect.h5", out / "report" / "people_and_redirected.png")
    real, real_who = read_eye_patches(real_npz)
    sets = {
        "real_video": video,
        "people": out / "people.h5",
        "redirect": out / "redirect.h5",
        "paper": out / "paper.h5",
    }
    rows = {}
    for name, path in sets.items():
        t1 = time.perf_counter()
        patches, who = read_eye_patches(path)
        rep = compare_patches(
            real, patches, RealismSettings(seed=args.seed), real_groups=real_who, simulated_groups=who
        )
        realism_sheet(real, rep, out / "report" / f"realism_{name}.png", title=name)
        rows[name] = {"set": name, **rep.as_dict(), "seconds": round(time.perf_counter() - t1, 1)}
        print(json.dumps(rows[name]), flush=True)
    r0 = next(iter(rows.values()))["real"]
    print(
        f"\nsets made in {t_sets:.0f} s; MPIIGaze: sharpness {r0['sharpness']}, high-frequency share "
        f"{r0['high_frequency_share']}"
    )
    print("| set | patches (floor) | accuracy (floor) | AUC | sharpness | high-freq. share | mean-patch RMS (floor) |")
    print("|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        print(
            f"| {name} | {r['patches_per_set']} ({r['floor_patches_per_set']}) | "
            f"{r['accuracy']:.3f} ({r['floor_accuracy']:.3f}) | {r['auc']:.3f} | "
            f"{r['simulated']['sharpness']:.2f} | {r['simulated']['high_frequency_share']:.4f} | "
            f"{r['mean_patch_rms']:.1f} ({r['mean_patch_rms_floor']:.1f}) |"
        )
    print(
        "caveat: the MPIIGaze patches show one participant; real_video (other real people) says what "
        "identity alone counts"
    )


if __name__ == "__main__":
    main()
