"""How good is a gaze model (the built-in demo model by default) on people it never saw?

``python benchmarks/demo_model.py [--model M.pt] [--per-person 50] [-o /tmp/demo_eval] [--card]``

1. **Simulated held-apart people**: the test people of ``benchmarks/people.py`` (none among
   the demo's training photos), ``--per-person`` images each in the ``wheelchair`` rig
   (``gazeaug simulate --seed 1``), normalized and evaluated: mean and median error, the
   best constant guess, the ratio, Pearson r of pitch and yaw (``gazeaug evaluate``'s metrics).
2. **The real MPIIFaceGaze frame** of ``../shared/data/gaze/mpiifacegaze_p00_example``
   (a laptop's webcam, the screen rig of a real person: not the demo's wheelchair rig):
   the angle between the predicted gaze and the direction from the face centre to the
   annotated 3D target.

Prints one JSON line; ``--card`` also records it in the model's card (``M.json``, under
``measured.demo_model``; ``benchmarks/card.py``).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from shared_data import add_data_option, require_data  # noqa: E402  (benchmarks/shared_data.py)


def real_frame_error(est, folder: Path) -> float:
    """Degrees between the model's gaze and the annotated target of the real MPIIFaceGaze frame."""
    import numpy as np

    from facemesh.conventions import angular_error_deg, pitchyaw_to_vector
    from gazeaug.normalize import normalize_image
    from gazeaug.pipeline import default_landmark_model, fit_face, load_input

    ann = json.loads((folder / "annotation.json").read_text())
    image, camera, source = load_input(folder / ann["image"], folder / "cameraCalib.xml")
    fit = fit_face(image, camera, default_landmark_model(), source=source)
    s = normalize_image(image, fit.camera, fit.pose, fit.model.vertices_mm, fit.keypoints, settings=est.normalization)
    assert s.face is not None
    pred = est.predict(s.left.image[None], s.right.image[None], s.face.head_pose[None])[0]
    g = s.face.camera.denormalize_vector(pitchyaw_to_vector(pred))
    truth = np.asarray(ann["gaze_target_3d_camera_mm"]) - s.face.camera.reference_mm
    return float(angular_error_deg(g, truth))


def main() -> None:
    """Run it."""
    from people import PEOPLE_FILES, other_people  # benchmarks/people.py

    from gazeaug.datasets import open_dataset
    from gazeaug.errors import GazeAugError
    from gazeaug.estimator import load_estimator
    from gazeaug.evaluate import evaluate_h5
    from gazeaug.jobs import JobSettings, run_dataset
    from gazeaug.models.train_demo import DEMO_MODEL
    from gazeaug.sampling import BUILTIN_RIGS
    from gazeaug.simulate import simulate

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=DEMO_MODEL)
    ap.add_argument("--per-person", type=int, default=50)
    add_data_option(ap)
    ap.add_argument("-o", "--output", type=Path, default=Path("/tmp/demo_eval"))
    ap.add_argument("--card", action="store_true", help="record the figures in the model's card (M.json)")
    args = ap.parse_args()
    require_data(ap, args.data, *PEOPLE_FILES)
    warnings.simplefilter("ignore")
    try:
        est = load_estimator(args.model)
    except GazeAugError as exc:
        ap.exit(2, f"{ap.prog}: {exc}\n")
    test = args.output / "test_wheelchair"
    h5 = args.output / "test_wheelchair.h5"
    if not h5.is_file():
        people = list(other_people(args.data))
        simulate(
            people, BUILTIN_RIGS["wheelchair"], test, per_face=args.per_person, seed=1, overwrite=True, progress=False
        )
        run_dataset(
            open_dataset(test), h5, JobSettings(kind="normalize-dataset"), workers=2, overwrite=True, progress=False
        )
    assert est.kind == "pytorch", "evaluate_h5 takes the PyTorch model"
    m = evaluate_h5(est._runner, h5)["metrics"]
    out = {
        "model": str(args.model),
        "simulated_people_wheelchair": {
            k: (round(v, 3) if isinstance(v, float) else v)
            for k, v in m.items()
            if k
            in (
                "count",
                "mean_deg",
                "median_deg",
                "constant_guess_deg",
                "ratio_to_constant",
                "bias_removed_deg",
                "pearson_pitch",
                "pearson_yaw",
            )
        },
    }
    real = args.data / "gaze" / "mpiifacegaze_p00_example"
    if real.is_dir():
        out["real_mpiifacegaze_frame_deg"] = round(real_frame_error(est, real), 2)
    print(json.dumps(out))
    if args.card:
        from card import record_or_exit, shown  # benchmarks/card.py

        figures = {k: v for k, v in out.items() if k != "model"}
        per = "" if args.per_person == 50 else f" --per-person {args.per_person}"
        command = f"python benchmarks/demo_model.py --model {shown(args.model)}{per} --card"
        record_or_exit(args.model, "demo_model", figures, command)


if __name__ == "__main__":
    main()
