"""Every command block of the README and of the docs' guides runs, as written, on tiny settings.

The ```bash and ```python blocks of the README, then of each page in the docs site's order
(mkdocs.yml's nav), are read from the files themselves and run in order in one scratch folder (with the repository's ``configs/`` beside them), so a command that a later one
depends on (a data set, a run folder) is there when it is needed. The only changes are the ones
in :data:`TINY`: smaller numbers (``--scenes 2000`` -> 6, ``--episodes 100`` -> 1) and ``--set``
overrides that shrink training budgets; ``<time>`` becomes the newest run folder, and the ROS port
a free one. The few lines that cannot run on one machine are listed in :data:`SKIPPED` with the
reason; anything else new in the README is run automatically.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cli_zygote
import pytest
import yaml
from conftest import binpick_here

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def documents() -> list[Path]:
    """The README, then every page of the docs site in its nav order."""
    import yaml as _yaml

    def pages(node) -> list[str]:
        if isinstance(node, str):
            return [node]
        if isinstance(node, dict):
            return [p for value in node.values() for p in pages(value)]
        return [p for item in node for p in pages(item)]

    nav = _yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"]
    return [README, *(ROOT / "docs" / page for page in pages(nav))]

SKIPPED = {
    "make demo": "runs `binpick demo`, which tests/test_pipeline.py runs; here it would reinstall .venv",
    "make test": "the test suite itself",
    "tensorboard --logdir runs": "a web server that runs until stopped",
    "ray start --head --port=6379 --num-cpus=1": "Ray's own command, for a cluster of several machines",
    "ray start --address=A_HOST:6379 --num-cpus=8": "needs the machines B, C, ... of a cluster",
    "binpick rl distributed --workers 16 --address A_HOST:6379": "needs the cluster above (a local Ray run is tested)",
    "binpick data generate --out runs/data/random_20k --scenes 20000 --domain random --policies '' --held-out can,mug,toy "
    "--scenes-per-world 16 --address A_HOST:6379": "needs a cluster (tests/test_domain.py runs Ray scene workers locally)",
    "python experiments/rod.py pretrain --runs runs/rod16": "a benchmark on the full data sets (hours on a CPU); "
                                                           "the commands above run its pieces",
    "python experiments/rod.py finetune --runs runs/rod16": "a benchmark, after the one above",
    "python experiments/rod.py generalise --runs runs/rod16": "a benchmark, after the two above",
    "binpick ros pick-node --camera runs/frame/camera.yaml --master http://127.0.0.1:11311/": "a node that serves until stopped, "
        "with nothing here to ask it; tests/test_ros.py runs the whole loop through it",
    "unshare -n sh -c 'ip link set lo up && exec .venv-ros2/bin/binpick ros2 pick-node --params ros/ros2/pick_node.yaml'":
        "a node that serves until stopped; tests/test_ros2.py starts it from the same parameter file and runs the whole loop "
        "through it in a namespace",
    "ROS_PACKAGE_PATH=$PWD/ros:$ROS_PACKAGE_PATH roslaunch binpick pick_node.launch params:=$PWD/my_node.yaml": "a node that "
        "serves until stopped, from your own parameter file; tests/test_ros.py launches it from the shipped one",
    "ROS_PACKAGE_PATH=$PWD/ros:$ROS_PACKAGE_PATH roslaunch binpick pick_node.launch params:=$PWD/my_pick_node.yaml": "as above, "
        "in the first-pick guide",
    "python ros/binpick/examples/plan_client.py --product robosuite/milk": "needs the node above; tests/test_ros.py runs "
        "the client against the launched node",
    "python ros/binpick/examples/plan_client.py --product my/product": "needs your node and product; tests/test_ros.py runs "
        "the client",
    "python experiments/plan.py files": "a benchmark (50 orders, each planned twice); tests/test_picking.py runs its pieces",
    "python experiments/plan.py latency": "a benchmark on an idle machine; tests/test_ros.py and test_ros2.py run its loops",
    "binpick train configs/detection/rod_warehouse.yaml --address local --workers 2": "Ray Train on the full config "
        "(hours); tests/test_ray_train.py trains a small detector on one and two Ray workers, one of them killed",
    "binpick train configs/detection/rod_warehouse.yaml --address A_HOST:6379 --workers 8": "needs a cluster",
    "binpick train --resume runs/rod_warehouse/<time> --address A_HOST:6379 --workers 8": "needs a cluster",
    "binpick train configs/rl/rl_arm2d_curriculum_keypoints_bottleneck_deep.yaml --address A_HOST:6379 --set a3c.workers=16":
        "needs a cluster (tests/test_distributed.py runs an A3C YAML on local Ray actors)",
    "binpick train configs/rl/rl_fetchreach_gp_her.yaml --address A_HOST:6379 --workers 8": "needs a cluster "
        "(tests/test_distributed.py runs a GP + HER YAML on local Ray simulator actors)",
    "binpick data generate --out runs/data/bins_learnt_3000 --scenes 3000 --policies learnt --held-out can,mug,toy "
    "--set split_rule=random --address A_HOST:6379": "needs a cluster (tests/test_domain.py runs Ray scene workers locally)",
    "binpick data generate --out runs/data/bins_learnt --scenes 1000 --policies learnt --held-out can,mug,toy "
    "--set split_rule=random --address A_HOST:6379": "needs a cluster",
    "binpick train configs/detection/rod_finetune_photo_learnt.yaml --address A_HOST:6379 --workers 8": "needs a cluster "
        "(tests/test_ray_train.py trains a small detector on local Ray Train workers)",
    "nohup python tools/rebuild.py photo > runs/rebuild/photo.log 2>&1": "hours of CPU (tests/test_train.py checks every "
        "recipe's configs; the --status line runs here)",
    "python tools/rebuild.py photo --again finetune": "makes a fine-tune anew, after the hours of the line above",
    "binpick demo --gripper jaws": "the demo with another hand (tests/test_suction_planning.py plans for a jaws-only cell)",
    "binpick data generate --out runs/data/grasp_trials_both_realistic --scenes 600 --policies '' --grasp-trials 3 --gripper both "
    "--copies 3,6 --distractors 2,3 --held-out can,mug,toy --sensor realistic --workers 1": "hours of trials "
        "(tests/test_suction_planning.py records suction trials on a tiny set and trains on them)",
    "python experiments/grasp.py suction": "a benchmark on the trials above",
    "python experiments/grasp.py calibrate": "a benchmark on the trials above",
    "python experiments/rod.py photo --weights runs/rod_finetune_photo_learnt/<time> rod_photo_learnt_tiny_320": "needs "
        "the cluster training above (tests/test_shipping.py checks the choice)",
    "python experiments/rod.py ship-best --candidates runs/rod_finetune_photo_learnt/<time>": "needs the cluster "
        "training above",
    "python experiments/pick.py --robot panda --orders 50": "a benchmark (100 orders with the arm); tests/test_arm.py runs one",
    "binpick demo --robot panda --orders 2": "the demo's orders made by the arm (about half a minute an order here); "
                                            "tests/test_arm.py runs one through the same pipeline, report included",
    "python experiments/grasp.py eval": "a benchmark (40 bins of held-out products, the shipped grasp model); "
                                       "tests/test_grasping.py runs its pieces",
}

TINY_RL = {"total_timesteps": 150, "checkpoint_every": 75, "eval.every": 150, "eval.episodes": 1, "gp.warmup_episodes": 2,
           "gp.iterations": 3, "gp.batch_episodes": 8, "gp.imagined_per_real": 1, "gp.max_points": 60,
           "replay.capacity_episodes": 100, "sac.batch_size": 16, "sac.net_arch": "[8,8]"}
# (regular expression, replacement) on each command: smaller numbers, then shorter training
TINY: list[tuple[str, str]] = [
    (r"--scenes 20000\b", "--scenes 6"),  # randomised: 3 worlds of 2 below, one of them val (the anchors need the boxes of 4 scenes)
    (r"--scenes-per-world 16\b", "--scenes-per-world 2"),  # (each randomised world costs more than its scenes)
    (r"--scenes 120\b", "--scenes 4"),
    (r"--scenes 6000\b", "--scenes 8 --scenes-per-world 4"),  # the larger fine-tuning set: two worlds
    (r"--scenes 2000\b", "--scenes 6 --scenes-per-world 2"),  # 3 worlds of 2: one each for val, test and train (split_rule=random)
    (r"--scene 12\b", "--scene 4"),  # a scene the 6 above hold
    (r"--policies x,y", "--policies y"),  # the one the rod_* configs and `data show --policy y` read
    (r"--scenes 400\b", "--scenes 4 --scenes-per-world 1 --val-fraction 0.5"),
    (r"--scenes 800\b", "--scenes 4 --scenes-per-world 1 --val-fraction 0.5"),  # grasp trials: train and val worlds
    (r"--photo-views \d+", "--photo-views 0"),  # (each view renders all 40 products: ~10 s; views are test_warehouse_data's and test_verifier's)
    (r"--grasp-trials \d+", "--grasp-trials 1"),
    (r"--workers \d+", "--workers 1"),
    (r"--orders \d+", "--orders 1"),
    (r"--episodes \d+", "--episodes 1"),
    (r"\bepisodes=\d+", "episodes=2"),  # evaluate_policy(..., episodes=100) in the Python blocks
    (r"--steps \d+", "--steps 60"),
    (r"^binpick envs tour$", "binpick envs tour --episodes 1"),
    (r"^binpick demo$", "binpick demo --orders 1"),
    (r"^(binpick (?:rl )?train configs/rl/\S+.*)$", r"\1 " + " ".join(f"--set {k}={v}" for k, v in TINY_RL.items())),
    (r"total_timesteps=300, eval__every=300", "total_timesteps=150, eval__every=150"),  # binpick.train(...) in Python
    (r"binpick\.train\(\"configs/rl/[^\n]*\)", lambda match: tiny_keywords(match.group(0))),
    (r"^(binpick april run configs/\S+.*)$", r"\1 --set collect.episodes=2 --set perception_training.epochs=1 "
                                            r"--set eval.episodes=1 --set policy.rl_config=tiny_rl.yaml"),
    (r"^(binpick grasp train configs/\S+.*)$", r"\1 --set epochs=1 --set batch_size=2 --set threads=1"),
    (r"^(binpick detect pickability configs/\S+.*)$", r"\1 --set epochs=1 --set width=4 --set threads=1"),
    (r"^(binpick detect train configs/\S+.*)$", r"\1 --set train.epochs=1 --set train.batch_size=4 --set train.workers=0 "
                                               r"--set train.threads=1 --set data.image_size=128 --set data.train_sizes=[96,128]"),
]


def readme_blocks() -> list[tuple[str, str, str]]:
    """(language, text, file:line) of every fenced block of the README and the guides, in reading order."""
    blocks = []
    for document in documents():
        language, lines, start = None, [], 0
        for number, line in enumerate(document.read_text().splitlines(), 1):
            if line.startswith("```"):
                if language is None:
                    language, lines, start = line[3:].strip() or "text", [], number
                else:
                    blocks.append((language, "\n".join(lines), f"{document.relative_to(ROOT)}:{start}"))
                    language = None
            elif language is not None:
                lines.append(line)
    return blocks


def commands(block: str) -> list[str]:
    """The block's command lines, comments removed (``#`` outside quotes ends a command)."""
    result = []
    for line in re.sub(r"\s*\\\n\s*", " ", block).splitlines():  # a line ending in a backslash goes on in the next
        command = re.split(r"\s+#\s", " " + line.strip() + " ", maxsplit=1)[0].strip()
        if command and not command.startswith("#"):
            result.append(command)
    return result


