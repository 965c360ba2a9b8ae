"""The Ray engine on real Ray: a local instance, a head node joined by address, and a two-node cluster losing a node.

Expected values come from the local engine (the one the other tests pin): every
array, row order, source label and skip must be the same.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
from helpers import default_sigint

from gazeaug.datasets import open_dataset
from gazeaug.engine import Engine, check_address, map_blocks
from gazeaug.errors import GazeAugError
from gazeaug.io_h5 import part_path
from gazeaug.jobs import JobSettings, run_dataset, shard_dir

ray = pytest.importorskip("ray", reason="the ray extra is not installed (pip install -e '.[ray]')")
ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the functions below: the workers do not see tests/

GAZEAUG = [sys.executable, "-m", "gazeaug.cli"]
SETTINGS = JobSettings(kind="augment", per_sample=2, seed=7)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A folder dataset of 9 samples: 8 simulated images of the built-in face, and one without a face (index 5)."""
    from gazeaug.sampling import load_rig
    from gazeaug.simulate import simulate

    root = tmp_path_factory.mktemp("raydata") / "sim"
    simulate([None], load_rig("screen"), root, per_face=8, seed=1, progress=False)
    lines = (root / "labels.csv").read_text().splitlines()
    grey = lines[1].split(",")
    grey[0] = "sim00/grey.jpg"
    cv2.imwrite(str(root / "sim00" / "grey.jpg"), np.full((480, 640, 3), 128, np.uint8))
    lines.insert(6, ",".join(grey))
    (root / "labels.csv").write_text("\n".join(lines) + "\n")
    return root


