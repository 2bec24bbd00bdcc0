"""The layers of the architecture (README) hold: no package imports one above it, no module cycles.

The contracts live in pyproject.toml ([tool.importlinter]); import-linter checks them on the real
import graph. A change that imports upward fails here with the offending import named.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINT = [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"]


def test_import_contracts_are_kept():
    result = subprocess.run([*LINT, "--config", str(ROOT / "pyproject.toml")],
                            capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-1000:]
    assert "Contracts: 2 kept, 0 broken." in result.stdout


def test_the_contract_catches_an_upward_import(tmp_path):
    """The check can fail: the same contracts on a copy of the package with one upward import."""
    import shutil

    package = tmp_path / "src" / "binpick"
    shutil.copytree(ROOT / "src" / "binpick", package, ignore=shutil.ignore_patterns("__pycache__", "weights"))
    with open(package / "envs" / "arm2d.py", "a") as handle:
        handle.write("\nfrom binpick.rl import evaluate  # noqa: E402,F401  (upward on purpose)\n")
    result = subprocess.run([*LINT, "--config", str(ROOT / "pyproject.toml")],
                            capture_output=True, text=True, cwd=tmp_path, timeout=120,
                            env={"PYTHONPATH": str(tmp_path / "src"), "PATH": "/usr/bin:/bin"})
    assert result.returncode != 0 and "binpick.envs is not allowed to import binpick.rl" in result.stdout, result.stdout[-2000:]
