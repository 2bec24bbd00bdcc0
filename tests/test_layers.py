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
    assert "Contracts: 5 kept, 0 broken." in result.stdout


BREAKS = {  # contract (its name's start) -> (module given one bad import, the import, what import-linter must report)
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
