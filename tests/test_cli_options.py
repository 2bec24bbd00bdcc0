"""One convention across every verb: ``--out`` is a folder, a shop photo is ``--photo``, a scene index
``--scene``, ``--size`` is pixels (a product's dimensions are ``--product-size``), every command
that reads a config takes ``--set``, and help never prints a Python type as a metavar."""

from __future__ import annotations

import pytest
import typer
from typer.testing import CliRunner

from binpick.cli import app

runner = CliRunner()


def commands():
    root = typer.main.get_command(app)

    def walk(command, path):
        if hasattr(command, "commands"):
            for name, sub in command.commands.items():
                yield from walk(sub, [*path, name])
        else:
            yield " ".join(path), command

    return list(walk(root, []))


COMMANDS = commands()


def options(command) -> dict[str, object]:
    return {name: p for p in command.params if type(p).__name__.endswith("Option") for name in p.opts}


def test_the_walk_sees_every_verb():
    names = [name for name, _ in COMMANDS]
    assert len(names) >= 29 and {"plan", "detect predict", "data generate", "rl train", "checks"} <= set(names)


@pytest.mark.parametrize("name, command", COMMANDS, ids=[n for n, _ in COMMANDS])
def test_every_verb_follows_the_option_convention(name, command):
    found = options(command)
    for retired, now in (("--json", "--out"), ("--overlay", "--out"), ("--query-image", "--photo"), ("--index", "--scene"),
                         ("--heatmap-file", "--out")):
        assert retired not in found, f"{name}: {retired} is {now} everywhere"
    if "--out" in found:
        assert "folder" in found["--out"].help.lower(), f"{name}: --out must be a folder: {found['--out'].help!r}"
    if "--size" in found:
        assert "pixels" in found["--size"].help, f"{name}: --size is pixels; metres are --product-size"
    for option in found.values():
        if "photo" in (option.help or "").lower() and option.name in ("photo", "query_image"):
            assert "--photo" in option.opts
    takes_config = any(p.name == "config" for p in command.params)
    if takes_config:
        assert "--set" in found, f"{name} reads a config: it takes --set"


@pytest.mark.parametrize("name", [n for n, _ in COMMANDS])
def test_help_prints_no_python_type(name):
    result = runner.invoke(app, [*name.split(), "--help"], env={"COLUMNS": "100"})
    assert result.exit_code == 0, result.output
    assert "list[" not in result.output and "Path]" not in result.output, result.output
