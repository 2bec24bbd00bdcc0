"""The suite's own schedule: the long tests named to start first are tests that exist, and each test
process's first block (pytest-xdist's work stealing) starts with its share of them."""

from __future__ import annotations

import ast
from pathlib import Path

from conftest import LONG, block_sizes, deal_long_tests_first

TESTS = Path(__file__).resolve().parent


def test_every_long_first_name_is_a_test_of_the_suite():
    missing = []
    for name in LONG:
        file, _, function = name.partition("::")
        tree = ast.parse((TESTS / file).read_text()) if (TESTS / file).is_file() else None
        if tree is None or function not in {node.name for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)}:
            missing.append(name)
    assert not missing, f"renamed or removed, still named in conftest.LONG: {missing}"


class Item:
    def __init__(self, nodeid: str) -> None:
        self.nodeid = nodeid


def test_each_test_process_starts_with_its_share_of_the_long_tests():
    names = sorted(LONG, key=LONG.get, reverse=True)
    items = [Item(f"tests/test_x.py::test_{i}") for i in range(200)] + [Item(f"tests/{name}") for name in names]
    ordered = deal_long_tests_first(items, 3)
    assert sorted(map(id, ordered)) == sorted(map(id, items))  # every test once
    starts, loads = 0, []
    for size in block_sizes(len(items), 3):
        block = ordered[starts:starts + size]
        starts += size
        weights = [LONG.get(item.nodeid.split("/")[-1], 0) for item in block]
        long = [w for w in weights if w]
        assert weights[:len(long)] == sorted(long, reverse=True)  # the block's long tests come first, longest first
        loads.append(sum(long))
    assert names[0] in [item.nodeid.split("/")[-1] for item in ordered[:block_sizes(len(items), 3)[0]]]
    assert max(loads) - min(loads) <= LONG[names[0]]  # no block holds them all
    assert min(loads) > 0
    assert block_sizes(1063, 3) == [354, 354, 355]
