"""The ``--data`` option every benchmark that reads ``../shared/data`` takes, and its one-line refusal.

``../shared/data`` is the test data that lies beside a clone (``../shared/README.md``); a benchmark
names the files it needs from it, and a missing one is refused before any work starts::

    ap = argparse.ArgumentParser()
    add_data_option(ap)
    args = ap.parse_args()
    require_data(ap, args.data, "faces", "gaze/mpiigaze_eyes_unlabeled/test_eyes.npz")
"""

from __future__ import annotations

import argparse
from pathlib import Path

#: ``../shared/data`` beside the clone that holds this script.
DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def add_data_option(ap: argparse.ArgumentParser) -> None:
    """Add ``--data DIR`` (default :data:`DEFAULT_DATA`) to a benchmark's parser."""
    ap.add_argument(
        "--data",
        type=Path,
        default=DEFAULT_DATA,
        help="the shared test data folder (default: ../shared/data beside the clone)",
    )


def require_data(ap: argparse.ArgumentParser, data: Path, *needed: str) -> None:
    """Exit 2 with one line naming the first of ``needed`` (paths relative to ``data``) missing."""
    for rel in needed:
        if not (data / rel).exists():
            ap.exit(2, f"{ap.prog}: {data / rel}: no such file or folder (--data: the shared test data folder)\n")
