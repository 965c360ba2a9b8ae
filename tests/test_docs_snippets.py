"""Every fenced command and snippet of README.md and docs/*.md runs as written (rules: tests/doc_snippets.py)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import shared_data_dir
from doc_snippets import (
    CLI_NAMES,
    DOCS,
    REPO,
    RUNNABLE_PROGRAMS,
    Block,
    Command,
    blocks,
    cli_words,
    commands,
    not_run_reason,
    output_paths,
    substitute,
)

VENV_BIN = Path(sys.executable).parent
TIMEOUT_S = 600


def _run(args: list[str] | str, cwd: Path, *, shell: bool = False) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PATH=f"{VENV_BIN}{os.pathsep}{os.environ.get('PATH', '')}", MPLBACKEND="Agg")
    return subprocess.run(
        args, cwd=cwd, env=env, shell=shell, executable="/bin/bash" if shell else None,
        capture_output=True, text=True, timeout=TIMEOUT_S, check=False,
    )  # fmt: skip


def _must(args: list[str], cwd: Path) -> None:
    done = _run(args, cwd)
    assert done.returncode == 0, f"preparing the docs' inputs: {' '.join(args)}\n{done.stderr[-3000:]}"


def _save_video(frames: list[np.ndarray], path: Path, fps: float) -> None:
    import cv2

    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    for frame in frames:
        writer.write(frame)
    writer.release()


def _clip(folder: Path, shared: Path | None) -> None:
    """clip.mp4: 2 s of a real video (../shared) or of a simulated gaze sequence."""
    import cv2

    source = None if shared is None else shared / "faces" / "pexels" / "video00.mp4"
    frames: list[np.ndarray] = []
    if source is not None and source.is_file():
        cap = cv2.VideoCapture(str(source))
        fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
        while len(frames) < int(2 * fps):
            ok, frame = cap.read()
            if not ok:
                break
            scale = 640 / max(frame.shape[:2])
            frames.append(cv2.resize(frame, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA))
        cap.release()
    else:
        fps = 10.0
        seq = folder / "_sequence"
        rig = str(REPO / "data_samples" / "rigs" / "wheelchair_objects.yaml")  # a sequence needs targets
        args = ["--sequence", "2", "--fps", "10", "--rig", rig, "-o", str(seq), "--quiet"]
        _must(["gazeaug", "simulate", *args], folder)
        frames = [cv2.imread(str(p)) for p in sorted(seq.rglob("*.jpg"))]
        shutil.rmtree(seq)
    assert frames, "no frames for clip.mp4"
    _save_video(frames, folder / "clip.mp4", fps)


def _mpii(folder: Path, shared: Path | None) -> None:
    """day01_0087.jpg, cameraCalib.xml, faceModelGeneric.txt, landmarks6.json: the real p00 frame or a stand-in."""
    sample = None if shared is None else shared / "gaze" / "mpiifacegaze_p00_example"
    if sample is None or not sample.is_dir():
        from helpers import synthetic_mpii_sample

        from facemesh.io import load_image_rgb, save_image_rgb
        from facemesh.landmarks import MediaPipeFaceMesh

        sample = folder / "_mpii"
        with MediaPipeFaceMesh() as detector:
            synthetic_mpii_sample(sample, detector)
        save_image_rgb(sample / "day01_0087.jpg", load_image_rgb(sample / "day01_0087.png"))
    for name in ("day01_0087.jpg", "cameraCalib.xml", "faceModelGeneric.txt"):
        shutil.copy(sample / name, folder / name)
    annotation = json.loads((sample / "annotation.json").read_text())
    (folder / "landmarks6.json").write_text(json.dumps(annotation["landmarks_6_px"]))


def _dataset(folder: Path, name: str, seed: int) -> None:
    """A folder dataset of simulated people with subjects p00 and p01 (3 images each)."""
    out = folder / name
    _must(["gazeaug", "simulate", "--faces", "photo.jpg", "face.jpg", "--rig", "screen", "--per-face", "3",
           "--seed", str(seed), "-o", str(out), "--quiet"], folder)  # fmt: skip
    labels = out / "labels.csv"
    labels.write_text(re.sub(r",sim(\d\d),", r",p\1,", labels.read_text()))


def prepare_inputs(folder: Path) -> Path:
    """The inputs the docs name, small: photos, a calibration, datasets, a video, a model, a rig."""
    import cv2

    from facemesh.build import sample_image
    from facemesh.io import load_image_rgb, save_image_rgb

    shared = shared_data_dir()
    folder.mkdir(parents=True, exist_ok=True)
    astronaut = sample_image()
    for name in ("photo.jpg", "a.jpg", "b.jpg", "user.jpg"):
        save_image_rgb(folder / name, astronaut)
    other = None if shared is None else shared / "faces" / "sergey.png"
    save_image_rgb(folder / "face.jpg", load_image_rgb(other) if other and other.is_file() else astronaut)
    fs = cv2.FileStorage(str(folder / "calib.xml"), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", np.array([[600.0, 0, 255.5], [0, 600.0, 255.5], [0, 0, 1]]))
    fs.write("cam_distortion", np.zeros((1, 5)))
    fs.release()
    _mpii(folder, shared)
    _dataset(folder, "my_dataset", 0)
    _dataset(folder, "my_test_dataset", 1)
    (folder / "DATASET").symlink_to("my_dataset")
    rig = str(REPO / "data_samples" / "rigs" / "wheelchair_objects.yaml")
    _must(["gazeaug", "simulate", "--sequence", "3", "--fps", "10", "--pattern", "calibration",
           "--rig", rig, "-o", "calib", "--quiet"], folder)  # fmt: skip
    _clip(folder, shared)
    shutil.copy(REPO / "gazeaug" / "models" / "demo_wheelchair.pt", folder / "model.pt")
    _must(["gazeaug", "export", "model.pt", "-o", "model.onnx"], folder)
    shutil.copy(REPO / "data_samples" / "rigs" / "wheelchair_objects.yaml", folder / "RIG.yaml")
    return folder


@pytest.fixture(scope="session")
def doc_inputs(tmp_path_factory) -> Path:
    return prepare_inputs(tmp_path_factory.mktemp("doc_inputs"))


def _workdir(doc: Path, inputs: Path, tmp: Path) -> Path:
    """A folder for one document: links to the inputs, but not to what the document's commands write."""
    runnable = [b for b in blocks(doc) if b.lang == "bash" and b.role != "usage"]
    written = {p.rstrip("/") for b in runnable for c in commands(b) for p in output_paths(c.text)}
    work = tmp / doc.stem
    work.mkdir()
    for item in inputs.iterdir():
        if item.name not in written:
            (work / item.name).symlink_to(item.resolve(), target_is_directory=item.is_dir())
    (work / ".venv").symlink_to(Path(sys.prefix), target_is_directory=True)
    (work / "data_samples").symlink_to(REPO / "data_samples", target_is_directory=True)
    return work


