"""One registry style for models, renderers and dataset readers; the command line's choices come from them."""

from __future__ import annotations

import subprocess
import sys

import pytest

from gazeaug.cli import build_parser, main
from gazeaug.datasets import DATASETS, DatasetError, detect_format, open_dataset, register_dataset
from gazeaug.errors import GazeAugError
from gazeaug.models import MODELS
from gazeaug.registry import Registry
from gazeaug.render import RENDERERS, create_renderer, register_renderer


def test_a_registry_imports_a_target_only_when_asked_for_it():
    reg = Registry("gadget")
    reg.register("fraction", "fractions:Fraction")
    reg.register("bad", "no_such_module_here:thing")

    @reg.register("double", tag=1)
    def double(x):
        return 2 * x

    assert list(reg) == ["fraction", "bad", "double"] and "bad" in reg and len(reg) == 3
    assert reg.names() == ["bad", "double", "fraction"] and reg.names(tag=1) == ["double"]
    assert reg.create("double", 4) == 8 and str(reg.create("fraction", 3, 4)) == "3/4"
    with pytest.raises(ModuleNotFoundError):  # imported only now
        reg["bad"]
    with pytest.raises(GazeAugError, match=r"gadget: expected one of \['bad', 'double', 'fraction'\], got 'x'"):
        reg.create("x")
    with pytest.raises(KeyError):
        reg["x"]
    reg.register("fraction", double)  # registered again: replaced in place, options kept
    assert list(reg) == ["fraction", "bad", "double"] and reg.create("fraction", 1) == 2


def test_listing_the_names_imports_no_heavy_library():
    code = (
        "import sys\n"
        "from gazeaug.cli import build_parser\n"
        "build_parser().parse_args(['augment', 'x', '-o', 'y.h5'])\n"
        "heavy = ('torch', 'open3d', 'mediapipe', 'h5py', 'gazeaug.render.raycast', 'gazeaug.datasets.utmultiview')\n"
        "print([m for m in heavy if m in sys.modules])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def _choices(parser, *path):
    """The ``choices`` of option ``path[-1]`` of sub-command ``path[:-1]``."""
    import argparse

    p = parser
    for name in path[:-1]:
        sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
        p = sub.choices[name]
    return next(a for a in p._actions if path[-1] in a.option_strings).choices


def test_command_line_choices_are_the_registries():
    parser = build_parser()
    formats = ["ethxgaze", "ethxgaze_normalized", "folder", "gazecapture", "mpiifacegaze", "utmultiview"]
    for path in (("augment", "--format"), ("normalize-dataset", "--format"), ("evaluate", "--format")):
        assert _choices(parser, *path) == formats == sorted(DATASETS)
    assert _choices(parser, "experiment", "--train-format") == formats
    for cmd in ("render", "preview", "augment"):  # pyrender is for benchmarks only
        assert _choices(parser, cmd, "--renderer") == ["filament", "raycast"]
    assert _choices(parser, "bench", "render", "--renderer") == ["filament", "pyrender", "raycast"] == sorted(RENDERERS)
    assert _choices(parser, "train", "--model") == ["mobilenet_gaze", "mobilenet_gaze_wide"] == list(MODELS)


def test_help_lists_the_formats(capsys):
    for cmd in ("augment", "evaluate"):
        assert main([cmd, "--help"]) == 0
        assert "{ethxgaze,ethxgaze_normalized,folder,gazecapture,mpiifacegaze,utmultiview}" in capsys.readouterr().out
    assert main(["augment", "x", "-o", "y.h5", "--format", "povray"]) == 2
    assert "invalid choice: 'povray'" in capsys.readouterr().err


def _touch(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("")


def test_detection_order_from_the_most_specific_layout(tmp_path):
    assert list(DATASETS) == ["folder", "gazecapture", "ethxgaze", "ethxgaze_normalized", "utmultiview", "mpiifacegaze"]
    # every folder below also has the loosest layout, MPIIFaceGaze's pXX/pXX.txt
    layouts = {
        "folder": ["labels.csv", "data/annotation_train/subject0000.csv", "GazeCapture_supplementary.h5"],
        "gazecapture": ["GazeCapture_supplementary.h5", "data/annotation_train/subject0000.csv"],
        "ethxgaze": ["data/annotation_test/subject0001.csv"],
        "mpiifacegaze": [],
    }
    for expected, files in layouts.items():
        root = tmp_path / expected
        for f in [*files, "p00/p00.txt"]:
            _touch(root / f)
        assert detect_format(root) == expected


def test_a_reader_and_a_renderer_registered_by_a_user(tmp_path, monkeypatch):
    monkeypatch.setattr(DATASETS, "_entries", dict(DATASETS._entries))
    monkeypatch.setattr(RENDERERS, "_entries", dict(RENDERERS._entries))

    class Mine:
        def __init__(self, root):
            self.root = root

    register_dataset("mine", Mine, detect=lambda root: (root / "mine.txt").is_file())
    _touch(tmp_path / "mine.txt")
    assert detect_format(tmp_path) == "mine" and open_dataset(tmp_path).root == tmp_path
    with pytest.raises(DatasetError, match=r"format: expected one of \[.*'mine'.*\], got 'nope'"):
        open_dataset(tmp_path, "nope")

    @register_renderer("fake", benchmark_only=True)
    class Fake:
        def __init__(self, **options):
            self.options = options

    assert create_renderer("fake", a=1).options == {"a": 1}
    assert RENDERERS.names(benchmark_only=False) == ["filament", "raycast"]
    with pytest.raises(GazeAugError, match="renderer: expected one of"):
        create_renderer("povray")