def tiny_keywords(call: str) -> str:
    """``binpick.train("configs/rl/rl_x.yaml", total_timesteps=300)`` with TINY_RL's settings as keywords
    (SECTION__KEY), except those the call sets itself."""
    given = set(re.findall(r"(\w+)=", call))
    extra = [f"{key.replace('.', '__')}={value}" for key, value in TINY_RL.items() if key.replace(".", "__") not in given]
    return call[:-1] + ", " + ", ".join(extra) + ")"


def tiny(command: str) -> str:
    for pattern, replacement in TINY:
        command = re.sub(pattern, replacement, command)
    return command


def resolve_times(command: str, folder: Path) -> str:
    """``runs/x/<time>`` -> the newest run folder under ``runs/x``."""
    def newest(match: re.Match) -> str:
        parent = folder / match.group(1)
        runs = sorted(p for p in parent.iterdir() if p.is_dir()) if parent.is_dir() else []
        assert runs, f"no run folder under {parent} for {command!r}"
        return str(runs[-1].relative_to(folder))

    return re.sub(r"([\w.\-/]+?)/<time>", newest, command)


def prepare(folder: Path, blocks) -> None:
    """What the README assumes a reader has: the repository's configs and tools, and the products YAML with its files."""
    shutil.copytree(ROOT / "configs", folder / "configs")
    shutil.copytree(ROOT / "tools", folder / "tools", ignore=shutil.ignore_patterns("__pycache__"))
    settings = {"name": "tiny_rl", "env": "FetchReach", "min_action_scale": 0.4, "gp": {"enabled": True}}
    for key, value in TINY_RL.items():
        section, _, leaf = key.rpartition(".")
        (settings.setdefault(section, {}) if section else settings)[leaf] = yaml.safe_load(str(value))
    (folder / "tiny_rl.yaml").write_text(yaml.safe_dump(settings))
    products = next(text for language, text, _ in blocks if language == "yaml" and "products:" in text)
    (folder / "products.yaml").write_text(products)
    from PIL import Image

    from test_own_products import write_box

    for entry in yaml.safe_load(products)["products"]:
        (folder / entry["mesh"]).parent.mkdir(parents=True, exist_ok=True)
        write_box(folder / entry["mesh"], 0.09, 0.05, 0.03)
        for name in [entry.get("texture"), entry.get("photo"), *entry.get("photos", [])]:
            if name:
                Image.new("RGB", (64, 64), (200, 60, 50)).save(folder / name)