def _parser_for(program: str, path: list[str]):
    """The argparse parser of ``program path...`` (the deepest subcommand the path names)."""
    import argparse

    if program == "facemesh":
        from facemesh.cli import build_parser
    else:
        from gazeaug.cli import build_parser
    parser = build_parser()
    for word in path:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or word not in subs[0].choices:
            break
        parser = subs[0].choices[word]
    return parser


def _check_options(command: str, where: str) -> None:
    """Every option a facemesh/gazeaug command line names exists in that (sub)command's parser."""
    parsed = cli_words(command)
    if parsed is None:
        return
    program, path, options = parsed
    parser = _parser_for(program, path)
    missing = [o for o in options if o not in parser._option_string_actions]
    assert not missing, f"{where}: `{parser.prog}` has no option {', '.join(missing)}"


def _check_not_run(command: Command, block: Block, why: str) -> None:
    """What a command that is not run can still be checked for."""
    where = f"{block.doc.relative_to(REPO)}:{command.line}"
    text = command.text
    if text.startswith("pip install"):
        section = (REPO / "pyproject.toml").read_text().split("[project.optional-dependencies]")[1].split("\n[")[0]
        extras = re.findall(r"^([A-Za-z0-9_-]+)\s*=", section, flags=re.MULTILINE)  # tomllib: Python >= 3.11
        for group in re.findall(r"\[([a-z,]+)\]", text):
            for extra in group.split(","):
                assert extra in extras, f"{where}: no extra [{extra}] in pyproject.toml"
    elif text.startswith("ray "):  # ray start / ray job submit [... -- COMMAND]: the options of both parts
        ray_part, _, inner = text.partition(" -- ")
        sub = re.match(r"ray ((?:job )?\w+)", ray_part)
        assert sub is not None, f"{where}: {text}"
        usage = _run([str(VENV_BIN / "ray"), *sub.group(1).split(), "--help"], REPO)
        assert usage.returncode == 0, f"{where}: ray {sub.group(1)} --help: {usage.stderr[-500:]}"
        for option in re.findall(r"(?<=\s)--[a-z][a-z-]*", ray_part):
            assert option in usage.stdout, f"{where}: `ray {sub.group(1)}` has no option {option}"
        _check_options(inner, where)
    elif text.startswith("make "):
        target = text.split()[1]
        done = _run(["make", "-n", "-C", str(REPO), target], REPO)
        assert done.returncode == 0, f"{where}: make -n {target}: {done.stderr}"
    else:
        _check_options(text, where)


