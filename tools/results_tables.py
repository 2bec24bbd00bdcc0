"""The README's results table, generated from results/*.json so that its figures cannot drift from
what the experiments measured.

    python tools/results_tables.py            # rewrite the table in README.md from results/*.json
    python tools/results_tables.py --check    # exit 1, a line per row, if README.md differs from them

The table sits in README.md between ``<!-- results_table:start -->`` and ``<!-- results_table:end -->``;
everything between the markers is this script's, so a figure edited by hand there is reported by
``--check`` (and by tests/test_results_tables.py) until the script writes it again. Each row is one
function below that reads its figures from one results file; the thesis's and peers' figures that no
results file holds are written in the function as they are in the README.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
README = ROOT / "README.md"
START, END = "<!-- results_table:start -->", "<!-- results_table:end -->"
HEADER = "| what | binpick | thesis or peer |\n|---|---|---|"


class TableError(Exception):
    """A results file or key a row needs, or README's markers, not found: one line, not a traceback."""


@dataclass(frozen=True)
class Row:
    """One row of the table, with the results file its figures come from (named when it differs)."""

    what: str
    binpick: str
    peer: str
    source: str

    def line(self) -> str:
        return f"| {self.what} | {self.binpick} | {self.peer} |"


def value(file: str, *key: str) -> Any:
    """``results/FILE``'s value at the nested ``key``; a missing file or key raises :class:`TableError`
    naming both, so a half-run experiment is one clear line."""
    path = RESULTS / file
    where = f"results/{file}"
    dotted = ".".join(key)
    try:
        node: Any = json.loads(path.read_text())
    except FileNotFoundError:
        raise TableError(f"{where} is missing (needed for {dotted})") from None
    except (OSError, ValueError) as error:
        raise TableError(f"{where} cannot be read ({error}; needed for {dotted})") from None
    for depth, part in enumerate(key):
        if not isinstance(node, dict) or part not in node:
            raise TableError(f"{where} has no key {'.'.join(key[:depth + 1])}")
        node = node[part]
    return node


def percent(fraction: float) -> str:
    return f"{fraction:.0%}"


def steps_range(steps: list[int]) -> str:
    """Per-seed simulator steps as the README gives them: lowest–highest."""
    low, high = min(steps), max(steps)
    return f"{low:,}" if low == high else f"{low:,}–{high:,}"


def mean_std(file: str, key: str) -> str:
    return f"{value(file, key, 'mean'):.1f} ± {value(file, key, 'std'):.1f}"


def fetchreach_steps() -> Row:
    """Thesis ch. 3's data efficiency against the peers, all three measured by the same experiment."""
    file = "rl_fetchreach_vs_sb3.json"
    return Row("FetchReach, random goals: simulator steps to 95% success (GP imagination + episode HER)",
               steps_range(value(file, "binpick", "sim_steps_to_95")),
               f"SB3 SAC+HER {steps_range(value(file, 'sb3_sac_her', 'sim_steps_to_95'))}; "
               f"RL Zoo TQC+HER {steps_range(value(file, 'tqc_her_zoo', 'sim_steps_to_95'))}", file)


def arm2d_fixed_goal() -> Row:
    """Table 3.1: the A3C row, as it acts (sampling its policy)."""
    file = "rl_arm2d.json"
    return Row("Arm2D from images, fixed goal (Table 3.1): A3C, actions per episode",
               mean_std(file, "a3c"), "thesis 15 ± 3", file)


def arm2d_curriculum() -> Row:
    """Table 3.2: goals anywhere, the curriculum run's sampled policy."""
    file = "rl_arm2d.json"
    return Row("Arm2D from images, goals anywhere (Table 3.2), with the curriculum",
               mean_std(file, "curriculum_whole_area"), "thesis 25 ± 6", file)


