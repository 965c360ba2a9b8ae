"""Every fenced command and code snippet of README.md and docs/*.md, ready to run or check.

How the docs are tested (docs/index.md, "How the docs are tested", says the same for readers):

- A ```` ```bash ```` block is run as written, one command at a time, in a folder per document
  that holds small inputs under the names the docs use (:func:`prepare_inputs`: ``photo.jpg``,
  ``calib.xml``, ``my_dataset/``, ``clip.mp4``, ``model.pt``, ...). Blocks of one document run in
  order in that folder, so a later block sees what an earlier one wrote. Only the sizes change
  (:data:`SIZE_SUBSTITUTIONS`: 2 images per face instead of 200, one epoch), and a few commands
  that need what a test machine lacks are only checked (:data:`NOT_RUN`).
- A ```` ```bash usage ```` block is a synopsis (``[...]`` optional, ``a|b`` choices): not run,
  but every option it names must exist in that command's parser.
- A ```` ```python ```` block runs as a script in the same folder, after the document's earlier
  blocks.
- A ```` ```yaml ```` block that names a file of the project (``# data_samples/rigs/X.yaml``)
  must hold the same data as that file; any other rig block must load as a rig.
- An ```` ```xml ```` block is a calibration file: it must load (:func:`facemesh.load_camera`).
- ```` ```csv ````, ```` ```text ```` and unlabelled blocks are examples of outputs or formats
  and are not run.

After each command, every file or folder it names with ``-o``/``--output`` must exist. Only
facemesh, gazeaug and python commands run (:data:`RUNNABLE_PROGRAMS`); any other must be in
:data:`NOT_RUN`, with what is checked instead.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOCS = (REPO / "README.md", *sorted((REPO / "docs").glob("*.md")))

# (pattern, replacement, why): applied in order to every command and Python snippet before it runs.
SIZE_SUBSTITUTIONS: tuple[tuple[str, str, str], ...] = (
    (r"--per-face \d+", "--per-face 2", "2 images per face instead of 20-200"),
    (r"--identities-per-face \d+", "--identities-per-face 2", "as many identities as images"),
    (r"--sequence \d+", "--sequence 3 --fps 10", "3 s sequences at 10 frames/s"),
    (r"\bFACES\.\.\.", "photo.jpg", "placeholder: the training photos"),
    (r"\bPEOPLE\.\.\.", "face.jpg", "placeholder: the test people's photos"),
    (r"^((?:\.venv/bin/)?gazeaug train (?!.*--epochs).*)$", r"\1 --epochs 1", "one epoch"),
    (
        r"^((?:\.venv/bin/)?gazeaug experiment (?!.*--epochs).*?)(\s*)$",
        r"\1 --epochs 1 --seeds 1 --per-face 2",
        "one epoch, one seed, 2 images per face",
    ),
)

# (pattern, why): commands that are only checked (options exist), not run.
NOT_RUN: tuple[tuple[str, str], ...] = (
    (r"^make test\b", "the test suite itself (CI runs it)"),
    (r"^make demo\b", "set-up and demo: `make -n demo` is checked instead"),
    (r"^pip install\b", "installs: the extra it names must exist in pyproject.toml"),
    (r"--show\b", "needs a camera and a display"),
    (r"--ray-address (?!auto\b)\S", "needs a running Ray cluster (tests/test_ray.py starts one)"),
    (r"^ray (start|job submit)\b", "starts, joins or submits to a Ray cluster on the reader's machines"),
)

#: Programs a runnable block may run; any other command must match :data:`NOT_RUN` (so a new
#: command that would start servers or change the machine fails the test until someone decides).
RUNNABLE_PROGRAMS = ("facemesh", "gazeaug", "python")

CLI_NAMES = ("facemesh", "gazeaug")


@dataclass(frozen=True)
class Block:
    """One fenced block: the document, the line of its opening fence, its info string and text."""

    doc: Path
    line: int
    lang: str
    role: str  # the info string's second word ("usage") or ""
    text: str

    @property
    def where(self) -> str:
        return f"{self.doc.relative_to(REPO)}:{self.line}"


@dataclass(frozen=True)
class Command:
    """One shell command of a block: continuation lines joined, comments dropped."""

    line: int
    text: str


def _fences(doc: Path, lines: list[str]) -> list[tuple[int, int, str, str, str]]:
    """Every fenced block of a Markdown file's lines: (opening line index, closing line index,
    indent, info string's first word, its second word).

    A fence is ```` ``` ```` or ``~~~`` (three or more), indented up to 4 spaces (list items); it
    closes at the first line that starts with the same indent and at least as many of the same
    character, and nothing else on it. Raises ValueError on a block never closed.
    """
    out = []
    i = 0
    while i < len(lines):
        m = re.match(r"^( {0,4})(`{3,}|~{3,})\s*(\S*)\s*(\S*)", lines[i])
        if m:
            indent, fence = m.group(1), m.group(2)
            close = re.compile(re.escape(indent) + re.escape(fence[0]) + "{" + str(len(fence)) + r",}\s*$")
            j = i + 1
            while j < len(lines) and not close.match(lines[j]):
                j += 1
            if j == len(lines):
                raise ValueError(f"{doc}:{i + 1}: fenced block never closed")
            out.append((i, j, indent, m.group(3), m.group(4)))
            i = j
        i += 1
    return out