def _run_bash(block: Block, work: Path) -> None:
    for command in commands(block):
        where = f"{block.doc.relative_to(REPO)}:{command.line}"
        why = not_run_reason(command.text)
        if why is not None:
            _check_not_run(command, block, why)
            continue
        program = Path(command.text.split()[0]).name
        assert program in RUNNABLE_PROGRAMS, (
            f"{where}: `{command.text}`: the docs test runs only {', '.join(RUNNABLE_PROGRAMS)} commands; "
            "add this one to NOT_RUN in tests/doc_snippets.py with what to check instead"
        )
        text = substitute(command.text)
        done = _run(text, work, shell=True)
        assert done.returncode == 0, (
            f"{where}: `{command.text}` (run as `{text}`) exited {done.returncode}:\n{done.stderr[-3000:]}"
        )
        for out in output_paths(text):
            assert (work / out).exists(), f"{where}: `{command.text}` did not write {out}"


def _run_python(block: Block, work: Path) -> None:
    script = _block_file(block, work, ".py")
    done = _run([sys.executable, script.name], work)
    assert done.returncode == 0, f"{block.where}: the Python snippet failed:\n{done.stderr[-3000:]}"


def _check_yaml(block: Block, work: Path) -> None:
    from gazeaug.sampling import load_rig

    data = yaml.safe_load(block.text)
    first = block.text.strip().split("\n")[0]
    m = re.match(r"#\s*(data_samples/\S+\.yaml)", first)
    if m:
        shipped = yaml.safe_load((REPO / m.group(1)).read_text())
        assert _same_data(data, shipped), f"{block.where}: differs from {m.group(1)}:\n{data}\n{shipped}"
    elif "camera_position_mm" in data:
        load_rig(_block_file(block, work, ".yaml"))


def _same_data(a: object, b: object) -> bool:
    """Equal YAML data, numbers to 1e-9 (a file may hold 229.99999999999997 where the doc shows 230.0)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same_data(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same_data(x, y) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return abs(a - b) <= 1e-9 * max(1.0, abs(a), abs(b))
    return a == b


def _block_file(block: Block, work: Path, suffix: str) -> Path:
    """The block's text (size substitutions applied) as a file in the document's folder."""
    path = work / f"block_{block.line}{suffix}"
    path.write_text(substitute(block.text))
    return path


def _check_xml(block: Block, work: Path) -> None:
    """A calibration file example must load."""
    from facemesh import load_camera

    load_camera(_block_file(block, work, ".xml"))


@pytest.mark.parametrize("doc", DOCS, ids=[str(d.relative_to(REPO)) for d in DOCS])
def test_doc_snippets_run(doc: Path, doc_inputs: Path, tmp_path: Path) -> None:
    work = _workdir(doc, doc_inputs, tmp_path)
    for block in blocks(doc):
        if block.lang == "bash" and block.role == "usage":
            for command in commands(block):
                _check_options(command.text, f"{block.doc.relative_to(REPO)}:{command.line}")
        elif block.lang == "bash":
            _run_bash(block, work)
        elif block.lang == "python":
            _run_python(block, work)
        elif block.lang == "yaml":
            _check_yaml(block, work)
        elif block.lang == "xml":
            _check_xml(block, work)
    for check in AFTER_RUN.get(doc.name, ()):
        check(work)


def _gaze_csv_columns_documented(work: Path) -> None:
    """tracking.md's table of gaze.csv columns lists the columns `track --rig` wrote, no more, no fewer."""
    header = set((work / "out" / "gaze.csv").read_text().split("\n")[0].split(","))
    documented = _documented_names(REPO / "docs" / "tracking.md", "column")
    assert header == documented, f"gaze.csv: {header ^ documented}"


