"""Shared fixtures: every test runs headless (MUJOCO_GL=egl unless the caller chose otherwise); under
pytest-xdist (``make test`` runs three test processes on two cores) every worker computes on one thread."""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
if os.environ.get("PYTEST_XDIST_WORKER"):  # several test processes (make test): one thread each, or
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # torch's threads of two processes fight over 2 cores
    os.environ.setdefault("LP_NUM_THREADS", "0")  # and so do Mesa's software renderer's (EGL): render in the caller's thread
# Ray Train's controller looks at its workers every 2 s by default: each tiny run here would wait up to
# that long at every start, end and restart (the Ray processes a test starts inherit this)
os.environ.setdefault("RAY_TRAIN_HEALTH_CHECK_INTERVAL_S", "0.2")
# Ray lowers its workers' priority (niceness 15): beside two busy test processes a Ray test's workers got almost no
# CPU, so the test (and its cluster, and its controller's checks) lasted minutes for seconds of work
os.environ.setdefault("RAY_worker_niceness", "0")

import pytest  # noqa: E402

import binpick  # noqa: E402,F401  (registers the envs)

MUJOCO_ENV_IDS = [i for i in binpick.ENV_IDS if not i.endswith("Arm2D-v0")]


@pytest.fixture
def make_env():
    """binpick.make that closes every env it made, so GL contexts never pile up across tests."""
    made = []

    def _make(env_id: str, **kwargs):
        env = binpick.make(env_id, **kwargs)
        made.append(env)
        return env

    yield _make
    for env in made:
        env.close()


def train_rl_run(config: dict, root: Path) -> Path:
    """``binpick rl train`` of ``config`` (a mapping) under ``root``: the run folder."""
    import yaml

    (root / "run.yaml").write_text(yaml.safe_dump(config))
    result = binpick_here(["rl", "train", root / "run.yaml", "--runs", root / "runs"])
    assert result.returncode == 0, result.stderr
    (run,) = (root / "runs" / config["name"]).iterdir()
    return run


@pytest.fixture(scope="module")
def ray_cluster():
    """A private Ray cluster (127.0.0.1, 2 CPUs) for the tests of a module that a test process runs: each
    run of a test that asks for it joins it instead of starting its own. (Per module, not once per test
    process: a cluster left idle under the rest of a process's tests once hung in ``ray.shutdown``.)"""
    import ray

    from binpick.core.cluster import start_ray

    start_ray(None, 2)
    yield
    ray.shutdown()


# The longest tests (CPU seconds measured on a 2-core machine, Ray's processes included) start first, dealt
# among the test processes. pytest-xdist's work stealing first splits the collection into one contiguous
# block per test process and later steals from the ends of the blocks: long tests sorted to the front of
# the collection would all land in the first block and run one after another in one process.
LONG = {"test_readme.py::test_every_readme_block_runs_on_tiny_settings": 140,
        "test_ray_train.py::test_two_workers_take_the_local_grasp_quality_run_s_steps_and_a_killed_worker_is_replaced": 60,
        "test_distributed.py::test_gp_her_from_an_rl_yaml_on_ray_simulators_ends_as_a_run_without_the_fault": 50,
        "test_distributed.py::test_a_killed_driver_resumes_on_ray_with_the_steps_and_evaluations_of_an_uninterrupted_run": 40,
        "test_april.py::test_april_pipeline_runs_resumes_and_deploys_from_pixels": 40,
        "test_a3c.py::test_a3c_run_with_curriculum_resumes_and_evaluates": 35,
        "test_readme.py::test_each_standalone_readme_command_runs_on_tiny_settings": 15,
        "test_arm.py::test_the_arm_picks_with_its_suction_cup": 28,
        "test_resume.py::test_a3c_run_killed_at_a_boundary_resumes_with_every_evaluation_once": 14,
        "test_detection.py::test_training_learns_the_toy_set_resumes_and_predicts": 27,
        "test_ray_train.py::test_two_ray_workers_share_the_local_detector_run_s_steps": 25,
        "test_distributed.py::test_a3c_from_an_rl_yaml_on_ray_actors_ends_as_a_run_without_the_fault": 20,
        "test_ray_train.py::test_one_ray_worker_trains_exactly_the_local_pickability_head": 20}


