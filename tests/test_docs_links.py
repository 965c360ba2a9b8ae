"""Every relative link of README.md and docs/*.md reaches a file, and every ``#anchor`` a heading of it.

Anchors are GitHub's: the heading's text lowercased, every character but letters, digits,
``_``, ``-`` and spaces dropped, spaces turned into ``-``; a repeated heading gets ``-1``,
``-2``, ... Headings inside fenced blocks are not headings.
"""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

from doc_snippets import DOCS, REPO, prose

LINK = re.compile(r"\]\(([^)\s#]*)(?:#([^)\s]+))?\)")


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading's text (before duplicates are numbered)."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(text: str) -> set[str]:
    """The anchors of a Markdown document's headings, repeated ones numbered."""
    seen: dict[str, int] = {}
    out = set()
    for match in re.finditer(r"^#{1,6} (.*)$", prose(Path("<text>"), text), re.M):
        base = anchor(match.group(1))
        n = seen.get(base, 0)
        out.add(base if n == 0 else f"{base}-{n}")
        seen[base] = n + 1
    return out


@cache
def _anchors_of(doc: Path) -> set[str]:
    return anchors(doc.read_text(encoding="utf-8"))


def test_anchor_is_githubs() -> None:
    """Hand-derived from GitHub's rule."""
    assert anchor("Measured: the photo known, or the design (2026-11-30)") == (
        "measured-the-photo-known-or-the-design-2026-11-30"
    )
    assert anchors("# A\n## A\n```\n# B\n```\n## B_c x\n  ~~~\n# C\n  ~~~\n") == {"a", "a-1", "b_c-x"}
    # A longer fence holds a shorter one; a fence line with more after it does not close.
    assert anchors("````md\n```\n# D\n```\n````\n# E\n```bash\n# F\n```bash\n# G\n```\n") == {"e"}


def test_every_relative_link_and_anchor_resolves() -> None:
    bad, checked, anchored = [], 0, 0
    for doc in DOCS:
        for match in LINK.finditer(prose(doc)):
            path, fragment = match.group(1), match.group(2)
            if re.match(r"[a-z]+:", path):  # https:, mailto:
                continue
            target = (doc.parent / path).resolve() if path else doc
            checked, anchored = checked + 1, anchored + bool(fragment)
            where = f"{doc.relative_to(REPO)}: ({path}{'#' + fragment if fragment else ''})"
            if not target.exists():
                bad.append(f"{where}: no such file")
            elif fragment and target.suffix == ".md" and fragment not in _anchors_of(target):
                bad.append(f"{where}: no such heading")
    assert checked >= 100 and anchored >= 50, f"the patterns found only {checked} links, {anchored} with an anchor"
    assert not bad, "\n".join(bad)
