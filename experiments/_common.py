"""Shared by the benchmarks: machine facts, peak memory, results JSON and docs/RESULTS.md sections.

Each benchmark owns one section of docs/RESULTS.md between ``<!-- NAME:start -->`` and
``<!-- NAME:end -->`` and rewrites only that, so benchmarks can be re-run one at a time.
"""

from __future__ import annotations

import json
import os
import platform
import resource
import sys
import time
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
RESULTS_MD = ROOT / "docs" / "RESULTS.md"


def peak_rss_mib() -> float:
    """Peak resident memory of this process so far, MiB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


LOAD_AT_START = os.getloadavg()[0]  # the machine's load when this script started (its own work not yet in it)
ARGV_AT_START = list(sys.argv)  # the script's command line (a benchmark that runs binpick's CLI in process rewrites sys.argv)


GENERATED = ("results", "docs/RESULTS.md", "README.md")  # what the benchmarks write: no change to the code they measure
CODE_AT_START: tuple[str | None, bool] | None = None  # (commit, dirty) when the script started: a commit made
# while it ran is not what it measured
DIGESTS_AT_START: dict[str, str] = {}


def provenance() -> dict:
    """What a figure was measured with: the commit (and whether the tree had changes) when the script
    started, the command line, the machine's load average when it started and now, and when."""
    import subprocess

    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""

    global CODE_AT_START, DIGESTS_AT_START
    if CODE_AT_START is None:
        # changes to what runs, not to what runs write (results, the page and README tables they regenerate)
        changed = git("status", "--porcelain", "--untracked-files=no", "--", ".", *(f":(exclude){p}" for p in GENERATED))
        CODE_AT_START = (git("rev-parse", "HEAD") or None, bool(changed))
        DIGESTS_AT_START = input_digests()  # the weights it started with, not those a run ships at its end
    return {"commit": CODE_AT_START[0], "dirty": CODE_AT_START[1],
            "command": " ".join([Path(ARGV_AT_START[0]).name if ARGV_AT_START else "python", *ARGV_AT_START[1:]]),
            "digests": DIGESTS_AT_START,
            "load_average_start": round(LOAD_AT_START, 2), "load_average_end": round(os.getloadavg()[0], 2),
            "utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}


def input_digests() -> dict[str, str]:
    """SHA-256 (first 16 hex digits) of what a figure was measured with that the commit alone may not
    pin: every file named on the command line (configs, weights, data cards) and the weights binpick
    ships (an experiment loads them by default; a run can replace them without a commit)."""
    files = [Path(arg) for arg in ARGV_AT_START[1:] if not arg.startswith("-")]
    files = [f if f.is_absolute() else Path.cwd() / f for f in files]
    return input_digests_of(files + sorted((ROOT / "src" / "binpick").glob("*/weights/*.safetensors")))


def input_digests_of(files: list[Path]) -> dict[str, str]:
    """``{path as the page names it: first 16 hex digits of its SHA-256}`` of the regular files among ``files``."""
    import hashlib

    digests = {}
    for file in files:
        try:
            if file.is_file() and file.stat().st_size < 512 * 2**20:
                digest = hashlib.sha256()
                with file.open("rb") as stream:
                    for chunk in iter(lambda: stream.read(2**20), b""):
                        digest.update(chunk)
                digests[repo_relative(file)] = digest.hexdigest()[:16]
        except OSError:
            continue
    return digests


def machine() -> dict:
    import mujoco
    import numpy

    return {
        "cpu_count": os.cpu_count(),
        "processor": platform.processor() or platform.machine(),
        "python": sys.version.split()[0],
        "mujoco": mujoco.__version__,
        "numpy": numpy.__version__,
        "mujoco_gl": os.environ.get("MUJOCO_GL"),
        "date": time.strftime("%Y-%m-%d"),
    }


def latest_run(runs: Path, name: str) -> Path | None:
    """The newest run folder of ``name`` under ``runs`` (finished or not), or None."""
    folder = Path(runs) / name
    runs_of = sorted(p for p in folder.glob("*") if (p / "config.yaml").is_file()) if folder.is_dir() else []
    return runs_of[-1] if runs_of else None


def keyed_run_dirs(items: list[str]) -> list[tuple[str, Path]]:
    """``KEY=RUN_DIR`` arguments (run folders relative to the repository) -> (key, folder); a bad one is one line."""
    pairs = []
    for item in items:
        key, _, run = item.partition("=")
        if not key or not run:
            sys.exit(f"{item!r}: expected KEY=RUN_DIR")
        pairs.append((key, ROOT / run))
    return pairs


def training_scalars(run: Path, *tags: str, optional: tuple[str, ...] = ()) -> dict[str, list[tuple[int, float]]]:
    """(step, value) pairs of each tag in a run's TensorBoard log (``run/tb``), and of those ``optional`` tags it
    has; a missing folder or required tag is one line."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    if not (run / "tb").is_dir():
        sys.exit(f"{run}: no TensorBoard folder (tb/); is it a run folder?")
    events = EventAccumulator(str(run / "tb"), size_guidance={"scalars": 0})
    events.Reload()
    found = events.Tags()["scalars"]
    if missing := [tag for tag in tags if tag not in found]:
        sys.exit(f"{run}: its TensorBoard has no {', '.join(missing)} yet")
    return {tag: [(event.step, event.value) for event in events.Scalars(tag)]
            for tag in (*tags, *(tag for tag in optional if tag in found))}


ROW_SKIP = ("benchmark", "machine", "provenance", "provenance_by_row")


def write_result(name: str, payload: dict, measured: set[str] | frozenset[str] = frozenset(),
                 merged: dict[str, set[str]] | None = None) -> Path:
    """results/NAME.json: the payload, the machine and this run's provenance; and per top-level row
    (``provenance_by_row``) the provenance of the run that measured it: this run's for the rows it
    changed and the rows it names as ``measured`` (measured again, perhaps to the same figures), the
    earlier one for rows it kept as they were, so a row measured on older code than its neighbours
    says so. ``merged``: rows that join this run's sub-rows to an earlier run's (each hand's rows of
    ``by_gripper``): their provenance goes per sub-row (``by_gripper.jaws``), this run's for the
    sub-rows it names, the earlier one for the others."""
    from binpick.core.files import atomic_write_text

    path = RESULTS / f"{name}.json"
    now = provenance()
    try:
        previous = json.loads(path.read_text())
    except (OSError, ValueError):
        previous = {}
    earlier = previous.get("provenance_by_row") or {}
    if not earlier and previous.get("provenance"):  # written before rows had their own: its last writer, said so
        earlier = {key: {**previous["provenance"], "inferred": "the file's last writer; the row may be older"} for key in previous
                   if key not in ROW_SKIP}
    by_row = {}
    for key, value in payload.items():
        if key in ROW_SKIP:
            continue
        kept = key not in measured and key in previous and json.dumps(previous[key], sort_keys=True) == json.dumps(value, sort_keys=True)
        by_row[key] = earlier.get(key, {"commit": None, "note": "measured before results recorded provenance"}) if kept else now
    for key, subs in (merged or {}).items():
        if isinstance(payload.get(key), dict):
            before = by_row.pop(key)
            for sub in payload[key]:
                dotted = f"{key}.{sub}"
                by_row[dotted] = now if sub in subs else earlier.get(dotted, earlier.get(key, before))
    body = {key: value for key, value in payload.items() if key not in ROW_SKIP}
    return atomic_write_text(path, json.dumps({"benchmark": name, "machine": machine(), **body, "provenance": now,
                                               "provenance_by_row": by_row}, indent=2) + "\n")


def write_section(name: str, markdown: str) -> None:
    """Replace (or append) this benchmark's section of docs/RESULTS.md."""
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    block = f"{start}\n{markdown.strip()}\n{end}"
    text = RESULTS_MD.read_text() if RESULTS_MD.exists() else "# Results\n"
    if start in text and end in text:
        before, rest = text.split(start, 1)
        _, after = rest.split(end, 1)
        text = before + block + after
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    from binpick.core.files import atomic_write_text

    atomic_write_text(RESULTS_MD, text)


def repo_relative(path: str | Path) -> str:
    """A path as the page names it: relative to the repository when it lies inside this checkout, from its
    ``runs/`` folder when a results file recorded it in another checkout, else as it is."""
    path = Path(path)
    if path.is_relative_to(ROOT):
        return str(path.relative_to(ROOT))
    if path.is_absolute() and "runs" in path.parts:
        return str(Path(*path.parts[path.parts.index("runs"):]))
    return str(path)


def write_section_of(name: str, render: Callable[[dict], str], results_file: str) -> str:
    """Replace this benchmark's section with ``render`` of ``results/RESULTS_FILE`` as written (and return
    it), so that the page holds what ``tools/results_tables.py --page`` makes of the same file."""
    markdown = section_markdown(render, json.loads((RESULTS / results_file).read_text()), results_file)
    write_section(name, markdown)
    rewrite_siblings(name, results_file)
    return markdown


def rewrite_siblings(name: str, results_file: str) -> None:
    """The other sections rendered from the same results file (their figures or provenance line may have
    changed with it), rewritten as ``tools/results_tables.py --page`` would."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("results_tables", ROOT / "tools" / "results_tables.py")
    tables = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("results_tables", tables)
    spec.loader.exec_module(tables)
    for section in tables.PAGE_SECTIONS:
        if section.results == results_file and section.name != name:
            try:
                write_section(section.name, tables.render(section))
            except tables.TableError as error:
                print(f"note: {error}", file=sys.stderr)


def section_markdown(render: Callable[[dict], str], result: dict, results_file: str) -> str:
    """A section as the page shows it: the script's rendering of its results, then where they came from."""
    return render(result).strip() + "\n\n" + provenance_line(result, results_file)


def provenance_line(result: dict, results_file: str) -> str:
    """Which code measured a results file's rows: one commit and date per group of rows, the newest first
    (``inferred``: the commit that committed rows written before provenance was recorded)."""
    rows = result.get("provenance_by_row") or {}
    if not rows and result.get("provenance"):
        rows = {"all": result["provenance"]}
    groups: dict[tuple, list[str]] = {}
    for key, where in rows.items():
        where = where or {}
        stamp = (str(where.get("commit") or "unknown")[:7], str(where.get("utc") or "")[:10], bool(where.get("inferred")),
                 bool(where.get("dirty")))
        groups.setdefault(stamp, []).append(key)
    if not groups:
        return f"*Provenance (`results/{results_file}`): not recorded.*"
    parts = []
    for (commit, date, inferred, dirty), keys in sorted(groups.items(), key=lambda item: item[0][1], reverse=True):
        what = "" if len(groups) == 1 else f" ({', '.join(f'`{k}`' for k in keys)})"
        if commit == "unknown":
            parts.append(f"not recorded{what}")
            continue
        how = "committed at" if inferred else "measured at"
        parts.append(f"{how} `{commit}`{' with uncommitted changes' if dirty else ''} {date}{what}")
    note = " (*committed at*: measured on that code or older)" if any(stamp[2] for stamp in groups) else ""
    return f"*Provenance (`results/{results_file}`): {'; '.join(parts)}{note}.*"


def recipe(name: str) -> tuple[Path, dict]:
    """A config of ``configs/`` by its name (``rod_warehouse``), with the overrides it implies: a name ending
    in ``_seed<N>`` is the config without that ending, trained again from seed N (a row of its own)."""
    import re

    found = sorted((ROOT / "configs").glob(f"*/{name}.yaml"))
    if found:
        return found[0], {}
    seeded = re.fullmatch(r"(.+)_seed(\d+)", name)
    if seeded and (base := sorted((ROOT / "configs").glob(f"*/{seeded.group(1)}.yaml"))):
        return base[0], {"seed": int(seeded.group(2)), "name": name}
    raise FileNotFoundError(f"no config named {name!r} under {ROOT / 'configs'}")


provenance()  # the code as it is when the script starts
