"""``gazeaug`` command line (a thin layer over the library)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``gazeaug`` command."""
    from . import __version__

    parser = argparse.ArgumentParser(
        prog="gazeaug",
        description="Semi-synthetic gaze dataset augmentation. Face meshes: see the 'facemesh' command.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_subparsers(dest="command", title="commands")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        print("\ngazeaug: no commands yet in this version; build face meshes with 'facemesh build'.", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
