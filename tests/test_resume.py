"""kill -9 at every boundary of a run's end, then ``--resume``: the resumed run finishes with the same
step count as an uninterrupted one, every evaluation once, and the wall time of both sessions.

Each killed run is a child process in which one function is wrapped to SIGKILL the process at the
boundary under test: after the last checkpoint, during the final evaluation, half-way through the
final checkpoint (its folder partly written) and during the final write of metrics/plots.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import binpick_here

# 250 steps: checkpoints at 50, 100, ..., 250 (the last one at the final step, by the callback),
# evaluations at 100, 200 and a final one at 250 that only run() makes
RL = {"name": "resume", "env": "FetchReach", "total_timesteps": 250, "checkpoint_every": 50, "min_action_scale": 0.4,
      "replay": {"capacity_episodes": 100, "her_additions": 1, "start_fraction": 0.01},
      "gp": {"enabled": True, "warmup_episodes": 2, "refit_every": 100, "imagined_per_real": 1, "batch_episodes": 8,
             "iterations": 3, "max_points": 60},
      "sac": {"batch_size": 16, "net_arch": [8, 8]}, "eval": {"every": 100, "episodes": 2}}

KILLERS = {
    # the run's last checkpoint is committed (by the callback at step 250), nothing after it
    "after_last_checkpoint": """
original = train.Trainer.save_checkpoint
def patched(self):
    path = original(self)
    if self.model.num_timesteps >= self.config.total_timesteps:
        die()
    return path
train.Trainer.save_checkpoint = patched
""",
    # inside the final evaluation (after the last checkpoint, before metrics.json)
    "during_final_evaluation": """
original = train.Evaluate.evaluate
def patched(self):
    if self.model.num_timesteps >= self.config.total_timesteps:
        die()
    return original(self)
train.Evaluate.evaluate = patched
""",
    # the final checkpoint half written: the algorithm is in the new folder, the policy is not
    "during_final_checkpoint_write": """
calls = []
original = train.save_policy
def patched(model, path, **meta):
    if model.num_timesteps >= 250:
        calls.append(path)
        if len(calls) == 2:  # the callback's checkpoint at 250 went through; run()'s own one dies
            die()
    return original(model, path, **meta)
train.save_policy = patched
""",
    # metrics.json and curves.png being written
    "during_final_write": """
original = train.atomic_write_json
def patched(path, data, indent=2):
    if str(path).endswith("metrics.json"):
        die()
    return original(path, data, indent)
train.atomic_write_json = patched
""",
}

HARNESS = """
import os, signal, sys
from pathlib import Path
from binpick.core.config import from_dict, load_yaml
from binpick.rl import train
from binpick.rl.config import RLConfig

def die():
    os.kill(os.getpid(), signal.SIGKILL)

{killer}
trainer = train.trainer_for(from_dict(RLConfig, load_yaml(sys.argv[1])), Path(sys.argv[2]))
trainer.run()
"""


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict:
    """The same run, not interrupted."""
    from conftest import train_rl_run

    run = train_rl_run(RL, tmp_path_factory.mktemp("reference"))
    for name in ("config.yaml", "metrics.json", "curves.png", "tb"):
        assert (run / name).exists(), name
    checkpoint = run / "checkpoints" / (run / "checkpoints" / "latest").read_text()
    assert {p.name for p in checkpoint.iterdir()} == {"algorithm.safetensors", "policy.safetensors", "replay.npz",
                                                     "replay.json", "state.json", "gp.safetensors"}  # and no pickle
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["her_episodes"] > 0 and metrics["gp_fits"] >= 1
    evaluation = binpick_here(["rl", "eval", run, "--episodes", "2"])
    assert evaluation.returncode == 0 and "actions per episode" in evaluation.stdout, evaluation.stderr
    wrong_env = binpick_here(["rl", "eval", run, "--env", "Reacher"])
    assert wrong_env.returncode == 2 and "trained on binpick/FetchReach-v0, not binpick/Reacher-v0" in wrong_env.stderr
    return metrics


@pytest.mark.parametrize("boundary", list(KILLERS))
def test_rl_run_killed_at_a_boundary_resumes_to_the_same_end(boundary, reference, tmp_path):
    (tmp_path / "rl.yaml").write_text(yaml.safe_dump(RL))
    killed = subprocess.run([sys.executable, "-c", HARNESS.format(killer=KILLERS[boundary]), str(tmp_path / "rl.yaml"),
                             str(tmp_path / "runs")], capture_output=True, text=True, timeout=300)
    assert killed.returncode == -9, (killed.returncode, killed.stderr[-2000:])
    (run,) = (tmp_path / "runs" / "resume").iterdir()
    latest = run / "checkpoints" / (run / "checkpoints" / "latest").read_text()
    wall_before = json.loads((latest / "state.json").read_text())["metrics"]["wall_seconds"]
    assert wall_before > 0
    resumed = binpick_here(["rl", "train", "--resume", run])
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["sim_steps"] == reference["sim_steps"] == RL["total_timesteps"]
    steps = [e["sim_steps"] for e in metrics["evaluations"]]
    assert steps == [e["sim_steps"] for e in reference["evaluations"]] == [100, 200, 250]
    assert metrics["wall_seconds"] >= wall_before - 0.1  # the killed session's time is kept (metrics.json rounds to 0.1 s)
    assert (run / "curves.png").is_file() and not list(run.glob("checkpoints/.partial-*"))


DETECT = """name: toy
data: {{train: {coco}, val: {coco}, targets: all, image_size: 64, augment: false}}
train: {{epochs: 3, batch_size: 4, warmup_steps: 1, eval_every: 1, workers: 0, threads: 1}}
"""
DETECT_KILLERS = {
    "during_last_evaluation": """
