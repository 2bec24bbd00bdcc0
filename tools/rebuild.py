"""Rebuild a shipped model from its configs, step after step, skipping what is done and resuming what
was interrupted: data sets, pre-training, fine-tuning, evaluation, shipping.

    python tools/rebuild.py photo                 # run (or continue) configs/rebuild/photo.yaml
    python tools/rebuild.py photo --status        # what is done, what runs where, hours per step
    nohup python tools/rebuild.py photo > runs/rebuild/photo.log 2>&1 &    # hours of CPU: in the background

A recipe (configs/rebuild/<name>.yaml) lists steps, each either ``train: CONFIG`` (any ``binpick train``
config: a data set, a detector, ...; ``set:`` overrides may name an earlier step's run folder as
``{step}``) or ``run: [ARGV...]`` (a script of this repository, with the same ``{step}`` names). Every
train step is ``binpick train`` in a child process, continued with ``binpick train --resume RUN`` after
a crash, a kill or the end of a session; a run step is run again until it exits 0. What each step
did, with its run folder, command lines and hours, is kept in ``runs/rebuild/<name>/state.json``,
written atomically after every change, so the same command picks up where the last one stopped.
"""

from __future__ import annotations

import argparse
import fcntl
import calendar
import json
import os
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "configs" / "rebuild"
BINPICK = [sys.executable, "-c", "from binpick.cli import main; main()"]
PLACEHOLDER = re.compile(r"\{([a-z0-9_]+)\}")


@dataclass(frozen=True)
class Step:
    """One step of a recipe: a ``binpick train`` config, or a command of this repository."""

    name: str
    train: str | None = None
    set: dict[str, Any] = field(default_factory=dict)
    run: list[str] = field(default_factory=list)
    why: str = ""

    def __post_init__(self) -> None:
        if not re.fullmatch(r"[a-z0-9_]+", self.name):
            raise ValueError(f"step name {self.name!r}: lower-case letters, digits and _ only")
        if (self.train is None) == (not self.run):
            raise ValueError(f"step {self.name!r}: give either train: CONFIG or run: [ARGV...]")
        if self.set and self.train is None:
            raise ValueError(f"step {self.name!r}: set: goes with train:")


@dataclass(frozen=True)
class Recipe:
    name: str
    steps: list[Step]
    about: str = ""

    @classmethod
    def load(cls, name: str) -> Recipe:
        from binpick.core.files import read_yaml

        path = RECIPES / f"{name}.yaml"
        if not path.is_file():
            known = ", ".join(sorted(p.stem for p in RECIPES.glob("*.yaml")))
            raise SystemExit(f"no recipe {name!r} in {RECIPES.relative_to(ROOT)} (known: {known})")
        data = read_yaml(path)
        try:
            steps = [Step(**step) for step in data.get("steps") or []]
        except (TypeError, ValueError) as error:
            raise SystemExit(f"{path.relative_to(ROOT)}: {error}") from None
        names = [step.name for step in steps]
        if not steps or len(set(names)) != len(names):
            raise SystemExit(f"{path.relative_to(ROOT)}: steps must be a non-empty list of uniquely named steps")
        for index, step in enumerate(steps):
            for text in [*map(str, step.set.values()), *step.run]:
                for ref in PLACEHOLDER.findall(text):
                    if ref not in names[:index]:
                        raise SystemExit(f"{path.relative_to(ROOT)}: step {step.name!r} names {{{ref}}}, "
                                         "which is not an earlier step")
            if step.train and not (ROOT / step.train).is_file():
                raise SystemExit(f"{path.relative_to(ROOT)}: step {step.name!r}: no config {step.train}")
        return cls(name=name, steps=steps, about=str(data.get("about") or ""))


class State:
    """``runs/rebuild/<recipe>/state.json``: per step its run folder, status, commands and seconds."""

    def __init__(self, folder: Path) -> None:
        from binpick.core.files import read_json

        self.folder = folder
        self.path = folder / "state.json"
        self.data: dict[str, Any] = read_json(self.path) if self.path.is_file() else {"steps": {}}

    def step(self, name: str) -> dict[str, Any]:
        return self.data["steps"].setdefault(name, {"status": "pending", "seconds": 0.0, "attempts": []})

    def save(self) -> None:
        from binpick.core.files import atomic_write_json

        atomic_write_json(self.path, self.data)


