"""``gazeaug`` command line: a thin layer over the library.

Exit codes: 0 success; 2 bad input (missing or unreadable file, no face, bad
option values); 1 anything unexpected. Outputs are written atomically: on
failure nothing is left behind.
"""

from __future__ import annotations

import argparse
import json
import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeGuard

import numpy as np

from facemesh.cli import (
    CAMERA_HELP,
    DEFAULT_CAMERA_HELP,
    FACE_INDEX_HELP,
    FACE_MODEL_HELP,
    KEYPOINTS_HELP,
    OneLineParser,
    finite_float,
)
from facemesh.cli import integer_in as _integer

from .train_augment import STRENGTHS as AUGMENT_NAMES  # numpy only: no torch at start-up

__all__ = ["main", "entry", "build_parser"]


#: Upper bounds of counts that would only exhaust memory or processes: preview samples, worker processes.
MAX_PREVIEW = 4096
MAX_WORKERS = 256

#: Help of ``--renderer`` (render, preview, augment).
RENDERER_HELP = (
    "eye-patch renderer: raycast, Open3D ray casting on the CPU; filament, Open3D's offscreen renderer "
    "(GPU or Mesa) (default raycast)"
)
#: Help of ``--lr`` (train, experiment).
LR_HELP = "AdamW learning rate, decayed by cosine to 1%% of it at the end (default 0.003)"

_positive_int = _integer(1)
_seed = _integer(0)  # numpy's generators take no negative seeds


def _count(maximum: int) -> Any:
    """Argparse type: an integer from 1 to ``maximum``."""
    return _integer(1, maximum)


def _add_engine_options(p: argparse.ArgumentParser, *, block_size: bool = True) -> None:
    """``--engine``, ``--ray-address``, ``--workers`` (and ``--block-size``): where a dataset run goes."""
    p.add_argument(
        "--engine",
        choices=("local", "ray"),
        default="local",
        help="local: this machine's processes (default); ray: actors on a Ray cluster (pip install 'gazeaug[ray]'; "
        "docs/ray.md)",
    )
    p.add_argument(
        "--ray-address",
        default=None,
        metavar="HOST:PORT",
        help="join the Ray cluster whose head is there (`ray start --head` prints it; 'auto': the cluster "
        "this machine is part of, as in `ray job submit`); without it --engine ray starts Ray on this machine",
    )
    if block_size:
        p.add_argument(
            "--block-size",
            type=_count(1_000_000),
            default=None,
            help="--engine ray: samples per block, the unit sent to an actor and retried (default 64)",
        )
    p.add_argument(
        "--workers",
        type=_count(MAX_WORKERS),
        default=None,
        help=f"processes (local, default 1) or Ray actors (default: every CPU of the cluster); at most {MAX_WORKERS}",
    )


def _engine(args: argparse.Namespace, *, local_workers: bool = True) -> Any:
    """The :class:`gazeaug.engine.Engine` of the options of :func:`_add_engine_options`.

    ``local_workers``: whether the command has worker processes on the local engine.
    """
    from .engine import Engine
    from .errors import GazeAugError

    block_size = getattr(args, "block_size", None)
    if args.engine != "ray":
        if args.ray_address is not None:
            raise GazeAugError("--ray-address: only with --engine ray")
        if block_size is not None:
            raise GazeAugError("--block-size: only with --engine ray")
        if not local_workers and args.workers not in (None, 1):
            raise GazeAugError(f"--workers: `gazeaug {args.command}` runs one process here; use --engine ray for more")
    return Engine(args.engine, address=args.ray_address, workers=args.workers, block_size=block_size or 64)


def _add_input_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--camera", type=Path, help=CAMERA_HELP)
    p.add_argument(
        "--landmarks", type=Path, help="your own 2D landmarks (.npy/.json/.csv, N x 2 px); needs --face-model"
    )
    p.add_argument("--face-model", default=None, help=FACE_MODEL_HELP)
    p.add_argument("--keypoints", default=None, help=KEYPOINTS_HELP)
    p.add_argument("--face-index", type=int, default=None, help=FACE_INDEX_HELP)


def _add_normalization_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--distance", type=finite_float, default=600.0, help="normalized distance d_n in mm (default 600)")
    p.add_argument("--focal", type=finite_float, default=650.0, help="normalized focal length f_n in px (default 650)")
    p.add_argument(
        "--patch-size",
        type=int,
        nargs=2,
        default=(60, 36),
        metavar=("W", "H"),
        help="eye patch width and height, px (default 60 36)",
    )
    p.add_argument(
        "--face-patch",
        type=int,
        nargs=2,
        default=None,
        metavar=("W", "H"),
        help="also make a normalized face patch of this width and height, px (ETH-XGaze's: 224 224); default: none",
    )
    p.add_argument(
        "--face-distance",
        type=finite_float,
        default=None,
        help="the face camera's normalized distance in mm (default 600, ETH-XGaze's; needs --face-patch)",
    )
    p.add_argument(
        "--face-focal",
        type=finite_float,
        default=None,
        help="the face camera's normalized focal length in px (default 960, ETH-XGaze's; needs --face-patch)",
    )
    p.add_argument(
        "--no-antialias",
        action="store_true",
        help="plain bilinear sampling, as cv2.warpPerspective (default: antialiased, each pixel's footprint "
        "averaged from an image pyramid)",
    )


def _add_gaze_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--gaze-target",
        type=finite_float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="3D point looked at, mm, camera frame of the image (OpenCV: x right, y down, z forward)",
    )


#: The head-pose distribution's options (:func:`_add_distribution_options`), as argparse names them.
_DISTRIBUTION_OPTIONS = ("yaw_mean", "pitch_mean", "yaw_var", "pitch_var", "yaw_std", "pitch_std", "rig")


def _given_distribution_options(args: argparse.Namespace) -> list[str]:
    """The head-pose distribution's options given on the command line, ``--rig`` aside, as flags."""
    return [f"--{n.replace('_', '-')}" for n in _DISTRIBUTION_OPTIONS if n != "rig" and getattr(args, n) is not None]


def _add_distribution_options(
    p: argparse.ArgumentParser, default: str = "the paper's, yaw 0, pitch 30, variances 10 deg^2"
) -> None:
    g = p.add_argument_group(f"head-pose distribution (default: {default})")
    g.add_argument(
        "--yaw-mean",
        type=finite_float,
        default=None,
        help="mean head yaw, degrees; + = face turned toward the image's left (default 0)",
    )
    g.add_argument(
        "--pitch-mean",
        type=finite_float,
        default=None,
        help="mean head pitch, degrees; + = face turned up, the camera below the face (default 30)",
    )
    g.add_argument("--yaw-var", type=finite_float, default=None, help="variance of the yaw, deg^2 (default 10)")
    g.add_argument("--pitch-var", type=finite_float, default=None, help="variance of the pitch, deg^2 (default 10)")
    g.add_argument(
        "--yaw-std", type=finite_float, default=None, help="standard deviation of the yaw, deg (instead of --yaw-var)"
    )
    g.add_argument(
        "--pitch-std",
        type=finite_float,
        default=None,
        help="standard deviation of the pitch, deg (instead of --pitch-var)",
    )
    g.add_argument(
        "--rig",
        default=None,
        help="the distribution of a rig: 'wheelchair', 'screen' or a RIG.yaml (instead of the options above)",
    )


def _add_eyes_option(
    p: argparse.ArgumentParser, default: str = "each sample keeps its source's gaze in the head, the paper's method"
) -> None:
    p.add_argument(
        "--redirect-eyes",
        action="store_true",
        help="re-make the eyes as 3D eyeballs turned to the --rig's targets, head poses and targets drawn as the "
        "rig draws them, so that the set has the application's eye-in-head gaze (needs --rig and MediaPipe's "
        f"478 landmarks; docs/gazeaug.md) (default: {default})",
    )


def _add_with_source_option(p: argparse.ArgumentParser, what: str = "the set") -> None:
    p.add_argument(
        "--with-source",
        action="store_true",
        help=f"{what} also holds each source's own normalized row (the original data beside its augmentation; "
        "on issue 13's benchmark 0.8 deg better on average, docs/model.md) (default: the augmented rows "
        "alone, the paper's protocol)",
    )


