"""Train the built-in demo model that ``gazeaug track`` uses without ``--model``.

``python -m gazeaug.models.train_demo [-o gazeaug/models/demo_wheelchair.pt] [--data ../shared/data]
[--per-face 300] [--recipe direct|augment] [--workers 2] [--work DIR]``

**Trained on simulated people only** (``gazeaug simulate``): the freely
licensed single-face photos of ``../shared/data/faces`` (:data:`DEMO_PHOTOS`:
the public-domain astronaut, the Apache-2.0 business person and Sergey, Pexels'
image00 and image01; none of the research-only AFLW faces), every image its
own drawn identity (shape, eyes, skin, glasses, kappa, light). Two recipes:

- ``direct`` (the default): the subjects simulated in the ``wheelchair`` rig;
- ``augment``: simulated in the ``screen`` rig, then augmented for the
  ``wheelchair`` rig (``gazeaug augment --rig wheelchair``, 4 poses each), the
  paper's recipe.

Then ``gazeaug train`` with its fitted defaults. Everything derives from
``--seed``; the same inputs and versions give the same model. The card
``demo_wheelchair.json`` written beside it records the recipe, the day and how
it was made (written afresh, so a new model starts without figures); what the
file measured goes under ``measured`` by running ``python
benchmarks/demo_model.py --model M.pt --card`` and ``python
benchmarks/track_accuracy.py --model M.pt --card`` (docs/tracking.md). Takes
about 17 minutes on 2 cores (2026-11-28).

It is a demonstration of the pipeline, not a gaze tracker for real users:
measured on simulated people it never saw, and on one real MPIIFaceGaze frame,
in docs/tracking.md.
"""

from __future__ import annotations

import argparse
import datetime
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

#: The demo's training photos, relative to ``DATA/faces``: freely licensed, one face each.
DEMO_PHOTOS = ("astronaut.png", "business-person.png", "sergey.png", "pexels/image00.jpg", "pexels/image01.jpg")
#: Where the package's demo model lives.
DEMO_MODEL = Path(__file__).resolve().parent / "demo_wheelchair.pt"
#: Its card: how it was made, what it measured.
DEMO_CARD = DEMO_MODEL.with_suffix(".json")


def main(argv: list[str] | None = None) -> int:
    """Run it; returns the exit code."""
    from gazeaug.datasets import open_dataset
    from gazeaug.jobs import JobSettings, run_dataset
    from gazeaug.sampling import BUILTIN_RIGS
    from gazeaug.simulate import simulate
    from gazeaug.train import TrainSettings, train

    ap = argparse.ArgumentParser(prog="python -m gazeaug.models.train_demo", description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", type=Path, default=DEMO_MODEL)
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[3] / "shared" / "data")
    ap.add_argument("--per-face", type=int, default=300, help="simulated images per photo (default 300)")
    ap.add_argument("--recipe", choices=("direct", "augment"), default="direct")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--work", type=Path, default=None, help="keep the intermediate data here (default: a temp folder)")
    args = ap.parse_args(argv)
    faces = [args.data / "faces" / p for p in DEMO_PHOTOS]
    missing = [str(p) for p in faces if not p.is_file()]
    if missing:
        print(f"train_demo: error: missing training photos {missing} (set --data to ../shared/data)", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    work = args.work or Path(tempfile.mkdtemp(prefix="gazeaug-demo-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        rig = "wheelchair" if args.recipe == "direct" else "screen"
        sim = work / f"sim_{rig}"
        simulate(
            faces,
            BUILTIN_RIGS[rig],
            sim,
            per_face=args.per_face,
            identities_per_face=args.per_face,
            seed=args.seed,
            overwrite=True,
            progress=True,
        )
        h5 = work / "train.h5"
        wheelchair = BUILTIN_RIGS["wheelchair"]
        job = (
            JobSettings(
                kind="augment",
                per_sample=4,
                distribution=wheelchair.distribution(),
                seed=args.seed,
                rig=wheelchair.as_dict(),
            )
            if args.recipe == "augment"
            else JobSettings(kind="normalize-dataset", seed=args.seed)
        )
        run_dataset(open_dataset(sim, None), h5, job, workers=args.workers, overwrite=True, progress=True)
        log = train(h5, args.output, TrainSettings(seed=args.seed), progress=True)
        card = {
            "model": args.output.name,
            "trained_on": "simulated people only (gazeaug simulate), every image its own drawn identity",
            "photos": list(DEMO_PHOTOS),
            "recipe": args.recipe,
            "rig": "wheelchair",
            "per_face": args.per_face,
            "seed": args.seed,
            "trained": datetime.date.today().isoformat(),
            "train_error_deg": round(float(log[-1]["train_error_deg"]), 2),
            "epochs": len(log),
            "minutes": round((time.perf_counter() - t0) / 60, 1),
            "command": f"python -m gazeaug.models.train_demo --per-face {args.per_face} --recipe {args.recipe} "
            f"--seed {args.seed}",
        }
        args.output.with_suffix(".json").write_text(json.dumps(card, indent=1) + "\n", encoding="utf-8")
        print(json.dumps(card))
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
