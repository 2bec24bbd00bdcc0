"""binpick's command line: ``binpick <group> <command>``, a module per group (each command parses its
options, makes one library call and prints the result)."""

from __future__ import annotations

import os
import sys

import typer

from binpick.cli import april, checks, data, detect, envs, pick, plan, rl, ros, train  # noqa: F401  (each registers its commands)
from binpick.cli.app import DEFAULT_POLICY, app, print_error, progress
from binpick.core.errors import BinpickError, ConfigError

__all__ = ["DEFAULT_POLICY", "app", "main", "progress"]


FOLDER_OPTIONS = ("--out", "--runs")  # where output goes: an empty value would silently mean the current folder


def refuse_empty_folders(argv: list[str]) -> None:
    """``--out ''`` is a mistake (a shell variable that was not set), not the current folder: one line."""
    for index, argument in enumerate(argv):
        name, equals, value = argument.partition("=")
        if name in FOLDER_OPTIONS and ((equals and not value.strip()) or
                                       (not equals and index + 1 < len(argv) and not argv[index + 1].strip())):
            raise ConfigError(f"{name} is empty: give a folder (., for the current one)")


def main() -> None:
    """Console-script entry point: run the app; a user's mistake ends in one line and exit code 2.

    Click's usage errors (a bad option value, a missing argument) are printed the same way as
    binpick's own, instead of Typer's boxed panel."""
    try:
        refuse_empty_folders(sys.argv[1:])
        code = app(prog_name="binpick", standalone_mode=False)
    except typer.TyperException as error:  # Click's errors, as Typer vendors Click
        context = getattr(error, "ctx", None)
        if type(error).__name__ == "NoArgsIsHelpError" and context is not None:  # `binpick rl` alone: its help
            typer.echo(context.get_help())
        else:
            command = context.command_path if context is not None else "binpick"
            message = error.format_message() if hasattr(error, "format_message") else str(error)
            print_error(f"{message} (see '{command} --help')")
        sys.exit(getattr(error, "exit_code", 2))
    except typer.Abort:
        print_error("aborted")
        sys.exit(130)
    except BinpickError as error:
        print_error(str(error))
        if type(error).__name__ == "StalledPeer":  # threads blocked on the peer would keep the interpreter from exiting
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(2)
        sys.exit(2)
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()