def commit() -> str:
    """The repository's commit, marked ``-dirty`` when the tree has changes."""
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True,
                           text=True).stdout.strip()
    return (head or "unknown") + ("-dirty" if dirty else "")


def resolve(text: str, state: State) -> str:
    """``{step}`` -> that step's run folder (relative to the repository)."""
    def folder(match: re.Match) -> str:
        run = state.step(match.group(1)).get("run")
        if not run:
            raise SystemExit(f"{{{match.group(1)}}} has no run folder yet")
        return run
    return PLACEHOLDER.sub(folder, text)


def data_out(config: str) -> str | None:
    """A data-set config's output folder (a data set is its own run folder), else None."""
    from binpick.core.files import read_yaml

    data = read_yaml(ROOT / config)
    return str(data["out"]) if data.get("task") == "data" else None


def runs_under(folder: Path) -> set[Path]:
    return {p.parent for p in folder.glob("*/*/config.yaml")} if folder.is_dir() else set()


def finished(run: Path) -> bool:
    """A trainer's run that wrote its final weights or metrics; a data set with every scene written."""
    from binpick.core import jobs
    from binpick.core.files import read_json

    if (run / "dataset.json").is_file():
        return (jobs.progress(run) or 0) >= int(read_json(run / "dataset.json").get("scenes") or 0)
    return (run / "model.safetensors").is_file()


def command_for(step: Step, state: State, runs: Path) -> list[str]:
    record = state.step(step.name)
    if step.run:
        return [sys.executable, *(resolve(arg, state) for arg in step.run)]
    if record.get("run"):
        return [*BINPICK, "train", "--resume", record["run"]]
    settings = [item for key, value in step.set.items() for item in ("--set", f"{key}={resolve(str(value), state)}")]
    return [*BINPICK, "train", step.train, "--runs", str(runs.relative_to(ROOT)), *settings]


def count_lost_attempts(record: dict, running: bool = False) -> None:
    """Attempts whose process died with its machine (no exit recorded) still ran: their hours count, up
    to the last file written in the step's run folder before the next attempt began (their last sign
    of life). ``running``: the last attempt is this process's own, not lost."""
    attempts = record["attempts"][:-1] if running else record["attempts"]
    folder = ROOT / record["run"] if record.get("run") else None
    written = [p.stat().st_mtime for p in folder.rglob("*") if p.is_file()] if folder is not None and folder.is_dir() else []

    def utc(text: str) -> float:
        return calendar.timegm(time.strptime(text, "%Y-%m-%dT%H:%M:%SZ"))

    for index, attempt in enumerate(attempts):
        if "exit" in attempt:
            continue
        started = utc(attempt["started_utc"])
        until = utc(record["attempts"][index + 1]["started_utc"]) if index + 1 < len(record["attempts"]) else time.time()
        seconds = max(0.0, max((t for t in written if t <= until), default=started) - started)
        attempt |= {"seconds": round(seconds, 1), "exit": None, "lost": True}
        record["seconds"] = round(record.get("seconds", 0.0) + seconds, 1)


