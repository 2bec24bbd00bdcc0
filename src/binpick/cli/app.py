"""The `binpick` Typer app, its command groups, and what every command shares (console, --set, progress, errors)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from binpick.core.errors import ConfigError
from binpick.core.files import atomic_write, check_output_file, ensure_dir, parse_yaml
from binpick.cli.terminal import RichCallback

app = typer.Typer(help="Learned bin picking: simulated worlds, RL, APRiL and repeated object detection.",
                  no_args_is_help=True, pretty_exceptions_enable=False, add_completion=True)
envs_app = typer.Typer(help="The simulated worlds of the thesis (Gymnasium ids binpick/...).", no_args_is_help=True)
app.add_typer(envs_app, name="envs")
rl_app = typer.Typer(help="Reinforcement learning (thesis ch. 3): train and evaluate runs.", no_args_is_help=True)
app.add_typer(rl_app, name="rl")
april_app = typer.Typer(help="APRiL (thesis ch. 4): train the policy on state, deploy it on pixels.", no_args_is_help=True)
app.add_typer(april_app, name="april")
data_app = typer.Typer(help="Warehouse bin data sets with pickability from trial grasps (thesis §5.4.4, §6.3).",
                       no_args_is_help=True)
app.add_typer(data_app, name="data")
detect_app = typer.Typer(help="Repeated object detection (thesis ch. 5, §6.3): ROD and TDID.", no_args_is_help=True)
app.add_typer(detect_app, name="detect")
grasp_app = typer.Typer(help="Grasps from depth: train the grasp-quality model on simulated trials.",
                        no_args_is_help=True)
app.add_typer(grasp_app, name="grasp")
products_app = typer.Typer(help="The products binpick can generate bins of and pick: built in, or your own (--products YAML).",
                           no_args_is_help=True)
app.add_typer(products_app, name="products")
ros_app = typer.Typer(help="ROS 1 bridge (thesis §6.1.1): serve a binpick env as an action server, drive it over ROS.",
                      no_args_is_help=True)
app.add_typer(ros_app, name="ros")
ros2_app = typer.Typer(help="ROS 2 (PyPI's ros-rclpy wheels, in .venv-ros2): pick planning for a robot's camera.", no_args_is_help=True)
app.add_typer(ros2_app, name="ros2")

console = Console(markup=False)  # paths and names are printed as they are, never read as Rich markup
MAX_SEED = 2**32 - 1  # NumPy's legacy seeding (SB3, Gymnasium) takes 32-bit seeds


def seed_option(text: str):
    """A ``--seed`` option that takes only what every seeded library accepts: 0 .. 2^32 - 1."""
    return typer.Option("--seed", min=0, max=MAX_SEED, help=text)


SetOption = Annotated[list[str] | None, typer.Option("--set", metavar="KEY=VALUE", help="Env parameter KEY=VALUE (repeatable), e.g. --set goal_area=0.5")]
POLICIES = ("random",)
DEFAULT_POLICY = "learnt"
DEFAULT_GRIPPER = "both"  # the hand the demo, picks and plans use unless told: jaws and a suction cup  # the grasp policy of pick and demo: the best in results/grasp.json and results/pick.json


def _print_version(value: bool) -> None:
    if value:
        from binpick import __version__

        console.print(f"binpick {__version__}")
        raise typer.Exit()


@app.callback()
def _root(version: Annotated[bool, typer.Option("--version", callback=_print_version, is_eager=True,
                                                help="Print binpick's version and exit")] = False) -> None:
    pass


def parse_settings(pairs: list[str] | None) -> dict:
    """``["goal_area=0.5", "image=grey"]`` -> ``{"goal_area": 0.5, "image": "grey"}`` (YAML scalars)."""
    settings = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set expects KEY=VALUE, got {pair!r}")
        settings[key.strip()] = parse_yaml(value, f"--set {key.strip()}") if value.strip() else None
    return settings


def progress() -> RichCallback:
    """Progress bars on this command's console (``with progress() as callback: job.run(callback)``)."""
    return RichCallback(console)


@contextmanager
def job_progress(run_dir: Path, resume_command: str) -> Iterator[RichCallback]:
    """Progress bars for a resumable job; Ctrl-C or SIGTERM ends it (exit 130) with the command that
    continues it, after the job has written what it can."""
    try:
        with progress() as callback:
            yield callback
    except KeyboardInterrupt:
        print_error(f"interrupted: {run_dir} keeps every checkpoint written; continue with: {resume_command}")
        raise typer.Exit(130) from None


def _check_runtime(value: str) -> str:
    from binpick.core.config import check_choice

    return check_choice("--runtime", value, ("torch", "onnx"))  # before any work (a plan's folder is made later)


RuntimeOption = Annotated[str, typer.Option(callback=_check_runtime, help="Run the photo-conditioned detector in torch or onnx "
                                                                         "(ONNX Runtime; pip install 'binpick[onnx]')")]


def _check_gripper(value: str) -> str:
    from binpick.core.config import check_choice
    from binpick.grippers import GRIPPERS

    return check_choice("--gripper", value, GRIPPERS)


GripperOption = Annotated[str, typer.Option(callback=_check_gripper, help="The hand's tools: jaws, suction (a cup) or both "
                                                                         "(the planner chooses per detection; grasps only for tools the hand has)")]


