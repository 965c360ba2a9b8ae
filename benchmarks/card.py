"""Record a benchmark's figures in a model's card (the ``.json`` beside the ``.pt``).

``python benchmarks/demo_model.py --card`` and ``python benchmarks/track_accuracy.py
--model M.pt --card`` put what they measured under the card's ``measured`` entry, so a
retrained demo model (``python -m gazeaug.models.train_demo``, which writes the card
afresh) gets its figures back by running the two benchmarks, not by hand.
"""

from __future__ import annotations

import datetime
import json
import sys
from pathlib import Path
from typing import Any

from facemesh.io import atomic_write


class CardError(ValueError):
    """The model's card exists but cannot be read as a JSON object."""


def card_path(model: Path) -> Path:
    """The card of a model file: ``M.pt`` -> ``M.json``."""
    return model.with_suffix(".json")


def shown(path: Path) -> str:
    """``path`` as a command names it: relative to the repository when inside it."""
    root = Path(__file__).resolve().parents[1]
    try:
        return str(path.resolve().relative_to(root))
    except ValueError:
        return str(path)


def record(model: Path, key: str, figures: dict[str, Any], command: str) -> Path:
    """Set ``card["measured"][key]`` to ``figures`` (with the command and today's date); returns the card.

    The card is rewritten whole (:func:`facemesh.io.atomic_write`), so an interrupted run
    leaves the previous card. A model without a card gets one holding only ``measured``.

    Raises:
        CardError: the card exists but is not a JSON object (the card is left as it was).
    """
    path = card_path(model)
    card: dict[str, Any] = {}
    if path.is_file():
        try:
            card = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise CardError(f"{path}: the model card is not readable JSON ({exc})") from None
        if not isinstance(card, dict):
            raise CardError(f"{path}: the model card must be a JSON object, got {type(card).__name__}")
    measured = card.get("measured")
    if not isinstance(measured, dict):
        measured = {}
    measured[key] = {"command": command, "date": datetime.date.today().isoformat(), **figures}
    card["measured"] = measured
    with atomic_write(path) as f:
        f.write((json.dumps(card, indent=1) + "\n").encode("utf-8"))
    return path


def record_or_exit(model: Path, key: str, figures: dict[str, Any], command: str) -> None:
    """:func:`record`, saying where on stderr; a card that cannot be read is one line on stderr and exit 2."""
    try:
        path = record(model, key, figures, command)
    except (CardError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    print(f"recorded in {path}", file=sys.stderr)
