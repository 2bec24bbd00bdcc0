"""The README's results table is what results/*.json give (tools/results_tables.py writes it), so a
figure edited by hand, or a results file re-measured without regenerating the table, fails here."""

from __future__ import annotations

import importlib.util
import json
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tables() -> Iterator[ModuleType]:
    """The tool, imported from its file (tools/ is not a package)."""
    spec = importlib.util.spec_from_file_location("results_tables", ROOT / "tools" / "results_tables.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass looks its module up while the class is made
    spec.loader.exec_module(module)
    yield module
    del sys.modules[spec.name]


def test_committed_readme_is_what_the_results_give(tables: ModuleType) -> None:
    problems = tables.check()
    assert not problems, ("run `python tools/results_tables.py` to regenerate the README's table:\n"
                          + "\n".join(problems))


def test_a_figure_edited_by_hand_is_reported_with_its_row(tables: ModuleType) -> None:
    text = (ROOT / "README.md").read_text()
    row = tables.photo_query_ap50()
    assert row.line() in text
    by_hand = " / ".join(["1.23", *row.binpick.split(" / ")[1:]])  # the seen AP50 alone, to one no run gives
    problems = tables.check(text.replace(row.line(), row.line().replace(row.binpick, by_hand)))
    assert len(problems) == 1
    assert row.what in problems[0] and "results/rod.json" in problems[0] and by_hand in problems[0]


def test_a_missing_key_is_one_line_naming_file_and_key(tables: ModuleType, tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    for path in (ROOT / "results").glob("*.json"):
        shutil.copy(path, tmp_path / path.name)
    pick = json.loads((tmp_path / "pick.json").read_text())
    del pick["arm"]["picks_per_hour"]
    (tmp_path / "pick.json").write_text(json.dumps(pick))
    monkeypatch.setattr(tables, "RESULTS", tmp_path)
    assert tables.check() == ["results table row pick_with_panda: results/pick.json has no key arm.picks_per_hour"]
    with pytest.raises(tables.TableError, match="pick.json has no key arm.picks_per_hour"):
        tables.readme_table()
