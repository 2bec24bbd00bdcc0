"""The rebuild tool's bookkeeping: hours of an attempt lost with its machine still count."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))


def _utc(seconds: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(seconds))


def test_an_attempt_lost_with_its_machine_counts_until_its_last_write_before_the_next(tmp_path, monkeypatch):
    import rebuild

    monkeypatch.setattr(rebuild, "ROOT", tmp_path)
    run = tmp_path / "runs" / "step"
    run.mkdir(parents=True)
    now = time.time()
    first, second = now - 10_000, now - 2_000  # the first attempt died; the second resumed in the same folder
    for name, written in (("a", first + 3_000), ("b", first + 7_000), ("c", second + 500)):
        (run / name).write_text(name)
        os.utime(run / name, (written, written))
    record = {"status": "running", "seconds": 0.0, "run": "runs/step",
              "attempts": [{"started_utc": _utc(first)}, {"started_utc": _utc(second)}]}
    rebuild.count_lost_attempts(record, running=True)
    assert record["attempts"][0]["lost"] and abs(record["attempts"][0]["seconds"] - 7_000) < 2  # its last write, not the next's
    assert "exit" not in record["attempts"][1] and abs(record["seconds"] - 7_000) < 2
    rebuild.count_lost_attempts(record, running=True)  # counted once
    assert abs(record["seconds"] - 7_000) < 2
