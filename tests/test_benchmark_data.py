"""The benchmarks' ``--data`` option: one definition (benchmarks/shared_data.py), one refusal."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from doc_snippets import REPO

BENCHMARKS = REPO / "benchmarks"


def test_no_benchmark_defines_data_itself() -> None:
    own = [
        p.name for p in sorted(BENCHMARKS.glob("*.py")) if p.name != "shared_data.py" and '"--data"' in p.read_text()
    ]
    assert not own, f"define --data with shared_data.add_data_option, not again in: {own}"
    users = [p.name for p in BENCHMARKS.glob("*.py") if "add_data_option(ap)" in p.read_text()]
    assert len(users) >= 10, users  # the pattern still finds them


def test_a_missing_data_file_is_one_line_and_exit_2(tmp_path: Path) -> None:
    (tmp_path / "faces").mkdir()  # a folder that has faces/ but not the photo the script needs
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / "check_simulator.py"), "--data", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    missing = tmp_path / "faces" / "sergey.png"
    assert lines == [f"check_simulator.py: {missing}: no such file or folder (--data: the shared test data folder)"]
    assert done.stdout == ""
