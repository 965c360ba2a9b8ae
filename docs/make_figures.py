"""Draw every picture in docs/img: ``python docs/make_figures.py [NAME ...]`` (default: all).

NAME is one of (``--list`` prints them with their files):

- ``convention``: pitch_convention.png, the head-pose pitch convention, drawn from
  :mod:`facemesh.conventions` itself (the face direction of a pitch of +30 deg), so the
  picture cannot disagree with the code;
- ``rigs``: simulated_rigs.png, simulated images of the built-in sample in both rigs;
- ``identities``: identities.png, eye patches of simulated identities;
- ``preview``: preview_sheet.png and preview_distribution.png, ``gazeaug preview`` on the
  built-in sample (16 augmented samples, the default distribution, seed 0);
- ``texture_mix``: texture_mix.png, three photos simulated without and with another's skin mixed in
  (needs ../shared);
- ``placements``: placements.png, ``benchmarks/compare_placements.py`` (needs ../shared);
- ``reconstruction``: reconstruction.png, ``benchmarks/bench_reconstruct.py`` (needs ../shared).

Pictures that need ../shared/data are skipped with a message when it is absent.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from facemesh.conventions import pitchyaw_to_vector  # noqa: E402

OUT = Path(__file__).resolve().parent / "img" / "pitch_convention.png"
SIM_OUT = Path(__file__).resolve().parent / "img" / "simulated_rigs.png"


def simulation_figure() -> None:
    """Simulated images of the built-in sample from both rigs, the eyeballs' axes drawn to the targets."""
    import json
    import tempfile

    import cv2

    from facemesh.io import load_image_rgb, save_image_rgb
    from facemesh.pose import project_points
    from facemesh.types import CameraIntrinsics
    from gazeaug.sampling import BUILTIN_RIGS
    from gazeaug.simulate import simulate

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for rig_name in ("screen", "wheelchair"):
            rig = BUILTIN_RIGS[rig_name]
            out = Path(tmp) / rig_name
            simulate([None], rig, out, per_face=3, seed=3, progress=False)
            w, h = rig.image_size_wh
            k = np.array([[rig.focal_px, 0, (w - 1) / 2], [0, rig.focal_px, (h - 1) / 2], [0, 0, 1]])
            cam = CameraIntrinsics(k, np.zeros(5), (w, h))
            tiles = []
            for line in (out / "simulation.jsonl").read_text().splitlines():
                t = json.loads(line)
                img = load_image_rgb(out / t["image"])
                for side in ("left", "right"):
                    c = np.array(t["eyeball_centres_mm"][side])
                    a = np.array(t["optical_axes"][side])
                    p0, p1 = project_points(np.stack([c, c + 150 * a]), cam)
                    cv2.arrowedLine(
                        img,
                        tuple(int(v) for v in p0),
                        tuple(int(v) for v in p1),
                        (255, 230, 0),
                        2,
                        cv2.LINE_AA,
                        tipLength=0.2,
                    )
                cv2.putText(img, rig_name, (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 255), 2, cv2.LINE_AA)
                tiles.append(img)
            rows.append(np.concatenate(tiles, axis=1))
    sheet = np.concatenate(rows, axis=0)
    save_image_rgb(SIM_OUT, cv2.resize(sheet, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
    print(f"wrote {SIM_OUT}")


ID_OUT = Path(__file__).resolve().parent / "img" / "identities.png"


def identities_figure() -> None:
    """Normalized eye patches of simulated identities: eight from each of three photos (rows), as a model sees them."""
    import tempfile
    import warnings

    import cv2

    from facemesh.io import load_image_rgb, save_image_rgb
    from gazeaug.datasets import open_dataset
    from gazeaug.normalize import normalize_image
    from gazeaug.pipeline import default_landmark_model, fit_face
    from gazeaug.sampling import BUILTIN_RIGS
    from gazeaug.simulate import simulate

    shared = Path(__file__).resolve().parents[2] / "shared" / "data" / "faces"
    faces: list[str | None] = [None] + [
        str(shared / n) for n in ("sergey.png", "pexels/image00.jpg") if (shared / n).is_file()
    ]
    det = default_landmark_model()
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "sim"
        simulate(faces, BUILTIN_RIGS["screen"], out, per_face=8, identities_per_face=8, progress=False)
        tiles = []
        for smp in open_dataset(out):
            fit = fit_face(load_image_rgb(smp.image_path), smp.camera, det)
            n = normalize_image(
                fit.image, smp.camera, fit.pose, fit.model.vertices_mm, fit.keypoints, gaze_target_mm=smp.gaze_target_mm
            )
            tiles.append(np.concatenate([n.right.image, n.left.image], axis=1))
    rows = [np.concatenate(tiles[i : i + 8], axis=1) for i in range(0, len(tiles) - len(tiles) % 8, 8)]
    sheet = np.concatenate(rows, axis=0)
    save_image_rgb(ID_OUT, cv2.resize(sheet, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST))
    print(f"wrote {ID_OUT}")


def convention_figure() -> None:
    """Side view (the subject's right side; the camera frame's y down, z forward)."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    for ax, title, cam_angle in (
        (axes[0], "webcam on a screen: camera above, face pitch about -10 deg", -10.0),
        (axes[1], "wheelchair camera: 30 deg below, face pitch +30 deg", 30.0),
    ):
        # world: the head at the origin looking along -x of the plot (to the left); y up in the plot
        head = plt.Circle((0, 0), 1.0, fc="#f2d0b0", ec="k")
        ax.add_patch(head)
        ax.plot([-0.95], [0.25], "ko", ms=4)  # eye
        ax.annotate("", xy=(-3.2, 0.25), xytext=(-0.95, 0.25), arrowprops={"arrowstyle": "->", "color": "tab:blue"})
        ax.text(-3.2, 0.4, "face / gaze direction", color="tab:blue", fontsize=8)
        # the camera sits on a ray from the eye at -cam_angle (below for +30), 3.5 units away, looking at the eye
        a = np.radians(cam_angle)
        cam = np.array([-0.95 - 3.5 * np.cos(a), 0.25 - 3.5 * np.sin(a)])
        ax.plot(*cam, "s", color="tab:red", ms=10)
        ax.annotate(
            "", xy=(-0.95, 0.25), xytext=tuple(cam), arrowprops={"arrowstyle": "->", "color": "tab:red", "ls": "--"}
        )
        ax.text(cam[0] - 0.2, cam[1] - 0.45, "camera", color="tab:red", fontsize=8)
        # the head pose the camera measures: the face direction in the camera frame
        # camera frame (seen from the side): z toward the eye, y down; the face points along the plot's -x
        z = np.array([np.cos(a), np.sin(a)])  # plot coordinates of the camera's z axis
        y_down = np.array([np.sin(a), -np.cos(a)])  # perpendicular, pointing down in the plot
        face = np.array([-1.0, 0.0])
        v = np.array([0.0, face @ y_down, face @ z])  # (x, y, z) in the camera frame
        pitch = np.degrees(np.arcsin(-v[1] / np.linalg.norm(v)))
        check = pitchyaw_to_vector([np.radians(pitch), 0.0])
        assert np.allclose(check, v / np.linalg.norm(v)), "figure disagrees with the conventions"
        ax.set_title(f"{title}\nmeasured head pose pitch = {pitch:+.0f} deg", fontsize=9)
        ax.set_xlim(-5, 1.5)
        ax.set_ylim(-2.5, 2.0)
        ax.set_aspect("equal")
        ax.axis("off")
    fig.suptitle("Head pose pitch > 0: the face points above the camera's line of sight (camera below the face)")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT, dpi=100, bbox_inches="tight")
    print(f"wrote {OUT}")


IMG = Path(__file__).resolve().parent / "img"
REPO = IMG.parents[1]
SHARED_FACES = REPO.parent / "shared" / "data" / "faces"


def preview_figure() -> None:
    """``gazeaug preview`` on the built-in sample: the contact sheet and its distribution plot."""
    import shutil
    import tempfile

    from gazeaug.cli import main as gazeaug_main

    with tempfile.TemporaryDirectory() as tmp:
        sheet = Path(tmp) / "sheet.png"
        if gazeaug_main(["preview", "-n", "16", "--seed", "0", "-o", str(sheet)]) != 0:
            raise SystemExit("make_figures: gazeaug preview failed")
        shutil.copy(sheet, IMG / "preview_sheet.png")
        shutil.copy(Path(tmp) / "sheet_distribution.png", IMG / "preview_distribution.png")
    print(f"wrote {IMG / 'preview_sheet.png'}, {IMG / 'preview_distribution.png'}")


def texture_mix_figure() -> None:
    """Three photos simulated (screen rig, seed 0) without and with another photo's skin mixed in (needs ../shared)."""
    import tempfile
    import warnings

    import cv2

    from facemesh.io import load_image_rgb, save_image_rgb
    from gazeaug.sampling import BUILTIN_RIGS
    from gazeaug.simulate import SimSettings, simulate

    names = ("sergey.png", "business-person.png", "aflw_deca/AFLW2000_image00302.jpg")
    if not all((SHARED_FACES / n).is_file() for n in names):
        print(f"skipped texture_mix.png: {SHARED_FACES} not found")
        return
    warnings.simplefilter("ignore")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for share, name in ((0.0, "plain"), (1.0, "mixed")):
            simulate(
                [str(SHARED_FACES / n) for n in names],
                BUILTIN_RIGS["screen"],
                Path(tmp) / name,
                per_face=1,
                progress=False,
                settings=SimSettings(texture_mix_share=share),
            )
        for i in range(len(names)):
            pair = [
                load_image_rgb(Path(tmp) / k / f"sim{i:02d}" / "00000.jpg")[100:400, 170:470]
                for k in ("plain", "mixed")
            ]
            rows.append(np.concatenate(pair, axis=1))
    sheet = np.concatenate(rows, axis=0)
    save_image_rgb(IMG / "texture_mix.png", cv2.resize(sheet, None, fx=0.75, fy=0.75, interpolation=cv2.INTER_AREA))
    print(f"wrote {IMG / 'texture_mix.png'}")


def _benchmark(script: str, *args: str) -> None:
    """Run a benchmark script that draws a figure (it needs ../shared/data/faces)."""
    import subprocess
    import sys

    if not SHARED_FACES.is_dir():
        print(f"skipped {script}: {SHARED_FACES} not found")
        return
    subprocess.run([sys.executable, str(REPO / "benchmarks" / script), *args], check=True, cwd=REPO)


FIGURES = {
    "convention": (convention_figure, ("pitch_convention.png",)),
    "rigs": (simulation_figure, ("simulated_rigs.png",)),
    "identities": (identities_figure, ("identities.png",)),
    "preview": (preview_figure, ("preview_sheet.png", "preview_distribution.png")),
    "texture_mix": (texture_mix_figure, ("texture_mix.png",)),
    "placements": (
        lambda: _benchmark("compare_placements.py", str(SHARED_FACES), "-o", str(IMG / "placements.png")),
        ("placements.png",),
    ),
    "reconstruction": (
        lambda: _benchmark("bench_reconstruct.py", "--figure", str(IMG / "reconstruction.png")),
        ("reconstruction.png",),
    ),
}


def main(argv: list[str] | None = None) -> int:
    """Draw the figures named (default: all)."""
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "names", nargs="*", metavar="NAME", help=f"figures to draw: {', '.join(FIGURES)} (default: all)"
    )
    parser.add_argument("--list", action="store_true", help="list the figures and their files, draw nothing")
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in FIGURES]
    if unknown:
        parser.error(f"unknown figure {', '.join(unknown)}: expected one of {', '.join(FIGURES)}")
    if args.list:
        for name, (_, files) in FIGURES.items():
            print(f"{name}: {', '.join('docs/img/' + f for f in files)}")
        return 0
    IMG.mkdir(parents=True, exist_ok=True)
    for name in args.names or list(FIGURES):
        FIGURES[name][0]()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
