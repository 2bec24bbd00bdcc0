"""Every results row says what it was measured with: a run's rows carry its provenance, rows it kept
as they were keep the provenance of the run that measured them."""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))


def test_rows_a_run_changed_carry_its_provenance_and_kept_rows_keep_theirs(tmp_path, monkeypatch):
    import _common

    monkeypatch.setattr(_common, "RESULTS", tmp_path)
    (tmp_path / "x.json").write_text(json.dumps({"old": 1, "provenance": {"commit": "aaa"}}))  # before rows had their own
    monkeypatch.setattr(_common, "provenance", lambda: {"commit": "bbb"})
    _common.write_result("x", {"old": 1, "new": 2})
    written = json.loads((tmp_path / "x.json").read_text())
    assert written["provenance"] == {"commit": "bbb"} and written["provenance_by_row"]["new"] == {"commit": "bbb"}
    assert written["provenance_by_row"]["old"]["commit"] == "aaa" and "inferred" in written["provenance_by_row"]["old"]
    monkeypatch.setattr(_common, "provenance", lambda: {"commit": "ccc"})
    _common.write_result("x", {**{k: v for k, v in written.items() if k not in ("benchmark", "machine")}, "old": 3})
    again = json.loads((tmp_path / "x.json").read_text())["provenance_by_row"]
    assert again == {"old": {"commit": "ccc"}, "new": {"commit": "bbb"}}  # re-measured; kept from the run that made it
    monkeypatch.setattr(_common, "provenance", lambda: {"commit": "ddd"})
    _common.write_result("x", {"old": 3, "new": 2}, measured={"new"})  # measured again, to the same figure
    assert json.loads((tmp_path / "x.json").read_text())["provenance_by_row"] == {"old": {"commit": "ccc"}, "new": {"commit": "ddd"}}


def test_a_row_merged_from_two_runs_says_which_run_measured_each_sub_row(tmp_path, monkeypatch):
    """pick.py without --tool-rows measures the default hand and keeps the other hands' rows: those keep
    the provenance of the run that measured them, even though the row as a whole changed."""
    import _common

    monkeypatch.setattr(_common, "RESULTS", tmp_path)
    monkeypatch.setattr(_common, "provenance", lambda: {"commit": "aaa"})
    _common.write_result("x", {"by_gripper": {"both": 1, "jaws": 2, "suction": 3}})
    monkeypatch.setattr(_common, "provenance", lambda: {"commit": "bbb"})
    _common.write_result("x", {"by_gripper": {"both": 9, "jaws": 2, "suction": 3}}, merged={"by_gripper": {"both"}})
    rows = json.loads((tmp_path / "x.json").read_text())["provenance_by_row"]
    assert rows == {"by_gripper.both": {"commit": "bbb"}, "by_gripper.jaws": {"commit": "aaa"}, "by_gripper.suction": {"commit": "aaa"}}
    monkeypatch.setattr(_common, "provenance", lambda: {"commit": "ccc"})
    _common.write_result("x", {"by_gripper": {"both": 9, "jaws": 5, "suction": 3}}, merged={"by_gripper": {"jaws"}})
    rows = json.loads((tmp_path / "x.json").read_text())["provenance_by_row"]
    assert rows == {"by_gripper.both": {"commit": "bbb"}, "by_gripper.jaws": {"commit": "ccc"}, "by_gripper.suction": {"commit": "aaa"}}
    line = _common.provenance_line({"provenance_by_row": rows}, "x.json")
    assert "`by_gripper.jaws`" in line and "`by_gripper.both`" in line


def test_the_command_recorded_is_the_script_s_own_when_it_runs_binpick_in_process(monkeypatch):
    """A benchmark that runs binpick's CLI in its own process (the hostile-input one) rewrites sys.argv;
    the row still names the command that measured it."""
    import _common

    monkeypatch.setattr(_common, "ARGV_AT_START", ["/x/benchmarks/hostile.py", "--only", "rl"])
    monkeypatch.setattr(sys, "argv", ["binpick", "rl", "eval", "/tmp/corpus/run", "--episodes", "1"])
    assert _common.provenance()["command"] == "hostile.py --only rl"


def test_plan_stages_run_side_by_side_each_add_their_rows(tmp_path, monkeypatch):
    """Two stages of experiments/plan.py started from the same file: the one that writes last keeps
    what the other wrote (its rows, and its entries of a shared row) and adds its own."""
    import _common
    import plan

    monkeypatch.setattr(_common, "RESULTS", tmp_path)
    start = {"file_orders_by_sensor": {"perfect": 1, "realistic": 2}, "single_copy": 3}
    (tmp_path / "plan.json").write_text(json.dumps({**start, "file_orders_by_sensor": {"perfect": 10, "realistic": 2}}))
    mine = {"file_orders_by_sensor": {"perfect": 1, "realistic": 20}, "single_copy": 3, "latency_ms": 4}
    merged = plan.changes_onto_latest(start, mine)
    assert merged == {"file_orders_by_sensor": {"perfect": 10, "realistic": 20}, "single_copy": 3, "latency_ms": 4}


def test_a_stage_keeps_a_row_another_stage_made_after_it_started(tmp_path, monkeypatch):
    import _common
    import plan

    monkeypatch.setattr(_common, "RESULTS", tmp_path)
    (tmp_path / "plan.json").write_text(json.dumps({"sim_orders": {"b": 2}}))  # made by a stage that ended meanwhile
    assert plan.changes_onto_latest({}, {"sim_orders": {"a": 1}}) == {"sim_orders": {"b": 2, "a": 1}}


def test_rows_pooling_every_hand_s_orders_are_kept_when_only_some_hands_orders_are_here(tmp_path):
    """A run with the default hand only (a fresh clone, no --tool-rows) must not remake by_category and
    calibration from that hand's orders alone: they pool every hand's."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("pick_experiment", Path(__file__).resolve().parents[1] / "experiments" / "pick.py")
    pick = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(pick)
    (tmp_path / "both_seen").mkdir()
    (tmp_path / "both_seen" / "results.json").write_text(json.dumps({"orders": [{"product": "robosuite/can"}]}))
    by_gripper = {"both": {"seen": {"folder": str(tmp_path / "both_seen")}},
                  "jaws": {"seen": {"folder": str(tmp_path / "elsewhere")}}}
    previous = {"by_category": {"boxes": {"jaws": 1}}, "calibration": {"jaws": 2}}
    assert pick.pooled_rows(None, by_gripper, previous) == previous
    assert pick.executed_orders(by_gripper) == {"both": [{"product": "robosuite/can"}]}