def blocks(doc: Path) -> list[Block]:
    """The fenced blocks of a Markdown file, in order."""
    lines = doc.read_text(encoding="utf-8").split("\n")
    out: list[Block] = []
    for i, j, indent, lang, role in _fences(doc, lines):
        text = "\n".join(line[len(indent) :] if line.startswith(indent) else line for line in lines[i + 1 : j])
        out.append(Block(doc, i + 1, lang, role, text))
    return out


def prose(doc: Path, text: str | None = None) -> str:
    """A Markdown file's text with every fenced block's lines (fences included) left empty, so
    that what looks like a heading or a link inside a block is not taken for one; line numbers
    are kept. ``text``: the document's text if already read (``doc`` then only names it)."""
    lines = (doc.read_text(encoding="utf-8") if text is None else text).split("\n")
    for i, j, *_ in _fences(doc, lines):
        lines[i : j + 1] = [""] * (j + 1 - i)
    return "\n".join(lines)


def _strip_comment(line: str) -> str:
    """A shell line without its trailing ``# comment`` (a ``#`` outside quotes, after a space)."""
    quote = ""
    for k, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = ""
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (k == 0 or line[k - 1].isspace()):
            return line[:k].rstrip()
    return line.rstrip()


def commands(block: Block) -> list[Command]:
    """The block's shell commands: ``\\`` continuations joined, comments and blank lines dropped.

    In a synopsis (``bash usage``) a line that starts indented also continues the previous one.
    """
    out: list[Command] = []
    pending = ""
    start = 0
    for k, raw in enumerate(block.text.split("\n")):
        line = _strip_comment(raw)
        if not pending:
            start = block.line + 1 + k
        if line.endswith("\\"):
            pending += line[:-1].strip() + " "
            continue
        text = (pending + line.strip()).strip()
        pending = ""
        if not text:
            continue
        if block.role == "usage" and raw[:1].isspace() and out:
            out[-1] = Command(out[-1].line, f"{out[-1].text} {text}")
        else:
            out.append(Command(start, text))
    return out


def substitute(text: str) -> str:
    """``text`` with :data:`SIZE_SUBSTITUTIONS` applied (line by line)."""
    for pattern, replacement, _ in SIZE_SUBSTITUTIONS:
        text = re.sub(pattern, replacement, text, flags=re.MULTILINE)
    return text


def not_run_reason(command: str) -> str | None:
    """Why ``command`` is checked but not run, or None."""
    for pattern, why in NOT_RUN:
        if re.search(pattern, command):
            return why
    return None


def cli_words(command: str) -> tuple[str, list[str], list[str]] | None:
    """(program, subcommand path, option strings) of a facemesh/gazeaug command, or None for other commands.

    The subcommand path is the leading words that name subcommands (``["model", "export"]``);
    options are every ``-x``/``--xyz`` token, including those inside ``[...]`` of a synopsis.
    """
    words = command.split()
    if not words:
        return None
    program = Path(words[0]).name
    if program not in CLI_NAMES:
        return None
    path: list[str] = []
    for w in words[1:]:
        if re.fullmatch(r"[a-z][a-z0-9-]*", w):
            path.append(w)
        else:
            break
    options = re.findall(r"(?:(?<=[\s\[|])|^)(--?[a-zA-Z][a-zA-Z0-9-]*)", command)
    return program, path, options


def output_paths(command: str) -> list[str]:
    """The paths a command names with ``-o``/``--output``."""
    try:
        words = shlex.split(command)
    except ValueError:
        return []
    return [words[k + 1] for k, w in enumerate(words[:-1]) if w in ("-o", "--output")]