def run_step(step: Step, state: State, runs: Path) -> None:
    record = state.step(step.name)
    argv = command_for(step, state, runs)
    shown = " ".join(shlex.quote(a) for a in (["binpick", *argv[3:]] if argv[:3] == BINPICK else ["python", *argv[1:]]))
    before = runs_under(runs)
    out = data_out(step.train) if step.train else None
    if out and not record.get("run"):
        record["run"] = out
    count_lost_attempts(record)
    started = time.time()
    attempt = {"command": shown, "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(started)), "commit": commit()}
    record["attempts"].append(attempt)
    record["status"] = "running"
    state.save()
    print(f"\n== {step.name}: {shown}", flush=True)
    child = subprocess.Popen(argv, cwd=ROOT, env=os.environ | {"PYTHONUNBUFFERED": "1"})
    try:
        while child.poll() is None:
            time.sleep(2)
            if step.train and not record.get("run"):  # the run folder the child made: resumable from now on
                new = sorted(runs_under(runs) - before)
                if new:
                    record["run"] = str(new[-1].relative_to(ROOT))
                    state.save()
    except KeyboardInterrupt:
        child.terminate()
        child.wait()
    seconds = time.time() - started
    count_lost_attempts(record, running=True)  # an attempt lost before this one began (a state from older code)
    record["seconds"] = round(record.get("seconds", 0.0) + seconds, 1)
    attempt |= {"seconds": round(seconds, 1), "exit": child.returncode}
    done = child.returncode == 0 and (not step.train or (record.get("run") and finished(ROOT / record["run"])))
    record["status"] = "done" if done else "interrupted"
    if done:
        record["finished_utc"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    state.save()
    hours = record["seconds"] / 3600
    if not done:
        raise SystemExit(f"{step.name} stopped (exit {child.returncode}) after {hours:.2f} h in all; "
                         f"the same command continues it: python tools/rebuild.py {state.folder.name}")
    print(f"== {step.name}: done in {hours:.2f} h of wall time ({record.get('run') or 'no run folder'})", flush=True)


def status(recipe: Recipe, state: State) -> None:
    print(f"{recipe.name}: {recipe.about}".rstrip(": "))
    for step in recipe.steps:
        record = state.step(step.name)
        what = step.train or " ".join(step.run)
        counted = json.loads(json.dumps(record))  # lost attempts' hours shown, not written (the run writes them)
        count_lost_attempts(counted, running=record["status"] == "running")
        seconds = counted.get("seconds", 0)
        if record["status"] == "running" and record.get("attempts"):  # this attempt's time so far
            started = calendar.timegm(time.strptime(record["attempts"][-1]["started_utc"], "%Y-%m-%dT%H:%M:%SZ"))
            seconds += max(0.0, time.time() - started)
        print(f"  {step.name:<14} {record['status']:<12} {seconds / 3600:6.2f} h  {what}"
              f"{'  -> ' + record['run'] if record.get('run') else ''}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("recipe", help="a recipe in configs/rebuild (photo, crop, ...)")
    parser.add_argument("--status", action="store_true", help="show the steps and stop")
    parser.add_argument("--until", help="stop after this step")
    parser.add_argument("--again", nargs="*", default=[], metavar="STEP",
                        help="run these steps and every later one again (new run folders)")
    args = parser.parse_args()
    os.chdir(ROOT)
    recipe = Recipe.load(args.recipe)
    runs = ROOT / "runs" / "rebuild" / recipe.name
    runs.mkdir(parents=True, exist_ok=True)
    state = State(runs)
    if args.status:
        status(recipe, state)
        return
    names = [step.name for step in recipe.steps]
    for name in [*args.again, *([args.until] if args.until else [])]:
        if name not in names:
            raise SystemExit(f"no step {name!r} in {recipe.name} (steps: {', '.join(names)})")
    lock = open(runs / "lock", "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise SystemExit(f"another rebuild of {recipe.name} is running (runs/rebuild/{recipe.name}/lock)") from None
    if args.again:  # a step made anew makes every later step anew too (they read its run folder)
        first = min(names.index(name) for name in args.again)
        for name in names[first:]:
            if state.step(name)["status"] != "pending":
                train = recipe.steps[names.index(name)].train
                print(f"== {name}: made anew" + (" (a data set resumes its folder: delete it to make it again)"
                                                 if train and data_out(train) else ""), flush=True)
            state.data["steps"][name] = {"status": "pending", "seconds": 0.0, "attempts": []}
    state.save()
    for step in recipe.steps:
        if state.step(step.name)["status"] == "done":
            print(f"== {step.name}: done ({state.step(step.name).get('run') or 'ran'}), skipped", flush=True)
        else:
            run_step(step, state, runs)
        if step.name == args.until:
            break
    status(recipe, state)


if __name__ == "__main__":
    main()
