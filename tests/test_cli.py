"""The ``binpick`` command as a person uses it: outputs, files written, and one-line errors."""

from __future__ import annotations

import json
import os
import subprocess

import pytest
import cli_zygote
from PIL import Image
from typer.testing import CliRunner

import binpick
from binpick.cli import app

runner = CliRunner()


def run_cli(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """The real console entry point in a fresh process, as a shell user would run it."""
    return cli_zygote.run(
        [*args],
        capture_output=True, text=True, timeout=120, env={**os.environ, **(env or {})},
    )


def test_envs_list_shows_every_id():
    result = runner.invoke(app, ["envs", "list"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    for env_id in binpick.ENV_IDS:
        assert env_id in result.output


def test_envs_show_writes_frame_and_observation(tmp_path):
    result = runner.invoke(app, ["envs", "show", "Arm2D", "--out", str(tmp_path), "--size", "128"])
    assert result.exit_code == 0, result.output
    assert Image.open(tmp_path / "Arm2D-v0.png").size == (128, 128)
    assert Image.open(tmp_path / "Arm2D-v0_obs.png").size == (64, 64)


def test_envs_show_fetch_with_grey_image_observation(tmp_path):
    result = runner.invoke(app, ["envs", "show", "binpick/FetchReach-v0", "--out", str(tmp_path), "--size", "96",
                                 "--set", "image=grey", "--set", "image_size=48"])
    assert result.exit_code == 0, result.output
    assert Image.open(tmp_path / "FetchReach-v0.png").size == (96, 96)
    observation = Image.open(tmp_path / "FetchReach-v0_obs.png")
    assert observation.size == (48, 48) and observation.mode == "L"


def test_envs_rollout_prints_length_and_success_and_writes_json(tmp_path):
    out = tmp_path / "rollout.json"
    result = runner.invoke(app, ["envs", "rollout", "Reacher", "--episodes", "4", "--out", str(tmp_path)],
                           env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "actions per episode" in result.output and "success" in result.output
    assert "binpick/Reacher-v0 · random: 1/4 (25%)" in result.output  # output not a terminal: plain progress lines
    assert "binpick/Reacher-v0 · random: 4/4 (100%)" in result.output
    summary = json.loads(out.read_text())
    assert summary["episodes"] == 4 and summary["max_episode_steps"] == 50
    assert 0 < summary["mean_length"] <= 50 and 0 <= summary["success_rate"] <= 1


@pytest.mark.parametrize(
    "args,expected",
    [
        (["envs", "rollout", "nope"], ["unknown env id 'nope'", *binpick.ENV_IDS]),
        (["envs", "rollout", "Arm2D", "--set", "goal_area=2"], ["goal_area", "[0.0, 1.0]", "2"]),
        (["envs", "rollout", "Arm2D", "--set", "tolerance=0"], ["tolerance", "(0.0, 0.5]"]),
        (["envs", "show", "FetchReach", "--set", "image_size=8"], ["image_size", "[16, 1024]", "8"]),
        (["envs", "show", "Reacher", "--set", "image=colour"], ["image", "'rgb'", "'grey'", "'colour'"]),
        (["envs", "show", "Reacher", "--size", "5000"], ["width", "[16, 1024]"]),
        (["envs", "show", "Reacher", "--set", "speed=3"], ["no parameter speed", "tolerance"]),
        (["envs", "rollout", "Arm2D", "--episodes", "0"], ["episodes", ">= 1"]),
        (["envs", "rollout", "Arm2D", "--set", "noequals"], ["KEY=VALUE"]),
    ],
)
def test_bad_input_gives_one_line_and_exit_code_2(args, expected, tmp_path):
    result = run_cli(*args)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr + result.stdout
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr
    for fragment in expected:
        assert fragment in lines[0]


def test_missing_opengl_platform_names_the_fix(tmp_path):
    result = run_cli("envs", "show", "FetchReach", "--out", str(tmp_path / "unused"), env={"MUJOCO_GL": "bogus"})
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    message = result.stderr.strip()
    assert len(message.splitlines()) == 1
    for fragment in ("MUJOCO_GL=bogus", "libegl1 libegl-mesa0 libgl1-mesa-dri", "MUJOCO_GL=egl", "libosmesa6"):
        assert fragment in message


def test_binpick_checks_names_what_works_and_fails_on_a_broken_renderer():
    result = run_cli("checks", env={"COLUMNS": "300"})
    assert result.returncode == 0, result.stdout + result.stderr
    for row in ("versions", "threads", "rendering", "shipped weights", "ROS 1", "ROS 2"):
        assert row in result.stdout
    assert "torch 2." in result.stdout and "MUJOCO_GL=egl" in result.stdout
    broken = run_cli("checks", env={"COLUMNS": "300", "MUJOCO_GL": "bogus"})
    assert broken.returncode == 1 and "fail" in broken.stdout and "libegl1" in broken.stdout, broken.stdout


def test_detect_predict_on_the_shipped_sample_finds_the_product_and_writes_its_folder(tmp_path):
    result = run_cli("detect", "predict", "--sample", "--out", str(tmp_path))
    assert result.returncode == 0, result.stderr
    detections = json.loads(result.stdout.strip().splitlines()[0])
    assert detections and all(d["score"] >= 0.3 for d in detections)
    written = json.loads((tmp_path / "detections.json").read_text())
    assert written["detections"] == detections and Image.open(tmp_path / "overlay.png").size == (640, 480)


def test_a_prediction_that_finds_nothing_says_its_best_score_and_the_threshold_that_shows_it(tmp_path):
    result = run_cli("detect", "predict", "--sample", "--min-score", "0.99")
    assert result.returncode == 0 and json.loads(result.stdout) == []
    hint = result.stderr.strip()
    assert hint.startswith("warning: no detection scores 0.99; the best scores 0.") and "--min-score 0." in hint, hint
    lowered = hint.rsplit("--min-score ", 1)[1].split()[0]
    shown = run_cli("detect", "predict", "--sample", "--min-score", lowered)
    assert json.loads(shown.stdout), shown.stderr


def test_shell_completion_completes_verbs_and_options():
    verbs = run_cli(env={"_BINPICK_COMPLETE": "complete_bash", "COMP_WORDS": "binpick de", "COMP_CWORD": "1"})
    assert verbs.returncode == 0 and verbs.stdout.split() == ["demo", "detect"], verbs.stdout + verbs.stderr
    option = run_cli(env={"_BINPICK_COMPLETE": "complete_bash", "COMP_WORDS": "binpick plan --pro", "COMP_CWORD": "2"})
    assert option.stdout.split() == ["--product-size"]
