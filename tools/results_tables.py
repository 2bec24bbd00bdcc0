"""The README's results table and the whole results page (docs/RESULTS.md), generated from
results/*.json so that their figures cannot drift from what the experiments measured.

    python tools/results_tables.py            # rewrite the table in README.md from results/*.json
    python tools/results_tables.py --page     # rewrite every section of docs/RESULTS.md from results/*.json
    python tools/results_tables.py --check    # exit 1, a line per row or section, if either differs from them

The table sits in README.md between ``<!-- results_table:start -->`` and ``<!-- results_table:end -->``;
everything between the markers is this script's, so a figure edited by hand there is reported by
``--check`` (and by tests/test_results_tables.py) until the script writes it again. Each row is one
function below that reads its figures from one results file; the thesis's and peers' figures that no
results file holds are written in the function as they are in the README.

Each section of docs/RESULTS.md (between ``<!-- NAME:start -->`` and ``<!-- NAME:end -->``) is written by
a function ``section(result)`` of the experiment or benchmark that measures it, from the results file
that script writes; :data:`PAGE_SECTIONS` names them in page order. The script calls the same function
when it runs, so the page holds the same text whether the script or this tool wrote it last. Text
outside the markers is the page's own and is kept as it is.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any, Callable

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
README = ROOT / "README.md"
PAGE = ROOT / "docs" / "RESULTS.md"
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
    return _pick_with_arm("arm", "a Panda arm", "panda")


def pick_with_ur5e() -> Row:
    """The same orders executed by the UR5e arm."""
    return _pick_with_arm("arm_ur5e", "a UR5e arm", "ur5e")


def _pick_with_arm(key: str, name: str, robot: str) -> Row:
    file = "pick.json"
    return Row(f"The same orders picked by {name} (`experiments/pick.py --robot {robot}`): placed, seen / "
               "held-out; picks per hour of robot time",
               f"{percent(value(file, key, 'seen', 'pick_success'))} / "
               f"{percent(value(file, key, 'held_out', 'pick_success'))}; "
               f"{value(file, key, 'picks_per_hour'):,.0f} per hour, {value(file, key, 'collisions')} collisions",
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
    parts = ("seen", "held_out", "shifted_domain")
    figures = [value(file, "photo", part, "ap50") for part in parts]
    targets = [value(file, "photo", "targets", part) for part in parts]
    return Row("Photo-query detection AP50 of the shipped picking detector, seen / held-out products / shifted set-up",
               " / ".join(f"{ap50:.2f}" for ap50 in figures), "target " + " / ".join(f"{t:.2f}" for t in targets), file)


def detector_latency() -> Row:
    """The picking detector's time per image in PyTorch and exported to ONNX Runtime."""
    file = "rod.json"
    return Row("Picking detector per image, PyTorch / ONNX Runtime (`benchmarks/onnx_latency.py`; same boxes)",
               f"{value(file, 'latency_ms', 'onnx', 'torch'):.1f} / {value(file, 'latency_ms', 'onnx', 'onnx'):.1f} ms",
               "—", file)


