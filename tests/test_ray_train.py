"""Training on a Ray cluster (Ray Train, gloo, loopback only): the detector, the pickability head and the
grasp-quality model. One worker is the local run, two share each step (without batch norm: the
local run's steps), a worker killed mid-run is replaced and the run ends as an uninterrupted one does
(each Ray Train fit starts a handful of actor processes: the tests make as few fits as they can)."""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
import cli_zygote
from synthetic_coco import make_coco

from binpick.core.config import from_dict
from binpick.core.errors import ConfigError
from binpick.core.files import read_json
from binpick.detection.config import DetectConfig
from binpick.detection.train import DetectorTrainer
from binpick.detection.weights_file import WEIGHTS_FILE
from binpick.integrations.ray.training import train_on_ray
from binpick.core.jobs import KINDS

DETECT, PICKABILITY, QUALITY = (KINDS[task].job for task in ("detect", "pickability", "grasp_quality"))



def tiny_config(tmp: Path, epochs: int) -> DetectConfig:
    coco = make_coco(tmp / "coco", images=8, size=64, seed=1)
    return from_dict(DetectConfig, {
        "name": "tiny_detect", "data": {"train": str(coco), "val": str(coco), "targets": "all", "image_size": 64, "augment": False},
        "train": {"epochs": epochs, "batch_size": 4, "warmup_steps": 1, "eval_every": 1, "workers": 0, "threads": 1}}, where="test")


def test_two_ray_workers_share_the_local_detector_run_s_steps(tmp_path, ray_cluster):
    """The detector on two workers: each takes half of every global batch, so the run makes the local
    run's steps and evaluations (its batch norm sees half a batch: the losses are close, not equal; a
    single worker's exactness is the pickability head's test below) and writes a local run's files."""
    config = tiny_config(tmp_path, epochs=2)
    local = DetectorTrainer.new(config, tmp_path / "local").run()
    run_dir = DetectorTrainer.new(config, tmp_path / "ray").run_dir
    remote = train_on_ray(run_dir, DETECT, workers=2)
    assert remote["steps"] == local["steps"] == 4  # 8 images, global batch 4, two epochs
    assert [h["epoch"] for h in remote["history"]] == [1, 2] and all(h.get("ap50") is not None for h in remote["history"])
    for name in ("metrics.json", WEIGHTS_FILE, "config.yaml"):
        assert (run_dir / name).is_file(), name
    assert list((run_dir / "tb").iterdir()) and list((run_dir / "checkpoints").glob("ckpt-*"))


def test_a_worker_s_own_error_is_raised_as_it_was_without_restarts_that_cannot_mend_it(tmp_path, monkeypatch):
    """A damaged data file met by the workers (not by the driver, which made the run before): the worker
    keeps binpick's error in the run folder and raises it; the group Ray Train restarts after that ends
    at once on the record, before any training; the driver raises the error in one line. Ray Train's
    own part (a failed worker's group restarted) is the kill test's below: here the workers' function runs
    in this process, under a stand-in for the trainer that fails the first group and restarts it."""
    import ray.train.torch

    import binpick.core.cluster
    from binpick.core.errors import InputFileError

    groups: list[str] = []

    class OneRestart:
        def __init__(self, worker, train_loop_config, **options):
            self.worker, self.settings = worker, train_loop_config
            assert options["run_config"].failure_config.max_failures >= 1  # Ray Train restarts a failed group

        def fit(self):
            try:
                self.worker(self.settings)
                groups.append("trained")
            except InputFileError:
                groups.append("failed")
                self.worker(self.settings)  # the restarted group
                groups.append("restarted and ended")
            return type("Result", (), {"error": None})()

    monkeypatch.setattr(ray.train.torch, "TorchTrainer", OneRestart)
    monkeypatch.setattr(binpick.core.cluster, "start_ray", lambda address, workers: False)
    config = tiny_config(tmp_path, epochs=1)
    run_dir = DetectorTrainer.new(config, tmp_path / "ray").run_dir
    Path(config.data.train).write_text("{not json")
    with pytest.raises(InputFileError, match="annotations.json") as raised:
        train_on_ray(run_dir, DETECT, workers=1)
    assert groups == ["failed", "restarted and ended"]
    assert "\n" not in str(raised.value) and "Traceback" not in str(raised.value)
    assert not list((run_dir / "checkpoints").glob("ckpt-*")) and not (run_dir / "metrics.json").exists()


