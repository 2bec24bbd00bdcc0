"""The README's results table and every section of docs/RESULTS.md are what results/*.json give
(tools/results_tables.py writes them, each page section through its script's ``section`` function), so
a figure edited by hand, or a results file re-measured without regenerating them, fails here."""

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


def test_committed_page_is_what_the_results_give(tables: ModuleType) -> None:
    problems = tables.check_page()
    assert not problems, ("run `python tools/results_tables.py --page` to regenerate docs/RESULTS.md from results/*.json "
                          "(sections that differ or cannot be generated):\n" + "\n".join(problems))


def test_every_section_on_the_page_is_generated_in_page_order(tables: ModuleType) -> None:
    on_page = tables.MARKER.findall((ROOT / "docs" / "RESULTS.md").read_text())
    registered = [section.name for section in tables.PAGE_SECTIONS]
    assert [name for name in on_page if name not in registered] == [], "sections no script generates"
    assert on_page == registered, "PAGE_SECTIONS lists the page's sections in the page's order"


def test_a_figure_edited_on_the_page_is_reported_with_its_section(tables: ModuleType) -> None:
    text = (ROOT / "docs" / "RESULTS.md").read_text()
    section = next(s for s in tables.PAGE_SECTIONS if s.name == "ros_latency")
    line = next(line for line in tables.render(section).splitlines() if line.startswith("| round trip per action, median |"))
    figure = line.split(" | ")[1]
    assert line in text
    by_hand = line.replace(figure, "1.23 ms")  # the median alone, to one no run gives
    before = tables.check_page(text)
    problems = [p for p in tables.check_page(text.replace(line, by_hand)) if p not in before]
    assert len(problems) == 1
    assert "section ros_latency" in problems[0] and "results/ros_latency.json" in problems[0] and "1.23 ms" in problems[0]


def test_a_missing_results_file_is_one_line_naming_it(tables: ModuleType, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    for path in (ROOT / "results").glob("*.json"):
        if path.name != "suction_model.json":
            shutil.copy(path, tmp_path / path.name)
    monkeypatch.setattr(tables, "RESULTS", tmp_path)
    problems = [p for p in tables.check_page() if "suction_model" in p]
    assert problems == ["docs/RESULTS.md section suction_model: results/suction_model.json is missing"]


def test_page_rewrites_its_sections_and_keeps_the_text_around_them(tables: ModuleType, tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    text = (ROOT / "docs" / "RESULTS.md").read_text()
    block = tables.page_blocks(text)["ros_latency"]
    page = tmp_path / "RESULTS.md"
    page.write_text("Written by hand, kept.\n" + text.replace(block, "stale") + "\nAfter the last section, kept.\n")
    monkeypatch.setattr(tables, "PAGE", page)
    assert not [p for p in tables.write_page() if "ros_latency" in p]
    written = page.read_text()
    assert written.startswith("Written by hand, kept.\n") and written.endswith("\nAfter the last section, kept.\n")
    assert tables.page_blocks(written)["ros_latency"] == block


def test_every_results_file_says_which_code_measured_it():
    """Each results file carries provenance: the run's own, or (files older than recorded provenance)
    the commit that committed it, marked inferred; and each of its rows names one."""
    import json

    root = Path(__file__).resolve().parents[1]
    problems = []
    for path in sorted((root / "results").glob("*.json")):
        result = json.loads(path.read_text())
        provenance = result.get("provenance") or {}
        if not provenance.get("commit"):
            problems.append(f"{path.name}: no provenance commit")
        rows = result.get("provenance_by_row") or {}
        unnamed = [key for key in result if key not in ("benchmark", "machine", "provenance", "provenance_by_row") and key not in rows
                   and not any(k.startswith(f"{key}.") for k in rows)]  # (or per sub-row: by_gripper.jaws)
        if unnamed:
            problems.append(f"{path.name}: rows without provenance {unnamed}")
    assert not problems, "\n".join(problems) + "\n(python tools/backfill_provenance.py infers it from git)"


def test_writing_one_section_rewrites_the_others_of_its_results_file(tables: ModuleType, tmp_path, monkeypatch) -> None:
    """rod.json feeds three sections: a script that writes one (onnx) brings the others up to date too."""
    common = tables.common()
    page = tmp_path / "RESULTS.md"
    text = (ROOT / "docs" / "RESULTS.md").read_text()
    blocks = tables.page_blocks(text)
    stale = text.replace(blocks["rod_recurrent"], blocks["rod_recurrent"] + "\nA line no results file gives.")
    page.write_text(stale)
    monkeypatch.setattr(common, "RESULTS_MD", page)
    onnx = tables.script("benchmarks/onnx_latency.py")
    common.write_section_of("onnx", onnx.section, "rod.json")
    assert tables.page_blocks(page.read_text()) == blocks  # rod_recurrent regenerated, the rest as generated