ROWS: tuple[Callable[[], Row], ...] = (fetchreach_steps, arm2d_fixed_goal, arm2d_curriculum, pick_in_simulation, pick_by_hand,
                                       pick_with_panda, pick_with_ur5e, plan_from_files, single_copy, planning_latency, photo_query_ap50,
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


@dataclass(frozen=True)
class Section:
    """One section of docs/RESULTS.md: the script and function that write it, and the results file
    (under results/) the function is given."""

    name: str
    script: str
    function: str
    results: str

    @property
    def start(self) -> str:
        return f"<!-- {self.name}:start -->"

    @property
    def end(self) -> str:
        return f"<!-- {self.name}:end -->"


PAGE_SECTIONS: tuple[Section, ...] = (
    Section("random_policy", "experiments/random_policy.py", "section", "random_policy.json"),
    Section("env_speed", "benchmarks/env_speed.py", "section", "env_speed.json"),
    Section("gp_cost", "benchmarks/gp_cost.py", "section", "gp_cost.json"),
    Section("rl_arm2d", "experiments/rl_arm2d.py", "section", "rl_arm2d.json"),
    Section("rl_fetchreach_vs_sb3", "experiments/rl_fetchreach_vs_sb3.py", "section", "rl_fetchreach_vs_sb3.json"),
    Section("table_3_3", "experiments/rl_fetchreach_gp_tables.py", "section_table_3_3", "rl_fetchreach_gp_tables.json"),
    Section("table_3_4", "experiments/rl_fetchreach_gp_tables.py", "section_table_3_4", "rl_fetchreach_gp_tables.json"),
    Section("april", "experiments/april.py", "section", "april.json"),
    Section("data_stats", "experiments/data_stats.py", "section", "data_stats.json"),
    Section("data_speed", "benchmarks/data_speed.py", "section", "data_speed.json"),
    Section("sim_to_real", "experiments/sim_to_real.py", "section", "sim_to_real.json"),
    Section("rod", "experiments/rod.py", "section", "rod.json"),
    Section("rod_recurrent", "experiments/rod_recurrent.py", "section", "rod.json"),
    Section("ros_latency", "benchmarks/ros_latency.py", "section", "ros_latency.json"),
    Section("ray_scaling", "benchmarks/ray_scaling.py", "section", "ray_scaling.json"),
    Section("pick", "experiments/pick.py", "section", "pick.json"),
    Section("grasp", "experiments/grasp.py", "section_grasp", "grasp.json"),
    Section("plan", "experiments/plan.py", "section", "plan.json"),
    Section("rod_pickability", "experiments/rod_pickability.py", "section", "rod_pickability.json"),
    Section("hostile", "benchmarks/hostile.py", "section", "hostile.json"),
    Section("verify", "experiments/verify.py", "section", "verify.json"),
    Section("onnx", "benchmarks/onnx_latency.py", "section", "rod.json"),
    Section("ray_train", "benchmarks/ray_train_scaling.py", "section", "ray_scaling.json"),
    Section("ray_jobs", "benchmarks/ray_jobs_scaling.py", "section", "ray_scaling.json"),
    Section("ray_rl", "benchmarks/ray_rl_curve.py", "section", "ray_scaling.json"),
    Section("grasp_tools", "experiments/grasp.py", "section_grasp_tools", "grasp.json"),
    Section("suction_model", "experiments/suction_model.py", "section", "suction_model.json"),
    Section("calibration", "experiments/calibration.py", "section", "calibration.json"),
)
MARKER = re.compile(r"<!-- (\w+):start -->")


def script(path: str) -> ModuleType:
    """The experiment or benchmark at ``path`` (relative to the repository), imported from its file under its
    own name, as the scripts import each other, without running its ``main()``."""
    file = ROOT / path
    loaded = sys.modules.get(file.stem)
    if loaded is not None and Path(getattr(loaded, "__file__", "") or "").resolve() == file:
        return loaded
    experiments = str(ROOT / "experiments")  # the scripts' ``import _common`` (benchmarks add it themselves)
    if experiments not in sys.path:
        sys.path.insert(0, experiments)
    spec = importlib.util.spec_from_file_location(file.stem, file)
    module = importlib.util.module_from_spec(spec)
    sys.modules[file.stem] = module  # a dataclass in it looks its module up while the class is made
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[file.stem]
        raise
    return module


def common() -> ModuleType:
    """experiments/_common.py, which also frames each section (its provenance line)."""
    return script("experiments/_common.py")


def render(section: Section) -> str:
    """The section's markdown from its results file; what it lacks raises :class:`TableError`, one line."""
    where = f"docs/RESULTS.md section {section.name}"
    try:
        result = json.loads((RESULTS / section.results).read_text())
    except FileNotFoundError:
        raise TableError(f"{where}: results/{section.results} is missing") from None
    except (OSError, ValueError) as error:
        raise TableError(f"{where}: results/{section.results} cannot be read ({error})") from None
    try:
        function = getattr(script(section.script), section.function, None)
    except (Exception, SystemExit) as error:  # the script itself fails to import: named, not a traceback
        raise TableError(f"{where}: {section.script} cannot be imported ({type(error).__name__}: {error})") from None
    if not callable(function):
        raise TableError(f"{where}: {section.script} has no function {section.function}(result)")
    try:
        return common().section_markdown(function, result, section.results).strip()
    except FileNotFoundError as error:
        raise TableError(f"{where}: {section.script} {section.function}() reads {error.filename}, which is missing") from None
    except (KeyError, IndexError, TypeError, ValueError, ZeroDivisionError, AttributeError) as error:
        raise TableError(f"{where}: results/{section.results} does not give it ({section.script} {section.function}(): "
                         f"{type(error).__name__}: {error})") from None


def page_blocks(text: str) -> dict[str, str]:
    """Each section's text on the page, between its markers, by name (a start marker without its end: absent)."""
    blocks = {}
    for name in MARKER.findall(text):
        start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
        if end in text.split(start, 1)[1]:
            blocks[name] = text.split(start, 1)[1].split(end, 1)[0].strip()
    return blocks


def with_section(text: str, section: Section, markdown: str) -> str:
    """Page text with the section's block replaced by ``markdown`` (appended when the page lacks it), as
    ``_common.write_section`` writes it."""
    block = f"{section.start}\n{markdown.strip()}\n{section.end}"
    if section.start in text and section.end in text.split(section.start, 1)[1]:
        before, rest = text.split(section.start, 1)
        return before + block + rest.split(section.end, 1)[1]
    return text.rstrip() + "\n\n" + block + "\n"


def first_difference(written: str, made: str) -> str:
    """Where a section on the page first differs from the generated one: line number and both lines, cut short."""
    have, want = written.splitlines(), made.splitlines()
    for number, (h, w) in enumerate(zip(have, want), 1):
        if h != w:
            at = next((i for i, (a, b) in enumerate(zip(h, w)) if a != b), min(len(h), len(w)))
            start = max(at - 30, 0)
            return f'line {number}: page "…{h[start:start + 90]}…", generated "…{w[start:start + 90]}…"'
    return f"the page has {len(have)} lines, generated {len(want)}"


def check_page(text: str | None = None) -> list[str]:
    """One line per section where page text (docs/RESULTS.md's by default) differs from what results/*.json
    give, or that they cannot give, and per section on the page that no script generates; an empty list
    when the page is up to date."""
    text = PAGE.read_text() if text is None else text
    blocks = page_blocks(text)
    problems = []
    for section in PAGE_SECTIONS:
        try:
            made = render(section)
        except TableError as problem:
            problems.append(str(problem))
            continue
        if section.name not in blocks:
            problems.append(f"docs/RESULTS.md lacks the section {section.name} ({section.script} {section.function}())")
        elif blocks[section.name] != made:
            problems.append(f"docs/RESULTS.md section {section.name} differs from what results/{section.results} gives "
                            f"({section.script} {section.function}()): {first_difference(blocks[section.name], made)}")
    registered = {section.name for section in PAGE_SECTIONS}
    problems += [f"docs/RESULTS.md section {name} is generated by no script (not in tools/results_tables.py PAGE_SECTIONS)"
                 for name in MARKER.findall(text) if name not in registered]
    return problems


def write_page() -> list[str]:
    """Rewrite every section of docs/RESULTS.md that results/*.json give; the lines for those they cannot."""
    text, problems = PAGE.read_text(), []
    for section in PAGE_SECTIONS:
        try:
            text = with_section(text, section, render(section))
        except TableError as problem:
            problems.append(str(problem))
    PAGE.write_text(text)
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Write (or --check) README.md's results table and docs/RESULTS.md "
                                                 "from results/*.json.")
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--check", action="store_true",
                      help="change nothing; exit 1 with a line per row or section where README.md or docs/RESULTS.md "
                           "differs from results/*.json")
    what.add_argument("--page", action="store_true",
                      help="rewrite every section of docs/RESULTS.md from results/*.json (text outside the markers kept)")
    args = parser.parse_args(argv)
    if args.check:
        problems = check() + check_page()
        for problem in problems:
            print(problem, file=sys.stderr)
        return 1 if problems else 0
    if args.page:
        problems = write_page()
        for problem in problems:
            print(problem, file=sys.stderr)
        print(f"docs/RESULTS.md: {len(PAGE_SECTIONS) - len(problems)} of {len(PAGE_SECTIONS)} sections written from results/*.json")
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