#: Checks of a document's outputs after its blocks ran (in its folder).
AFTER_RUN = {"tracking.md": (_gaze_csv_columns_documented,)}


def test_every_bash_block_is_a_command_or_marked_usage() -> None:
    """A synopsis ([...] optional, a|b choices) cannot run: it must say so (```bash usage)."""
    wrong = []
    for doc in DOCS:
        for block in blocks(doc):
            if block.lang == "bash" and block.role != "usage":
                for command in commands(block):
                    if re.search(r"\s\[-|\w\|\w|\.\.\.", command.text) and not re.search(
                        r"\bFACES|\bPEOPLE", command.text
                    ):
                        wrong.append(f"{block.where}: {command.text}")
            assert block.lang in ("", "bash", "python", "yaml", "csv", "text", "xml"), (
                f"{block.where}: language {block.lang!r}"
            )
    assert not wrong, "synopsis lines in runnable blocks (mark the block ```bash usage):\n" + "\n".join(wrong)


def test_cli_words_reads_synopses() -> None:
    """The option scanner: hand-written lines, so a scanner that finds nothing cannot pass the option checks."""
    assert cli_words("gazeaug render [IMAGE|MESH.glb] -o eyes.npz [--yaw DEG --pitch DEG | --original-pose]") == (
        "gazeaug", ["render"], ["-o", "--yaw", "--pitch", "--original-pose"],
    )  # fmt: skip
    assert cli_words(".venv/bin/facemesh model export mediapipe -o model.obj") == (
        "facemesh", ["model", "export", "mediapipe"], ["-o"],
    )  # fmt: skip
    assert cli_words("ls -l") is None
    assert set(CLI_NAMES) == {"facemesh", "gazeaug"}
    with pytest.raises(AssertionError, match="has no option --no-such-option"):
        _check_options("gazeaug render x.glb --no-such-option", "here")


def _documented_names(doc: Path, first_header: str) -> set[str]:
    """The names in the first column of the table whose header row starts with ``| first_header |``.

    A name is backticked; one backtick span may list several (`gaze_x, gaze_y`); backticked
    options (`--rig`) say when a name is present and are not names. The table may be indented
    (inside a list item).
    """
    lines = [line.strip() for line in doc.read_text(encoding="utf-8").split("\n")]
    start = [k for k, line in enumerate(lines) if line.startswith(f"| {first_header} |")]
    assert len(start) == 1, f"{doc.name}: expected one table headed '{first_header}', found {len(start)}"
    names: set[str] = set()
    for line in lines[start[0] + 2 :]:
        if not line.startswith("|"):
            break
        for span in re.findall(r"`([^`]+)`", line.split("|")[1]):
            names.update(n.strip() for n in span.split(",") if not n.strip().startswith("-"))
    return names


def test_documented_npz_keys_are_the_written_ones(tmp_path: Path) -> None:
    """docs/gazeaug.md's table of .npz keys names every key `normalize` and `render` write, and no other."""
    from gazeaug.cli import main

    written: set[str] = set()
    for i, args in enumerate(
        (
            ["normalize", "--gaze-target", "0", "100", "0"],
            ["render", "--seed", "1"],
            ["normalize", "--gaze-target", "0", "100", "0", "--face-patch", "32", "32"],  # the optional keys
        )
    ):
        out = tmp_path / f"{args[0]}{i}.npz"
        assert main([*args, "-o", str(out)]) == 0
        with np.load(out) as z:
            written |= set(z.files)
    documented = _documented_names(REPO / "docs" / "gazeaug.md", "key")
    assert written == documented, (
        f"written, not documented: {written - documented}; documented, not written: {documented - written}"
    )