def kill_a_worker_after_the_first_checkpoint(run_dir: Path, killed: list[tuple[int, bool]]) -> None:
    """SIGKILL one Ray Train worker once the run's first checkpoint is on disk; records (pid, whether the
    run had already ended then)."""
    deadline = time.monotonic() + 300  # Ray's workers run at niceness 15: beside busy test processes they start late
    while time.monotonic() < deadline and not list((run_dir / "checkpoints").glob("ckpt-*")):
        time.sleep(0.05)
    ours = _descendants(os.getpid())  # this test process's cluster only: another test process may be training on Ray too
    pids = [p for p in subprocess.run(["pgrep", "-f", "RayTrainWorker"], capture_output=True, text=True).stdout.split()
            if int(p) in ours]
    if pids:
        ended = (run_dir / "metrics.json").exists()
        os.kill(int(pids[-1]), signal.SIGKILL)
        killed.append((int(pids[-1]), ended))


def test_one_ray_worker_trains_exactly_the_local_pickability_head(tmp_path, ray_cluster):
    import torch

    from binpick.detection.model import DetectorNetwork, ModelSpec
    from binpick.detection.pickability_training import PickabilityConfig, PickabilityTrainer
    from binpick.detection.weights_file import save_detector

    train = make_coco(tmp_path / "train", images=16, seed=3, pickable=True, depth=True, pickable_rule="small")
    val = make_coco(tmp_path / "val", images=6, seed=4, pickable=True, depth=True, pickable_rule="small")
    torch.manual_seed(0)
    save_detector(DetectorNetwork(ModelSpec(), 128), tmp_path / "detector.safetensors")
    config = PickabilityConfig(detector=str(tmp_path / "detector.safetensors"), train=[str(train)], val=str(val),
                               epochs=2, batch_size=8, width=8, jittered=1, threads=1)
    local = PickabilityTrainer.new(config, tmp_path / "local").run()
    run_dir = PickabilityTrainer.new(config, tmp_path / "ray").run_dir
    remote = train_on_ray(run_dir, PICKABILITY, workers=1)
    assert remote["history"] == local["history"]  # losses and val AUCs, to the last digit
    assert (run_dir / "windows.safetensors").is_file() and (run_dir / "model.safetensors").is_file()


def test_two_workers_take_the_local_grasp_quality_run_s_steps_and_a_killed_worker_is_replaced(tmp_path, ray_cluster):
    """Two workers, one of them killed after the first checkpoint: Ray Train replaces it, the group
    resumes from that checkpoint, and the run ends as the single local process's uninterrupted run does
    (every epoch evaluated once, the same validation AUCs)."""
    from binpick.grasping.training import QualityTrainConfig, QualityTrainer
    from binpick.warehouse.dataset import DataGeneration
    from binpick.warehouse.generation import GenerateConfig

    data = tmp_path / "trials"
    DataGeneration.new(GenerateConfig(out=str(data), scenes=4, policies=["analytic"], grasp_trials=3, workers=1, image_size=128,
                                      copies=(2, 3), distractors=(0, 1), targets=["can", "procedural_box"], scenes_per_world=1,
                                      val_fraction=0.5)).run()
    epochs = 8
    config = QualityTrainConfig(data=str(data), epochs=epochs, batch_size=4, threads=1)
    local = QualityTrainer.new(config, tmp_path / "local").run()
    run_dir = QualityTrainer.new(config, tmp_path / "ray").run_dir
    killed: list[tuple[int, bool]] = []
    watcher = threading.Thread(target=kill_a_worker_after_the_first_checkpoint, args=(run_dir, killed), daemon=True)
    watcher.start()
    remote = train_on_ray(run_dir, QUALITY, workers=2)
    watcher.join(timeout=5)
    assert killed and not killed[0][1], f"no Ray Train worker was killed while the run went on: {killed}"
    assert [h["epoch"] for h in remote["history"]] == list(range(1, epochs + 1))  # no evaluation lost or repeated
    # each worker takes half of every batch and the gradients are averaged: the single process's step
    # (rank 0 logs the loss of its half, so the losses are compared loosely and the val AUCs exactly)
    assert [h["val_auc"] for h in remote["history"]] == pytest.approx([h["val_auc"] for h in local["history"]], abs=1e-6)
    assert remote["best_val_auc"] == pytest.approx(local["best_val_auc"], abs=1e-6)
    assert read_json(run_dir / "metrics.json")["epochs"] == epochs


