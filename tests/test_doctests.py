"""The examples in docstrings run (doctests with hand-derived values); the docs' own blocks: test_docs_snippets.py."""

import doctest

import pytest

import facemesh.conventions

MODULES = (facemesh.conventions,)


@pytest.mark.parametrize("module", MODULES, ids=[m.__name__ for m in MODULES])
def test_docstring_examples(module) -> None:
    result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0, f"{module.__name__}: no examples found"
    assert result.failed == 0
