"""`binpick checks`: what this machine can run (rendering, ROS 1 and 2, shipped weights, versions, threads),
each line a verdict and, where something is missing, the step that fixes it."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

import typer
from rich.table import Table
from rich.text import Text

from binpick.cli.app import app, console

PACKAGES = ("torch", "mujoco", "gymnasium", "gymnasium-robotics", "stable-baselines3", "gpytorch", "pycocotools",
            "opencv-python-headless", "ray", "safetensors", "mink", "ruckig", "onnxruntime", "rerun-sdk")
Check = tuple[str, str, str]  # (what, "ok" | "warn" | "fail", detail)


def _render() -> Check:
    """MuJoCo's offscreen renderer through EGL: every image binpick makes passes through it."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    backend = os.environ["MUJOCO_GL"]
    try:
        import mujoco

        started = time.perf_counter()
        model = mujoco.MjModel.from_xml_string('<mujoco><worldbody><light pos="0 0 1"/><geom type="box" size=".1 .1 .1" '
                                               'rgba="1 0 0 1"/><camera name="c" pos="0 0 1"/></worldbody></mujoco>')
        with mujoco.Renderer(model, 32, 32) as renderer:
            data = mujoco.MjData(model)
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, "c")
            frame = renderer.render()
        if frame.max() == 0:
            return "rendering", "fail", f"MUJOCO_GL={backend} rendered a black frame"
        return "rendering", "ok", f"MUJOCO_GL={backend}, a frame in {1000 * (time.perf_counter() - started):.0f} ms"
    except Exception as error:  # any failure here is the answer the check exists to give
        return ("rendering", "fail", f"MUJOCO_GL={backend}: {type(error).__name__}: {error}; as root: apt-get install "
                "libegl1 libegl-mesa0 libgl1-mesa-dri (docs/install.md)")


def _ros1() -> Check:
    from binpick.integrations.ros1 import ros_missing

    reason = ros_missing()
    return ("ROS 1 (rospy, actionlib)", "warn", reason) if reason else ("ROS 1 (rospy, actionlib)", "ok", "importable")


def _ros2() -> Check:
    """ROS 2 lives in its own interpreter (.venv-ros2): asked there, not here."""
    from binpick.integrations.ros2 import ros2_missing

    if ros2_missing() is None:
        return "ROS 2 (rclpy)", "ok", "importable in this interpreter"
    here = Path(sys.executable).parent.parent
    python = here.parent / ".venv-ros2" / "bin" / "python"
    if not python.is_file():
        return "ROS 2 (rclpy)", "warn", f"no {python}: scripts/setup.sh makes it (PyPI's ros-rclpy wheels)"
    probe = subprocess.run([str(python), "-c", "from binpick.integrations.ros2 import ros2_missing; print(ros2_missing() or 'ok')"],
                           capture_output=True, text=True, timeout=120)
    answer = (probe.stdout.strip().splitlines() or [probe.stderr.strip()[-200:]])[-1]
    return ("ROS 2 (rclpy)", "ok", f"importable with {python}") if answer == "ok" else ("ROS 2 (rclpy)", "warn", answer)


def _weights() -> Check:
    """The shipped models the demo and the planner load, read (not only found)."""
    from binpick.detection.detector import SHIPPED, shipped_weights
    from binpick.detection.verifier import SHIPPED as VERIFIER
    from binpick.detection.weights_file import read_detector_file
    from binpick.grasping.quality import SHIPPED as GRASP, GraspQuality
    from binpick.grasping.suction_quality import SHIPPED as SUCTION, SuctionQuality

    try:
        for name in SHIPPED:
            read_detector_file(shipped_weights(name))
        missing = [path.name for path in (GRASP, SUCTION, VERIFIER) if not path.is_file()]
        if not missing:
            GraspQuality.load(GRASP)
            SuctionQuality.load(SUCTION)
    except Exception as error:  # a damaged or missing file is the finding
        return "shipped weights", "fail", f"{error} (reinstall binpick)"
    if missing:
        return "shipped weights", "fail", f"missing {', '.join(missing)} (reinstall binpick)"
    return "shipped weights", "ok", f"{len(SHIPPED)} detectors, the jaws' and the suction cup's quality models and the product check"


def _arm() -> Check:
    """The arms (--robot panda, --robot ur5e): robosuite's model files, mink's IK and Ruckig's timing, one IK solve each."""
    try:
        from binpick.arm import ArmKinematics
        from binpick.sim.robot_arm import ARM_MODELS, RobotArm

        started = time.perf_counter()
        for model in ARM_MODELS.values():
            if not ArmKinematics(RobotArm(model)).solve([0.0, 0.0, 0.12], 0.0).ok:
                return "arms", "fail", f"the {model.name}'s IK missed a grasp in the middle of the bin"
        return "arms", "ok", (f"{' and '.join(ARM_MODELS)}: models, mink and Ruckig load; the cells and one IK solve each in "
                              f"{time.perf_counter() - started:.1f} s")
    except Exception as error:  # a missing model file or package is the finding
        return "arms", "warn", f"--robot panda and ur5e unavailable: {type(error).__name__}: {error}"


def _threads() -> Check:
    import torch

    cores, threads = os.cpu_count() or 1, torch.get_num_threads()
    omp = os.environ.get("OMP_NUM_THREADS", "unset")
    level = "warn" if threads > cores else "ok"
    return "threads", level, f"{cores} cores, torch uses {threads} threads (OMP_NUM_THREADS {omp})"


def _versions() -> Check:
    found, missing = [], []
    for name in PACKAGES:
        try:
            found.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            missing.append(name)
    detail = f"Python {platform.python_version()}; " + ", ".join(found)
    return "versions", "ok", detail + (f"; not installed: {', '.join(missing)}" if missing else "")


CHECKS: tuple[Callable[[], Check], ...] = (_versions, _threads, _render, _weights, _arm, _ros1, _ros2)


def run_checks() -> list[Check]:
    return [check() for check in CHECKS]


@app.command("checks")
def checks() -> None:
    """What this machine can run: rendering (EGL), ROS 1 and 2, the shipped weights, versions and
    threads. Exit 1 when something binpick needs is broken (ROS is optional: a warning)."""
    table = Table(title="binpick checks")
    for column in ("check", "", "detail"):
        table.add_column(column, no_wrap=column != "detail")
    results = run_checks()
    style = {"ok": "green", "warn": "yellow", "fail": "bold red"}
    for what, level, detail in results:
        table.add_row(what, Text(level, style=style[level]), Text(detail))
    console.print(table)
    if any(level == "fail" for _, level, _ in results):
        raise typer.Exit(1)