original = train.evaluate_model
def patched(model, dataset, *args, **kwargs):
    if trainer.epoch >= 3:
        die()
    return original(model, dataset, *args, **kwargs)
train.evaluate_model = patched
""",
    "after_last_checkpoint": """
original = train.DetectorTrainer._checkpoint
def patched(self):
    original(self)
    if self.epoch >= 3:
        die()
train.DetectorTrainer._checkpoint = patched
""",
    "during_final_weights": """
original = train.save_detector
def patched(*args, **kwargs):
    die()
train.save_detector = patched
""",
}
DETECT_HARNESS = """
import os, signal, sys
from pathlib import Path
from binpick.detection import train
from binpick.detection.config import DetectConfig
from binpick.core.config import load_config

def die():
    os.kill(os.getpid(), signal.SIGKILL)

{killer}
trainer = train.DetectorTrainer.new(load_config(DetectConfig, sys.argv[1]), Path(sys.argv[2]))
trainer.run()
"""


@pytest.mark.parametrize("boundary", list(DETECT_KILLERS))
def test_detector_run_killed_at_a_boundary_resumes_to_the_same_end(boundary, tmp_path):
    from synthetic_coco import make_coco

    coco = make_coco(tmp_path / "toy", images=4, size=64)
    (tmp_path / "rod.yaml").write_text(DETECT.format(coco=coco))
    killed = subprocess.run([sys.executable, "-c", DETECT_HARNESS.format(killer=DETECT_KILLERS[boundary]),
                             str(tmp_path / "rod.yaml"), str(tmp_path / "runs")], capture_output=True, text=True, timeout=300,
                            cwd=Path(__file__).parent)
    assert killed.returncode == -9, (killed.returncode, killed.stderr[-2000:])
    (run,) = (tmp_path / "runs" / "toy").iterdir()
    resumed = binpick_here(["detect", "train", "--resume", run])
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["epochs"] == 3 and [r["epoch"] for r in metrics["history"]] == [1, 2, 3]
    assert all("ap50" in r for r in metrics["history"])  # every evaluation, once
    assert (run / "model.safetensors").is_file()


A3C = {"name": "a3c", "env": "Arm2D", "env_kwargs": {"image_size": 32, "tolerance": 0.2}, "algorithm": "a3c",
       "total_timesteps": 200, "checkpoint_every": 100, "a3c": {"workers": 2, "n_steps": 10}, "eval": {"every": 100, "episodes": 1}}
A3C_KILLERS = {
    "during_last_evaluation": """
original = A3CTrainer.evaluate
def patched(self, area):
    if self.steps >= self.config.total_timesteps:
        die()
    return original(self, area)
A3CTrainer.evaluate = patched
""",
    "after_last_checkpoint": """
original = A3CTrainer.save_checkpoint
def patched(self):
    path = original(self)
    if self.steps >= self.config.total_timesteps:
        die()
    return path
A3CTrainer.save_checkpoint = patched
""",
}
A3C_HARNESS = """
import os, signal, sys
from pathlib import Path
from binpick.core.config import from_dict, load_yaml
from binpick.rl.a3c.train import A3CTrainer
from binpick.rl.config import RLConfig

def die():
    os.kill(os.getpid(), signal.SIGKILL)

{killer}
if __name__ == "__main__":  # the workers are spawned processes
    A3CTrainer.new(from_dict(RLConfig, load_yaml(sys.argv[1])), Path(sys.argv[2])).run()
"""


@pytest.mark.parametrize("boundary", list(A3C_KILLERS))
def test_a3c_run_killed_at_a_boundary_resumes_with_every_evaluation_once(boundary, tmp_path):
    (tmp_path / "a3c.yaml").write_text(yaml.safe_dump(A3C))
    script = tmp_path / "harness.py"
    script.write_text(A3C_HARNESS.format(killer=A3C_KILLERS[boundary]))
    killed = subprocess.run([sys.executable, str(script), str(tmp_path / "a3c.yaml"), str(tmp_path / "runs")],
                            capture_output=True, text=True, timeout=300)
    assert killed.returncode == -9, (killed.returncode, killed.stderr[-2000:])
    (run,) = (tmp_path / "runs" / "a3c").iterdir()
    resumed = binpick_here(["rl", "train", "--resume", run])
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    metrics = json.loads((run / "metrics.json").read_text())
    steps = [e["sim_steps"] for e in metrics["evaluations"]]
    # workers add 10-step rollouts asynchronously, so evaluations land at or just after 100 and 200 (and, as
    # in an uninterrupted run, once more at the final count when the workers went past the last one)
    assert metrics["sim_steps"] >= 200 and steps == sorted(set(steps)) and steps[-1] == metrics["sim_steps"]
    assert sum(100 <= s < 200 for s in steps) == 1 and sum(s >= 200 for s in steps) in (1, 2)