def _check_robot(value: str) -> str:
    from binpick.core.config import check_choice

    return check_choice("--robot", value, ("floating", "panda", "ur5e"))


RobotOption = Annotated[str, typer.Option(callback=_check_robot, help="What executes the picks: floating (a gripper alone, "
                                                                     "fast), panda (a Franka Panda arm) or ur5e (a UR5e "
                                                                     "arm): IK, timed motion, its reach in the plan")]

CellOption = Annotated[Path | None, typer.Option(help="Your cell file (YAML): the gripper's tools, the jaws' stroke and "
                                                       "fingers, the cup, the TCP offset, the arm (see binpick.cell; "
                                                       "configs/cells/). Replaces --gripper")]


def load_cell(path: Path | None, robot: str | None = None):
    """The --cell file (None: none given), checked against ``robot``'s arm; a mistake in it is one line."""
    from binpick.cell import load_cell as load

    return load(path, robot)


PlanRobotOption = Annotated[str, typer.Option(callback=_check_robot, help="floating: any grasp goes; panda or ur5e: only grasps the "
                                                                         "arm of binpick's cell can take (its base at x -0.52, "
                                                                         "y 0.18 m in the base frame; the others are rejected "
                                                                         "with the reason)")]

RerunOption = Annotated[bool, typer.Option("--rerun", help="Also record each order in 3D to a Rerun .rrd file in the output "
                                                           "folder (pip install 'binpick[rerun]')")]


ResumeOption = Annotated[Path | None, typer.Option(help="Run folder to continue from its latest checkpoint")]
RunsOption = Annotated[Path, typer.Option(help="Where new run folders go")]
ConfigSetOption = Annotated[list[str] | None, typer.Option("--set", metavar="KEY=VALUE", help="Config override KEY=VALUE or SECTION.KEY=VALUE, applied "
                                                                        "before validation (repeatable), e.g. --set train.epochs=2")]


def start_or_resume(task: str, config: Path | None, resume: Path | None, runs: Path, overrides: dict, where=lambda job: ""):
    """A per-task command's job (:func:`binpick.core.jobs.open_job`): a new run of ``task`` from
    ``config`` (YAML + ``--set`` overrides, validated once) or ``--resume`` of one of its run folders;
    ``where(job)`` says how far a resumed run had come."""
    from binpick.core.jobs import open_job

    job = open_job(config, resume, task=task, runs=runs, overrides=overrides)
    console.print(f"resuming {resume}{where(job)}" if resume is not None else f"run folder: {job.run_dir}")
    return job


def fmt_metric(value) -> str:
    return "n/a" if value is None else f"{value:.3f}"


def parse_pair(text: str, name: str) -> tuple[int, int]:
    try:
        low, high = (int(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--{name} must be LOW,HIGH (two integers), got {text!r}") from None
    return low, high


def parse_dimensions(text: str, option: str = "--product-size") -> list[float]:
    """``L,W,H`` in metres, each in (0, 2]."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(0.0 < v <= 2.0 for v in values):
        raise ConfigError(f"{option} must be three lengths in metres L,W,H (each in (0, 2]), got {text!r}")
    return values


def product_library(products_file: Path | None):
    """The built-in products, plus a user's YAML of their own when given (checked as data generate checks it)."""
    from binpick.sim import default_library, load_products

    library = default_library()
    return load_products(products_file, library) if products_file is not None else library


def evaluate_with_progress(env, policy, label: str, episodes: int, seed: int) -> None:
    """Seeded evaluation episodes with a progress bar; prints the summary and closes the env."""
    from binpick.rl.common.evaluate import evaluate_policy

    try:
        with progress() as callback, callback.task(label, episodes) as task:
            result = evaluate_policy(policy, env, episodes=episodes, seed=seed, on_episode=lambda *_: task.update(advance=1))
    finally:
        env.close()
    console.print(result.summary())


def check_png_path(path: Path, option: str = "--out") -> Path:
    """A PNG path that can be written (checked before the work that fills it starts)."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ConfigError(f"{option} must end in .png, got {str(path)!r}")
    return check_output_file(path, option)


def save_png(array, path: Path, option: str = "--out") -> None:
    from PIL import Image

    path = check_png_path(path, option)
    atomic_write(path, lambda handle: Image.fromarray(array).save(handle, format="PNG"))


def warn(message: str | None) -> None:
    """``warning: <message>`` as one line on stderr (nothing for None)."""
    if message:
        Console(stderr=True, highlight=False).print(f"warning: {' '.join(message.split())}", markup=False, soft_wrap=True)


def output_folder(path: Path, option: str = "--out") -> Path:
    """``--out`` is a folder in every verb: a name like a file's (plan.json, frame.png) is what an older
    binpick took, so say what changed rather than make a folder of that name."""
    if Path(path).suffix.lower() in (".json", ".png", ".jpg", ".jpeg", ".gif", ".rrd", ".onnx"):
        raise ConfigError(f"{option} is a folder (the command names its files in it), got {str(path)!r}")
    return ensure_dir(path, option)


def print_error(message: str) -> None:
    """``error: <message>`` as one line on stderr; the message is never read as Rich markup."""
    from rich.text import Text

    line = " ".join(str(message).split())  # one line, whatever the message holds
    Console(stderr=True, highlight=False).print(Text.assemble(("error: ", "bold red"), line), soft_wrap=True)