def pick_in_simulation() -> Row:
    """Ch. 6's pipeline in simulation with the default hand; right product: each group's share of lifts."""
    file = "pick.json"
    return Row("Orders placed in simulation, seen / held-out products (`experiments/pick.py`; the hand with jaws and a "
               "suction cup)",
               f"{percent(value(file, 'seen', 'pick_success'))} / {percent(value(file, 'held_out', 'pick_success'))}"
               f" (right product {percent(value(file, 'seen', 'right_product'))} / "
               f"{percent(value(file, 'held_out', 'right_product'))})",
               "Dex-Net 4.0: above 95% on novel objects in bins", file)


def pick_by_hand() -> Row:
    """The same orders with jaws alone, the suction cup alone and both (seen and held-out together)."""
    file = "pick.json"

    def placed(gripper: str) -> str:
        groups = [value(file, "by_gripper", gripper, group) for group in ("seen", "held_out")]
        orders = sum(g["orders"] for g in groups)
        return percent(sum(g["pick_success"] * g["orders"] for g in groups) / max(orders, 1))

    return Row("The same orders by hand: jaws alone / suction cup alone / both, placed (seen and held-out together)",
               " / ".join(placed(g) for g in ("jaws", "suction", "both")),
               "Dex-Net 4.0: the ambidextrous policy beats either tool alone", file)


def single_copy() -> Row:
    """The instance a user points at, in bins holding one copy of it, on depth as sensors give it."""
    file = "plan.json"
    return Row("Single-copy bins, realistic depth: the pointed instance placed (`experiments/plan.py single`)",
               f"{percent(value(file, 'single_copy', 'pick_success'))} of {value(file, 'single_copy', 'orders')} "
               f"(right object {percent(value(file, 'single_copy', 'right_object'))})", "target ≥ 90%", file)


def planning_latency() -> Row:
    """Planning per frame as a warm ``Picker`` caller sees it, file reading excluded, per camera resolution."""
    file = "plan.json"
    sizes = ("640x480", "1920x1080", "4000x3000")
    medians = [value(file, "planning_latency", "by_size", size, "median") for size in sizes]
    return Row("Planning per frame, both tools, warm `Picker` (median; 640×480 / 1920×1080 / 4000×3000; "
               "`benchmarks/plan_latency.py`)", " / ".join(f"{m:.1f}" for m in medians) + " ms", "target 100 / 150 / 300 ms", file)


def pick_with_panda() -> Row:
    """The same orders executed by the Panda arm; picks per hour over seen and held-out orders together."""
    file = "pick.json"
    return Row("The same orders picked by a Panda arm (`experiments/pick.py --robot panda`): placed, seen / "
               "held-out; picks per hour of robot time",
               f"{percent(value(file, 'arm', 'seen', 'pick_success'))} / "
               f"{percent(value(file, 'arm', 'held_out', 'pick_success'))}; "
               f"{value(file, 'arm', 'picks_per_hour'):,.0f} per hour, {value(file, 'arm', 'collisions')} collisions",
               "Dex-Net 4.0: about 300 per hour (ABB YuMi)", file)


def plan_from_files() -> Row:
    """Orders planned from the files a camera writes (``binpick plan``), per set-up."""
    file = "plan.json"
    default = value(file, "file_orders_by_domain", "default", "files", "pick_success")
    shifted = value(file, "file_orders_by_domain", "shifted", "files", "pick_success")
    return Row("Orders placed from a camera's files, default / shifted camera and light (`experiments/plan.py`)",
               f"{percent(default)} / {percent(shifted)}", "—", file)


def photo_query_ap50() -> Row:
    """The pick pipeline's detector (photo query) on seen, held-out and shifted bins."""
    file = "rod.json"
    figures = [value(file, "photo", part, "ap50") for part in ("seen", "held_out", "shifted_domain")]
    return Row("Photo-query detection AP50, seen / held-out products / shifted set-up",
               " / ".join(f"{ap50:.2f}" for ap50 in figures), "—", file)