def test_documented_h5_schema_is_the_written_one(tmp_path: Path) -> None:
    """docs/datasets.md's tables of HDF5 datasets and attributes are those `augment` writes."""
    import h5py

    from gazeaug.cli import main

    assert main(["simulate", "--rig", "screen", "--per-face", "2", "-o", str(tmp_path / "sim"), "--quiet"]) == 0
    out = tmp_path / "a.h5"  # with the optional columns: face, and eye_keypoints (redirected eyes)
    args = [
        "augment",
        str(tmp_path / "sim"),
        "-o",
        str(out),
        "--per-sample",
        "2",
        "--quiet",
        "--face-patch",
        "16",
        "16",
        "--rig",
        "wheelchair",
        "--redirect-eyes",
    ]
    assert main(args) == 0
    datasets: set[str] = set()
    with h5py.File(out, "r") as f:
        f.visititems(lambda name, obj: datasets.add(name) if isinstance(obj, h5py.Dataset) else None)
        attributes = set(f.attrs)
    doc = REPO / "docs" / "datasets.md"
    documented = _documented_names(doc, "dataset")
    expanded = {n for d in documented for n in ([d.replace("*", s) for s in ("left", "right")] if "*" in d else [d])}
    assert datasets == expanded, (
        f"written, not documented: {datasets - expanded}; documented, not written: {expanded - datasets}"
    )
    documented_attrs = _documented_names(doc, "attribute")
    assert attributes == documented_attrs, f"{attributes ^ documented_attrs}"


def test_commands_join_continuations_and_drop_comments() -> None:
    """The block splitter on a hand-written block: continuations joined, comments (not quoted #) dropped."""
    text = "# a comment\ngazeaug render x.glb \\\n    --yaw 10 --pitch 30 -o 'a #b.npz'   # at this pose\n\nls  -l\n"
    block = Block(REPO / "README.md", 10, "bash", "", text)
    assert commands(block) == [
        Command(12, "gazeaug render x.glb --yaw 10 --pitch 30 -o 'a #b.npz'"),
        Command(15, "ls  -l"),
    ]
    assert output_paths(commands(block)[0].text) == ["a #b.npz"]
    synopsis = Block(REPO / "README.md", 1, "bash", "usage", "gazeaug a [--x X]\n        [--y]  # note\ngazeaug b\n")
    assert commands(synopsis) == [Command(2, "gazeaug a [--x X] [--y]"), Command(4, "gazeaug b")]


def test_a_failing_or_silent_command_fails_the_doc(tmp_path: Path) -> None:
    """A command that exits non-zero, or does not write what it names with -o, fails with its doc and line."""
    failing = Block(REPO / "docs" / "x.md", 3, "bash", "", "gazeaug render --no-such-option -o a.npz")
    with pytest.raises(AssertionError, match=r"docs/x.md:4: .* exited 2"):
        _run_bash(failing, tmp_path)
    silent = Block(REPO / "docs" / "x.md", 3, "bash", "", "gazeaug --version -o never_written.txt")
    with pytest.raises(AssertionError, match="did not write never_written.txt"):
        _run_bash(silent, tmp_path)
    # only facemesh, gazeaug and python run: anything else must be declared (and is then only checked)
    unknown = Block(REPO / "docs" / "x.md", 3, "bash", "", f"touch {tmp_path / 'touched'}")
    with pytest.raises(AssertionError, match="runs only facemesh, gazeaug, python"):
        _run_bash(unknown, tmp_path)
    assert not (tmp_path / "touched").exists()
    assert not_run_reason("ray start --head --port 6379") is not None
    with pytest.raises(AssertionError, match="has no option --no-such"):
        _run_bash(Block(REPO / "docs" / "x.md", 3, "bash", "", "ray start --no-such 1"), tmp_path)
