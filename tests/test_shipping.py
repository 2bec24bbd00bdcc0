"""Shipping a detector: the candidate whose worst standard set is highest, refused where it is worse
than the shipped weights on any set unless a reason is given, and the choice kept with the weights."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))


def _scores(seen: float, held_out: float, shifted: float) -> dict:
    return {"seen": {"ap50": seen}, "held_out": {"ap50": held_out}, "shifted": {"ap50": shifted}}


@pytest.fixture
def rod(tmp_path, monkeypatch):
    import _common
    import rod as rod_module

    monkeypatch.setattr(_common, "ROOT", tmp_path)
    rows = {"rod_photo_learnt_tiny_320": _scores(0.68, 0.69, 0.30),
            "pretrain": _scores(0.51, 0.56, 0.67),  # best on shifted, worst on seen
            "finetune": _scores(0.86, 0.81, 0.62),  # the highest worst: 0.62
            "finetune_plain": _scores(0.90, 0.80, 0.32)}  # best on seen, not shipped for it
    for name in ("pretrain", "finetune", "finetune_plain"):
        rows[name]["run"] = f"{name}/t"  # the run folder each was measured from
    (tmp_path / "rod.json").write_text(json.dumps({"photo": {"by_weights": rows}}))
    monkeypatch.setattr(_common, "RESULTS", tmp_path)
    shipped: list[tuple[Path, dict]] = []
    monkeypatch.setattr(rod_module, "ship_photo", lambda run, head_from, shipping=None: shipped.append((run, shipping)))
    monkeypatch.setattr(rod_module, "rewrite_section", lambda: None)
    with_head = {}  # run name -> its rows carrying the pickability head (none: the head is not measured)
    monkeypatch.setattr(rod_module, "measured_with_head", lambda run, head_from: with_head.get(Path(run).parent.name))
    rod_module.with_head_rows = with_head
    return rod_module, rows, shipped


def test_the_candidate_with_the_highest_worst_set_ships_with_its_comparison(rod, tmp_path):
    rod_module, _, shipped = rod
    runs = [tmp_path / name / "t" for name in ("pretrain", "finetune", "finetune_plain")]
    rod_module.ship_best(runs, "rod_photo_learnt_tiny_320", None, "photo")
    (run, meta), = shipped
    assert run == runs[1] and meta["worse_on"] == [] and meta["reason"] is None and meta["recipe"] == "photo"
    assert meta["candidates"] == {"finetune": 0.62, "finetune_plain": 0.32, "pretrain": 0.51}
    assert meta["scores"] == {"seen": 0.86, "held_out": 0.81, "shifted": 0.62} and meta["replaced"]["seen"] == 0.68
    rows = json.loads((tmp_path / "rod.json").read_text())["photo"]["by_weights"]
    # the shipped name's old row no longer describes its file: kept as what was replaced, until the new file is measured
    assert "rod_photo_learnt_tiny_320" not in rows and rows["rod_photo_learnt_tiny_320_replaced"]["seen"]["ap50"] == 0.68


def test_a_pickability_head_ships_only_where_it_raises_the_worst_set(rod, tmp_path, monkeypatch):
    rod_module, _, _ = rod
    shipped = []
    monkeypatch.setattr(rod_module, "ship_photo", lambda run, head_from, shipping=None: shipped.append((run, head_from, shipping)))
    runs = [tmp_path / name / "t" for name in ("pretrain", "finetune")]
    rod_module.with_head_rows["finetune"] = _scores(0.84, 0.81, 0.55)  # the head re-ranks: shifted falls under 0.62
    rod_module.with_head_rows["pretrain"] = _scores(0.60, 0.60, 0.66)
    rod_module.ship_best(runs, "rod_photo_learnt_tiny_320", None, "photo")
    (run, head, meta), = shipped
    assert run == runs[1] and head is None and meta["chosen"] == "finetune"  # as trained: worst 0.62 over 0.60 and 0.55
    assert meta["candidates"]["finetune+pickability_head"] == 0.55
    rows = json.loads((tmp_path / "rod.json").read_text())["photo"]["by_weights"]  # the measured variants join the table
    assert rows["finetune+pickability_head"]["shifted"]["ap50"] == 0.55 and rows["finetune+pickability_head"]["run"] == "finetune/t"
    rod_module.with_head_rows["finetune"] = _scores(0.88, 0.83, 0.64)  # now the head helps everywhere: it ships with it
    rows["rod_photo_learnt_tiny_320"] = _scores(0.68, 0.69, 0.30)  # the shipped file measured again
    (tmp_path / "rod.json").write_text(json.dumps({"photo": {"by_weights": rows}}))
    shipped.clear()
    rod_module.ship_best(runs, "rod_photo_learnt_tiny_320", None, "photo")
    (run, head, meta), = shipped
    assert run == runs[1] and head == "rod_photo_learnt_tiny_320" and meta["chosen"] == "finetune+pickability_head"


def test_a_candidate_worse_on_any_set_is_refused_unless_a_reason_is_given(rod, tmp_path):
    rod_module, rows, shipped = rod
    rows["rod_photo_learnt_tiny_320"] = _scores(0.83, 0.75, 0.40)
    (tmp_path / "rod.json").write_text(json.dumps({"photo": {"by_weights": rows}}))
    runs = [tmp_path / "pretrain" / "t", tmp_path / "finetune_plain" / "t"]  # worst: 0.51 and 0.32
    with pytest.raises(SystemExit, match=r"not shipped: pretrain is worse than the shipped weights on "
                                         r"rod_photo_learnt_tiny_320: seen 0\.510 < 0\.830; rod_photo_learnt_tiny_320: held_out 0\.560 < 0\.750"):
        rod_module.ship_best(runs, "rod_photo_learnt_tiny_320", None, None)
    assert not shipped
    rod_module.ship_best(runs, "rod_photo_learnt_tiny_320", "the shifted set-up matters more than seen bins here", None)
    (run, meta), = shipped
    assert run == runs[0] and meta["reason"].startswith("the shifted") and len(meta["worse_on"]) == 2


def test_a_candidate_is_compared_with_both_shipped_names_and_their_realistic_twins(rod, tmp_path):
    rod_module, rows, shipped = rod
    rows["rod_photo_tiny_320"] = _scores(0.90, 0.75, 0.40)  # the other name the photo detector ships under: best on seen
    rows["finetune"]["seen_realistic"] = {"ap50": 0.60}
    rows["rod_photo_learnt_tiny_320"]["seen_realistic"] = {"ap50": 0.61}
    (tmp_path / "rod.json").write_text(json.dumps({"photo": {"by_weights": rows}}))
    runs = [tmp_path / "finetune" / "t"]
    with pytest.raises(SystemExit, match=r"rod_photo_learnt_tiny_320: seen_realistic 0\.600 < 0\.610; "
                                         r"rod_photo_tiny_320: seen 0\.860 < 0\.900"):
        rod_module.ship_best(runs, "rod_photo_learnt_tiny_320", None, None)
    assert not shipped


def test_a_candidate_not_yet_measured_is_named_with_the_command_that_measures_it(rod, tmp_path):
    rod_module, _, shipped = rod
    with pytest.raises(SystemExit, match=r"not measured: .*never_measured.*python experiments/rod.py photo --weights"):
        rod_module.ship_best([tmp_path / "never_measured" / "t"], "rod_photo_learnt_tiny_320", None, None)
    assert not shipped


def test_a_newer_run_of_a_measured_name_or_a_set_never_measured_is_refused(rod, tmp_path):
    rod_module, rows, shipped = rod
    with pytest.raises(SystemExit, match=r"not measured: .*finetune/20261207"):  # its namesake's scores are not its own
        rod_module.ship_best([tmp_path / "finetune" / "20261207"], "rod_photo_learnt_tiny_320", None, None)
    rows["finetune"]["shifted"] = {"ap50": None}
    (tmp_path / "rod.json").write_text(json.dumps({"photo": {"by_weights": rows}}))
    with pytest.raises(SystemExit, match=r"has no AP50 on shifted"):
        rod_module.ship_best([tmp_path / "finetune" / "t"], "rod_photo_learnt_tiny_320", "any reason", None)
    assert not shipped