def detector_latency() -> Row:
    """The picking detector's time per image in PyTorch and exported to ONNX Runtime."""
    file = "rod.json"
    return Row("Picking detector per image, PyTorch / ONNX Runtime (`benchmarks/onnx_latency.py`; same boxes)",
               f"{value(file, 'latency_ms', 'onnx', 'torch'):.1f} / {value(file, 'latency_ms', 'onnx', 'onnx'):.1f} ms",
               "—", file)


ROWS: tuple[Callable[[], Row], ...] = (fetchreach_steps, arm2d_fixed_goal, arm2d_curriculum, pick_in_simulation, pick_by_hand,
                                       pick_with_panda, plan_from_files, single_copy, planning_latency, photo_query_ap50,
                                       detector_latency)


def build(row: Callable[[], Row]) -> Row | str:
    """The row, or the one line saying which results file or key it lacks."""
    try:
        return row()
    except TableError as missing:
        return f"results table row {row.__name__}: {missing}"
    except (TypeError, ValueError, ZeroDivisionError) as error:  # a key holding null or text where a figure belongs
        return f"results table row {row.__name__}: a figure it reads is not a number ({error})"


def readme_table() -> str:
    """The whole table, as README.md should hold it between the markers."""
    built = [build(row) for row in ROWS]
    if errors := [made for made in built if isinstance(made, str)]:
        raise TableError("\n".join(errors))
    return "\n".join([HEADER, *(made.line() for made in built if isinstance(made, Row))])


def split_readme(text: str) -> tuple[str, str, str]:
    """README text before the table block, the table between the markers, and the text after it."""
    if text.count(START) != 1 or text.count(END) != 1 or text.index(START) > text.index(END):
        raise TableError(f"README.md needs one {START} ... {END} pair around the results table")
    before, rest = text.split(START, 1)
    table, after = rest.split(END, 1)
    return before, table.strip(), after


def with_table(text: str, table: str) -> str:
    """README text with the block between the markers replaced by ``table``."""
    before, _, after = split_readme(text)
    return f"{before}{START}\n{table.strip()}\n{END}{after}"


def cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def check(text: str | None = None) -> list[str]:
    """One line per row where README text (README.md's by default) differs from what results/*.json
    give, or that they cannot give; an empty list when the README is up to date."""
    text = README.read_text() if text is None else text
    try:
        _, table, _ = split_readme(text)
    except TableError as missing:
        return [str(missing)]
    lines = table.splitlines()
    problems = []
    if lines[:2] != HEADER.splitlines():
        problems.append(f"README results table: its header is not {HEADER.splitlines()[0]}")
    written = [line for line in lines[2:] if line.strip()]
    for index, made in enumerate(build(row) for row in ROWS):
        if isinstance(made, str):
            problems.append(made)
        elif index >= len(written):
            problems.append(f'README results table lacks the row "{made.what}" (results/{made.source})')
        elif written[index] != made.line():
            have = cells(written[index]) + [""] * 3
            want = {"what": made.what, "binpick": made.binpick, "thesis or peer": made.peer}
            diffs = [f'{column} "{h}", generated "{w}"' for (column, w), h in zip(want.items(), have) if h != w]
            problems.append(f'README results row "{made.what}" differs from results/{made.source}: '
                            f'{"; ".join(diffs) or "in its layout"}')
    problems += [f"README results table has a row no results file gives: {extra}" for extra in written[len(ROWS):]]
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Write (or --check) README.md's results table from results/*.json.")
    parser.add_argument("--check", action="store_true",
                        help="change nothing; exit 1 with a line per row where README.md differs from results/*.json")
    args = parser.parse_args(argv)
    if args.check:
        problems = check()
        for problem in problems:
            print(problem, file=sys.stderr)
        return 1 if problems else 0
    try:
        text = with_table(README.read_text(), readme_table())
    except TableError as problem:
        print(problem, file=sys.stderr)
        return 1
    README.write_text(text)
    print("README.md: results table written from results/*.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