def _eyes(args: argparse.Namespace) -> str:
    """``JobSettings.eyes`` from ``--redirect-eyes`` (which needs ``--rig``)."""
    from .errors import GazeAugError

    if not args.redirect_eyes:
        return "keep"
    if args.rig is None:
        raise GazeAugError("--redirect-eyes turns the eyes to a rig's targets: give --rig (a built-in name or a file)")
    return "redirect"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``gazeaug`` command."""
    from . import __version__
    from .datasets import DATASETS
    from .experiment import BUILTIN_TEST_RIG
    from .render import RENDERERS
    from .selection import MAX_DWELL_S, MAX_MARGIN_DEG
    from .train_data import PRELOAD_CHOICES

    formats = DATASETS.names()  # the registries' names: listing them imports no reader, renderer or model
    renderers = RENDERERS.names(benchmark_only=False)
    format_help = "dataset format (default: detected from the folder's layout)"

    parser = OneLineParser(
        prog="gazeaug",
        description="Semi-synthetic gaze dataset augmentation (face meshes: see the 'facemesh' command).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", title="commands", required=True)

    n = sub.add_parser("normalize", help="normalize the eyes of a face image (Zhang et al. 2018) into an .npz")
    n.add_argument("image", nargs="?", type=Path, help="face image (default: the built-in sample)")
    n.add_argument("-o", "--output", type=Path, required=True, help="output .npz")
    _add_input_options(n)
    _add_gaze_options(n)
    _add_normalization_options(n)

    r = sub.add_parser("render", help="render both eyes of a face (image or .glb) at a new head pose into an .npz")
    r.add_argument("input", nargs="?", type=Path, help="face image or facemesh .glb (default: the built-in sample)")
    r.add_argument("-o", "--output", type=Path, required=True, help="output .npz")
    r.add_argument(
        "--yaw",
        type=finite_float,
        default=None,
        help="absolute head yaw, degrees, not relative to the photo's pose: the paper's R(yaw, pitch) in the "
        "camera frame, the head on the optical axis (0 = facing the camera; + = turned toward the image's left); "
        "with --pitch (default: both drawn from the head-pose distribution)",
    )
    r.add_argument(
        "--pitch",
        type=finite_float,
        default=None,
        help="absolute head pitch, degrees, as --yaw (+ = face turned up, the camera below the face); with --yaw",
    )
    r.add_argument(
        "--original-pose",
        action="store_true",
        help="keep the photo's own head pose and distance (reproduces gazeaug normalize); not with --yaw/--pitch",
    )
    r.add_argument(
        "--seed",
        type=_seed,
        default=None,
        help="seed of the head pose drawn from the distribution; not with --yaw/--pitch or --original-pose (default 0)",
    )
    r.add_argument(
        "--distance-to-camera",
        type=finite_float,
        default=None,
        help="camera to the point between the eyes, mm (default: the photo's distance); not with --original-pose",
    )
    r.add_argument("--renderer", choices=renderers, default="raycast", help=RENDERER_HELP)
    _add_input_options(r)
    _add_gaze_options(r)
    _add_normalization_options(r)
    _add_distribution_options(r)

    pv = sub.add_parser("preview", help="contact sheet of augmented eye patches and a plot of their distributions")
    pv.add_argument("input", nargs="?", type=Path, help="face image or .glb (default: the built-in sample)")
    pv.add_argument("-o", "--output", type=Path, required=True, help="contact sheet .png (the plot goes beside it)")
    pv.add_argument(
        "-n",
        type=_count(MAX_PREVIEW),
        default=16,
        help=f"number of augmented samples (default 16, at most {MAX_PREVIEW})",
    )
    pv.add_argument("--seed", type=_seed, default=0, help="seed of the head poses drawn (default 0)")
    pv.add_argument("--renderer", choices=renderers, default="raycast", help=RENDERER_HELP)
    _add_input_options(pv)
    _add_gaze_options(pv)
    _add_normalization_options(pv)
    _add_distribution_options(pv)

    for name, help_ in (
        ("augment", "augment a gaze dataset into an HDF5 training set (K renders per sample)"),
        ("normalize-dataset", "normalize a gaze dataset into an HDF5 training set (the baseline)"),
    ):
        a = sub.add_parser(name, help=help_)
        a.add_argument("dataset", type=Path, help="the dataset's root folder")
        a.add_argument("-o", "--output", type=Path, required=True, help="output .h5")
        a.add_argument("--format", choices=formats, help=format_help)
        _add_engine_options(a)
        a.add_argument(
            "--seed",
            type=_seed,
            default=0,
            help="seed of the head poses drawn (sample i draws from [seed, i]) (default 0)"
            if name == "augment"
            else "recorded with the settings; normalizing draws nothing at random (default 0)",
        )
        a.add_argument("--resume", action="store_true", help="continue an interrupted run (OUT.h5.part)")
        a.add_argument("--overwrite", action="store_true", help="replace an existing complete OUT.h5")
        a.add_argument("--limit", type=_positive_int, default=None, help="only the first N samples")
        a.add_argument("--quiet", action="store_true", help="no progress bar")
        _add_normalization_options(a)
        if name == "augment":
            a.add_argument(
                "--per-sample", type=_positive_int, default=4, help="K augmented samples per input sample (default 4)"
            )
            a.add_argument("--renderer", choices=renderers, default="raycast", help=RENDERER_HELP)
            _add_distribution_options(a)
            _add_eyes_option(a)
            _add_with_source_option(a)

    t = sub.add_parser("train", help="train the gaze model on an HDF5 training set")
    t.add_argument("train", type=Path, help="training set (.h5 from augment or normalize-dataset)")
    t.add_argument("-o", "--output", type=Path, required=True, help="model file (.pt)")
    tv = t.add_mutually_exclusive_group()
    tv.add_argument("--val", type=Path, default=None, help="a validation set (.h5) (default: no validation)")
    tv.add_argument(
        "--val-subjects",
        nargs="+",
        default=None,
        help="hold these subjects of the training set out, to validate on (default: no validation)",
    )
    t.add_argument(
        "--epochs",
        type=_positive_int,
        default=None,
        help="passes over the training set (default: fitted to its size, enough to show the model "
        "500k samples, at least 10, at most 2000)",
    )
    t.add_argument(
        "--batch-size",
        type=_positive_int,
        default=None,
        help="samples per step (default: fitted to the training set's size, rows / 128 as a power of two, 32 to 256)",
    )
    t.add_argument(
        "--samples",
        type=_positive_int,
        default=None,
        help="how many samples the fitted epochs show the model (default 500000; 1000000 read new people "
        "better in one measured run, at twice the time: docs/model.md); ignored with --epochs",
    )
    t.add_argument("--lr", type=finite_float, default=None, help=LR_HELP)
    t.add_argument(
        "--seed", type=_seed, default=0, help="seeds the weights, the shuffling and the augmentation (default 0)"
    )
    t.add_argument(
        "--device",
        choices=("auto", "cpu", "cuda"),
        default="auto",
        help="where to train; auto: CUDA when present, else the CPU (default auto)",
    )
    _add_train_input_options(t)
    t.add_argument(
        "--preload",
        choices=PRELOAD_CHOICES,
        default="auto",
        help="hold the training rows on the device, read once (yes), or stream them from the file each epoch (no); "
        "auto: held when they fit in half the memory free there, on the host at most 16 GiB. The same model "
        "either way (default auto)",
    )
    t.add_argument(
        "--no-cuda-graphs",
        action="store_true",
        help="on CUDA, call the model step by step rather than replay its forward and backward as CUDA graphs "
        "(the same training, slower; for a model that cannot be captured)",
    )
    t.add_argument("--resume", action="store_true", help="continue from the checkpoint beside the model (OUT.ckpt.pt)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")

    ev = sub.add_parser("evaluate", help="angular error of a model on a raw dataset or a normalized .h5")
    ev.add_argument("model", type=Path, help="a gaze model: .pt (gazeaug train) or .onnx (gazeaug export)")
    ev.add_argument("dataset", type=Path, help="a dataset folder (any reader) or a normalized .h5")
    ev.add_argument("-o", "--output", type=Path, required=True, help="report folder (errors.json/.csv/_hist.png)")
    ev.add_argument("--format", choices=formats, help=format_help)
    ev.add_argument("--limit", type=_positive_int, default=None, help="only the first N samples of a dataset folder")
    ev.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_mirror_option(ev)
    _add_engine_options(ev)

    pr = sub.add_parser("predict", help="gaze of the face in an image (camera frame) and a picture of it")
    pr.add_argument("model", type=Path, help="a gaze model: .pt (gazeaug train) or .onnx (gazeaug export)")
    pr.add_argument("image", type=Path, help="face image (the largest face is used)")
    pr.add_argument(
        "--camera",
        type=Path,
        help=f"calibration file (default: {DEFAULT_CAMERA_HELP})",
    )
    pr.add_argument("-o", "--output", type=Path, default=None, help="picture with the gaze arrow (.png/.jpg)")
    _add_mirror_option(pr)

    tk = sub.add_parser(
        "track",
        help="gaze per frame of a video, image folder or camera; with a rig, the point of gaze and dwell selections",
        description="Writes OUT/gaze.csv (one row per frame), OUT/overlay.mp4, OUT/summary.json, and with --rig "
        "OUT/selections.csv; prints one JSON line at the end. See docs/tracking.md.",
    )
    tk.add_argument(
        "source", help="a video file, a folder of images (name order), one image, or a camera (0, /dev/video0)"
    )
    tk.add_argument("-o", "--output", type=Path, required=True, help="output folder")
    tk.add_argument(
        "--model",
        type=Path,
        default=None,
        help="a gaze model: .pt (gazeaug train) or .onnx (gazeaug export) (default: the built-in demo model, "
        "trained on simulated people for the wheelchair rig; docs/tracking.md)",
    )
    tk.add_argument(
        "--camera",
        type=Path,
        help="the source's calibration file (default: the rig's camera when the frame size is the rig's, "
        f"else {DEFAULT_CAMERA_HELP})",
    )
    tk.add_argument(
        "--rig", help="a rig (built-in name or RIG.yaml) with targets and planes: point of gaze and selection"
    )
    tk.add_argument("--max-frames", type=_positive_int, default=None, help="stop after N frames")
    tk.add_argument(
        "--fps",
        type=finite_float,
        default=None,
        help="frame rate of a folder of images (default: its sequence.json, else 30)",
    )
    tk.add_argument(
        "--dwell",
        type=finite_float,
        default=0.6,
        help=f"seconds on a target to select it (default 0.6, at most {MAX_DWELL_S:g})",
    )
    tk.add_argument(
        "--margin",
        type=finite_float,
        default=5.0,
        help="how far off a target, in degrees of gaze, still counts as looking at it "
        f"(default 5, at most {MAX_MARGIN_DEG:g})",
    )
    tk.add_argument("--no-smoothing", action="store_true", help="no One-Euro smoothing of the gaze")
    tk.add_argument("--static", action="store_true", help="detect the face afresh in every frame (no tracking)")
    tk.add_argument("--no-video", action="store_true", help="do not write overlay.mp4")
    tk.add_argument("--show", action="store_true", help="show the overlay in a window (needs a display; q quits)")
    tk.add_argument(
        "--calibration", type=Path, default=None, help="the user's calibration for this model (gazeaug calibrate)"
    )
    tk.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_mirror_option(tk)

    cb = sub.add_parser(
        "calibrate",
        help="fit a user's correction of a model's gaze from a video of them looking at known points",
        description="Writes USER.json for `gazeaug track --calibration`; prints one JSON line (the kind of "
        "correction kept by leave-one-point-out, the errors before and after). See docs/tracking.md.",
    )
    cb.add_argument(
        "source", help="a video file or folder of images (a simulated --sequence folder needs no --targets)"
    )
    cb.add_argument("-o", "--output", type=Path, required=True, help="the calibration file (.json)")
    cb.add_argument(
        "--model", type=Path, default=None, help="the model to calibrate (.pt or .onnx; default: the demo model)"
    )
    cb.add_argument("--rig", default=None, help="the rig (built-in name or RIG.yaml) placing the camera and targets")
    cb.add_argument(
        "--targets",
        type=Path,
        default=None,
        help="CSV: start_s,end_s,target (a rig target's name) or start_s,end_s,x_mm,y_mm,z_mm (rig frame)",
    )
    cb.add_argument("--camera", type=Path, help="the source's calibration file (as for track)")
    cb.add_argument(
        "--settle", type=finite_float, default=0.3, help="seconds left out at the start of each look (default 0.3)"
    )
    cb.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_mirror_option(cb)

    ex = sub.add_parser("export", help="export a model to ONNX")
    ex.add_argument("model", type=Path, help="model file (.pt from gazeaug train)")
    ex.add_argument("-o", "--output", type=Path, required=True, help="output .onnx")

    sm = sub.add_parser("simulate", help="simulated subjects with known gaze, written as a folder dataset")
    sm.add_argument(
        "--faces",
        type=Path,
        nargs="*",
        default=None,
        help="face photos or videos (.mp4 .avi .mov .mkv .webm; well-spread frames) (default: the built-in sample)",
    )
    sm.add_argument("--rig", default="screen", help="'screen', 'wheelchair' or a RIG.yaml (default screen)")
    sm.add_argument("--per-face", type=_positive_int, default=10, help="images per face (default 10)")
    sm.add_argument(
        "--identities-per-face",
        type=_positive_int,
        default=1,
        help="simulated identities drawn from each face (shape, eyes, skin, glasses; default 1); "
        "each is a subject of its own",
    )
    sm.add_argument(
        "--per-video", type=_positive_int, default=8, help="frames taken from each video in --faces (default 8)"
    )
    sm.add_argument(
        "--all-faces", action="store_true", help="every face of a picture with several people (default: the largest)"
    )
    sm.add_argument(
        "--no-identity-variation",
        action="store_true",
        help="no identity draws: every subject looks like its photo (only the eye-axis offset is drawn)",
    )
    sm.add_argument(
        "--texture-mix",
        type=finite_float,
        default=0.0,
        metavar="SHARE",
        help="share of subjects whose skin is mixed with another face's of the run (0 to 1; the other's "
        "weight drawn in 0.25-0.6; default 0: each face's own skin)",
    )
    sm.add_argument(
        "--seed", type=_seed, default=0, help="everything drawn (identities, poses, gaze) derives from it (default 0)"
    )
    sm.add_argument("-o", "--output", type=Path, required=True, help="dataset folder to create")
    sm.add_argument("--overwrite", action="store_true", help="replace an existing dataset folder that simulate wrote")
    sm.add_argument(
        "--sequence",
        type=finite_float,
        default=None,
        metavar="SECONDS",
        help="one subject (the one face given) looking at the rig's targets for SECONDS, frames at --fps, "
        "with truth.csv for `gazeaug track` to score (needs a rig with targets; docs/tracking.md)",
    )
    sm.add_argument("--fps", type=finite_float, default=30.0, help="frame rate of a --sequence (default 30)")
    sm.add_argument(
        "--pattern",
        choices=("targets", "calibration"),
        default="targets",
        help="a --sequence's looks: the rig's targets with glances between (default), or a 3 x 3 calibration grid",
    )
    sm.add_argument(
        "--identity-seed",
        type=_seed,
        default=None,
        help="a --sequence's subject from this seed (default --seed): the same person in sequences of other seeds",
    )
    sm.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_engine_options(sm, block_size=False)  # one face per block

    xp = sub.add_parser("experiment", help="original vs. augmented training on the same data (the paper's Table 1)")
    xp.add_argument("--train", type=Path, default=None, help="training dataset folder (default: simulated 'screen')")
    xp.add_argument("--test", type=Path, default=None, help="test dataset folder (default: simulated 'wheelchair')")
    xp.add_argument(
        "--test-same-rig",
        type=Path,
        default=None,
        help="optional: the test people in the training rig (read with --test-format), to split the error into "
        "'new person' and 'new person, new rig' (the built-in setup simulates it)",
    )
    xp.add_argument("--faces", type=Path, nargs="*", default=None, help="extra face photos for the simulated setup")
    xp.add_argument(
        "--large",
        action="store_true",
        help="a larger simulated setup: 400 training images per face and 200 per test set (default 60 and 60)",
    )
    xp.add_argument(
        "--per-face",
        type=_positive_int,
        default=None,
        metavar="N",
        help="images per face in every simulated set of the built-in setup (default 60; --large: 400 and 200)",
    )
    xp.add_argument("-o", "--output", type=Path, required=True, help="report folder")
    xp.add_argument("--train-format", choices=formats, default=None, help=format_help)
    xp.add_argument("--test-format", choices=formats, default=None, help=format_help)
    xp.add_argument(
        "--per-sample", type=_positive_int, default=4, help="K augmented samples per training sample (default 4)"
    )
    _add_eyes_option(
        xp,
        "with --train/--test each sample keeps its source's gaze in the head, the paper's method; the built-in "
        f"setup redirects the eyes, to --rig {BUILTIN_TEST_RIG} unless another is given",
    )
    _add_with_source_option(xp, "the augmented model's training set")
    xp.add_argument(
        "--keep-eyes",
        action="store_true",
        help="the paper's method on the built-in setup: each augmented sample keeps its source's gaze in the head, "
        f"head poses from the distribution options (default there: --rig {BUILTIN_TEST_RIG} --redirect-eyes, the "
        "rig its test set is simulated in; with --train/--test keeping the eyes is the default)",
    )
    xp.add_argument(
        "--epochs",
        type=_positive_int,
        default=None,
        help="epochs of the augmented model; the original model gets as many optimizer steps "
        "(default: fitted to the augmented set's size as gazeaug train fits them; the built-in setup "
        "fits them for 100k samples instead of 500k)",
    )
    xp.add_argument(
        "--batch-size",
        type=_positive_int,
        default=None,
        help="samples per step, both models (default: fitted to the augmented set's size, as gazeaug train fits it)",
    )
    xp.add_argument("--lr", type=finite_float, default=3e-3, help=LR_HELP)
    _add_train_input_options(
        xp,
        "; the augmented model's alone (only redirected eyes are drawn: needs --redirect-eyes), the report says so",
    )
    _add_normalization_options(xp)
    xp.add_argument("--seed", type=_seed, default=0, help="the first seed (default 0)")
    xp.add_argument(
        "--seeds",
        type=_count(100),
        default=3,
        help="runs with seeds SEED, SEED+1, ...; every figure is their mean and standard deviation (default 3)",
    )
    xp.add_argument(
        "--workers",
        type=_count(MAX_WORKERS),
        default=1,
        help=f"processes of the dataset runs (augment, normalize-dataset) (default 1, at most {MAX_WORKERS})",
    )
    xp.add_argument("--quiet", action="store_true", help="no progress bars")
    _add_distribution_options(
        xp,
        "the paper's, yaw 0, pitch 30, variances 10 deg^2; the built-in setup: the --rig "
        f"{BUILTIN_TEST_RIG} its test set is simulated in, unless --keep-eyes",
    )

    rl = sub.add_parser(
        "realism",
        help="how far simulated eye patches are from real ones (a classifier two-sample test; docs/simulation.md)",
    )
    rl.add_argument(
        "real",
        type=Path,
        help="real eye patches: an .npz with 'images' (N, H, W[, 3]) uint8, as MPIIGaze's, or a training set .h5",
    )
    rl.add_argument("simulated", type=Path, help="simulated eye patches: a training set .h5 (or an .npz as above)")
    rl.add_argument("-o", "--output", type=Path, required=True, help="report folder (realism.json, realism.png)")
    rl.add_argument(
        "--patches",
        type=_integer(40),
        default=3000,
        help="at most this many patches per set (default 3000, at least 40)",
    )
    rl.add_argument("--epochs", type=_positive_int, default=8, help="the classifier's passes (default 8)")
    rl.add_argument("--seed", type=_seed, default=0, help="every random choice (default 0)")

    b = sub.add_parser("bench", help="benchmarks that print one JSON line")
    bsub = b.add_subparsers(dest="bench", required=True)
    br = bsub.add_parser("render", help="eye patches per second")
    br.add_argument(
        "--renderer",
        choices=RENDERERS.names(),
        default="raycast",
        help="the renderer timed; pyrender is the paper's (pip install 'gazeaug[bench]') (default raycast)",
    )
    br.add_argument("--n", type=_positive_int, default=2000, help="samples (two patches each; default 2000)")
    br.add_argument(
        "--per-face", type=_positive_int, default=16, help="samples per face before a new face (default 16)"
    )
    br.add_argument("--faces", type=Path, nargs="*", default=None, help="face images (default: the built-in sample)")
    br.add_argument("--seed", type=_seed, default=0, help="seed of the head poses drawn (default 0)")
    br.add_argument(
        "--workers", type=_count(MAX_WORKERS), default=1, help=f"processes (default 1, at most {MAX_WORKERS})"
    )
    br.add_argument("--batch", type=_positive_int, default=16, help="samples per render call (default 16)")
    return parser


def _settings(args: argparse.Namespace) -> Any:
    from .errors import GazeAugError
    from .normalize import NormalizationSettings

    face: dict[str, Any] = {}
    if args.face_patch is not None:
        face["face_patch_size_wh"] = tuple(args.face_patch)
    elif args.face_distance is not None or args.face_focal is not None:
        raise GazeAugError("--face-distance and --face-focal need --face-patch W H")
    if args.face_distance is not None:
        face["face_distance_mm"] = args.face_distance
    if args.face_focal is not None:
        face["face_focal_px"] = args.face_focal
    return NormalizationSettings(
        distance_mm=args.distance,
        focal_px=args.focal,
        patch_size_wh=tuple(args.patch_size),
        antialias=not args.no_antialias,
        **face,
    )


def _distribution(args: argparse.Namespace) -> Any:
    from .errors import GazeAugError
    from .sampling import HeadPoseDistribution, load_rig

    given = _given_distribution_options(args)
    if args.rig is not None:
        if given:
            raise GazeAugError(f"--rig sets the head-pose distribution; give it or {', '.join(given)}, not both")
        return load_rig(args.rig).distribution()
    for axis in ("yaw", "pitch"):
        if getattr(args, f"{axis}_var") is not None and getattr(args, f"{axis}_std") is not None:
            raise GazeAugError(f"give --{axis}-var or --{axis}-std, not both")
    var = []
    for axis in ("yaw", "pitch"):
        v, s = getattr(args, f"{axis}_var"), getattr(args, f"{axis}_std")
        if s is not None:
            if not (math.isfinite(s) and s >= 0):
                raise GazeAugError(f"--{axis}-std must be finite and >= 0, got {s}")
            v = s * s
        var.append(10.0 if v is None else v)
    yaw_mean = 0.0 if args.yaw_mean is None else args.yaw_mean
    pitch_mean = 30.0 if args.pitch_mean is None else args.pitch_mean
    return HeadPoseDistribution.from_variance(yaw_mean, pitch_mean, var[0], var[1])


def _fit_input(args: argparse.Namespace, path: Path | None) -> Any:
    """The face in the input image (--camera, --landmarks, --face-model, --keypoints, --face-index), as a FaceFit."""
    from facemesh.build import fit_face, landmark_model_for, load_input
    from facemesh.face_models import parse_keypoints

    image, camera, source = load_input(path, args.camera)
    keypoints = None if args.keypoints is None else parse_keypoints(args.keypoints)
    detector, face_model = landmark_model_for(args.landmarks, args.face_model, keypoints)
    return fit_face(image, camera, detector, face_model=face_model, face_index=args.face_index, source=source)


def _is_mesh_file(path: Path | None) -> TypeGuard[Path]:
    """Whether a face input is a saved mesh (.glb/.gltf) rather than an image (None: the built-in photo)."""
    return path is not None and path.suffix.lower() in (".glb", ".gltf")


def _face_asset(args: argparse.Namespace, path: Path | None) -> tuple[Any, str]:
    """The face to render (from a .glb or an image) and its name."""
    from .augment import face_asset
    from .pipeline import load_mesh, mesh_for_fit

    if _is_mesh_file(path):
        from facemesh.face_models import parse_keypoints

        keypoints = None if args.keypoints is None else parse_keypoints(args.keypoints)
        return face_asset(load_mesh(path), keypoints), str(path)
    fit = _fit_input(args, path)
    return face_asset(mesh_for_fit(fit)), fit.source


def _cmd_normalize(args: argparse.Namespace) -> int:
    from .normalize import normalize_image, save_npz

    settings = _settings(args)
    fit = _fit_input(args, args.image)
    image, camera, source = fit.image, fit.camera, fit.source
    sample = normalize_image(
        image,
        camera,
        fit.pose,
        fit.model.vertices_mm,
        fit.keypoints,
        gaze_target_mm=args.gaze_target,
        settings=settings,
        meta={"input": source, "camera": camera.source},
    )
    save_npz(args.output, sample)
    _report(args.output, sample)
    return 0


def _report(path: Path, sample: Any) -> None:
    out = {"output": str(path), "source": sample.source}
    for side in ("left", "right"):
        e = sample.eye(side)
        out[f"head_pose_{side}_deg"] = np.round(np.degrees(e.head_pose), 3).tolist()
        if e.gaze is not None:
            out[f"gaze_{side}_deg"] = np.round(np.degrees(e.gaze), 3).tolist()
    print(json.dumps(out))


def _cmd_render(args: argparse.Namespace) -> int:
    from .augment import render_poses, sampled_placement, source_placement, warn_texture_shortfall
    from .errors import GazeAugError
    from .normalize import save_npz
    from .render import create_renderer

    settings = _settings(args)
    if (args.yaw is None) != (args.pitch is None):
        raise GazeAugError("give both --yaw and --pitch (or neither, to sample a pose)")
    if args.original_pose and args.yaw is not None:
        raise GazeAugError("--original-pose and --yaw/--pitch exclude each other")
    if args.original_pose or args.yaw is not None:  # options that only a drawn pose would use
        fixed = "--original-pose" if args.original_pose else "--yaw/--pitch"
        unused = [f"--{n.replace('_', '-')}" for n in _DISTRIBUTION_OPTIONS + ("seed",) if getattr(args, n) is not None]
        if args.original_pose and args.distance_to_camera is not None:
            unused.append("--distance-to-camera")
        if unused:
            raise GazeAugError(f"{', '.join(unused)}: not used with {fixed}, which sets the head pose itself")
    args.seed = 0 if args.seed is None else args.seed
    dist = None if args.original_pose or args.yaw is not None else _distribution(args)
    asset, source = _face_asset(args, args.input)
    if args.original_pose:
        place = source_placement(asset)
    else:
        if args.yaw is not None:
            yaw, pitch = math.radians(args.yaw), math.radians(args.pitch)
        else:
            assert dist is not None
            yaw, pitch = dist.sample(1, args.seed)[0]
        place = sampled_placement(asset, yaw, pitch, args.distance_to_camera)
    if _is_mesh_file(args.input):  # its texture margin was chosen when it was built
        warn_texture_shortfall(asset, [place], settings, source)
    scene = create_renderer(args.renderer, settings=settings).scene(asset.render_mesh)
    meta: dict[str, Any] = {"input": source, "seed": args.seed}
    if dist is not None:
        meta["distribution"] = dist.as_dict()
    sample = render_poses(
        scene,
        asset,
        [place],
        gaze_target_mm=args.gaze_target,
        settings=settings,
        renderer_name=args.renderer,
        meta=meta,
    )[0]
    save_npz(args.output, sample)
    _report(args.output, sample)
    return 0


def _cmd_preview(args: argparse.Namespace) -> int:
    from facemesh.io import save_image_rgb

    from .augment import render_poses, sampled_placements, source_placement
    from .errors import GazeAugError
    from .render import create_renderer
    from .viz import contact_sheet, plot_distributions

    if args.n < 1:
        raise GazeAugError(f"-n: expected >= 1, got {args.n}")
    if args.output.suffix.lower() != ".png":
        raise GazeAugError(f"{args.output}: the contact sheet is written as .png")
    settings = _settings(args)
    dist = _distribution(args)
    asset, source = _face_asset(args, args.input)
    # without a known gaze, the subject is taken to look into the source camera
    target = args.gaze_target if args.gaze_target is not None else (0.0, 0.0, 0.0)
    scene = create_renderer(args.renderer, settings=settings).scene(asset.render_mesh)
    yp = dist.sample(args.n, args.seed)
    places = sampled_placements(asset, yp)
    augmented = render_poses(
        scene, asset, places, gaze_target_mm=target, settings=settings, renderer_name=args.renderer
    )
    original = render_poses(scene, asset, [source_placement(asset)], gaze_target_mm=target, settings=settings)
    sheet = contact_sheet(augmented)
    plot_path = args.output.with_name(args.output.stem + "_distribution.png")
    save_image_rgb(args.output, sheet)
    plot_distributions(
        {"original": original, "augmented": augmented}, plot_path, title=f"{Path(source).name}: head pose and gaze"
    )
    print(json.dumps({"sheet": str(args.output), "plot": str(plot_path), "samples": args.n, "seed": args.seed}))
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from .augment import face_asset
    from .bench import bench_render
    from .errors import GazeAugError
    from .pipeline import default_landmark_model, fit_face, load_input, mesh_for_fit

    if args.n < 1 or args.per_face < 1 or args.workers < 1 or args.batch < 1:
        raise GazeAugError("--n, --per-face, --workers and --batch must be >= 1")
    paths = args.faces or [None]
    detector = default_landmark_model()
    assets = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for p in paths:
            image, camera, source = load_input(p, None)
            assets.append(face_asset(mesh_for_fit(fit_face(image, camera, detector, source=source))))
    result = bench_render(
        assets,
        renderer=args.renderer,
        n=args.n,
        per_face=args.per_face,
        seed=args.seed,
        workers=args.workers,
        batch=args.batch,
    )
    print(json.dumps(result))
    return 0


def _cmd_dataset(args: argparse.Namespace) -> int:
    from .datasets import open_dataset
    from .jobs import JobSettings, run_dataset
    from .sampling import load_rig

    if args.command == "augment":  # the options first, then the data
        settings = JobSettings(
            kind="augment",
            per_sample=args.per_sample,
            distribution=_distribution(args),
            seed=args.seed,
            renderer=args.renderer,
            normalization=_settings(args),
            rig=None if args.rig is None else load_rig(args.rig).as_dict(),
            eyes=_eyes(args),
            with_source=args.with_source,
        )
    else:
        settings = JobSettings(kind="normalize-dataset", seed=args.seed, normalization=_settings(args))
    engine = _engine(args)
    reader = open_dataset(args.dataset, args.format)
    summary = run_dataset(
        reader,
        args.output,
        settings,
        workers=args.workers or 1,
        engine=engine,
        resume=args.resume,
        overwrite=args.overwrite,
        limit=args.limit,
        progress=not args.quiet,
    )
    short = {k: summary[k] for k in ("output", "samples", "rows", "skipped", "samples_per_second")}
    print(json.dumps(short))
    return 0


def _add_train_input_options(p: argparse.ArgumentParser, keypoint_note: str = "") -> None:
    """The training options of ``train`` and ``experiment`` (read by :func:`_train_input_settings`).

    ``keypoint_note`` ends ``--keypoint-loss``'s help (what it means for this command).
    """
    from .models import MODELS

    p.add_argument(
        "--model",
        choices=MODELS.names(),
        default="mobilenet_gaze",
        help="the gaze model's architecture, a registered name (default mobilenet_gaze)",
    )
    p.add_argument(
        "--keypoint-loss",
        type=finite_float,
        default=0.0,
        metavar="W",
        help="also teach the eye encoder where each eye's iris centre and opening centre lie (the set's "
        "eye_keypoints, written by augment --redirect-eyes), weight W, 0 to 100 (default 0: off); the model "
        f"file is the same network either way{keypoint_note} (docs/model.md)",
    )
    p.add_argument(
        "--no-augment",
        action="store_true",
        help="no training-time augmentation (shifts, blur, colour, contrast, brightness, gamma, noise; "
        "on by default, see docs/model.md)",
    )
    p.add_argument(
        "--augment",
        action="append",
        default=None,
        metavar="NAME=VALUE",
        help="one strength of the training-time augmentation, again for each (e.g. mirror=0.5 scale=0.15): "
        f"{', '.join(AUGMENT_NAMES)}; 0 turns one off (defaults and ranges: docs/model.md)",
    )
    p.add_argument(
        "--input",
        default="rgb",
        metavar="{rgb,grey_equalized}",
        help="the model's input: rgb (default) or grey_equalized (grey + histogram equalization, as MPIIGaze; "
        "recorded in the model and applied by predict, evaluate)",
    )
    p.add_argument(
        "--no-mirror-average",
        action="store_true",
        help="the model predicts from the eyes alone; by default its answer is averaged with its answer on the "
        "mirrored eyes (recorded in the model and applied by predict, evaluate, track, export)",
    )
    p.add_argument(
        "--shift-average",
        type=int,
        default=3,
        metavar="PX",
        help="the model's answer is averaged over its eye patches translated by PX pixels (9 answers; "
        "0: off; 0 to 8, default 3; recorded in the model and applied by predict, evaluate, track, export)",
    )
    p.add_argument(
        "--face",
        action="store_true",
        help="the model also reads the normalized face patch (the data must carry one: made with --face-patch W H; "
        "default: the eyes and the head pose)",
    )
    p.add_argument(
        "--no-balance-axes",
        action="store_true",
        help="the plain L1 loss on (pitch, yaw); by default each axis is weighed by the inverse of its spread "
        "over the training labels, so the narrower pitch counts as much as the yaw (docs/model.md)",
    )


def _augment_settings(pairs: list[str] | None, enabled: bool) -> Any:
    """The :class:`~gazeaug.train_augment.TrainAugment` of ``--augment NAME=VALUE`` (each once) and ``--no-augment``.

    Raises:
        GazeAugError: an unknown name, a name given twice, a value that is not a number (its range is
            :class:`~gazeaug.train_augment.TrainAugment`'s to check), or strengths with ``--no-augment``.
    """
    from .errors import GazeAugError
    from .train_augment import TrainAugment

    strengths: dict[str, float | int] = {}
    for pair in pairs or []:
        name, sep, text = pair.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or name not in AUGMENT_NAMES:
            raise GazeAugError(f"--augment {pair!r}: expected NAME=VALUE, NAME one of {', '.join(AUGMENT_NAMES)}")
        if name in strengths:
            raise GazeAugError(f"--augment {name}: given twice")
        try:
            value = float(text)
        except ValueError:
            raise GazeAugError(f"--augment {name}: expected a number, got {text.strip()!r}") from None
        strengths[name] = int(value) if name == "shift_px" and value.is_integer() else value
    if strengths and not enabled:
        raise GazeAugError("--augment and --no-augment: give one or the other")
    try:
        return TrainAugment(enabled=enabled, **strengths)  # type: ignore[arg-type]  # it checks each value
    except GazeAugError as exc:
        raise GazeAugError(f"--augment {exc}") from None


def _train_input_settings(args: argparse.Namespace) -> dict[str, Any]:
    """The TrainSettings keywords of :func:`_add_train_input_options` (checked by TrainSettings)."""
    return {
        "model": args.model,
        "keypoint_loss_weight": args.keypoint_loss,
        "augment": _augment_settings(args.augment, not args.no_augment),
        "input_mode": args.input,
        "mirror_average": not args.no_mirror_average,
        "shift_average_px": args.shift_average,
        "model_options": {"face": True} if args.face else {},
        "balance_axes": not args.no_balance_axes,
    }


def _cmd_train(args: argparse.Namespace) -> int:
    from .train import TrainSettings, train

    settings = TrainSettings(
        epochs=args.epochs,
        batch_size=args.batch_size,
        auto_samples=TrainSettings.auto_samples if args.samples is None else args.samples,
        lr=TrainSettings.lr if args.lr is None else args.lr,
        seed=args.seed,
        device=args.device,
        **_train_input_settings(args),
    )
    log = train(
        args.train,
        args.output,
        settings,
        val_path=args.val,
        val_subjects=args.val_subjects,
        resume=args.resume,
        progress=not args.quiet,
        given=tuple(k for k, v in (("lr", args.lr), ("auto_samples", args.samples)) if v is not None),
        preload=args.preload,
        keep_unfinished=True,
        cuda_graphs=not args.no_cuda_graphs,
    )
    print(json.dumps({"model": str(args.output), "epochs": len(log), "last": log[-1]}))
    return 0


def _add_mirror_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--mirror-average",
        choices=("on", "off"),
        default=None,
        help="average the network's answers on the eyes and on their mirror image, or read it plainly "
        "(default: as the model file says; a .onnx export as it was exported)",
    )


def _mirror_choice(args: argparse.Namespace) -> bool | None:
    return None if args.mirror_average is None else args.mirror_average == "on"


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from .errors import GazeAugError
    from .estimator import load_estimator
    from .evaluate import evaluate_dataset, evaluate_h5, write_report

    engine = _engine(args, local_workers=False)
    model = load_estimator(args.model, mirror_average=_mirror_choice(args))
    if args.dataset.suffix in (".h5", ".hdf5"):
        if engine.kind != "local":
            raise GazeAugError("--engine ray: for raw datasets; a normalized .h5 is evaluated here")
        result = evaluate_h5(model, args.dataset)
    else:
        from .datasets import open_dataset

        reader = open_dataset(args.dataset, args.format)
        result = evaluate_dataset(model, model.meta, reader, limit=args.limit, progress=not args.quiet, engine=engine)
    paths = write_report(result, args.output)
    short = {k: result[k] for k in ("count", "mean_deg", "median_deg", "skipped", "mirror_average")}
    short["per_subject"] = {k: round(v["mean_deg"], 3) for k, v in result["per_subject"].items()}
    short["report"] = str(paths["json"])
    print(json.dumps(short))
    return 0


def _cmd_predict(args: argparse.Namespace) -> int:
    from facemesh.conventions import vector_to_pitchyaw
    from facemesh.io import save_image_rgb
    from facemesh.pose import project_points

    from .estimator import load_estimator
    from .evaluate import predict_image
    from .pipeline import default_landmark_model, fit_face, load_input

    model = load_estimator(args.model, mirror_average=_mirror_choice(args))
    image, camera, source = load_input(args.image, args.camera)
    fit = fit_face(image, camera, default_landmark_model(), source=source)
    g, sample = predict_image(model, image, fit, model.normalization)
    assert sample.face is not None
    origin = sample.face.camera.reference_mm
    out: dict[str, Any] = {
        "image": source,
        "gaze_vector_camera": np.round(g, 6).tolist(),
        "gaze_pitchyaw_camera_deg": np.round(np.degrees(vector_to_pitchyaw(g)), 3).tolist(),
        "gaze_origin_mm": np.round(origin, 2).tolist(),
        "mirror_average": model.mirror_average,
    }
    if args.output is not None:
        import cv2

        pts = project_points(np.stack([origin, origin + 150.0 * g]), camera)
        pic = image.copy()
        a, b = (tuple(int(round(v)) for v in p) for p in pts)
        thick = max(2, image.shape[1] // 300)
        cv2.arrowedLine(pic, a, b, (255, 40, 40), thick, cv2.LINE_AA, tipLength=0.15)
        save_image_rgb(args.output, pic)
        out["picture"] = str(args.output)
    print(json.dumps(out))
    return 0


def _model_or_demo(path: Path | None) -> Path:
    """The model given, or the built-in demo model (with a warning saying what it is)."""
    import warnings

    from .errors import GazeAugError
    from .models.train_demo import DEMO_MODEL

    if path is not None:
        return path
    if not DEMO_MODEL.is_file():
        raise GazeAugError(f"no --model given and the built-in demo model is missing ({DEMO_MODEL}); give --model")
    warnings.warn(
        "no --model: using the built-in demo model, trained on simulated people for the wheelchair rig "
        "(a demonstration, not a tracker for real users; docs/tracking.md)",
        stacklevel=2,
    )
    return DEMO_MODEL


def _cmd_track(args: argparse.Namespace) -> int:
    from .errors import GazeAugError
    from .selection import MAX_DWELL_S, MAX_MARGIN_DEG
    from .track import MAX_FPS, MIN_FPS

    if not args.dwell > 0:
        raise GazeAugError(f"--dwell: expected seconds > 0, got {args.dwell}")
    if not 0 <= args.margin <= MAX_MARGIN_DEG:
        raise GazeAugError(f"--margin: expected degrees from 0 to {MAX_MARGIN_DEG:g}, got {args.margin}")
    if args.dwell > MAX_DWELL_S:
        raise GazeAugError(f"--dwell: expected seconds up to {MAX_DWELL_S:g}, got {args.dwell}")
    if args.fps is not None and not MIN_FPS <= args.fps <= MAX_FPS:
        raise GazeAugError(f"--fps: expected frames per second from {MIN_FPS:g} to {MAX_FPS:g}, got {args.fps}")

    from .estimator import load_estimator
    from .sampling import load_rig
    from .selection import SelectionSettings, SmoothingSettings
    from .track import TrackSettings, track

    settings = TrackSettings(
        smoothing=None if args.no_smoothing else SmoothingSettings(),
        selection=SelectionSettings(dwell_s=args.dwell, margin_deg=args.margin),
        tracking=not args.static,
        max_frames=args.max_frames,
        folder_fps=args.fps,
        video=not args.no_video,
        show=args.show,
    )
    rig = load_rig(args.rig) if args.rig is not None else None
    camera = _frames_camera(args.camera)
    model = _model_or_demo(args.model)
    estimator = load_estimator(model, mirror_average=_mirror_choice(args))
    calibration = None
    if args.calibration is not None:
        from .calibration import load_calibration

        calibration = load_calibration(
            args.calibration, estimator.model_sha256, mirror_average=estimator.mirror_average
        )
    summary = track(
        args.source,
        args.output,
        estimator,
        camera=camera,
        rig=rig,
        settings=settings,
        progress=not args.quiet,
        calibration=calibration,
    )
    print(json.dumps(summary))
    return 0


def _frames_camera(path: Path | None) -> Any:
    """``--camera`` of a command that reads frames: the intrinsics, or the file when it gives no image size.

    A file without a size (MPIIGaze's ``Camera.mat``, a bare OpenCV matrix) is read with the first
    frame's size by :func:`gazeaug.track.track`; a file with one is checked now, before any work.
    """
    from facemesh.camera import CameraSizeMissing, load_camera

    if path is None:
        return None
    try:
        return load_camera(path)
    except CameraSizeMissing:
        return Path(path)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from .calibration import calibrate
    from .estimator import load_estimator
    from .sampling import load_rig

    rig = load_rig(args.rig) if args.rig is not None else None
    camera = _frames_camera(args.camera)
    estimator = load_estimator(_model_or_demo(args.model), mirror_average=_mirror_choice(args))
    cal, report = calibrate(
        args.source,
        estimator,
        rig=rig,
        targets=args.targets,
        camera=camera,
        settle_s=args.settle,
        progress=not args.quiet,
    )
    cal.save(args.output)
    print(json.dumps({**report, "calibration": str(args.output)}))
    return 0


def _cmd_realism(args: argparse.Namespace) -> int:
    from facemesh.io import atomic_write

    from .realism import RealismSettings, compare_patches, read_eye_patches, realism_sheet

    settings = RealismSettings(max_patches=args.patches, epochs=args.epochs, seed=args.seed)
    real, real_who = read_eye_patches(args.real, max_rows=args.patches, seed=args.seed)
    simulated, sim_who = read_eye_patches(args.simulated, max_rows=args.patches, seed=args.seed)
    report = compare_patches(real, simulated, settings, real_groups=real_who, simulated_groups=sim_who)
    out = {"real_file": str(args.real), "simulated_file": str(args.simulated), **report.as_dict()}
    args.output.mkdir(parents=True, exist_ok=True)
    realism_sheet(real, report, args.output / "realism.png", title=args.simulated.name)
    with atomic_write(args.output / "realism.json") as fh:  # last: a report with its JSON is complete
        fh.write(json.dumps(out, indent=1).encode("utf-8"))
    print(json.dumps({**out, "report": str(args.output / "realism.json")}))
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from .export import export_onnx
    from .train import load_model

    model, meta = load_model(args.model)
    path = export_onnx(model, meta, args.output)
    print(json.dumps({"onnx": str(path)}))
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from .sampling import load_rig
    from .simulate import SimSettings, simulate

    faces = list(args.faces) if args.faces else [None]
    from .errors import GazeAugError

    engine = _engine(args, local_workers=False)
    settings = SimSettings(vary_identity=not args.no_identity_variation, texture_mix_share=args.texture_mix)
    if args.sequence is not None and engine.kind != "local":
        raise GazeAugError("--sequence: one subject, simulated on this machine (no --engine ray)")
    if args.sequence is None:
        extra = [
            o
            for o, v, d in (
                ("--fps", args.fps, 30.0),
                ("--pattern", args.pattern, "targets"),
                ("--identity-seed", args.identity_seed, None),
            )
            if v != d
        ]
        if extra:
            raise GazeAugError(f"{', '.join(extra)}: only with --sequence")
    else:
        from .sequence import SequenceSettings, simulate_sequence

        if len(faces) != 1:
            raise GazeAugError(f"--sequence: one subject, so one face; got {len(faces)} faces")
        seq = simulate_sequence(
            faces[0],
            load_rig(args.rig),
            args.output,
            sequence=SequenceSettings(seconds=args.sequence, fps=args.fps, pattern=args.pattern),
            seed=args.seed,
            identity_seed=args.identity_seed,
            settings=settings,
            overwrite=args.overwrite,
            progress=not args.quiet,
        )
        print(json.dumps(seq))
        return 0
    summary = simulate(
        faces,
        load_rig(args.rig),
        args.output,
        per_face=args.per_face,
        seed=args.seed,
        progress=not args.quiet,
        overwrite=args.overwrite,
        identities_per_face=args.identities_per_face,
        per_video=args.per_video,
        all_faces=args.all_faces,
        settings=settings,
        engine=engine,
    )
    print(json.dumps({k: summary[k] for k in ("output", "images", "faces", "subjects")}))
    return 0


def _builtin_redirects(args: argparse.Namespace) -> None:
    """The built-in experiment's default recipe: ``--redirect-eyes``, ``--rig wheelchair`` unless another is given.

    Keeping the eyes (the paper's method) trains on the screen task's gaze relative to the head, which
    lies far from the wheelchair task's: such models read no eyes of the test person, and their
    difference is a difference of global offsets (docs/model.md, "The built-in setup").
    """
    from .errors import GazeAugError
    from .experiment import BUILTIN_TEST_RIG

    given = _given_distribution_options(args)
    if given:
        raise GazeAugError(
            f"the built-in experiment redirects the eyes to a rig's targets, and the rig sets the head poses: "
            f"give --keep-eyes to augment with {', '.join(given)} (the paper's method), or leave them out "
            f"(--rig chooses another rig)"
        )
    args.redirect_eyes = True
    if args.rig is None:
        args.rig = BUILTIN_TEST_RIG


def _cmd_experiment(args: argparse.Namespace) -> int:
    from .errors import GazeAugError
    from .experiment import (
        BUILTIN_TRAIN,
        ExperimentSettings,
        builtin_setup,
        metric_table,
        reading_verdict,
        reduction_table,
        run_experiment,
        table,
    )
    from .sampling import load_rig
    from .train import TrainSettings

    if (args.train is None) != (args.test is None):
        raise GazeAugError("give both --train and --test, or neither (the built-in simulated setup)")
    if args.test_same_rig is not None and args.test is None:
        raise GazeAugError("--test-same-rig goes with --train and --test (the built-in setup simulates its own)")
    if args.per_face is not None and (args.train is not None or args.large):
        raise GazeAugError("--per-face sizes the built-in simulated setup: not with --train/--test or --large")
    if args.keep_eyes and args.redirect_eyes:
        raise GazeAugError("give --keep-eyes (the paper's method) or --redirect-eyes, not both")
    if args.keypoint_loss and (args.keep_eyes or (args.train is not None and not args.redirect_eyes)):
        # the keypoints are where the drawn eyes put them: only redirected eyes are drawn
        fix = "drop --keep-eyes" if args.keep_eyes else "add --redirect-eyes (with --rig)"
        raise GazeAugError(
            f"--keypoint-loss needs redirected eyes, whose keypoints are drawn: {fix} or drop --keypoint-loss"
        )
    if args.train is None and not args.keep_eyes:
        _builtin_redirects(args)
    distribution = _distribution(args)  # a bad rig, distribution or patch is refused before minutes of work
    normalization = _settings(args)
    if args.face and normalization.face_patch_size_wh is None:
        raise GazeAugError("--face: the model reads a face patch; give its size with --face-patch W H (e.g. 224 224)")
    defaults = BUILTIN_TRAIN if args.train is None else TrainSettings()
    # every setting checked (the training's against the patches included) before the built-in sets are made
    settings = ExperimentSettings(
        per_sample=args.per_sample,
        distribution=distribution,
        train=TrainSettings(
            epochs=args.epochs,
            batch_size=args.batch_size,
            auto_samples=defaults.auto_samples,
            lr=args.lr,
            seed=args.seed,
            **_train_input_settings(args),
        ),
        workers=args.workers,
        seed=args.seed,
        seeds=args.seeds,
        rig=None if args.rig is None else load_rig(args.rig),
        eyes=_eyes(args),
        with_source=args.with_source,
        normalization=normalization,
    )
    if args.train is None:
        from facemesh.io import load_image_rgb

        for face in args.faces or []:
            load_image_rgb(face)  # every photo readable before the simulation starts
        setup = builtin_setup(
            args.output,
            extra_faces=args.faces or [],
            large=args.large,
            seed=args.seed,
            progress=not args.quiet,
            sizes=None if args.per_face is None else (args.per_face, args.per_face),
        )
        args.train, args.test, args.test_same_rig = setup.train, setup.test, setup.test_same_rig
    results = run_experiment(
        args.train,
        args.test,
        args.output,
        settings,
        train_format=args.train_format,
        test_format=args.test_format,
        test_same_rig=args.test_same_rig,
        test_same_rig_format=args.test_format,
        progress=not args.quiet,
    )
    print(table(results))
    print(reading_verdict(results))
    print(metric_table(results, "mean_deg"))
    print(reduction_table(results))
    b = results["tests"]["test"]["bootstrap"]
    print(
        json.dumps(
            {
                "report": str(args.output / "report.md"),
                "reduction_percent": results["reduction_percent"],
                "interval_percent": None if b is None else [b["low"], b["high"]],
                "steps": {k: results["runs"][k]["steps"] for k in ("original", "augmented")},
            }
        )
    )
    return 0


_COMMANDS = {
    "simulate": _cmd_simulate,
    "experiment": _cmd_experiment,
    "train": _cmd_train,
    "evaluate": _cmd_evaluate,
    "predict": _cmd_predict,
    "export": _cmd_export,
    "realism": _cmd_realism,
    "track": _cmd_track,
    "calibrate": _cmd_calibrate,
    "augment": _cmd_dataset,
    "normalize-dataset": _cmd_dataset,
    "normalize": _cmd_normalize,
    "render": _cmd_render,
    "preview": _cmd_preview,
    "bench": _cmd_bench,
}


def _check_outputs(args: argparse.Namespace) -> None:
    """Check every output path of the command before any work starts (see :mod:`facemesh.outputs`)."""
    from facemesh.outputs import check_output_file, check_output_folder, check_picture_path

    cmd, out = args.command, getattr(args, "output", None)
    if out is None:  # predict without -o; bench writes nothing
        return
    if cmd in ("normalize", "render"):
        check_output_file(out, (".npz",), what="eye patches file")
    elif cmd == "preview":
        check_output_file(out, (".png",), what="contact sheet")
        check_output_file(_beside_output(args)[0], what="distribution plot")
    elif cmd in ("augment", "normalize-dataset"):
        check_output_file(out, (".h5", ".hdf5"), what="training set")
        for beside in _beside_output(args):
            check_output_file(beside, what="file beside the training set")
    elif cmd == "train":
        check_output_file(out, (".pt",), what="model file")
        for beside in _beside_output(args):
            check_output_file(beside, what="file beside the model")
    elif cmd == "export":
        check_output_file(out, (".onnx",), what="ONNX file")
    elif cmd == "predict":
        check_picture_path(out)
    elif cmd in ("evaluate", "experiment", "realism"):
        check_output_folder(out, what="report folder")
    elif cmd == "track":
        check_output_folder(out, what="output folder")
    elif cmd == "calibrate":
        check_output_file(out, (".json",), what="calibration file")
    elif cmd == "simulate":
        check_output_folder(out, what="dataset folder")
    _refuse_output_over_input(args)


#: Files of a folder source that its reader uses besides the frames (a sequence folder's; gazeaug.sequence).
_SOURCE_FOLDER_FILES = ("sequence.json", "truth.csv")
#: The suffixes of the files written beside each command's output file (it is ``-o`` with its suffix replaced).
_BESIDE_OUTPUT = {
    "augment": (".h5.part", ".summary.json", ".distribution.png"),
    "normalize-dataset": (".h5.part", ".summary.json", ".distribution.png"),
    "train": (".ckpt.pt", ".log.csv", ".curves.png"),
}


def _beside_output(args: argparse.Namespace) -> list[Path]:
    """The files a command writes beside its ``-o`` file (``preview``: the distribution plot)."""
    out = Path(args.output)
    if args.command == "preview":
        return [out.with_name(out.stem + "_distribution.png")]
    return [out.with_suffix(x) for x in _BESIDE_OUTPUT.get(args.command, ())]


def _refuse_output_over_input(args: argparse.Namespace) -> None:
    """Refuse an output file that is one of the command's inputs (``predict photo.png -o photo.png``).

    Every argument naming an existing file is an input; a folder given as the source also holds
    :data:`_SOURCE_FOLDER_FILES` (``calibrate calib/ -o calib/sequence.json``). Output folders are
    checked by their commands (``track`` refuses a source among the files it writes).
    """
    from .errors import GazeAugError

    out = getattr(args, "output", None)
    if out is None or args.command in ("evaluate", "experiment", "realism", "track", "simulate"):
        return
    outs = [Path(out), *_beside_output(args)]
    inputs: list[Path] = []
    for key, value in vars(args).items():
        if key == "output":
            continue
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if not isinstance(v, (str, Path)) or not str(v):
                continue
            p = Path(v)
            try:  # any string argument is tried as a path: a name too long for one is no input
                if p.is_file():
                    inputs.append(p)
                elif p.is_dir() and key == "source":
                    inputs.extend(p / n for n in _SOURCE_FOLDER_FILES if (p / n).is_file())
            except OSError:
                continue
    for o in outs:
        if not o.exists():
            continue
        for p in inputs:
            if o.resolve() == p.resolve():
                raise GazeAugError(f"{o}: the output would replace the input {p}; choose another -o")


def _interrupted(args: argparse.Namespace) -> str | None:
    """What an interrupted command kept, and how to go on (one line); ``None``: no partial output.

    ``None`` leaves the line to :func:`facemesh.cli.run_command`: the files the command had
    finished, or that nothing was written.
    """
    out = getattr(args, "output", None)
    if args.command in ("augment", "normalize-dataset") and out is not None:
        from .io_h5 import part_path

        part = part_path(out)
        if part.exists():
            return f"kept {part} (every sample up to the last flush); run the same command with --resume to continue"
        if Path(out).exists():
            return f"{out} is complete; its summary files may be missing"
    if args.command == "train" and out is not None:
        from .train import unfinished_checkpoint

        ckpt = unfinished_checkpoint(out)  # a finished run's checkpoint beside it is no run to go on with
        if ckpt is not None:
            return f"kept {ckpt} (the last finished epoch); run the same command with --resume to continue"
    # track keeps a summary.json with its outputs; stopped before a frame was decoded, it kept nothing
    if args.command == "track" and out is not None and (Path(out) / "summary.json").is_file():
        return f"the outputs in {out} are complete up to the last frame processed"
    if args.command == "experiment" and out is not None:
        return f"the steps that finished are in {out}; run the same command again to redo the rest"
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (2 bad input, 130 Ctrl-C, 1 anything unexpected)."""
    from facemesh.cli import run_command

    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # bad options (one line printed, 2), --help or --version (0)
        return exc.code if isinstance(exc.code, int) else 2

    def command() -> int:
        _check_outputs(args)
        return _COMMANDS[args.command](args)

    return run_command(f"gazeaug {args.command}", command, lambda: _interrupted(args))


def entry() -> None:
    """The ``gazeaug`` console script (see :func:`facemesh.cli.console_entry`)."""
    from facemesh.cli import console_entry

    console_entry(main, "gazeaug")


if __name__ == "__main__":
    entry()
