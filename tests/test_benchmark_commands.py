"""Every ``python benchmarks/NAME.py ...`` command that README.md and docs/*.md quote parses as written.

The docs give each measured figure with the command that made it, mostly inline (in backticks,
often broken over two lines). Those commands are not run here (they take minutes to hours), but
their script must exist and accept their options: one Python process imports each script as
``__main__`` with the quoted arguments and stops it right after ``argparse`` has parsed them
(checks a script makes after parsing, such as ranges, are not reached).
Placeholders are filled in first: a single capital letter (``D``, ``S``, ``W``, ``H``) is a
number, and an optional group in brackets (``[--face-patch W H]``) is kept
with its brackets removed.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys

from doc_snippets import DOCS, REPO

# An optional environment prefix (`VAR=value python benchmarks/...`) is dropped.
QUOTED = re.compile(r"`(?:[A-Z_]+=\S+\s+)*(python3? benchmarks/[^`]+)`")

# Runs in a child process: argv[1] is a JSON list of [script, [args...]]; prints one JSON result per command.
DRIVER = r"""
import argparse, contextlib, io, json, os, runpy, sys, warnings
warnings.simplefilter("ignore")

class Parsed(BaseException):
    pass

parse_args = argparse.ArgumentParser.parse_args
parse_known_args = argparse.ArgumentParser.parse_known_args
inside = []

def parse_then_stop(self, *a, **k):
    inside.append(1)
    try:
        parse_args(self, *a, **k)  # unknown options are refused here, after parse_known_args
    finally:
        inside.pop()
    raise Parsed

def parse_known_then_stop(self, *a, **k):
    result = parse_known_args(self, *a, **k)
    if inside:  # called by parse_args: let it check the rest
        return result
    raise Parsed  # a script that parses with parse_known_args itself

argparse.ArgumentParser.parse_args = parse_then_stop
argparse.ArgumentParser.parse_known_args = parse_known_then_stop
for script, args in json.loads(sys.argv[1]):
    err = io.StringIO()
    sys.argv = [script, *args]
    sys.path[0] = os.path.abspath(os.path.dirname(script))  # as `python SCRIPT` sets it
    if "argparse" not in open(script).read():
        result = "has no argument parser"
    else:
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                runpy.run_path(script, run_name="__main__")
            result = "ran to the end without parsing its arguments"
        except Parsed:
            result = "ok"
        except SystemExit as exc:
            result = f"exit {exc.code}: {err.getvalue().strip()[-400:]}"
        except Exception as exc:
            result = f"{type(exc).__name__}: {exc}"
    print(json.dumps([script, args, result]), flush=True)
"""


def quoted_commands() -> list[tuple[str, list[str]]]:
    """``(script, args)`` of every distinct quoted benchmark command, placeholders filled in."""
    found: dict[str, tuple[str, list[str]]] = {}
    for doc in DOCS:
        for match in QUOTED.finditer(doc.read_text(encoding="utf-8")):
            words = match.group(1).replace("[", " ").replace("]", " ").split()[1:]
            words = ["7" if re.fullmatch(r"[A-Z]", w) else w for w in words]
            found.setdefault(" ".join(words), (words[0], words[1:]))
    return list(found.values())


def test_the_docs_quote_benchmark_commands() -> None:
    """The collector finds the commands (a broken pattern would make the test below vacuous)."""
    commands = quoted_commands()
    scripts = {script for script, _ in commands}
    assert {"benchmarks/generalization.py", "benchmarks/person_floor.py", "benchmarks/bench_train.py"} <= scripts
    assert len(commands) >= 30
    quoted = QUOTED.fullmatch("`PYTHONPATH=/x XP=1 python benchmarks/a.py -o\nOUT`")
    assert quoted is not None and quoted.group(1) == "python benchmarks/a.py -o\nOUT"


def test_every_quoted_benchmark_command_parses() -> None:
    commands = quoted_commands()
    missing = [script for script, _ in commands if not (REPO / script).is_file()]
    assert not missing, f"the docs quote benchmark scripts that do not exist: {sorted(set(missing))}"
    done = subprocess.run(
        [sys.executable, "-c", DRIVER, json.dumps(commands)],
        cwd=REPO, capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    results = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("[")]
    assert len(results) == len(commands), done.stdout[-3000:] + done.stderr[-3000:]
    bad = [f"python {script} {' '.join(args)}: {result}" for script, args, result in results if result != "ok"]
    assert not bad, "quoted in the docs but refused:\n" + "\n".join(bad)
