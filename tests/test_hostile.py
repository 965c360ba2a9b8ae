"""A hostile user: crafted and damaged files, bad options, read-only places, concurrent runs, Ctrl-C.

Every case asserts what a user must see: exit 2 (130 for Ctrl-C), one line on stderr naming
the problem, no traceback, nothing half-written, and outputs already there untouched.
Runs without ../shared (inputs are made here from the built-in sample photo).
"""

from __future__ import annotations

import csv
import json
import os
import pickle
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import default_sigint, expect_typed_error, mutations, unprivileged_prefix

from facemesh.outputs import OutputBusyError, output_lock

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _one_line(err: str, *phrases: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip() and ": warning: " not in ln]
    assert "Traceback" not in err, err
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}:\n{err}"
    for phrase in phrases:
        assert phrase in lines[0], f"{phrase!r} not in {lines[0]!r}"
    return lines[0]


def _run(cli, argv, capsys):
    code = cli(argv)
    out, err = capsys.readouterr()
    return code, out, err


def _gazeaug(argv, capsys):
    from gazeaug.cli import main

    return _run(main, [str(a) for a in argv], capsys)


def _facemesh(argv, capsys):
    from facemesh.cli import main

    return _run(main, [str(a) for a in argv], capsys)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def sample_jpg(tmp_path_factory) -> Path:
    from facemesh.build import sample_image
    from facemesh.io import save_image_rgb

    path = tmp_path_factory.mktemp("photo") / "face.jpg"
    save_image_rgb(path, sample_image())
    return path