def block_sizes(count: int, processes: int) -> list[int]:
    """The sizes of the blocks pytest-xdist's work stealing hands its test processes at the start."""
    sizes: list[int] = []
    for remaining in range(processes, 0, -1):
        sizes.append((count - sum(sizes)) // remaining)
    return sizes


def long_test_weight(item) -> float:
    return LONG.get(item.nodeid.split("/")[-1].split("[")[0], 0)  # [params]: each parameter weighs as the test


def deal_long_tests_first(items: list, processes: int) -> list:
    """``items`` reordered so that each test process's first block starts with its share of the long
    tests (longest first, each to the least loaded block), the rest in collection order after them."""
    long = sorted((item for item in items if long_test_weight(item)), key=long_test_weight, reverse=True)
    rest = [item for item in items if not long_test_weight(item)]
    blocks: list[list] = [[] for _ in range(processes)]
    loads = [0.0] * processes
    for item in long:
        index = loads.index(min(loads))
        blocks[index].append(item)
        loads[index] += long_test_weight(item)
    ordered = []
    for block, size in zip(blocks, block_sizes(len(items), processes)):
        fill = max(0, size - len(block))
        ordered += block + rest[:fill]
        rest = rest[fill:]
    return ordered + rest


@pytest.fixture(autouse=True)
def _one_torch_thread_per_worker():
    """A trainer run in-process (``detect train``, ``grasp train``) sets torch's thread count from its
    config; under several test processes that count must not outlive the test and oversubscribe the rest."""
    yield
    if os.environ.get("PYTEST_XDIST_WORKER"):
        import torch

        torch.set_num_threads(1)


def pytest_collection_modifyitems(config, items):
    processes = int(getattr(config, "workerinput", {}).get("workercount", 1))
    items[:] = deal_long_tests_first(items, processes)


ON_CI = os.environ.get("CI", "").lower() in ("true", "1", "yes")


def _skip_fails_on_ci(report) -> None:
    """On CI (``CI=true``) a skip is a failure: the README's set-up installs ROS 1, ROS 2, ONNX Runtime
    and Rerun, so a test that skips because one is missing there means a broken install, not a pass."""
    if ON_CI and report.skipped and not hasattr(report, "wasxfail"):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        report.outcome = "failed"
        report.longrepr = f"skipped on CI (CI=true), which installs everything the suite needs: {reason}"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    _skip_fails_on_ci(outcome.get_result())


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    _skip_fails_on_ci(outcome.get_result())


def run_cli(args: list[str], capsys, monkeypatch, cwd: Path | None = None) -> tuple[int, str]:
    """``binpick ARGS`` in this process (in ``cwd``): its exit code and what it printed on stderr;
    never a traceback (asserted here)."""
    import sys

    from binpick.cli import main

    if cwd is not None:
        monkeypatch.chdir(cwd)  # nothing a case writes lands in the repository
    monkeypatch.setattr(sys, "argv", ["binpick", *args])
    with pytest.raises(SystemExit) as exit_info:
        main()
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return exit_info.value.code, err


def binpick_here(args: list[str], cwd: Path | None = None, env: dict[str, str] | None = None):
    """``binpick ARGS`` through its real entry point, in this test process: a
    :class:`subprocess.CompletedProcess` (exit code, stdout, stderr) as ``subprocess.run`` gives.

    For the runs a test makes to set the stage or to finish one (a resume, an evaluation, a refused
    config), where the process itself (its signals, its end on a kill) is not what the test is about: it
    saves an interpreter start and the imports of torch, SB3 and MuJoCo (2-3 s of CPU each time).
    ``env``: variables set for the call only."""
    import contextlib
    import io
    import subprocess
    import sys

    from binpick.cli import main

    previous, saved_argv, saved_env = Path.cwd(), sys.argv, dict(os.environ)
    out, err = io.StringIO(), io.StringIO()
    try:
        os.environ.update(env or {})
        if cwd is not None:
            os.chdir(cwd)
        sys.argv = ["binpick", *map(str, args)]
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main()
                code = 0
            except SystemExit as exit_:
                code = exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 1)
    finally:
        os.chdir(previous)
        sys.argv = saved_argv
        for key in set(os.environ) - set(saved_env):  # only what changed is put back: other threads (Ray's,
            del os.environ[key]  # gRPC's) read the environment while this runs
        os.environ.update({key: value for key, value in saved_env.items() if os.environ.get(key) != value})
    return subprocess.CompletedProcess(["binpick", *map(str, args)], code, out.getvalue(), err.getvalue())
