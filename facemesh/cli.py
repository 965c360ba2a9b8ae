"""``facemesh`` command line: a thin layer over the library.

Exit codes: 0 success; 2 bad input (missing or unreadable file, no face, bad
option values); 1 anything unexpected. No output file is left behind on failure.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .face_models import KEYPOINTS
from .types import FaceMeshError, InputError

__all__ = [
    "main",
    "entry",
    "run_command",
    "console_entry",
    "OneLineParser",
    "finite_float",
    "build_parser",
    "error_line",
    "REMEDIES",
    "KEYPOINTS_HELP",
]


#: How each command line phrases an error's ``remedy`` (:class:`facemesh.types.FaceMeshError`).
REMEDIES = {
    "overwrite": "pass --overwrite to replace it",
    "resume": "pass --resume to continue it, or delete it to start over",
    "same_settings": "resume with the same options, or delete it to start over",
    "format": "pass --format",
    "landmarks": "pass --landmarks with the model's own points",
    "face_model": "pass --face-model (the 3D points your landmarks correspond to)",
    "stream": "pass --preload no to stream them from the file instead",
    "memory": "pass a smaller --batch-size, or --preload no where the rows were held (a new batch size starts over)",
    "keypoints": f"pass --keypoints (a layout: {', '.join(KEYPOINTS)}; or the indices RO,RI,LI,LO[,MR,ML])",
}

#: The camera assumed without a calibration file (:func:`facemesh.camera.default_camera`), for help texts.
DEFAULT_CAMERA_HELP = "focal length max(W, H) px, principal point at the image centre, no distortion, with a warning"
#: Help of ``--camera`` for a face input (both command lines).
CAMERA_HELP = (
    f"calibration: OpenCV XML/YAML/JSON FileStorage or MPIIFaceGaze Camera.mat (default: {DEFAULT_CAMERA_HELP})"
)
#: Help of ``--face-model`` (both command lines).
FACE_MODEL_HELP = (
    "the 3D face model the landmarks correspond to: 'mediapipe' or a model file (.obj, .pbtxt, .txt, .csv, .npy; "
    "mm) (default: mediapipe)"
)
#: Help of ``--face-index`` (both command lines).
FACE_INDEX_HELP = (
    "which face when there are several, by size: 0 = the largest, 1 = the second largest, ... (default: the largest)"
)

#: Help of the ``--keypoints`` option (both command lines).
KEYPOINTS_HELP = (
    "which face model points are the eye and mouth corners: a layout (" + ", ".join(KEYPOINTS) + ") or 4 or 6 indices "
    "RO,RI,LI,LO[,MR,ML] (right eye outer, inner, left eye inner, outer, mouth right, left); default: what the "
    "model file says"
)


def error_line(exc: BaseException) -> str:
    """An error as one line: the library's facts, then the remedy in the command line's terms."""
    text = " ".join(str(exc).split())
    remedy = getattr(exc, "remedy", None)
    return f"{text}; {REMEDIES[remedy]}" if remedy in REMEDIES else text


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``PROG CMD: error: ...``) and exit 2 (both command lines)."""

    def error(self, message: str) -> Any:  # type: ignore[override]
        """Print the problem on one line and exit 2 (argparse prints the usage too)."""
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


#: Upper bound of ``facemesh render --supersample``: the rays (and memory) grow as its square.
MAX_SUPERSAMPLE = 8


def integer_in(low: int, high: int | None = None) -> Any:
    """Argparse type: an integer >= ``low`` (and <= ``high`` when given)."""
    expected = f"an integer >= {low}" if high is None else f"an integer from {low} to {high}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {value}")
        return value

    return parse


