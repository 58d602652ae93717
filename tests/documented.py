"""The documents' code blocks that a test runs as they stand: a ```python (or ```bash) block right below a line
``<!-- tested by tests/test_x.py -->`` is run by that test, so the document shows exactly the tested code."""

from __future__ import annotations

import re

from tests.conftest import ROOT


def documented_code(document: str, test_file: str, language: str = "python") -> list[str]:
    """The ```{language} blocks of ``document`` (a path from the repository root) marked as run by ``test_file``,
    in the document's order."""
    mark = f"<!-- tested by {test_file} -->"
    text = (ROOT / document).read_text()
    blocks = re.findall(re.escape(mark) + r"\n```(python|bash)\n(.*?)\n```\n", text, re.DOTALL)
    assert blocks and len(blocks) == text.count(mark), \
        f"{document}: each '{mark}' must stand right above a ```python or ```bash block"
    return [code for kind, code in blocks if kind == language]