@pytest.fixture(scope="module")
def local_output(dataset, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("raylocal") / "local.h5"
    run_dataset(open_dataset(dataset), out, SETTINGS, progress=False)
    return out


def _contents(path: Path) -> dict:
    with h5py.File(path, "r") as f:
        out = {k: f[k][()] for k in f if isinstance(f[k], h5py.Dataset)}
        out.update({f"sources/{k}": f["sources"][k][()] for k in f["sources"]})
        skipped = json.loads(f.attrs["skipped"])
        out["skipped"] = [{k: v for k, v in s.items() if k != "node"} for s in skipped]
        out["nodes"] = [s.get("node") for s in skipped]
        out["complete"] = bool(f.attrs["complete"])
    return out


def _assert_same(got: Path, want: Path, *, same_paths: bool = True) -> None:
    """Every array equal; the skips equal (``same_paths=False``: the dataset given by another path)."""
    a, b = _contents(got), _contents(want)
    assert a["complete"] and b["complete"]
    if same_paths:
        assert a["skipped"] == b["skipped"]
    else:
        assert [s["source_index"] for s in a["skipped"]] == [s["source_index"] for s in b["skipped"]]
        assert [Path(s["image"]).name for s in a["skipped"]] == [Path(s["image"]).name for s in b["skipped"]]
    keys = set(a) - {"skipped", "nodes", "complete"}
    assert keys == set(b) - {"skipped", "nodes", "complete"}
    for k in sorted(keys):
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def ray_local():
    """A local Ray instance of 2 CPUs for one test (stopped after)."""
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    yield ray
    ray.shutdown()


# --- without Ray running ---------------------------------------------------------------------------------------------


def test_without_the_package_the_error_gives_the_install_hint(monkeypatch, dataset, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(GazeAugError, match=r"pip install 'gazeaug\[ray\]'"):
        run_dataset(open_dataset(dataset), tmp_path / "o.h5", SETTINGS, progress=False, engine=Engine("ray"))
    assert list(tmp_path.iterdir()) == []


def test_engine_settings_are_checked():
    with pytest.raises(GazeAugError, match="expected one of"):
        Engine("spark")
    with pytest.raises(GazeAugError, match="not ray"):
        Engine("local", address="127.0.0.1:6379")
    with pytest.raises(GazeAugError, match="HOST:PORT"):
        Engine("ray", address="localhost")
    with pytest.raises(GazeAugError, match="HOST:PORT"):
        Engine("ray", address="localhost:70000")
    with pytest.raises(GazeAugError, match="block size"):
        Engine("ray", block_size=0)


def test_a_wrong_address_fails_at_once_and_writes_nothing(dataset, tmp_path):
    closed = _free_port()
    t0 = time.monotonic()
    out = tmp_path / "o.h5"
    r = subprocess.run(
        [*GAZEAUG, "augment", str(dataset), "-o", str(out), "--engine", "ray", "--ray-address", f"127.0.0.1:{closed}"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and "no Ray cluster answers there" in r.stderr and "Traceback" not in r.stderr
    assert time.monotonic() - t0 < 60  # Ray's own attempt retries for minutes, then ends the process
    assert list(tmp_path.iterdir()) == []
    # something listens, but it is not a Ray head (an HTTP/1 server answers the gRPC greeting with text)
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen()

        def answer():
            conn, _ = srv.accept()
            with conn:
                conn.recv(64)
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n")

        th = threading.Thread(target=answer, daemon=True)
        th.start()
        with pytest.raises(GazeAugError, match="not a Ray head"):
            check_address(f"127.0.0.1:{srv.getsockname()[1]}")
        th.join(5)


def test_the_output_is_checked_before_ray_starts(dataset, local_output):
    from facemesh.outputs import OutputExistsError

    nowhere = Engine("ray", address=f"127.0.0.1:{_free_port()}")  # never asked: the output is refused first
    with pytest.raises(OutputExistsError, match="exists and is complete"):
        run_dataset(open_dataset(dataset), local_output, SETTINGS, progress=False, engine=nowhere)


def test_cli_options_are_checked(dataset, tmp_path):
    for extra, message in (
        (["--ray-address", "127.0.0.1:6379"], "only with --engine ray"),
        (["--block-size", "8"], "only with --engine ray"),
        (["--engine", "ray", "--ray-address", "nope"], "HOST:PORT"),
    ):
        r = subprocess.run(
            [*GAZEAUG, "augment", str(dataset), "-o", str(tmp_path / "o.h5"), *extra], capture_output=True, text=True
        )
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, r.stderr
    for cmd, message in (
        (["simulate", "-o", str(tmp_path / "s"), "--workers", "2"], "--engine ray"),
        (["simulate", "-o", str(tmp_path / "s"), "--engine", "ray", "--block-size", "4"], "--block-size"),
        (["evaluate", "m.pt", str(tmp_path / "x.h5"), "-o", str(tmp_path / "e"), "--block-size", "4"], "--engine ray"),
        (["evaluate", "m.pt", str(tmp_path / "x.h5"), "-o", str(tmp_path / "e"), "--workers", "3"], "--engine ray"),
    ):
        r = subprocess.run([*GAZEAUG, *cmd], capture_output=True, text=True)
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == []


# --- a local Ray instance --------------------------------------------------------------------------------------------


def test_ray_gives_the_local_arrays_in_the_local_order(ray_local, dataset, local_output, tmp_path):
    out = tmp_path / "ray.h5"
    summary = run_dataset(
        open_dataset(dataset), out, SETTINGS, progress=False, engine=Engine("ray", workers=2, block_size=2)
    )
    _assert_same(out, local_output)
    got = _contents(out)
    assert got["skipped"][0]["source_index"] == 5 and "no face" in got["skipped"][0]["reason"]
    assert got["nodes"][0] and socket.gethostname() in got["nodes"][0]  # the failing sample names its node
    assert summary["rows"] == 16 and summary["skipped"] == 1
    assert not shard_dir(out).exists() and not part_path(out).exists()
    # normalize-dataset too, with blocks that do not divide the dataset, and face patches in the shards
    from gazeaug.normalize import NormalizationSettings

    base = JobSettings(kind="normalize-dataset", normalization=NormalizationSettings(face_patch_size_wh=(32, 24)))
    run_dataset(open_dataset(dataset), tmp_path / "n_local.h5", base, progress=False)
    run_dataset(
        open_dataset(dataset),
        tmp_path / "n_ray.h5",
        base,
        progress=False,
        engine=Engine("ray", workers=2, block_size=4),
    )
    _assert_same(tmp_path / "n_ray.h5", tmp_path / "n_local.h5")
    assert _contents(tmp_path / "n_ray.h5")["face"].shape[1:] == (24, 32, 3)
    # and an augmentation with each source's own row (K + 1 rows per face): the same rows on Ray
    both = JobSettings(kind="augment", per_sample=1, seed=7, with_source=True)
    run_dataset(open_dataset(dataset), tmp_path / "s_local.h5", both, progress=False)
    engine = Engine("ray", workers=2, block_size=3)
    run_dataset(open_dataset(dataset), tmp_path / "s_ray.h5", both, progress=False, engine=engine)
    _assert_same(tmp_path / "s_ray.h5", tmp_path / "s_local.h5")
    assert _contents(tmp_path / "s_ray.h5")["source_index"].tolist() == [i for i in range(9) if i != 5 for _ in (0, 1)]


class _Interrupting:
    """A reader interrupted (KeyboardInterrupt, as Ctrl-C) when the driver reaches sample ``n``."""

    def __init__(self, inner, n, wait_for=None):
        self.inner, self.n, self.name, self.root, self.wait_for = inner, n, inner.name, inner.root, wait_for

    def __len__(self):
        return len(self.inner)

    def __iter__(self):
        for s in self.inner:
            if s.source_index == self.n:
                if self.wait_for is not None:  # let the blocks already sent write their shards
                    deadline = time.monotonic() + 60
                    while not self.wait_for() and time.monotonic() < deadline:
                        time.sleep(0.1)
                raise KeyboardInterrupt
            yield s


def test_interrupted_then_resumed_gives_the_same_file(ray_local, dataset, local_output, tmp_path):
    out = tmp_path / "r.h5"
    shards = shard_dir(out)
    engine = Engine("ray", workers=2, block_size=2)

    def some_shard_written():
        return shards.is_dir() and any(p.suffix == ".h5" and p.name.count(".") == 1 for p in shards.iterdir())

    with pytest.raises(KeyboardInterrupt):
        run_dataset(
            _Interrupting(open_dataset(dataset), 6, some_shard_written), out, SETTINGS, progress=False, engine=engine
        )
    assert part_path(out).exists() and not out.exists()
    with pytest.raises(GazeAugError, match="other settings"):
        run_dataset(
            open_dataset(dataset),
            out,
            JobSettings(kind="augment", per_sample=3, seed=7),
            resume=True,
            progress=False,
            engine=engine,
        )
    run_dataset(open_dataset(dataset), out, SETTINGS, resume=True, progress=False, engine=engine)
    _assert_same(out, local_output)  # nothing lost, nothing twice
    assert not shards.exists()


def _dies_from_sample_4(task):
    """Stands in for jobs._ray_work: the worker process dies on every block from sample 4 on."""
    from gazeaug import jobs

    if task.first >= 4:
        os._exit(1)
    return jobs._ray_work(task)


def test_workers_lost_too_often_keep_the_work_done(ray_local, dataset, local_output, tmp_path, monkeypatch):
    from gazeaug import jobs
    from gazeaug.engine import WorkersLostError

    out = tmp_path / "lost.h5"
    monkeypatch.setattr(jobs, "_ray_work", _dies_from_sample_4)
    with pytest.raises(WorkersLostError, match="--resume"):
        run_dataset(open_dataset(dataset), out, SETTINGS, progress=False, engine=Engine("ray", workers=2, block_size=2))
    assert part_path(out).exists()  # the blocks merged before stay, as after Ctrl-C
    monkeypatch.undo()
    run_dataset(open_dataset(dataset), out, SETTINGS, resume=True, progress=False, engine=Engine("ray", workers=2))
    _assert_same(out, local_output)


def test_an_error_in_the_work_stops_the_run_with_that_error(ray_local, tmp_path):
    from gazeaug.datasets.base import DatasetError

    with pytest.raises(DatasetError, match="block 3 is bad"):
        map_blocks(Engine("ray", workers=2), enumerate(range(6)), _fail_on_3, _nothing, on_result=lambda i, r: None)


def test_workers_that_cannot_start_say_why(ray_local):
    with pytest.raises(GazeAugError, match="could not start.*Every node needs gazeaug"):
        map_blocks(Engine("ray", workers=2), enumerate(range(3)), _fail_on_3, _no_module, on_result=lambda i, r: None)


def _nothing():
    pass


def _no_module():
    raise ModuleNotFoundError("No module named 'gazeaug'")


def _fail_on_3(block):
    from gazeaug.datasets.base import DatasetError

    if block == 3:
        raise DatasetError("block 3 is bad")
    return block


def test_simulate_and_evaluate_on_ray_match_local(ray_local, tmp_path):
    from gazeaug.sampling import load_rig
    from gazeaug.simulate import simulate

    rig = load_rig("screen")
    faces = [None, None]
    simulate(faces, rig, tmp_path / "a", per_face=2, seed=3, progress=False)
    simulate(faces, rig, tmp_path / "b", per_face=2, seed=3, progress=False, engine=Engine("ray", workers=2))
    for name in ("labels.csv", "simulation.jsonl", "sim00/00001.jpg", "sim01/00000.jpg"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name

    from gazeaug.evaluate import evaluate_dataset
    from gazeaug.train import load_model

    model, meta = load_model(Path(__file__).parents[1] / "gazeaug" / "models" / "demo_wheelchair.pt")
    a = evaluate_dataset(model, meta, open_dataset(tmp_path / "a"), progress=False)
    b = evaluate_dataset(model, meta, open_dataset(tmp_path / "a"), progress=False, engine=Engine("ray", block_size=3))
    assert a["rows"] == b["rows"] and a["mean_deg"] == b["mean_deg"]
    # an ONNX export, whose session does not pickle: each actor loads the file
    pytest.importorskip("onnxruntime")
    from gazeaug.estimator import load_estimator
    from gazeaug.export import export_onnx

    export_onnx(model, meta, tmp_path / "m.onnx")
    est = load_estimator(tmp_path / "m.onnx")
    ray_engine = Engine("ray", block_size=3)
    c = evaluate_dataset(est, est.meta, open_dataset(tmp_path / "a"), progress=False, engine=ray_engine)
    assert [r["index"] for r in c["rows"]] == [r["index"] for r in a["rows"]]
    np.testing.assert_allclose([r["error_deg"] for r in c["rows"]], [r["error_deg"] for r in a["rows"]], atol=0.01)
    # the .pt as `gazeaug evaluate` loads it: an estimator, sent to the actors whole
    pt = load_estimator(Path(__file__).parents[1] / "gazeaug" / "models" / "demo_wheelchair.pt")
    d = evaluate_dataset(pt, pt.meta, open_dataset(tmp_path / "a"), progress=False, engine=ray_engine)
    assert d["rows"] == a["rows"]


# --- a running head joined by address, and a cluster that loses a node -----------------------------------------------


def test_cli_against_ray_start_head_then_train_reads_it(dataset, local_output, tmp_path):
    """The issue's check: `ray start --head` running, `gazeaug augment --engine ray --ray-address` joins it."""
    port = _free_port()
    ray_cli = Path(sys.executable).parent / "ray"
    head = subprocess.Popen(  # started in another folder: the relative paths below must still work
        [str(ray_cli), "start", "--head", "--block", "--port", str(port), "--num-cpus", "2"]
        + ["--include-dashboard", "false", "--disable-usage-stats"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        cwd="/",
    )
    try:  # --block: the head's processes end with this one (no `ray stop`, which would stop every cluster here)
        deadline = time.monotonic() + 90
        while True:
            try:
                check_address(f"127.0.0.1:{port}")
                break
            except GazeAugError:
                assert time.monotonic() < deadline and head.poll() is None, "ray start --head did not come up"
                time.sleep(0.5)
        work = tmp_path / "work"
        work.mkdir()
        (work / "data").symlink_to(dataset)
        out = work / "joined.h5"
        cmd = [*GAZEAUG, "augment", "data", "-o", "joined.h5", "--engine", "ray", "--ray-address"]
        cmd += [f"127.0.0.1:{port}", "--per-sample", "2", "--seed", "7", "--block-size", "3", "--quiet"]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=work)  # relative paths
        assert r.returncode == 0, r.stderr[-2000:]
        assert json.loads(r.stdout)["rows"] == 16  # stdout: the result line only
        _assert_same(out, local_output, same_paths=False)
    finally:
        os.killpg(head.pid, signal.SIGTERM)
        head.wait(60)
    r = subprocess.run(
        [*GAZEAUG, "train", str(out), "-o", str(tmp_path / "m.pt"), "--epochs", "1", "--quiet"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "m.pt").is_file()


class _RemovingNode:
    """A reader that removes a node of the cluster when the driver reaches sample ``n`` (blocks are in flight)."""

    def __init__(self, inner, n, cluster, node):
        self.inner, self.n, self.cluster, self.node = inner, n, cluster, node
        self.name, self.root, self.removed = inner.name, inner.root, False

    def __len__(self):
        return len(self.inner)

    def __iter__(self):
        for s in self.inner:
            if s.source_index == self.n:
                self.cluster.remove_node(self.node, allow_graceful=False)
                self.removed = True
            yield s


def test_a_node_lost_mid_run_changes_nothing(dataset, local_output, tmp_path):
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    worker = cluster.add_node(num_cpus=1)
    try:
        ray.init(address=cluster.address, log_to_driver=False, logging_level="ERROR")
        cluster.wait_for_nodes()
        out = tmp_path / "fault.h5"
        reader = _RemovingNode(open_dataset(dataset), 6, cluster, worker)
        run_dataset(reader, out, SETTINGS, progress=False, engine=Engine("ray", workers=2, block_size=2))
        assert reader.removed
        _assert_same(out, local_output)
    finally:
        ray.shutdown()
        cluster.shutdown()


@pytest.mark.skipif(os.name != "posix", reason="process groups and SIGINT")
def test_ctrl_c_from_the_terminal_keeps_a_resumable_run(dataset, local_output, tmp_path):
    out = tmp_path / "c.h5"
    cmd = [*GAZEAUG, "augment", str(dataset), "-o", str(out), "--engine", "ray", "--workers", "2"]
    cmd += ["--per-sample", "2", "--seed", "7", "--block-size", "1"]
    log = tmp_path / "err.txt"
    with open(log, "w") as err:
        p = subprocess.Popen(
            cmd,
            stdout=subprocess.DEVNULL,
            stderr=err,
            start_new_session=True,
            text=True,
            preexec_fn=default_sigint,
        )
        deadline = time.monotonic() + 120
        while "sample" not in log.read_text() and time.monotonic() < deadline and p.poll() is None:
            time.sleep(0.2)  # the progress bar is up: Ray started, the output opened, the actors starting
        # At once: the actors take a second or more to load MediaPipe, so the run cannot be over yet.
        os.killpg(p.pid, signal.SIGINT)  # what Ctrl-C in a terminal does: the whole foreground group
        rc = p.wait(120)
    text = log.read_text()
    assert rc == 130 and "--resume" in text and "Traceback" not in text, text[-2000:]
    assert part_path(out).exists()
    r = subprocess.run(cmd + ["--resume", "--quiet"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    _assert_same(out, local_output)
    shutil.rmtree(tmp_path, ignore_errors=True)