def _descendants(root: int) -> set[int]:
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parent = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(parent, []).append(int(entry.name))
    found, stack = set(), [root]
    while stack:
        pid = stack.pop()
        found.add(pid)
        stack.extend(children.get(pid, []))
    return found


def test_the_private_cluster_listens_on_loopback_only(ray_cluster):
    """Every Ray process of the private cluster (this process's children) announces and listens on 127.0.0.1."""
    import ray

    @ray.remote
    def pid() -> int:
        return os.getpid()

    @ray.remote
    def environment() -> tuple[str | None, str | None]:
        return os.environ.get("GLOO_SOCKET_IFNAME"), os.environ.get("MUJOCO_GL")

    workers = set(ray.get([pid.remote() for _ in range(4)]))
    # the workers train with gloo on the loopback interface and render headless; this process's own environment is as it was
    assert ray.get(environment.remote()) == ("lo", os.environ.get("MUJOCO_GL", "egl")) and "GLOO_SOCKET_IFNAME" not in os.environ
    assert {node["NodeManagerAddress"] for node in ray.nodes()} == {"127.0.0.1"}
    ours = _descendants(os.getpid())
    assert workers <= ours
    listening = subprocess.run(["ss", "-ltnpH"], capture_output=True, text=True, check=True).stdout.splitlines()
    mine = [line for line in listening if any(f"pid={p}," in line for p in ours)]
    assert len(mine) >= 4, listening  # the GCS, the raylet, the workers
    for line in mine:
        local = line.split()[3].rsplit(":", 1)[0]
        assert local in ("127.0.0.1", "[::ffff:127.0.0.1]"), line


def test_ray_options_are_checked_before_a_run_folder_is_made(tmp_path):
    from binpick.core import jobs

    with pytest.raises(ConfigError, match="--workers goes with --address"):
        jobs.check_ray_job(jobs.KINDS["detect"], None, 2)
    with pytest.raises(ConfigError, match="workers setting"):  # a data set's Ray tasks come from its own config
        jobs.check_ray_job(jobs.KINDS["data"], "local", 2)
    with pytest.raises(ConfigError, match="rl, detect, pickability, grasp_quality, data"):  # what --address takes, named
        jobs.check_ray_job(jobs.KINDS["april"], "local", 1)
    with pytest.raises(ConfigError, match="a3c.workers"):  # A3C's rollout workers come from its own config
        jobs.check_ray_job(jobs.KINDS["rl"], "local", 2)
    with pytest.raises(ConfigError, match="HOST:PORT"):
        jobs.check_ray_job(jobs.KINDS["detect"], "not an address", 2)
    config = tmp_path / "rl.yaml"
    config.write_text("task: rl\nname: x\nenv: FetchReach\nalgorithm: sb3_sac_her\n")  # sac and a3c run on Ray
    result = cli_zygote.run(["train", str(config), "--address", "local", "--runs", str(tmp_path / "runs")],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode != 0 and "rl job (sb3_sac_her) trains here" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "runs").exists()