OWN_PROCESS = ("binpick rl distributed", "binpick ros")  # Ray and rospy keep per-process state: a process each
# Commands that need nothing an earlier block made and make nothing a later one reads: they run in a test
# of their own (each in its own folder), so that with one test process per core they run beside the rest
STANDALONE = ("binpick rl distributed --env FetchReach", "binpick detect export rod_photo_learnt_tiny_320")


def run_block(language: str, text: str, folder: Path, environment: dict, only: str | None = None,
              done: set[str] | None = None) -> list[str]:
    """Run one block; returns what ran (for the failure message). ``only``: run just the block's
    command that starts with it (a :data:`STANDALONE` one); else every command but those. ``done``: the
    commands already run in this chain (a page that repeats one word for word, e.g. ``binpick demo
    --orders 1``, has it run once: the same command on the same folder shows nothing new)."""
    if language == "python":
        import contextlib
        import io

        code, previous = resolve_times(tiny(text), folder), Path.cwd()
        started = time.perf_counter()
        try:
            os.chdir(folder)
            with contextlib.redirect_stdout(io.StringIO()):
                exec(compile(code, "README.md", "exec"), {"__name__": "__readme__"})  # noqa: S102 - the README's own code
        finally:
            os.chdir(previous)
        return [f"{time.perf_counter() - started:5.1f} s  python: {code.splitlines()[1][:60]}"]
    ran, background = [], []
    port = None
    try:
        for command in commands(text):
            if command.rstrip(" &") in SKIPPED:
                continue
            if (only is None) == command.startswith(STANDALONE) or (only is not None and not command.startswith(only)):
                continue
            if "11311" in command:  # the README's ROS port: a free one here
                from binpick.integrations.ros1.master import free_port

                port = port or free_port()
                command = command.replace("11311", str(port))
            command = resolve_times(tiny(command), folder)
            if done is not None and not command.endswith("&"):
                if command in done:
                    ran.append(f"  run above  {command}")
                    continue
                done.add(command)
            words = shlex.split(command.rstrip(" &"))
            started = time.perf_counter()
            if words[0] == "binpick" and not command.endswith("&") and not command.startswith(OWN_PROCESS):
                result = binpick_here(words[1:], cwd=folder)  # saves an interpreter start and the imports
                assert result.returncode == 0, f"README command failed: {command}\n{result.stderr[-3000:]}"
                ran.append(f"{time.perf_counter() - started:5.1f} s  {command}")
                continue
            if words[0] == "python":  # the reader's python is the one binpick is installed in
                words = [sys.executable, *words[1:]]
            # binpick in a process of its own: forked from the test's CLI server, as a fresh process has it
            popen, run = (cli_zygote.popen, cli_zygote.run) if words[0] == "binpick" else (subprocess.Popen, subprocess.run)
            words = words[1:] if words[0] == "binpick" else words
            if command.endswith("&"):
                background.append(popen(words, cwd=folder, env=environment, stdout=subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL, start_new_session=True))
                time.sleep(0.5)
                continue
            result = run(words, capture_output=True, text=True, cwd=folder, timeout=600, env=environment)
            assert result.returncode == 0, f"README command failed: {command}\n{result.stderr[-3000:]}"
            ran.append(f"{time.perf_counter() - started:5.1f} s  {command}")
    finally:
        for process in background:
            os.killpg(process.pid, signal.SIGTERM)
            process.wait(timeout=20)
    return ran


