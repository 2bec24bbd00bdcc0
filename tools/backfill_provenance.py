"""Give every results file provenance, saying so where it is inferred: a file written before results
recorded their own provenance gets, as its ``provenance`` and each row's, the commit that committed
it and that commit's date, marked ``inferred`` (its figures were measured on that code or older).
A file that has provenance but not per row gets its own provenance on each row, marked as the file's
last writer (a row may be older). Figures are not touched.

    python tools/backfill_provenance.py            # add the inferred provenance where it is missing
    python tools/backfill_provenance.py --check    # exit 1, a line per file, where provenance is missing
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
SKIP = ("benchmark", "machine", "provenance", "provenance_by_row")
INFERRED = "the commit that committed this file (it predates recorded provenance): measured on that code or older"


ROW_INFERRED = "the file's last writer; the row may be older"


def rows_without(result: dict) -> list[str]:
    """Top-level rows with no provenance of their own or of their sub-rows (``row.sub``)."""
    named = result.get("provenance_by_row") or {}
    return [key for key in result if key not in SKIP and key not in named and not any(k.startswith(f"{key}.") for k in named)]


def missing() -> list[Path]:
    """Results files without a ``provenance`` of their own, or with rows that name none."""
    found = []
    for path in sorted(RESULTS.glob("*.json")):
        result = json.loads(path.read_text()) or {}
        if not result.get("provenance") or rows_without(result):
            found.append(path)
    return found


def committed_by(path: Path) -> dict:
    """The last commit that changed ``path``: its id and date (UTC)."""
    line = subprocess.run(["git", "log", "-1", "--format=%H %cI", "--", str(path.relative_to(ROOT))], cwd=ROOT,
                          capture_output=True, text=True, check=True).stdout.strip()
    if not line:
        raise SystemExit(f"{path.relative_to(ROOT)} was never committed: its provenance cannot be inferred")
    commit, date = line.split()
    return {"commit": commit, "dirty": None, "utc": date, "inferred": INFERRED}


def backfill(path: Path) -> None:
    result = json.loads(path.read_text())
    if not result.get("provenance"):
        result["provenance"] = committed_by(path)
        row = result["provenance"]
    else:
        row = {**result["provenance"], "inferred": ROW_INFERRED}
    result["provenance_by_row"] = {**(result.get("provenance_by_row") or {}), **{key: row for key in rows_without(result)}}
    path.write_text(json.dumps(result, indent=2) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true")
    args = parser.parse_args()
    files = missing()
    if args.check:
        for path in files:
            print(f"{path.relative_to(ROOT)}: provenance missing for the file or some rows (python tools/backfill_provenance.py)")
        sys.exit(1 if files else 0)
    for path in files:
        backfill(path)
        print(f"{path.relative_to(ROOT)}: provenance inferred from git")


if __name__ == "__main__":
    main()
