"""The suite's own schedule: the tests named to start first (so that with one worker per core neither
waits at the end for a long test the other picked up late) are tests that exist."""

from __future__ import annotations

import ast
from pathlib import Path

from conftest import LONG_FIRST

TESTS = Path(__file__).resolve().parent


def test_every_long_first_name_is_a_test_of_the_suite():
    missing = []
    for name in LONG_FIRST:
        file, _, function = name.partition("::")
        tree = ast.parse((TESTS / file).read_text()) if (TESTS / file).is_file() else None
        if tree is None or function not in {node.name for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)}:
            missing.append(name)
    assert not missing, f"renamed or removed, still named in conftest.LONG_FIRST: {missing}"
