"""docs/cli.md, the generated command reference, is current and names every option of every command."""

import argparse
import importlib.util
import re
from pathlib import Path

import pytest

from facemesh.cli import build_parser as facemesh_parser
from gazeaug.cli import build_parser as gazeaug_parser

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "docs" / "make_cli_reference.py"
REFERENCE = REPO / "docs" / "cli.md"
FIX = "run `python docs/make_cli_reference.py` and commit docs/cli.md"


def _script():
    spec = importlib.util.spec_from_file_location("make_cli_reference", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _commands(parser: argparse.ArgumentParser):
    """Every (sub)command's parser, found independently of the generator."""
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                yield from _commands(child)


def _sections(text: str) -> dict[str, str]:
    """``## PROG`` heading -> the text up to the next such heading."""
    parts = re.split(r"^## (.+)$", text, flags=re.M)
    return {parts[i].strip(): parts[i + 1] for i in range(1, len(parts), 2)}


def test_reference_is_current():
    assert REFERENCE.is_file(), f"docs/cli.md is missing: {FIX}"
    assert REFERENCE.read_text(encoding="utf-8") == _script().render(), f"docs/cli.md is not current: {FIX}"


def test_check_mode_says_so(tmp_path, monkeypatch, capsys):
    module = _script()
    monkeypatch.setattr(module, "OUT", tmp_path / "cli.md")
    assert module.main(["--check"]) == 1
    assert "make_cli_reference.py" in capsys.readouterr().err
    assert module.main([]) == 0 and module.main(["--check"]) == 0


@pytest.mark.parametrize("build_parser", [facemesh_parser, gazeaug_parser], ids=["facemesh", "gazeaug"])
def test_every_option_is_documented_under_its_command(build_parser):
    sections = _sections(REFERENCE.read_text(encoding="utf-8"))
    for command in _commands(build_parser()):
        assert command.prog in sections, f"no '## {command.prog}' section in docs/cli.md: {FIX}"
        body = sections[command.prog]
        assert "```text\n" in body, f"{command.prog}: no usage block"
        for action in command._actions:
            if isinstance(action, argparse._HelpAction | argparse._SubParsersAction):
                continue
            names = action.option_strings or [action.dest if action.metavar is None else str(action.metavar)]
            for name in names:
                assert re.search(rf"(?<![\w-]){re.escape(name)}(?![\w-])", body), (
                    f"{command.prog} {name}: not in its section of docs/cli.md: {FIX}"
                )
            assert action.help, f"{command.prog} {names[0]}: no help string"