@pytest.mark.timeout(900)
def test_every_readme_block_runs_on_tiny_settings(tmp_path):
    blocks = readme_blocks()
    prepare(tmp_path, blocks)
    environment = {**os.environ, "ROS_HOME": str(tmp_path / "ros"), "ROS_LOG_DIR": str(tmp_path / "ros" / "log"),
                   "COLUMNS": "120", "XDG_CACHE_HOME": str(tmp_path / "cache")}
    ran, done = [], set()
    for language, text, line in blocks:
        if language in ("bash", "python"):
            ran += run_block(language, text, tmp_path, environment, done=done)
    # what the README promises is there
    assert (tmp_path / "runs" / "show" / "FetchReachObstacle-v0.png").is_file()
    assert (tmp_path / "runs" / "show" / "FetchReachObstacle-v0_obs.png").is_file()
    assert (tmp_path / "runs" / "predict" / "overlay.png").is_file() and (tmp_path / "runs" / "predict" / "heatmap.png").is_file()
    for folder in ("sample", "pointed"):
        assert json.loads((tmp_path / "runs" / folder / "plan.json").read_text())["plans"], folder
    assert json.loads((tmp_path / "runs" / "detect" / "detections.json").read_text())["detections"]
    assert (tmp_path / "runs" / "milk_orders" / "results.json").is_file()
    assert len(ran) >= 25, ran
    print("\n".join(ran))


@pytest.mark.timeout(600)
@pytest.mark.parametrize("command", STANDALONE)
def test_each_standalone_readme_command_runs_on_tiny_settings(command, tmp_path):
    blocks = [(language, text) for language, text, _ in readme_blocks()
              if language == "bash" and any(line.startswith(command) for line in commands(text))]
    assert blocks, f"{command!r} is in no README or guide block any more: take it out of STANDALONE"
    prepare(tmp_path, readme_blocks())
    environment = {**os.environ, "COLUMNS": "120", "XDG_CACHE_HOME": str(tmp_path / "cache")}
    ran = [line for language, text in blocks for line in run_block(language, text, tmp_path, environment, only=command)]
    assert len(ran) == 1, ran
    print("\n".join(ran))


def test_skipped_lines_are_still_in_the_readme():
    """A skip list entry whose line left the README would hide nothing: keep the list true."""
    every = {command.rstrip(" &") for language, text, _ in readme_blocks() if language == "bash" for command in commands(text)}
    assert set(SKIPPED) <= every, sorted(set(SKIPPED) - every)