def _folder_dataset(root: Path, photo: Path, n: int = 2, header_only: bool = False) -> Path:
    """A folder dataset (labels.csv) of ``n`` copies of the sample photo looking at the camera."""
    import shutil

    root.mkdir(parents=True, exist_ok=True)
    rows = []
    for i in range(n):
        shutil.copy(photo, root / f"img{i}.jpg")
        rows.append([f"img{i}.jpg", f"s{i % 2}", 600, 600, 255.5, 255.5, 0, 0, 0])
    with open(root / "labels.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["image", "subject", "fx", "fy", "cx", "cy", "target_x", "target_y", "target_z"])
        if not header_only:
            w.writerows(rows)
    return root


# --------------------------------------------------------------------------------------------
# 1. A crafted .pt never runs its code
# --------------------------------------------------------------------------------------------

torch_needed = pytest.mark.skipif(
    __import__("importlib").util.find_spec("torch") is None, reason="the gaze model needs torch ('gazeaug[train]')"
)


class _Payload:
    """Pickles into a call of exec: loading it with a full unpickler writes the marker file."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (exec, (f"open({str(self.marker)!r}, 'w').write('ran')",))


def _crafted_files(folder: Path) -> dict[str, tuple[Path, Path]]:
    """name -> (crafted file, marker its payload would create): torch's zip format and a bare pickle."""
    import torch

    out = {}
    # protocol 4 too: torch's safe unpickler stops at its FRAME opcode before it sees the callable
    for name in ("zip", "legacy", "zip4", "legacy4"):
        marker = folder / f"marker_{name}"
        path = folder / f"crafted_{name}.pt"
        obj = {"format": "gazeaug-model", "state_dict": {}, "payload": _Payload(marker)}
        protocol = 4 if name.endswith("4") else 2
        if name.startswith("zip"):
            torch.save(obj, path, pickle_protocol=protocol)
        else:
            path.write_bytes(pickle.dumps(obj, protocol=protocol))
        out[name] = (path, marker)
    return out


@torch_needed
def test_the_crafted_files_do_carry_code(tmp_path):
    """The check below can fail: an unrestricted load of these files runs their payload."""
    import torch

    for path, marker in _crafted_files(tmp_path).values():
        try:  # a bare pickle runs its payload, then fails torch's magic-number check
            torch.load(path, weights_only=False)
        except RuntimeError:
            pass
        assert marker.read_text() == "ran"


@torch_needed
def test_a_crafted_file_is_named_as_such_whatever_its_pickle_protocol(tmp_path):
    import torch

    from gazeaug.errors import GazeAugError
    from gazeaug.train import load_model

    for name, (path, marker) in _crafted_files(tmp_path).items():
        with pytest.raises(GazeAugError, match=r"refused without running them") as info:
            load_model(path)
        assert "exec" in str(info.value), (name, str(info.value))  # the callable it names
        assert not marker.exists(), name
    # a file of plain values saved with protocol 4: no callable of its own, the protocol is named
    plain = tmp_path / "plain4.pt"
    torch.save({"format": "gazeaug-model", "state_dict": {"w": torch.zeros(2)}}, plain, pickle_protocol=4)
    with pytest.raises(GazeAugError, match=r"pickle protocol 4"):
        load_model(plain)


@torch_needed
@pytest.mark.parametrize("command", ["predict", "evaluate", "export", "resume"])
def test_a_crafted_model_file_is_refused_and_runs_nothing(tmp_path, capsys, sample_jpg, command):
    from helpers import synthetic_h5

    for path, marker in _crafted_files(tmp_path).values():
        if command == "predict":
            argv = ["predict", path, sample_jpg]
        elif command == "evaluate":
            argv = ["evaluate", path, _folder_dataset(tmp_path / "ds", sample_jpg), "-o", tmp_path / "rep"]
        elif command == "export":
            argv = ["export", path, "-o", tmp_path / "m.onnx"]
        else:
            h5 = synthetic_h5(tmp_path / "t.h5", n=16) if not (tmp_path / "t.h5").exists() else tmp_path / "t.h5"
            model = tmp_path / "m.pt"
            (tmp_path / "m.ckpt.pt").write_bytes(path.read_bytes())
            argv = ["train", h5, "-o", model, "--resume", "--epochs", "1", "--quiet"]
        code, _, err = _gazeaug(argv, capsys)
        assert code == 2
        _one_line(err, "not a gazeaug " + ("checkpoint" if command == "resume" else "model"))
        assert not marker.exists(), "the file's code ran"
    assert not (tmp_path / "m.onnx").exists() and not (tmp_path / "m.pt").exists()


@torch_needed
@pytest.mark.parametrize(
    "content",
    [b"", b"PK\x03\x04garbage", b"\x80\x02}q\x00.", pickle.dumps({"a": 1}, protocol=4), os.urandom(300)],
    ids=["empty", "broken-zip", "empty-dict-pickle", "protocol-4-pickle", "random"],  # 4: torch warned about it
)
def test_damaged_model_files(tmp_path, capsys, content):
    p = tmp_path / "bad.pt"
    p.write_bytes(content)
    code, _, err = _gazeaug(["export", p, "-o", tmp_path / "m.onnx"], capsys)
    assert code == 2
    _one_line(err, str(p), "not a gazeaug model")


# --------------------------------------------------------------------------------------------
# 2, 10. Resume refuses another data selection and damaged checkpoints
# --------------------------------------------------------------------------------------------


@torch_needed
def test_resume_refuses_a_changed_validation_selection(tmp_path, capsys):
    from helpers import synthetic_h5

    h5 = synthetic_h5(tmp_path / "t.h5", n=32, subjects=("a", "b"))
    model = tmp_path / "m.pt"
    base = ["train", h5, "-o", model, "--epochs", "1", "--batch-size", "16", "--quiet"]
    assert _gazeaug([*base, "--val-subjects", "a"], capsys)[0] == 0
    before = model.read_bytes()
    for change in ([], ["--val-subjects", "b"], ["--val", h5]):
        code, _, err = _gazeaug([*base, "--resume", *change], capsys)
        assert code == 2, change
        _one_line(err, "another data selection")
        assert model.read_bytes() == before
    code, _, err = _gazeaug([*base, "--resume", "--val-subjects", "a"], capsys)
    assert code == 0, err


@torch_needed
def test_damaged_checkpoints_on_resume(tmp_path, capsys):
    import torch
    from helpers import synthetic_h5

    h5 = synthetic_h5(tmp_path / "t.h5", n=16)
    model, ckpt = tmp_path / "m.pt", tmp_path / "m.ckpt.pt"
    base = ["train", h5, "-o", model, "--epochs", "2", "--batch-size", "16", "--quiet"]
    assert _gazeaug(base, capsys)[0] == 0
    good = ckpt.read_bytes()
    good_obj = torch.load(ckpt, weights_only=True)
    damaged = {
        "truncated": good[: len(good) // 2],
        "random": os.urandom(len(good)),
        "empty": b"",
    }
    for name, mutate in {
        "no-optimizer": lambda d: d.pop("optimizer"),
        "log-wrong-type": lambda d: d.__setitem__("log", 7),
        "epoch-out-of-range": lambda d: d.__setitem__("epoch", 99),
        "weights-do-not-fit": lambda d: d.__setitem__("state_dict", {"w": torch.zeros(3)}),
    }.items():
        obj = dict(good_obj)
        mutate(obj)
        torch.save(obj, tmp_path / "x.pt")
        damaged[name] = (tmp_path / "x.pt").read_bytes()
    for name, data in damaged.items():
        ckpt.write_bytes(data)
        code, _, err = _gazeaug([*base, "--resume"], capsys)
        assert code == 2, name
        _one_line(err, str(ckpt), "checkpoint")


@torch_needed
def test_unknown_validation_subject_is_named(tmp_path, capsys):
    from helpers import synthetic_h5

    h5 = synthetic_h5(tmp_path / "t.h5", n=16, subjects=("p00", "p01"))
    code, _, err = _gazeaug(["train", h5, "-o", tmp_path / "m.pt", "--val-subjects", "p07", "--quiet"], capsys)
    assert code == 2
    _one_line(err, "p07", "p00, p01")


# --------------------------------------------------------------------------------------------
# 3. simulate never overwrites a dataset it was not told to
# --------------------------------------------------------------------------------------------


def test_simulate_refuses_a_non_empty_folder_and_swaps_on_overwrite(tmp_path, capsys):
    out = tmp_path / "sim"
    assert _gazeaug(["simulate", "-o", out, "--per-face", "2", "--quiet"], capsys)[0] == 0
    first = _snapshot(out)
    assert len(first["labels.csv"].decode().strip().splitlines()) == 3
    code, _, err = _gazeaug(["simulate", "-o", out, "--per-face", "1", "--quiet"], capsys)
    assert code == 2
    _one_line(err, "not empty", "--overwrite")
    assert _snapshot(out) == first
    code, _, err = _gazeaug(["simulate", "-o", out, "--per-face", "1", "--overwrite", "--quiet"], capsys)
    assert code == 0, err
    labels = (out / "labels.csv").read_text().strip().splitlines()
    images = sorted(p.relative_to(out).as_posix() for p in out.rglob("*.jpg"))
    assert len(labels) == 2 and images == [labels[1].split(",")[0]], "no image without its label row"
    assert not (tmp_path / "sim.part").exists() and not (tmp_path / "sim.lock").exists()
    # --overwrite never deletes a folder simulate did not write
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    code, _, err = _gazeaug(["simulate", "-o", mine, "--per-face", "1", "--overwrite", "--quiet"], capsys)
    assert code == 2
    _one_line(err, "not a folder this command wrote")
    assert (mine / "thesis.tex").read_text() == "years of work"


def test_simulate_names_the_photo_without_a_face(tmp_path, capsys):
    from facemesh.io import save_image_rgb

    blank = tmp_path / "blank.png"
    save_image_rgb(blank, np.full((200, 200, 3), 90, np.uint8))
    code, _, err = _gazeaug(["simulate", "--faces", blank, "-o", tmp_path / "sim", "--quiet"], capsys)
    assert code == 2
    _one_line(err, str(blank))
    assert not (tmp_path / "sim").exists() and not (tmp_path / "sim.part").exists()


def test_simulate_names_a_missing_photo_before_any_progress(tmp_path, capsys):
    # with progress bars on (no --quiet): the error is the only thing on stderr, and no folder appears
    for face, says in ((tmp_path / "gone.jpg", "no such file"), (tmp_path, "not a file")):
        code, _, err = _gazeaug(["simulate", "--faces", face, "-o", tmp_path / "sim"], capsys)
        assert code == 2
        _one_line(err, f"{face}: {says}")
        assert not (tmp_path / "sim").exists() and not (tmp_path / "sim.part").exists()


# --------------------------------------------------------------------------------------------
# 4. A live run's .part is not an interrupted run
# --------------------------------------------------------------------------------------------


def test_output_lock_excludes_a_second_holder(tmp_path):
    target = tmp_path / "out.h5"
    with output_lock(target) as lock:
        assert lock.read_text().strip() == str(os.getpid())
        code = f"from facemesh.outputs import output_lock\nwith output_lock({str(target)!r}):\n    pass\n"
        res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        assert res.returncode != 0 and "OutputBusyError" in res.stderr and f"pid {os.getpid()}" in res.stderr
        with pytest.raises(OutputBusyError, match="another run is writing it now"):
            with output_lock(target):
                pass
    assert not lock.exists()
    with output_lock(target):  # free again once released
        pass


def test_a_live_run_is_told_from_an_interrupted_one(tmp_path, capsys, sample_jpg):
    from gazeaug.io_h5 import part_path

    ds = _folder_dataset(tmp_path / "ds", sample_jpg)
    out = tmp_path / "out.h5"
    part = part_path(out)
    part.write_bytes(b"a run's file in progress")
    with output_lock(out):
        code, _, err = _gazeaug(["normalize-dataset", ds, "-o", out, "--quiet"], capsys)
        assert code == 2
        _one_line(err, "another run is writing it now")
        code, _, err = _gazeaug(["normalize-dataset", ds, "-o", out, "--quiet", "--resume"], capsys)
        assert code == 2
        _one_line(err, "another run is writing it now")
    assert part.read_bytes() == b"a run's file in progress"
    code, _, err = _gazeaug(["normalize-dataset", ds, "-o", out, "--quiet"], capsys)
    assert code == 2
    _one_line(err, "an interrupted run left it")


@torch_needed
def test_two_trainings_of_one_model_exclude_each_other(tmp_path, capsys):
    from helpers import synthetic_h5

    h5 = synthetic_h5(tmp_path / "t.h5", n=16)
    with output_lock(tmp_path / "m.pt"):
        code, _, err = _gazeaug(["train", h5, "-o", tmp_path / "m.pt", "--quiet"], capsys)
    assert code == 2
    _one_line(err, "another run is writing it now")


# --------------------------------------------------------------------------------------------
# 5, 6. Output paths are checked before any work
# --------------------------------------------------------------------------------------------


def _writing_commands(tmp: Path, out_dir: Path, photo: Path) -> list[tuple[str, list]]:
    """(program, argv) of every command that writes, with its outputs inside ``out_dir``."""
    ds = _folder_dataset(tmp / "ds", photo)
    h5, model = tmp / "missing.h5", tmp / "missing.pt"
    return [
        ("facemesh", ["build", photo, "-o", out_dir / "f.glb"]),
        ("facemesh", ["build", photo, "-o", tmp / "ok.glb", "--preview", out_dir / "p.png"]),
        ("facemesh", ["render", tmp / "missing.glb", "-o", out_dir / "r.png"]),
        ("facemesh", ["model", "export", "-o", out_dir / "m.obj"]),
        ("gazeaug", ["normalize", photo, "-o", out_dir / "n.npz"]),
        ("gazeaug", ["render", photo, "-o", out_dir / "r.npz"]),
        ("gazeaug", ["preview", photo, "-o", out_dir / "p.png"]),
        ("gazeaug", ["augment", ds, "-o", out_dir / "a.h5", "--quiet"]),
        ("gazeaug", ["normalize-dataset", ds, "-o", out_dir / "n.h5", "--quiet"]),
        ("gazeaug", ["train", h5, "-o", out_dir / "m.pt", "--quiet"]),
        ("gazeaug", ["evaluate", model, ds, "-o", out_dir / "report", "--quiet"]),
        ("gazeaug", ["predict", model, photo, "-o", out_dir / "p.png"]),
        ("gazeaug", ["export", model, "-o", out_dir / "m.onnx"]),
        ("gazeaug", ["simulate", "-o", out_dir / "sim", "--quiet"]),
        ("gazeaug", ["experiment", "-o", out_dir / "xp", "--quiet"]),
    ]


def test_read_only_folder_every_command(tmp_path, sample_jpg):
    prefix = unprivileged_prefix()
    ro = tmp_path / "ro"
    ro.mkdir()
    cmds = _writing_commands(tmp_path, ro, sample_jpg)
    os.chmod(ro, 0o555)
    try:
        for prog, argv in cmds:
            res = subprocess.run(
                [*prefix, str(BIN / prog), *map(str, argv)], capture_output=True, text=True, timeout=120
            )
            assert res.returncode == 2, (prog, argv, res.stderr)
            _one_line(res.stderr, str(ro), "read-only")
            assert list(ro.iterdir()) == [], (prog, argv)
    finally:
        os.chmod(ro, 0o755)


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_output_in_a_folder_that_takes_no_files(tmp_path, capsys):
    # /proc exists, yet creating a file there fails with ENOENT: the line names the folder as the problem
    # rather than saying "No such file or directory" of a folder that exists
    code, _, err = _gazeaug(["simulate", "-o", "/proc/gazeaug-x", "--per-face", "1", "--quiet"], capsys)
    assert code == 2
    _one_line(err, "/proc/gazeaug-x: cannot write the dataset folder: /proc: files cannot be created there")


@pytest.mark.parametrize("case", ["folder-named-like-the-file", "parent-is-a-file"])
def test_output_path_that_cannot_be_a_file(tmp_path, capsys, sample_jpg, case):
    tmp = tmp_path
    blocker = tmp / "blocker"
    blocker.write_text("a file")
    if case == "parent-is-a-file":
        out_dir, phrase = blocker, "is a file, not a folder"
    else:
        out_dir, phrase = tmp / "outs", "is a folder"
        for name in ("f.glb", "r.png", "m.obj", "n.npz", "r.npz", "p.png", "a.h5", "n.h5", "m.pt", "m.onnx"):
            (out_dir / name).mkdir(parents=True)
    for prog, argv in _writing_commands(tmp, out_dir, sample_jpg):
        if case != "parent-is-a-file" and argv[-2 if argv[-1] == "--quiet" else -1].name in (
            "report",
            "sim",
            "xp",
        ):
            continue  # folder outputs: a folder is what they want
        runner = _facemesh if prog == "facemesh" else _gazeaug
        code, _, err = runner(argv, capsys)
        assert code == 2, (argv, err)
        _one_line(err, phrase)
    assert blocker.read_text() == "a file"


def test_folder_outputs_refuse_an_existing_file(tmp_path, capsys, sample_jpg):
    existing = tmp_path / "report"
    existing.write_text("keep me")
    code, _, err = _gazeaug(["evaluate", tmp_path / "m.pt", sample_jpg, "-o", existing], capsys)
    assert code == 2
    _one_line(err, "is a file; the report folder must be a folder")
    code, _, err = _gazeaug(["simulate", "-o", existing, "--quiet"], capsys)
    assert code == 2
    assert existing.read_text() == "keep me"


@pytest.mark.parametrize(
    "prog, argv",
    [
        ("facemesh", ["render", "{glb}", "-o", "{tmp}/x.xyz"]),
        ("facemesh", ["build", "{photo}", "-o", "{tmp}/f.glb", "--preview", "{tmp}/x.xyz"]),
        ("gazeaug", ["predict", "{tmp}/m.pt", "{photo}", "-o", "{tmp}/x.xyz"]),
        ("gazeaug", ["preview", "{photo}", "-o", "{tmp}/x.jpg"]),
        ("facemesh", ["build", "{photo}", "-o", "{tmp}/f.obj"]),
    ],
)
def test_unknown_picture_extensions_are_refused_before_work(tmp_path, capsys, sample_jpg, prog, argv):
    glb = tmp_path / "in.glb"
    glb.write_bytes(b"not read: the output is checked first")
    argv = [a.format(tmp=tmp_path, photo=sample_jpg, glb=glb) for a in argv]
    runner = _facemesh if prog == "facemesh" else _gazeaug
    t0 = time.perf_counter()
    code, _, err = runner(argv, capsys)
    assert code == 2
    _one_line(err, "x" if "x." in " ".join(argv) else "f.obj")
    assert not (tmp_path / "f.glb").exists(), "build wrote its .glb before refusing the preview"
    assert time.perf_counter() - t0 < 10


# --------------------------------------------------------------------------------------------
# 9. Ctrl-C
# --------------------------------------------------------------------------------------------


def _interrupt_when(cmd: list, ready, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """Start ``cmd``, send SIGINT once ``ready()`` is true, return the finished process."""
    proc = subprocess.Popen(
        [*map(str, cmd)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint
    )
    t0 = time.monotonic()
    while not ready():
        if proc.poll() is not None or time.monotonic() - t0 > timeout:
            out, err = proc.communicate()
            pytest.fail(f"the run ended before it could be interrupted: {proc.returncode}\n{err}")
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


@torch_needed
def test_ctrl_c_during_training_keeps_the_checkpoint(tmp_path):
    from helpers import synthetic_h5

    h5 = synthetic_h5(tmp_path / "t.h5", n=64)
    model = tmp_path / "m.pt"
    ckpt = tmp_path / "m.ckpt.pt"
    cmd = [BIN / "gazeaug", "train", h5, "-o", model, "--epochs", "400", "--batch-size", "16", "--quiet"]
    res = _interrupt_when(cmd, ckpt.exists)
    assert res.returncode == 130, res.stderr
    _one_line(res.stderr, "interrupted", str(ckpt), "--resume")
    assert not model.exists() and not (tmp_path / "m.pt.lock").exists()


def test_ctrl_c_during_augment_keeps_a_resumable_part(tmp_path, sample_jpg, capsys):
    from gazeaug.io_h5 import part_path, read_h5

    ds = _folder_dataset(tmp_path / "ds", sample_jpg, n=200)
    out = tmp_path / "a.h5"
    cmd = [BIN / "gazeaug", "augment", ds, "-o", out, "--per-sample", "1", "--quiet", "--workers", "2"]
    seen: list[float] = []

    def working() -> bool:  # the .part exists and the workers have had time to start
        if part_path(out).exists() and not seen:
            seen.append(time.monotonic())
        return bool(seen) and time.monotonic() - seen[0] > 1.5

    res = _interrupt_when(cmd, working)
    assert res.returncode == 130, res.stderr
    _one_line(res.stderr, "interrupted", "kept", "--resume")
    assert part_path(out).exists() and not out.exists()
    code, _, err = _gazeaug(["augment", ds, "-o", out, "--per-sample", "1", "--quiet", "--resume"], capsys)
    assert code == 0, err
    assert len(read_h5(out, ["source_index"])["source_index"]) == 200


def test_ctrl_c_in_facemesh_build_writes_nothing(tmp_path, capsys, monkeypatch):
    import facemesh.build

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(facemesh.build, "build_mesh", interrupted)
    code, _, err = _facemesh(["build", "-o", tmp_path / "f.glb"], capsys)
    assert code == 130
    _one_line(err, "interrupted", "nothing was written")
    assert list(tmp_path.iterdir()) == []


def test_a_ctrl_c_a_native_module_turned_into_an_import_error_is_130(capsys):
    """A Ctrl-C during open3d's import came out as ImportError('initialization failed') caused
    by the KeyboardInterrupt (measured: a SIGINT about 2.5 s into ``gazeaug simulate``) and was
    phrased as a missing package, exit 2. It is an interruption: 130 and the interrupted line."""
    from facemesh.cli import NOTHING_WRITTEN, caused_by_ctrl_c, run_command

    def native_import() -> None:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as ki:
            raise ImportError("initialization failed") from ki

    code = run_command("gazeaug simulate", native_import)
    assert code == 130
    _one_line(capsys.readouterr().err, "interrupted", NOTHING_WRITTEN)
    plain = ImportError("No module named 'open3d'")
    assert not caused_by_ctrl_c(plain)
    assert run_command("gazeaug simulate", lambda: (_ for _ in ()).throw(plain)) == 2  # a real missing package
    _one_line(capsys.readouterr().err, "error", "open3d")
    looped = RuntimeError("a")  # a cycle of contexts ends the walk
    looped.__context__ = RuntimeError("b")
    looped.__context__.__context__ = looped
    assert not caused_by_ctrl_c(looped)


# --------------------------------------------------------------------------------------------
# 11. Outputs follow the umask
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o002])
def test_outputs_follow_the_umask(tmp_path, capsys, mask):
    from facemesh.io import atomic_write

    old = os.umask(mask)
    try:
        with atomic_write(tmp_path / "a.bin") as fh:
            fh.write(b"x")
        assert _facemesh(["model", "export", "-o", tmp_path / "m.obj"], capsys)[0] == 0
    finally:
        os.umask(old)
    for name in ("a.bin", "m.obj"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o666 & ~mask, name


def test_files_written_since_names_what_atomic_write_finished(tmp_path):
    from facemesh.io import atomic_write, files_written_count, files_written_since

    mark = files_written_count()
    assert files_written_since(mark) == ([], 0)
    with atomic_write(tmp_path / "a.bin") as fh:
        fh.write(b"a")
    with pytest.raises(KeyboardInterrupt), atomic_write(tmp_path / "b.bin") as fh:
        fh.write(b"b")
        raise KeyboardInterrupt  # not finished: not counted, and nothing left
    for i in range(20):
        with atomic_write(tmp_path / f"c{i}.bin") as fh:
            fh.write(b"c")
    done, count = files_written_since(mark)
    assert count == 21  # a.bin and the 20 c files
    assert done == [tmp_path / f"c{i}.bin" for i in range(4, 20)]  # the last 16 named
    assert not (tmp_path / "b.bin").exists()
    assert files_written_since(files_written_count()) == ([], 0)
    # a file removed since (a scratch folder's) is neither named nor counted: 21 - 2 = 19, the 16 last left
    (tmp_path / "c19.bin").unlink()
    (tmp_path / "c10.bin").unlink()
    done, count = files_written_since(mark)
    assert count == 19
    assert done == [tmp_path / f"c{i}.bin" for i in range(4, 19) if i != 10]


def test_files_in_a_removed_scratch_folder_are_not_counted_beyond_the_last_16(tmp_path):
    """``gazeaug simulate`` writes every image into ``OUT.part/`` and removes it on Ctrl-C. With
    more than 16 images the older ones were still counted, and the line read ``wrote  (the last 0
    of 30) whole before it``. Hand count: 1 kept file, then 30 in a scratch folder removed."""
    import shutil

    from facemesh.io import atomic_write, files_written_count, files_written_since

    mark = files_written_count()
    with atomic_write(tmp_path / "kept.bin") as fh:
        fh.write(b"k")
    for i in range(30):  # two subfolders, as a simulated dataset's subjects
        with atomic_write(tmp_path / "scratch" / f"s{i // 15}" / f"{i:02d}.jpg") as fh:
            fh.write(b"s")
    done, count = files_written_since(mark)
    assert count == 31
    assert done == [tmp_path / "scratch" / f"s{i // 15}" / f"{i:02d}.jpg" for i in range(14, 30)]
    shutil.rmtree(tmp_path / "scratch")
    assert files_written_since(mark) == ([], 1)  # kept.bin, beyond the last 16: counted, not named
    (tmp_path / "kept.bin").unlink()  # a single file beyond the last 16 removed: cannot be seen
    assert files_written_since(mark) == ([], 1)
    mark = files_written_count()
    for i in range(20):
        with atomic_write(tmp_path / "scratch2" / f"{i}.bin") as fh:
            fh.write(b"t")
    shutil.rmtree(tmp_path / "scratch2")
    assert files_written_since(mark) == ([], 0)


def test_an_interrupted_command_whose_scratch_folder_went_says_nothing_was_written(tmp_path, capsys):
    """run_command's line after a Ctrl-C, for a command that wrote 30 files into a scratch folder
    and removed it (``gazeaug simulate``'s ``OUT.part/``), and for one whose last files went but an
    earlier one stayed."""
    import shutil

    from facemesh.cli import NOTHING_WRITTEN, run_command
    from facemesh.io import atomic_write

    def scratch_then_ctrl_c(keep_first: bool) -> None:
        if keep_first:
            with atomic_write(tmp_path / "first.bin") as fh:
                fh.write(b"f")
        for i in range(30):
            with atomic_write(tmp_path / "OUT.part" / f"{i:02d}.jpg") as fh:
                fh.write(b"s")
        shutil.rmtree(tmp_path / "OUT.part")
        raise KeyboardInterrupt

    assert run_command("gazeaug simulate", lambda: scratch_then_ctrl_c(False)) == 130
    _one_line(capsys.readouterr().err, "interrupted", NOTHING_WRITTEN)
    assert run_command("gazeaug simulate", lambda: scratch_then_ctrl_c(True)) == 130
    err = capsys.readouterr().err
    _one_line(err, "interrupted", "wrote 1 file whole before it; nothing else was written")
    assert "(the last" not in err


# --------------------------------------------------------------------------------------------
# 12. Non-finite numbers
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "prog, argv",
    [
        ("facemesh", ["render", "x.glb", "-o", "{tmp}/r.png", "--yaw", "nan"]),
        ("facemesh", ["render", "x.glb", "-o", "{tmp}/r.png", "--pitch", "inf"]),
        ("facemesh", ["build", "-o", "{tmp}/f.glb", "--texture-margin", "nan"]),
        ("gazeaug", ["render", "-o", "{tmp}/r.npz", "--yaw", "nan", "--pitch", "0"]),
        ("gazeaug", ["preview", "-o", "{tmp}/p.png", "--pitch-mean=-inf"]),
        ("gazeaug", ["normalize", "-o", "{tmp}/n.npz", "--distance", "nan"]),
        ("gazeaug", ["train", "x.h5", "-o", "{tmp}/m.pt", "--lr", "nan"]),
    ],
)
def test_non_finite_numbers_are_refused(tmp_path, capsys, prog, argv):
    runner = _facemesh if prog == "facemesh" else _gazeaug
    code, _, err = runner([a.format(tmp=tmp_path) for a in argv], capsys)
    assert code == 2
    _one_line(err, "expected a finite number")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# 15, 16. Empty selections and messages that point at the real problem
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("case", ["header-only", "limit-0", "limit-negative"])
def test_empty_selections_are_errors(tmp_path, capsys, sample_jpg, case):
    ds = _folder_dataset(tmp_path / "ds", sample_jpg, header_only=case == "header-only")
    extra = {"header-only": [], "limit-0": ["--limit", "0"], "limit-negative": ["--limit", "-2"]}[case]
    out = tmp_path / "a.h5"
    argv = ["augment", ds, "-o", out, "--quiet", *extra]
    code, _, err = _gazeaug(argv, capsys)
    assert code == 2
    _one_line(err, "expected an integer >= 1" if extra else "no samples")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


def test_folder_labels_messages(tmp_path, sample_jpg):
    from gazeaug.datasets.base import DatasetError
    from gazeaug.datasets.folder import FolderDataset

    ds = _folder_dataset(tmp_path / "ds", sample_jpg, n=1)
    text = (ds / "labels.csv").read_text()
    # a UTF-8 byte-order mark (as Excel writes) is not part of the first column's name
    (ds / "labels.csv").write_bytes(b"\xef\xbb\xbf" + text.encode())
    assert len(list(FolderDataset(ds))) == 1
    # an empty target cell is named as such, even when gaze columns exist
    header, row = text.strip().splitlines()
    (ds / "labels.csv").write_text(header + ",gaze_x,gaze_y,gaze_z\n" + row[: row.rindex(",")] + ",,0,0,1\n")
    with pytest.raises(DatasetError, match="line 2: empty value in column 'target_z'"):
        list(FolderDataset(ds))
    # all target cells empty: the gaze direction is used
    (ds / "labels.csv").write_text(header + ",gaze_x,gaze_y,gaze_z\n" + row.rsplit(",", 3)[0] + ",,,,0,0,1\n")
    (sample,) = list(FolderDataset(ds))
    assert sample.gaze_target_mm is None and list(sample.gaze_vector) == [0, 0, 1]


# --------------------------------------------------------------------------------------------
# Fuzzed inputs: every reader gives its typed error (exit 2 at the CLI), never another exception
# --------------------------------------------------------------------------------------------


def test_fuzzed_folder_labels(tmp_path, sample_jpg):
    from gazeaug.datasets.folder import FolderDataset

    ds = _folder_dataset(tmp_path / "ds", sample_jpg, n=2)
    valid_csv = (ds / "labels.csv").read_bytes()
    rows = list(csv.DictReader(valid_csv.decode().splitlines()))
    valid_jsonl = "".join(json.dumps(r) + "\n" for r in rows).encode()
    for name, valid in (("labels.csv", valid_csv), ("labels.jsonl", valid_jsonl)):
        other = ds / ("labels.jsonl" if name == "labels.csv" else "labels.csv")
        other.unlink(missing_ok=True)
        for data in mutations(valid, seed=len(name)):
            expect_typed_error(lambda p: list(FolderDataset(p.parent)), ds / name, data)


def test_fuzzed_landmark_files(tmp_path):
    import io

    from facemesh.landmarks import load_landmarks_file

    pts = np.random.default_rng(0).uniform(0, 500, (68, 2))
    buf = io.BytesIO()
    np.save(buf, pts)
    valid = {
        ".npy": buf.getvalue(),
        ".json": json.dumps(pts.tolist()).encode(),
        ".csv": "\n".join(f"{x},{y}" for x, y in pts).encode(),
    }
    for suffix, data in valid.items():
        for m in mutations(data, seed=len(suffix)):
            expect_typed_error(load_landmarks_file, tmp_path / f"lm{suffix}", m)


def test_fuzzed_rig_files(tmp_path):
    from gazeaug.sampling import load_rig

    valid = (REPO / "data_samples" / "rigs" / "wheelchair.yaml").read_bytes()
    for m in mutations(valid, seed=3):
        expect_typed_error(load_rig, tmp_path / "rig.yaml", m)


def test_fuzzed_training_sets(tmp_path):
    pytest.importorskip("torch")
    from helpers import synthetic_h5

    from gazeaug.train import H5TrainingSet

    valid = synthetic_h5(tmp_path / "t.h5", n=8).read_bytes()
    for m in mutations(valid, seed=4, n=12):
        expect_typed_error(H5TrainingSet, tmp_path / "x.h5", m)


def test_library_render_refuses_a_non_finite_turn():
    from facemesh.conventions import rotation_from_yaw_pitch
    from facemesh.render import RaycastScene
    from facemesh.types import InputError

    v = np.array([[0.0, 0, 500], [10, 0, 500], [0, 10, 500]])
    tri, uv, tex = np.array([[0, 1, 2]]), np.array([[0, 0], [1, 0], [0, 1.0]]), np.zeros((4, 4, 3), np.uint8)
    RaycastScene(v, tri, uv, tex)
    turned = (v - v.mean(0)) @ rotation_from_yaw_pitch(np.nan, 0.0).T
    with pytest.raises(InputError, match="NaN or infinite"):
        RaycastScene(turned, tri, uv, tex)


# --------------------------------------------------------------------------------------------
# Second hostile round: resume of other data, failed runs, side outputs, bounds, clashes
# --------------------------------------------------------------------------------------------


def _interrupted_part(tmp_path, ds, out, extra=()):
    """A .part left by an interrupted run (KeyboardInterrupt after the first sample)."""
    from gazeaug.datasets import open_dataset
    from gazeaug.jobs import JobSettings, run_dataset

    class Interrupting:
        def __init__(self, reader):
            self.reader, self.name, self.root = reader, reader.name, reader.root

        def __len__(self):
            return len(self.reader)

        def __iter__(self):
            for i, s in enumerate(self.reader):
                if i == 1:
                    raise KeyboardInterrupt
                yield s

    with pytest.raises(KeyboardInterrupt):
        run_dataset(
            Interrupting(open_dataset(ds)),
            out,
            JobSettings(kind="normalize-dataset"),
            progress=False,
            flush_every=1,
            **dict(extra),
        )


def test_resume_refuses_another_dataset_or_limit(tmp_path, capsys, sample_jpg):
    from gazeaug.io_h5 import part_path

    ds = _folder_dataset(tmp_path / "ds", sample_jpg, n=3)
    other = _folder_dataset(tmp_path / "other", sample_jpg, n=3)
    out = tmp_path / "n.h5"
    _interrupted_part(tmp_path, ds, out)
    before = part_path(out).read_bytes()
    for argv, phrase in (
        (["normalize-dataset", other, "-o", out, "--resume", "--quiet"], "data.dataset"),
        (["normalize-dataset", ds, "-o", out, "--resume", "--quiet", "--limit", "2"], "data.samples"),
    ):
        code, _, err = _gazeaug(argv, capsys)
        assert code == 2, err
        _one_line(err, "other settings or data", phrase, "resume with the same options")
        assert part_path(out).read_bytes() == before and not out.exists()
    code, _, err = _gazeaug(["normalize-dataset", ds, "-o", out, "--resume", "--quiet"], capsys)
    assert code == 0, err


def test_a_failed_run_leaves_nothing_to_resume(tmp_path, capsys, sample_jpg):
    ds = _folder_dataset(tmp_path / "ds", sample_jpg, n=3)
    lines = (ds / "labels.csv").read_text().splitlines()
    lines[3] = lines[3].replace(",600,600,", ",nan,600,", 1)  # the third sample's focal length
    (ds / "labels.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "n.h5"
    code, _, err = _gazeaug(["normalize-dataset", ds, "-o", out, "--quiet"], capsys)
    assert code == 2
    _one_line(err, "line 4", "fx")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"], "a failed run is not an interrupted one"


@pytest.mark.parametrize(
    "argv, side",
    [
        (["train", "{h5}", "-o", "{tmp}/side.pt", "--quiet"], "side.curves.png"),
        (["train", "{h5}", "-o", "{tmp}/side.pt", "--quiet"], "side.ckpt.pt"),
        (["normalize-dataset", "{ds}", "-o", "{tmp}/side.h5", "--quiet"], "side.summary.json"),
        (["preview", "-o", "{tmp}/sh.png"], "sh_distribution.png"),
    ],
)
def test_files_beside_the_output_are_checked_before_work(tmp_path, capsys, sample_jpg, argv, side):
    (tmp_path / side).mkdir()
    ds = _folder_dataset(tmp_path / "ds", sample_jpg, n=1)
    argv = [a.format(tmp=tmp_path, h5=tmp_path / "missing.h5", ds=ds) for a in argv]
    code, _, err = _gazeaug(argv, capsys)
    assert code == 2
    _one_line(err, side, "is a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["ds", side])


@pytest.mark.parametrize(
    "argv, phrase",
    [
        (["render", "-o", "{tmp}/r.npz", "--seed", "-1"], "expected an integer >= 0"),
        (["preview", "-o", "{tmp}/p.png", "-n", "1000000000"], "expected an integer from 1 to"),
        (["augment", "{tmp}", "-o", "{tmp}/a.h5", "--workers", "100000"], "expected an integer from 1 to"),
        (["render", "-o", "{tmp}/r.npz", "--rig", "wheelchair", "--pitch-mean", "80"], "not both"),
        (["augment", "{tmp}", "-o", "{tmp}/a.h5", "--rig", "wheelchair", "--yaw-std", "3"], "not both"),
    ],
)
def test_options_out_of_bounds_or_clashing(tmp_path, capsys, argv, phrase):
    code, _, err = _gazeaug([a.format(tmp=tmp_path) for a in argv], capsys)
    assert code == 2
    _one_line(err, phrase)
    assert list(tmp_path.iterdir()) == []


def test_experiment_checks_its_photos_before_simulating(tmp_path, capsys):
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"not a picture")
    t0 = time.perf_counter()
    code, _, err = _gazeaug(["experiment", "-o", tmp_path / "xp", "--faces", bad, "--quiet"], capsys)
    assert code == 2
    _one_line(err, "bad.jpg")
    assert not (tmp_path / "xp").exists() and time.perf_counter() - t0 < 10


@pytest.mark.parametrize("prog", ["facemesh", "gazeaug"])
def test_a_ctrl_c_outside_main_is_one_line_and_130(monkeypatch, capsys, prog):
    import importlib
    import signal as signal_module

    cli = importlib.import_module(f"{prog}.cli")

    def interrupted(argv=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "main", interrupted)
    old = signal_module.getsignal(signal_module.SIGINT)
    try:
        with pytest.raises(SystemExit) as exc:
            cli.entry()
        assert exc.value.code == 130
        _one_line(capsys.readouterr().err, "interrupted")
        assert signal_module.getsignal(signal_module.SIGINT) == signal_module.SIG_IGN  # a late Ctrl-C is ignored
    finally:
        signal_module.signal(signal_module.SIGINT, old)


@pytest.mark.parametrize("prog", ["facemesh", "gazeaug"])
def test_a_ctrl_c_while_the_cli_loads_is_one_line_and_130(tmp_path, prog):
    # the console scripts' first module imports neither package until it runs: a Ctrl-C during
    # those imports (numpy, OpenCV, the CLI's modules) is the one line, not a traceback
    script = (
        "import importlib, gazeaug_console\n"
        "def interrupted(name):\n"
        "    raise KeyboardInterrupt\n"
        "importlib.import_module = interrupted\n"
        f"gazeaug_console.{prog}()\n"
    )
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert res.returncode == 130, res.stderr
    assert res.stderr == f"{prog}: interrupted before it started; nothing was written\n"
    # and the installed commands start from it
    assert f"from gazeaug_console import {prog}" in (BIN / prog).read_text()


def test_unreadable_inputs_exit_2(tmp_path):
    prefix = unprivileged_prefix()
    secret = tmp_path / "secret.glb"
    secret.write_bytes(b"glTF")
    os.chmod(secret, 0)
    for prog, argv in (("facemesh", ["info", secret]), ("gazeaug", ["normalize", secret, "-o", tmp_path / "n.npz"])):
        res = subprocess.run([*prefix, str(BIN / prog), *map(str, argv)], capture_output=True, text=True, timeout=120)
        assert res.returncode == 2, res.stderr
        _one_line(res.stderr, "secret.glb")


def test_a_flush_interrupted_half_way_writes_no_row_twice(tmp_path):
    """Ctrl-C between two keys of a flush, then the close that follows: each row once (was: 216 of 200)."""
    from helpers import synthetic_h5

    from gazeaug.io_h5 import H5TrainingSet, H5Writer, Rows, part_path

    src = H5TrainingSet(synthetic_h5(tmp_path / "src.h5", n=8)).read()
    rows = Rows({k: v for k, v in src.items() if k != "attrs"})
    out = tmp_path / "o.h5"
    w = H5Writer(out, {"settings": {"x": 1}}, (60, 36))
    w.append(rows, 0)
    calls = {"n": 0}
    real = w._f.__class__.__getitem__

    def interrupt_on_third_key(f, key):  # the third dataset touched during the flush
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real(f, key)

    w._f.__class__.__getitem__ = interrupt_on_third_key
    try:
        with pytest.raises(KeyboardInterrupt):
            w.flush()
    finally:
        w._f.__class__.__getitem__ = real
    w.close()  # what run_dataset does on Ctrl-C
    import h5py

    with h5py.File(part_path(out), "r") as f:
        assert f["left_eye"].shape[0] == 8 and f["gaze"].shape[0] == 8 and int(f.attrs["rows_done"]) == 8
        np.testing.assert_array_equal(f["source_index"][()], src["source_index"])


def test_a_worker_process_shows_a_warning_as_one_line():
    # workers=N runs in spawned processes, which the command line's warning display does not reach: a
    # ReprojectionWarning used to print as Python's two lines (file:line and the source line)
    code = (
        "import warnings\n"
        "from gazeaug.jobs import JobSettings, _worker_init\n"
        "_worker_init(JobSettings(kind='normalize-dataset'), 1)\n"
        "warnings.warn('landmark 291 lies 29.7 px from its reprojection', UserWarning)\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if "29.7 px" in ln or "warn(" in ln]
    assert lines == ["gazeaug: warning: landmark 291 lies 29.7 px from its reprojection"], res.stderr
