"""No file binpick reads can run code: every verb and loader that reads weights, checkpoints or
replay buffers, given a crafted pickle whose loading would create a marker file.

Each payload is first shown to be live (a plain unpickle does create the marker), so the tests below
can fail: they assert that binpick refuses the file in one line, or never opens it, and that the
marker was never created.
"""

from __future__ import annotations

import base64
import json
import os
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import binpick_here
import torch
import yaml

from conftest import run_cli, train_rl_run

TINY_RL = {"name": "tiny", "env": "FetchReach", "total_timesteps": 200, "checkpoint_every": 100, "min_action_scale": 0.4,
           "replay": {"capacity_episodes": 100, "her_additions": 1, "start_fraction": 0.01},
           "gp": {"enabled": True, "warmup_episodes": 2, "refit_every": 100, "imagined_per_real": 1, "batch_episodes": 8,
                  "iterations": 3, "max_points": 60},
           "sac": {"batch_size": 16, "net_arch": [8, 8]}, "eval": {"every": 100, "episodes": 1}}


class Payload:
    """Unpickling this calls ``open(marker, "w")``: proof that a file ran code."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def torch_payload(path: Path, marker: Path, **fields) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"format": "binpick-detector-1", "weights": Payload(marker), **fields}, path)
    return path


def pickle_payload(path: Path, marker: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(Payload(marker)))
    return path


def sb3_zip_payload(path: Path, marker: Path) -> Path:
    """A Stable-Baselines3 zip whose ``data`` holds a serialised (cloudpickled) object, as SB3 writes them."""
    path.parent.mkdir(parents=True, exist_ok=True)
    blob = base64.b64encode(pickle.dumps(Payload(marker))).decode()
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("data", json.dumps({"policy_class": {":type:": "<class>", ":serialized:": blob}}))
    return path


def object_npz_payload(path: Path, marker: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as handle:
        np.savez(handle, obs=np.array([Payload(marker)], dtype=object))
    return path


def object_npy_payload(path: Path, marker: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as handle:  # a handle: np.save would add .npy to the name
        np.save(handle, np.array([Payload(marker)], dtype=object), allow_pickle=True)
    return path


def test_the_payloads_are_live(tmp_path):
    """Loaded the unsafe way, each payload does run: so the tests below can fail."""
    loaders = [
        (torch_payload, lambda p: torch.load(p, weights_only=False)),
        (pickle_payload, lambda p: pickle.loads(p.read_bytes())),
        (object_npz_payload, lambda p: np.load(p, allow_pickle=True)["obs"]),
        (object_npy_payload, lambda p: np.load(p, allow_pickle=True)),
    ]
    for index, (make, unsafe_load) in enumerate(loaders):
        marker = tmp_path / f"ran_{index}"
        unsafe_load(make(tmp_path / f"payload_{index}", marker))
        assert marker.exists(), make.__name__
    marker = tmp_path / "ran_zip"
    with zipfile.ZipFile(sb3_zip_payload(tmp_path / "model.zip", marker)) as archive:
        data = json.loads(archive.read("data"))
    pickle.loads(base64.b64decode(data["policy_class"][":serialized:"]))
    assert marker.exists()


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory) -> Path:
    """A real (tiny) SAC + GP + HER run: its checkpoint is what a shared run folder holds."""
    return train_rl_run(TINY_RL, tmp_path_factory.mktemp("trained"))


def _run_folder(root: Path, name: str, config: dict, files: dict[str, object], marker: Path) -> Path:
    """A run folder whose latest checkpoint holds the given payload files."""
    run = root / name
    checkpoint = run / "checkpoints" / "ckpt-000000100"
    checkpoint.mkdir(parents=True)
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    (run / "checkpoints" / "latest").write_text(checkpoint.name)
    for file, make in files.items():
        make(checkpoint / file, marker)
    return run


def _verbs(root: Path, marker: Path, trained: Path) -> dict[str, tuple[list[str], str]]:
    """verb -> (arguments, the one line's fragment), each pointed at crafted files."""
    image = root / "scene.png"
    from PIL import Image

    Image.fromarray(np.full((64, 64, 3), 100, np.uint8)).save(image)
    coco = root / "coco.json"
    box = {"image_id": 1, "category_id": 1, "bbox": [4, 4, 10, 10], "area": 100, "iscrowd": 0}
    coco.write_text(json.dumps({"images": [{"id": 1, "file_name": "scene.png"}], "categories": [{"id": 1, "name": "t"}],
                                "annotations": [box | {"id": 1}, box | {"id": 2, "bbox": [30, 30, 10, 10]}]}))
    weights = torch_payload(root / "evil.pt", marker)
    disguised = pickle_payload(root / "evil.safetensors", marker)
    detector_run = root / "detector_run"
    torch_payload(detector_run / "model.pt", marker)
    detect_config = {"name": "d", "data": {"train": str(coco), "val": str(coco), "image_size": 64, "targets": "all"},
                     "train": {"epochs": 2, "batch_size": 2, "workers": 0}}
    detect_resume = _run_folder(root, "detect_resume", detect_config, {"state.pt": torch_payload}, marker)
    old_rl = _run_folder(root, "old_rl", TINY_RL, {"model.zip": sb3_zip_payload, "replay.pkl": pickle_payload,
                                                   "gp.pt": torch_payload}, marker)
    a3c_config = {"name": "a3c", "env": "Arm2D", "algorithm": "a3c", "total_timesteps": 100}
    a3c_run = _run_folder(root, "a3c_run", a3c_config, {"a3c.pt": torch_payload}, marker)
    (root / "a3c_more.yaml").write_text(yaml.safe_dump(a3c_config | {"total_timesteps": 300}))
    npz_run = root / "npz_run"
    shutil.copytree(trained, npz_run)
    latest = npz_run / "checkpoints" / (npz_run / "checkpoints" / "latest").read_text()
    object_npz_payload(latest / "replay.npz", marker)
    april = {"name": "a", "env": "FetchReach", "image": "grey",
             "policy": {"mode": "semantic", "rl_config": str(Path(__file__).parents[1] / "configs" / "rl" / "rl_fetchreach_gp_her.yaml")}}
    semantic = root / "april_semantic"
    semantic.mkdir()
    (semantic / "config.yaml").write_text(yaml.safe_dump(april))
    (semantic / "stages.json").write_text(json.dumps({"collect": {"sim_episodes": 1}, "perception": {},
                                                     "policy": {"semantic_run": str(trained), "sim_episodes": 1}}))
    torch_payload(semantic / "perception.pt", marker)
    latent = root / "april_latent"
    shutil.copytree(semantic, latent)
    (latent / "perception.pt").unlink()
    from binpick.april.perception import AutoPerception, PerceptionConfig, save_perception

    save_perception(AutoPerception(PerceptionConfig(latent=6, conditioned=6, channels=4), (64, 64, 1), 6),
                    latent / "perception.safetensors")
    (latent / "config.yaml").write_text(yaml.safe_dump(april | {"policy": april["policy"] | {"mode": "latent"}}))
    sb3_zip_payload(latent / "policy_latent.zip", marker)
    return {
        "detect predict --weights FILE.pt": (["detect", "predict", str(image), "--weights", str(weights), "--query-box", "1,1,5,5"],
                                             "refusing to load"),
        "detect predict --weights pickle named .safetensors": (["detect", "predict", str(image), "--weights", str(disguised),
                                                                "--query-box", "1,1,5,5"], "not a safetensors file"),
        "detect eval FILE.pt": (["detect", "eval", str(weights), "--data", str(coco)], "refusing to load"),
        "detect eval RUN (model.pt)": (["detect", "eval", str(detector_run), "--data", str(coco)], "refusing to load"),
        "pick --weights FILE.pt": (["pick", "--product", "robosuite/milk", "--weights", str(weights), "--out", str(root / "p")],
                                   "refusing to load"),
        "pick --grasp-weights pickle named .safetensors": (["pick", "--product", "robosuite/milk", "--grasp", "learnt",
                                                            "--grasp-weights", str(disguised), "--out", str(root / "g")],
                                                           "not a safetensors file"),
        "detect train --resume (state.pt)": (["detect", "train", "--resume", str(detect_resume)], "refusing to load"),
        "rl eval SB3 run (model.zip)": (["rl", "eval", str(old_rl)], "no policy.safetensors"),
        "rl eval A3C run (a3c.pt)": (["rl", "eval", str(a3c_run)], "refusing to load"),
        "rl train --resume (model.zip, replay.pkl, gp.pt)": (["rl", "train", "--resume", str(old_rl)], "older binpick"),
        "rl train --resume (object arrays in replay.npz)": (["rl", "train", "--resume", str(npz_run)], "replay.npz"),
        "rl train --init-from (a3c.pt)": (["rl", "train", str(root / "a3c_more.yaml"), "--init-from", str(a3c_run),
                                           "--runs", str(root / "runs")], "refusing to load"),
        "april eval (perception.pt)": (["april", "eval", str(semantic), "--episodes", "1"], "refusing to load"),
        "april eval (policy_latent.zip)": (["april", "eval", str(latent), "--episodes", "1"], "no policy_latent.safetensors"),
    }


def test_no_verb_runs_code_from_a_crafted_file(trained_run, tmp_path, capsys, monkeypatch):
    marker = tmp_path / "CODE_RAN"
    verbs = _verbs(tmp_path, marker, trained_run)
    for verb, (args, fragment) in verbs.items():
        code, err = run_cli(args, capsys, monkeypatch, tmp_path)
        lines = [line for line in err.splitlines() if line.strip()]
        assert code == 2 and len(lines) == 1 and fragment in lines[0], (verb, code, err)
        assert not marker.exists(), f"{verb} ran code from a file"
    print(f"{len(verbs)} verbs given crafted files, 0 executed: " + "; ".join(verbs))


def test_resume_never_opens_planted_pickles(trained_run, tmp_path):
    """A good checkpoint with pickles planted beside it (old names, as a shared folder might hold):
    the run resumes and finishes from the safetensors/npz/JSON files alone."""
    marker = tmp_path / "CODE_RAN"
    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    config = yaml.safe_load((run / "config.yaml").read_text())
    (run / "config.yaml").write_text(yaml.safe_dump(config | {"total_timesteps": 300}))
    latest = run / "checkpoints" / (run / "checkpoints" / "latest").read_text()
    sb3_zip_payload(latest / "model.zip", marker)
    pickle_payload(latest / "replay.pkl", marker)
    torch_payload(latest / "gp.pt", marker)
    result = binpick_here(["rl", "train", "--resume", str(run)])
    assert result.returncode == 0, result.stderr
    assert json.loads((run / "metrics.json").read_text())["sim_steps"] == 300
    assert not marker.exists()
    evaluated = binpick_here(["rl", "eval", str(run), "--episodes", "1"])
    assert evaluated.returncode == 0 and not marker.exists(), evaluated.stderr


def test_python_loaders_refuse_crafted_files(tmp_path):
    from binpick.core import tensorfile
    from binpick import Policy
    from binpick.detection import load_detector
    from binpick.core.errors import BinpickError
    from binpick.core.files import read_npz
    from binpick.core.depth import read_depth
    from binpick.grasping.quality import GraspQuality
    from binpick.april.perception import load_perception
    from binpick.rl.a3c.policy import load_a3c_policy
    from binpick.rl.gp_her.dynamics import GPDynamics
    from binpick.rl.common.persistence import load_saved_policy

    marker = tmp_path / "CODE_RAN"
    evil = torch_payload(tmp_path / "evil.pt", marker)
    disguised = pickle_payload(tmp_path / "evil.safetensors", marker)
    a3c = tmp_path / "a3c"
    torch_payload(a3c / "a3c.pt", marker)
    april = tmp_path / "april"
    april.mkdir()
    (april / "config.yaml").write_text(yaml.safe_dump({"name": "a", "env": "FetchReach", "policy": {
        "mode": "latent", "rl_config": str(Path(__file__).parents[1] / "configs" / "rl" / "rl_fetchreach_gp_her.yaml")}}))
    (april / "stages.json").write_text(json.dumps({"policy": {}}))
    torch_payload(april / "perception.pt", marker)
    calls = {
        "load_detector(.pt)": lambda: load_detector(evil),
        "load_detector(.safetensors)": lambda: load_detector(disguised),
        "load_perception": lambda: load_perception(evil),
        "GPDynamics.load": lambda: GPDynamics.load(disguised),
        "load_a3c_policy": lambda: load_a3c_policy(a3c),
        "load_saved_policy": lambda: load_saved_policy(disguised),
        "Policy.load": lambda: Policy.load(april),
        "tensorfile.load": lambda: tensorfile.load(evil, "binpick-detector-2"),
        "read_npz": lambda: read_npz(object_npz_payload(tmp_path / "evil.npz", marker)),
        "GraspQuality.load": lambda: GraspQuality.load(disguised),
        "read_depth(object .npy)": lambda: read_depth(object_npy_payload(tmp_path / "evil_depth.npy", marker)),
        "read_depth(.npz named .npy)": lambda: read_depth(object_npz_payload(tmp_path / "evil.npz", marker).rename(tmp_path / "zip.npy")),
    }
    for name, call in calls.items():
        with pytest.raises(BinpickError):
            call()
        assert not marker.exists(), f"{name} ran code from a file"


def test_plain_tensor_pt_files_of_older_binpick_still_load(tmp_path):
    """Older binpick .pt files hold only tensors and plain containers: torch.load(weights_only=True) reads them."""
    from binpick.detection import load_detector
    from binpick.detection.model import DetectorNetwork, ModelSpec

    model = DetectorNetwork(ModelSpec(), 64)
    torch.save({"format": "binpick-detector-1", "spec": {**ModelSpec().__dict__, "scales": [0.5, 1.0, 2.0]}, "image_size": 64,
                "query_size": 96, "weights": model.state_dict(), "config": {"name": "old"}}, tmp_path / "old.pt")
    loaded = load_detector(tmp_path / "old.pt")
    assert loaded.trained_config == {"name": "old"}
    assert all(torch.equal(a, b) for a, b in zip(model.state_dict().values(), loaded.state_dict().values()))
    assert os.path.getsize(tmp_path / "old.pt") > 0