def finite_float(text: str) -> float:
    """Argparse type: a finite float (NaN and infinities are refused)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``facemesh`` command."""
    from . import __version__
    from .mesh import BuildSettings
    from .reconstruct import MIN_SURFACE_POINTS, SURFACE_METHODS

    parser = OneLineParser(prog="facemesh", description="Textured 3D face meshes from face landmarks, as glTF.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    b = sub.add_parser("build", help="build the textured mesh of a face photo (.glb)")
    b.add_argument(
        "image", nargs="?", type=Path, help="face photo (default: the built-in sample, scikit-image's astronaut)"
    )
    b.add_argument("-o", "--output", type=Path, required=True, help="output .glb")
    b.add_argument("--camera", type=Path, help=CAMERA_HELP)
    b.add_argument("--face-index", type=int, default=None, help=FACE_INDEX_HELP)
    b.add_argument(
        "--vertices",
        choices=("canonical", "backprojected", "landmarks3d"),
        default="backprojected",
        help="where each vertex goes: canonical = the face model's point at the solved pose; backprojected = on "
        "the camera ray through its landmark, at the posed model's depth; landmarks3d = on that ray, at the "
        "detector's own depth (MediaPipe) (default: backprojected)",
    )
    b.add_argument("--face-model", default=None, help=FACE_MODEL_HELP)
    b.add_argument(
        "--landmarks", type=Path, help="your own 2D landmarks (.npy/.json/.csv, N x 2 px); needs --face-model"
    )
    b.add_argument("--keypoints", default=None, help=KEYPOINTS_HELP)
    methods = ("auto", *SURFACE_METHODS)
    b.add_argument(
        "--reconstruct",
        choices=(*methods, "ball_pivoting"),  # the former name of bpa, still accepted
        default="auto",
        metavar="{" + ",".join(methods) + "}",
        help=f"triangles: auto = the face model's, else {SURFACE_METHODS[0]} (Ball-Pivoting with its holes "
        f"closed; delaunay below {MIN_SURFACE_POINTS} points); or one method for any model (docs/face_model.md)",
    )
    b.add_argument(
        "--bpa-backend",
        choices=("open3d", "pymeshlab"),
        default="open3d",
        help="Ball-Pivoting implementation, when the triangles come from Ball-Pivoting (default: open3d)",
    )
    b.add_argument(
        "--texture-format",
        choices=("png", "jpeg"),
        default="png",
        help="texture encoding inside the .glb (default: png)",
    )
    b.add_argument(
        "--texture-margin",
        type=finite_float,
        default=BuildSettings.texture_margin,
        help="margin of photo kept around the face in the texture, a fraction of the landmarks' bounding box's "
        f"larger side (default {BuildSettings.texture_margin:g}: what gazeaug render needs up to 40 deg, "
        "docs/face_model.md)",
    )
    b.add_argument("--atlas", action="store_true", help="repack the texture into a compact atlas (xatlas)")
    b.add_argument(
        "--preview",
        type=Path,
        help="also write a picture (.png/.jpg): the mesh and its wireframe over the photo, beside a frontal view",
    )

    i = sub.add_parser("info", help="describe a .glb written by facemesh")
    i.add_argument("glb", type=Path, help="a .glb written by facemesh build")
    i.add_argument("--json", action="store_true", help="print the metadata as JSON")

    r = sub.add_parser("render", help="picture of a .glb's face turned by a yaw and a pitch")
    r.add_argument("glb", type=Path, help="a .glb written by facemesh build")
    r.add_argument(
        "--yaw",
        type=finite_float,
        default=0.0,
        help="degrees, relative to the photo's head pose (0: as photographed); > 0 turns the face toward the "
        "image's left, about the point between the eyes (default 0)",
    )
    r.add_argument(
        "--pitch",
        type=finite_float,
        default=0.0,
        help="degrees, relative to the photo's head pose (0: as photographed); > 0 turns the face up (default 0)",
    )
    r.add_argument(
        "--supersample",
        type=integer_in(1, MAX_SUPERSAMPLE),
        default=2,
        help=f"anti-aliasing: N x N rays per pixel, 1 = one ray through each pixel's centre, at most "
        f"{MAX_SUPERSAMPLE} (default 2)",
    )
    r.add_argument(
        "-o", "--output", type=Path, required=True, help="output picture (.png/.jpg), the photo's size, grey background"
    )

    m = sub.add_parser("model", help="face models")
    msub = m.add_subparsers(dest="model_command", required=True)
    e = msub.add_parser("export", help="write a face model as OBJ (mm, head frame)")
    e.add_argument(
        "model",
        nargs="?",
        default="mediapipe",
        help="'mediapipe' (built-in) or a model file (.obj, .pbtxt, .txt, .csv, .npy) (default: mediapipe)",
    )
    e.add_argument("-o", "--output", type=Path, required=True, help="output .obj")
    return parser


def _check_outputs(args: argparse.Namespace) -> None:
    """Check every output path of the command before any work starts (see :mod:`facemesh.outputs`)."""
    from .outputs import check_output_file, check_picture_path

    if args.command == "build":
        check_output_file(args.output, (".glb",), what="mesh (.glb)")
        if args.preview is not None:
            check_picture_path(args.preview, what="preview picture")
            same = args.image is not None and args.preview.exists() and args.image.exists()
            if same and args.preview.resolve() == args.image.resolve():
                raise InputError(f"{args.preview}: the preview would replace the input photo; choose another --preview")
    elif args.command == "render":
        check_picture_path(args.output)
    elif args.command == "model":
        check_output_file(args.output, (".obj",), what="face model (.obj)")


_COMMANDS: dict[str, Any] = {}

#: What a Ctrl-C kept when a command has no partial output of its own to name and finished no
#: file (its outputs are written whole or not at all).
NOTHING_WRITTEN = "nothing was written (outputs are written whole or not at all)"


def caused_by_ctrl_c(exc: BaseException) -> bool:
    """Whether a ``KeyboardInterrupt`` is among ``exc``'s causes or contexts.

    A Ctrl-C that arrives while a native module initializes (open3d's import, for one) comes
    out as that module's own error, here ``ImportError("initialization failed")`` with the
    ``KeyboardInterrupt`` as its cause; without this check it would read as a missing package.
    """
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return True
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return False


def run_command(
    prog: str, command: Callable[[], int | None], interrupted: Callable[[], str | None] = lambda: None
) -> int:
    """Run one command the way both command lines do: outputs' warnings and errors as one line each.

    Exit codes: 0 done; 2 bad input (the library's typed errors, phrased with
    :func:`error_line`; a file the system would not read or write); 130 Ctrl-C (also one that a
    native module turned into an error of its own, :func:`caused_by_ctrl_c`), with
    ``interrupted()`` saying what was kept (one line), or returning ``None`` when the command
    keeps no partial output of its own: then the files it finished are named, or
    :data:`NOTHING_WRITTEN` said; 1 anything unexpected (one line;
    ``GAZEAUG_DEBUG=1`` re-raises it for the traceback). With ``GAZEAUG_DEBUG=1`` the
    traceback of an exit-2 error (its causes included) is printed before its line too.
    """
    import os
    import traceback

    from .io import files_written_count, files_written_since

    mark = files_written_count()
    debug = os.environ.get("GAZEAUG_DEBUG", "").strip() not in ("", "0")

    def _debug_traceback(exc: BaseException) -> None:
        if debug:
            traceback.print_exception(exc, file=sys.stderr)

    def _show(message: Any, category: Any, filename: str, lineno: int, file: Any = None, line: Any = None) -> None:
        print(f"{prog}: warning: {message}", file=sys.stderr)

    def _interrupted() -> int:
        kept = interrupted()
        if kept is None:
            done, count = files_written_since(mark)
            kept = NOTHING_WRITTEN
            if count:
                names = ", ".join(str(p) for p in done)
                if not done:  # the last ones were removed since (a scratch folder): a count only
                    names = f"{count} file{'s' if count > 1 else ''}"
                elif count > len(done):
                    names += f" (the last {len(done)} of {count})"
                kept = f"wrote {names} whole before it; nothing else was written"
        print(f"{prog}: interrupted; {kept}", file=sys.stderr)
        return 130

    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show
            return command() or 0
    except KeyboardInterrupt:
        return _interrupted()
    except Exception as exc:  # noqa: BLE001 - no traceback reaches a user
        if caused_by_ctrl_c(exc):  # a Ctrl-C that a native module turned into its own error
            return _interrupted()
        if isinstance(exc, (FaceMeshError, ImportError)):
            _debug_traceback(exc)
            print(f"{prog}: error: {error_line(exc)}", file=sys.stderr)
            return 2
        if isinstance(exc, OSError):  # a file we could not read or write: the system's reason, one line
            _debug_traceback(exc)
            where = f"{exc.filename}: " if exc.filename else ""
            print(f"{prog}: error: {where}{exc.strerror or exc}", file=sys.stderr)
            return 2
        if debug:
            raise
        what = f"{exc.__class__.__name__}: {exc}".splitlines()[0][:300]
        print(f"{prog}: unexpected error: {what} (set GAZEAUG_DEBUG=1 to see the traceback)", file=sys.stderr)
        return 1


def console_entry(main: Callable[[], int], prog: str) -> None:
    """A console script: ``main``'s exit code; a Ctrl-C outside ``main``'s own handling is one line, 130.

    Once ``main`` has returned, the work is done and its outputs are complete: a late
    Ctrl-C (while the interpreter shuts down) is ignored rather than turned into 130.
    """
    import signal

    try:
        code = main()
    except KeyboardInterrupt:  # the same line as gazeaug_console's, for a Ctrl-C while the CLI loads
        print(f"{prog}: interrupted before it started; nothing was written", file=sys.stderr)
        code = 130
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    sys.exit(code)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (2 bad input, 130 Ctrl-C, 1 anything unexpected)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # bad options (one line printed, 2), --help or --version (0)
        return exc.code if isinstance(exc.code, int) else 2

    def command() -> None:
        _check_outputs(args)
        _COMMANDS[args.command](args)

    return run_command("facemesh", command)


def _cmd_build(args: argparse.Namespace) -> None:
    from .build import build_mesh, landmark_model_for, load_input
    from .face_models import parse_keypoints
    from .gltf import save_glb
    from .io import save_image_rgb
    from .mesh import BuildSettings
    from .reconstruct import BallPivotingSettings

    image, camera, source = load_input(args.image, args.camera)  # warns when no calibration is given
    keypoints = None if args.keypoints is None else parse_keypoints(args.keypoints)
    detector, face_model = landmark_model_for(args.landmarks, args.face_model, keypoints)
    settings = BuildSettings(
        vertex_placement=args.vertices,
        texture_margin=args.texture_margin,
        reconstruction=args.reconstruct,
        ball_pivoting=BallPivotingSettings(backend=args.bpa_backend),
    )
    try:
        mesh = build_mesh(
            image, camera, detector, face_model=face_model, face_index=args.face_index, settings=settings, source=source
        )
    finally:
        close = getattr(detector, "close", None)
        if close is not None:
            close()
    if args.atlas:
        from .atlas import atlas_mesh

        mesh = atlas_mesh(mesh)
    save_glb(mesh, args.output, texture_format=args.texture_format)
    print(
        f"facemesh: wrote {args.output} ({mesh.num_vertices} vertices, {mesh.num_triangles} triangles, "
        f"texture {mesh.texture.shape[1]}x{mesh.texture.shape[0]}, reprojection error "
        f"{mesh.pose.reprojection_error_px:.2f} px)"
    )
    if args.preview is not None:
        save_image_rgb(args.preview, _preview(image, mesh))
        print(f"facemesh: wrote {args.preview}")


#: Height of the preview's panels at least (smaller face crops are enlarged), pixels.
PREVIEW_MIN_HEIGHT_PX = 360


def _preview(image: np.ndarray, mesh: Any) -> np.ndarray:
    """The photo with the rendered mesh blended in, its wireframe and landmarks drawn, beside a frontal render."""
    import cv2

    from .conventions import rotation_to_head_pitchyaw
    from .draw import put_label
    from .pose import project_points
    from .render import RaycastScene

    h, w = image.shape[:2]
    k = mesh.camera.matrix
    over = RaycastScene.from_mesh(mesh).render(k, (w, h), supersample=1)
    canvas = image.copy()
    hit = over.coverage > 0
    canvas[hit] = (0.5 * canvas[hit] + 0.5 * over.image[hit]).astype(np.uint8)
    # Frontal view: undo the head rotation (about the head frame's origin).
    pitch, yaw = rotation_to_head_pitchyaw(mesh.pose.rotation)
    frontal = RaycastScene.from_mesh(mesh, rotation=mesh.pose.rotation.T).render(k, (w, h), supersample=2).image
    x0, y0, x1, y1 = (int(v) for v in mesh.landmarks.bbox_px)
    pad = int(0.2 * max(x1 - x0, y1 - y0))
    cx, cy = max(0, x0 - pad), max(0, y0 - pad)
    crop = (slice(cy, min(h, y1 + pad)), slice(cx, min(w, x1 + pad)))
    left, right = canvas[crop], frontal[crop]
    # small faces: enlarge the panels so the wireframe stays open and the labels fit inside them
    scale = max(1.0, PREVIEW_MIN_HEIGHT_PX / left.shape[0])
    if scale > 1.0:
        size = (round(left.shape[1] * scale), round(left.shape[0] * scale))
        left = np.asarray(cv2.resize(left, size, interpolation=cv2.INTER_CUBIC), dtype=np.uint8)
        right = np.asarray(cv2.resize(right, size, interpolation=cv2.INTER_CUBIC), dtype=np.uint8)
    else:
        left = left.copy()
    px = (project_points(mesh.vertices_mm, mesh.camera) - (cx, cy)) * scale
    thickness = max(1, round(max(h, w) * scale / 1000))
    for a, b, c in mesh.triangles:
        pts = np.round(px[[a, b, c]]).astype(np.int32)
        cv2.polylines(left, [pts], True, (40, 220, 255), thickness, cv2.LINE_AA)
    label = f"pitch {math.degrees(pitch):+.1f}  yaw {math.degrees(yaw):+.1f} deg"
    put_label(left, label, (5, 20))
    put_label(right, "turned frontal", (5, 20))
    return np.concatenate([left, right], axis=1)


def _cmd_info(args: argparse.Namespace) -> None:
    from .conventions import rotation_to_head_pitchyaw
    from .gltf import load_glb

    mesh = load_glb(args.glb)
    pitch, yaw = np.degrees(rotation_to_head_pitchyaw(mesh.pose.rotation))
    info = {
        "file": str(args.glb),
        "vertices": mesh.num_vertices,
        "triangles": mesh.num_triangles,
        "texture_size_wh": [int(mesh.texture.shape[1]), int(mesh.texture.shape[0])],
        "landmarks": mesh.landmarks.num_points,
        "landmark_model": mesh.landmarks.model_name,
        "face_model": mesh.face_model_name,
        "vertex_placement": mesh.vertex_placement,
        "image_size_wh": list(mesh.camera.image_size),
        "camera_source": mesh.camera.source,
        "focal_px": list(mesh.camera.focal_px),
        "head_pitch_yaw_deg": [round(float(pitch), 3), round(float(yaw), 3)],
        "head_translation_mm": [round(float(v), 3) for v in mesh.pose.translation_mm],
        "reprojection_error_px": round(mesh.pose.reprojection_error_px, 4),
        "reconstruction": mesh.reconstruction or {"method": "face model triangles"},
        "extras": mesh.extras,
    }
    if args.json:
        print(json.dumps(info, indent=2))
        return
    width = max(len(k) for k in info)
    for key, value in info.items():
        print(f"{key:<{width}}  {value}")


def _cmd_render(args: argparse.Namespace) -> None:
    from .conventions import rotation_from_yaw_pitch
    from .gltf import load_glb
    from .io import save_image_rgb
    from .render import RaycastScene

    mesh = load_glb(args.glb)
    rot = rotation_from_yaw_pitch(math.radians(args.yaw), math.radians(args.pitch))
    scene = RaycastScene.from_mesh(mesh, rotation=rot)
    w, h = mesh.camera.image_size
    img = scene.render(mesh.camera.matrix, (w, h), supersample=args.supersample, background=(128, 128, 128)).image
    save_image_rgb(args.output, img)
    print(f"facemesh: wrote {args.output} (yaw {args.yaw:+g} deg, pitch {args.pitch:+g} deg)")


def _cmd_model_export(args: argparse.Namespace) -> None:
    from .face_models import export_obj, resolve_face_model
    from .io import atomic_write

    model = resolve_face_model(args.model)
    with atomic_write(args.output) as fh:
        fh.write(export_obj(model).encode("utf-8"))
    n_tri = 0 if model.triangles is None else len(model.triangles)
    print(f"facemesh: wrote {args.output} ({model.num_points} vertices in mm, {n_tri} triangles)")


_COMMANDS.update(build=_cmd_build, info=_cmd_info, render=_cmd_render, model=_cmd_model_export)


def entry() -> None:
    """The ``facemesh`` console script (see :func:`console_entry`)."""
    console_entry(main, "facemesh")


if __name__ == "__main__":
    entry()
