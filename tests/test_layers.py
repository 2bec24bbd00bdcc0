"""The layers of the architecture (README) hold: no package imports one above it, no module cycles.

The contracts live in pyproject.toml ([tool.importlinter]); import-linter checks them on the real
import graph. A change that imports upward fails here with the offending import named.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINT = [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"]


def test_import_contracts_are_kept():
    result = subprocess.run([*LINT, "--config", str(ROOT / "pyproject.toml")],
                            capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-1000:]
    assert "Contracts: 6 kept, 0 broken." in result.stdout


BREAKS = {  # contract (its name's start) -> (module given one bad import, the import, what import-linter must report)
    "The core stands on nothing above it": ("core/files.py", "import binpick.grippers",
                                           "binpick.core is not allowed to import binpick.grippers"),
    "Layers": ("envs/arm2d.py", "from binpick.rl import evaluate", "binpick.envs is not allowed to import binpick.rl"),
    "Perception, grasping and picking run without the simulator": ("detection/ops.py", "import binpick.sim.products",
                                     "binpick.detection is not allowed to import binpick.sim"),
    "Perception, grasping and picking run without the simulator (MuJoCo)": ("grasping/camera.py", "import mujoco", "binpick.grasping is not allowed to import mujoco"),
    "Picking speaks no ROS": ("picking/workspace.py", "import rclpy", "binpick.picking is not allowed to import rclpy"),
    "Detection, grasping and RL are independent": ("detection/ops.py", "import binpick.grasping.camera",
                     "binpick.detection is not allowed to import binpick.grasping"),
}


@pytest.mark.parametrize("contract", list(BREAKS))
def test_each_contract_catches_its_violation(tmp_path, contract):
    """Every contract can fail: the same contracts on a copy of the package with one bad import."""
    import shutil

    module, line, report = BREAKS[contract]
    package = tmp_path / "src" / "binpick"
    shutil.copytree(ROOT / "src" / "binpick", package, ignore=shutil.ignore_patterns("__pycache__", "weights"))
    with open(package / module, "a") as handle:
        handle.write(f"\n{line}  # noqa: E402,F401  (a violation on purpose)\n")
    result = subprocess.run([*LINT, "--config", str(ROOT / "pyproject.toml")],
                            capture_output=True, text=True, cwd=tmp_path, timeout=120,
                            env={"PYTHONPATH": str(tmp_path / "src"), "PATH": "/usr/bin:/bin", "COLUMNS": "500"})
    assert result.returncode != 0 and report in result.stdout, result.stdout[-2000:]
    named = contract.removesuffix(" (MuJoCo)")
    assert any(line.startswith(named) and line.endswith("BROKEN") for line in result.stdout.splitlines()), result.stdout[-2000:]


# grimp (import-linter's graph) reads every import statement, in functions and under TYPE_CHECKING too
CYCLES = """
import json, grimp
graph = grimp.build_graph("binpick", exclude_type_checking_imports=False)
cycles = []
for module in sorted(graph.modules):
    for imported in sorted(graph.find_modules_directly_imported_by(module)):
        if imported.startswith("binpick") and graph.chain_exists(importer=imported, imported=module):
            cycles.append([module, *graph.find_shortest_chain(importer=imported, imported=module)])
print(json.dumps(cycles))
"""


def import_cycles(source: Path) -> list[list[str]]:
    """Every import cycle among binpick's modules in ``source`` (a src folder), each as its chain."""
    import json

    result = subprocess.run([sys.executable, "-c", CYCLES], capture_output=True, text=True, timeout=120,
                            env={"PYTHONPATH": str(source), "PATH": "/usr/bin:/bin"})
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads(result.stdout)


def test_no_import_cycles_not_even_through_imports_in_functions_or_for_types_only():
    """A module importing another inside a function (or for a type) still depends on it: no circle
    of modules may close that way either."""
    assert import_cycles(ROOT / "src") == []


def test_the_cycle_check_sees_an_import_made_inside_a_function(tmp_path):
    import shutil

    package = tmp_path / "src" / "binpick"
    shutil.copytree(ROOT / "src" / "binpick", package, ignore=shutil.ignore_patterns("__pycache__", "weights"))
    with open(package / "april" / "evaluate.py", "a") as handle:  # the pipeline imports evaluate in a function
        handle.write("\n\ndef planted():\n    from binpick.april.pipeline import AprilRun  # noqa: F401  (a cycle on purpose)\n")
    cycles = import_cycles(tmp_path / "src")
    assert ["binpick.april.evaluate", "binpick.april.pipeline", "binpick.april.evaluate"] in cycles, cycles
