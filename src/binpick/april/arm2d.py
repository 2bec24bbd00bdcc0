"""APRiL for Arm2D: an A3C policy trained on the arm's semantic state, deployed on pixels (ch. 4's recipe
on ch. 3's task).

End to end from pixels A3C needs far more steps than on the state (319 actions after 1M pixel
steps, 20 after 2M state steps). APRiL's answer is to learn the policy on the state and give it, at
deployment, the state read off the image. What the state policy needs are positions (its input is
cos/sin of the joints, the end point and the goal), so the perception here regresses keypoints -- the
two elbows, the end point and the goal -- by a spatial soft-argmax over heat maps, which keeps them to
a fraction of a pixel; APRiL's flattening AE (6 stride-2 convolutions to a 1x1 map, m = n = 10, ω = 10)
left the end point 0.06 off on its own 20,000 training images after 8 epochs (a trial, not a benchmark
row), about the 0.07 success radius. The joint angles follow from the elbows.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from torch import nn
from torch.nn import functional as F

from binpick.core import tensorfile
from binpick.envs.arm2d import VIEW_HALF_WIDTH, Arm2DEnv
from binpick.core.errors import ConfigError, InputFileError
from binpick.core.runs import SILENT, RunCallback

KEYPOINTS = ("elbow_1", "elbow_2", "end_point", "goal")
FORMAT = "binpick-arm2d-keypoints-1"


class Arm2DKeypoints(nn.Module):
    """uint8 images (B, H, W, 3) -> keypoints (B, 4, 2) in the arm's world units."""

    def __init__(self, image_size: int = 64, channels: int = 32) -> None:
        super().__init__()
        self.image_size, self.channels = image_size, channels
        c = channels
        self.body = nn.Sequential(
            nn.Conv2d(3, c // 2, 5, stride=2, padding=2), nn.ReLU(),  # half resolution: 32 x 32 for 64 px
            nn.Conv2d(c // 2, c, 3, padding=1), nn.ReLU(),
            nn.Conv2d(c, c, 3, padding=1), nn.ReLU(),
            nn.Conv2d(c, c, 3, padding=2, dilation=2), nn.ReLU(),  # sees a joint's two links and its disc
            nn.Conv2d(c, c, 3, padding=2, dilation=2), nn.ReLU(),
            nn.Conv2d(c, len(KEYPOINTS), 1),
        )
        side = (image_size + 1) // 2
        # world coordinates of the heat map cells' centres (image rows run down, world y up)
        centres = (torch.arange(side, dtype=torch.float32) + 0.5) / side * 2 * VIEW_HALF_WIDTH - VIEW_HALF_WIDTH
        self.register_buffer("xs", centres)
        self.register_buffer("ys", -centres)

    def forward(self, images: torch.Tensor | np.ndarray) -> torch.Tensor:
        x = torch.as_tensor(np.asarray(images) if not torch.is_tensor(images) else images)
        if x.dim() == 3:
            x = x[None]
        if tuple(x.shape[1:]) != (self.image_size, self.image_size, 3):
            raise ConfigError(f"Arm2D keypoints expect RGB images of {self.image_size} px, got {tuple(x.shape[1:])}")
        maps = self.body(x.permute(0, 3, 1, 2).float() / 255.0)
        b, k, h, w = maps.shape
        weights = F.softmax(maps.view(b, k, h * w), -1).view(b, k, h, w)
        return torch.stack([(weights.sum(2) * self.xs).sum(-1), (weights.sum(3) * self.ys).sum(-1)], -1)

    @torch.no_grad()
    def keypoints(self, images) -> np.ndarray:
        self.eval()
        return self(images).numpy().astype(np.float64)


def true_keypoints(env: Arm2DEnv) -> np.ndarray:
    """The elbows, end point and goal of the env as it is now, (4, 2)."""
    return np.vstack([env.joint_positions()[1:], env.goal[None]])


def state_from_keypoints(points: np.ndarray) -> dict[str, np.ndarray]:
    """The goal env's observation dict (cos/sin of the joints, end point; achieved and desired goal)
    from the four keypoints: each joint's angle is its link's direction less the previous link's."""
    elbow_1, elbow_2, end, goal = np.asarray(points, np.float64)
    directions = [np.arctan2(*v[::-1]) for v in (elbow_1, elbow_2 - elbow_1, end - elbow_2)]
    angles = np.diff(np.r_[0.0, directions])
    return {"observation": np.r_[np.cos(angles), np.sin(angles), end], "achieved_goal": end.copy(),
            "desired_goal": goal.copy()}


def collect(images: int, seed: int, image_size: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Images of random poses and goals anywhere in the play area, with their keypoints."""
    env = Arm2DEnv(image_size=image_size, goal_conditioned=True, image="rgb", goal_area=1.0)
    pictures = np.empty((images, image_size, image_size, 3), np.uint8)
    points = np.empty((images, len(KEYPOINTS), 2), np.float32)
    for i in range(images):
        observation, _ = env.reset(seed=seed + i)
        pictures[i], points[i] = observation["image"], true_keypoints(env.unwrapped)
    env.close()
    return pictures, points


def train_keypoints(images: np.ndarray, points: np.ndarray, epochs: int = 10, batch_size: int = 64,
                    learning_rate: float = 2e-3, seed: int = 0, callback: RunCallback = SILENT,
                    ) -> tuple[Arm2DKeypoints, list[dict[str, float]]]:
    """Adam on the L1 keypoint error, cosine-annealed; per epoch the mean error of each keypoint."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = Arm2DKeypoints(images.shape[1])
    optimizer = torch.optim.Adam(model.parameters(), lr=learning_rate)
    steps = max(1, len(images) // batch_size)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=epochs * steps)
    target = torch.as_tensor(points)
    history = []
    with callback.task("keypoints", epochs) as task:
        for epoch in range(epochs):
            model.train()
            order = rng.permutation(len(images))
            errors = torch.zeros(len(KEYPOINTS))
            for step in range(steps):
                batch = order[step * batch_size:(step + 1) * batch_size]
                error = (model(images[batch]) - target[batch]).abs()
                loss = error.mean()
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
                schedule.step()
                errors += error.detach().norm(dim=-1).mean(0) / steps
            history.append({"epoch": epoch + 1, **{name: float(e) for name, e in zip(KEYPOINTS, errors)}})
            task.update(epoch + 1, status=f"end point {errors[2]:.4f} · goal {errors[3]:.4f}")
    return model.eval(), history


def keypoint_errors(model: Arm2DKeypoints, images: np.ndarray, points: np.ndarray) -> dict[str, float]:
    """Median and 95th-percentile distance of each keypoint on images it did not train on."""
    predicted = np.concatenate([model.keypoints(images[i:i + 256]) for i in range(0, len(images), 256)])
    distance = np.linalg.norm(predicted - points, axis=-1)
    return {f"{name}_{stat}": float(f(distance[:, k])) for k, name in enumerate(KEYPOINTS)
            for stat, f in (("median", np.median), ("p95", lambda d: np.percentile(d, 95)))}


def save_keypoints(model: Arm2DKeypoints, path: Path, **meta: Any) -> Path:
    return tensorfile.save(path, FORMAT, tensors=model.state_dict(),
                           meta={"image_size": model.image_size, "channels": model.channels, **meta})


def load_keypoints(path: Path) -> Arm2DKeypoints:
    weights, meta, _ = tensorfile.load(path, FORMAT, "Arm2D keypoint weights")
    try:
        model = Arm2DKeypoints(int(meta["image_size"]), int(meta["channels"]))
        model.load_state_dict(weights)
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        raise InputFileError(f"Arm2D keypoint weights {str(path)!r} describe no valid network ({error})") from None
    return model.eval()


class PixelsAsArm2DState(gym.ObservationWrapper):
    """Deployment: a policy trained on Arm2D's flattened state gets that state read off the image."""

    def __init__(self, env: gym.Env, perceive) -> None:
        super().__init__(env)
        if "image" not in env.observation_space.spaces:
            raise ConfigError("PixelsAsArm2DState needs Arm2D with goal_conditioned=True and an rgb image")
        self.perceive = perceive  # image -> (4, 2) keypoints
        self.state_space = spaces.Dict({k: v for k, v in env.observation_space.spaces.items() if k != "image"})
        self.observation_space = spaces.flatten_space(self.state_space)

    def observation(self, observation):
        points = self.perceive(observation["image"])
        return spaces.flatten(self.state_space, state_from_keypoints(np.asarray(points).reshape(len(KEYPOINTS), 2)))


@dataclass(frozen=True)
class ReadStateOffPixels:
    """An A3C ``wrap_env`` (binpick.rl.a3c.train): Arm2D's pictures in, the state its frozen keypoint network
    (weights at ``path``) reads off them out, so a state learner trains acting on pixels -- APRiL's split
    inside RL (through it, and through A3C's own coarser reading, the state learner learns Arm2D's
    single goal at its pace from the true state; the `a3c_reading_error` note (docs/notes.md)). A path, not a network, so
    it pickles into A3C's spawned workers; each loads the weights itself."""

    path: str

    def __call__(self, env: gym.Env) -> gym.Env:
        model = load_keypoints(Path(self.path))
        image = getattr(env.observation_space, "spaces", {}).get("image")
        if image is None or tuple(image.shape) != (model.image_size, model.image_size, 3):
            raise ConfigError(f"keypoint weights {self.path!r} read RGB images of {model.image_size} px: set env_kwargs "
                              f"{{goal_conditioned: true, image: rgb, image_size: {model.image_size}}}")
        return PixelsAsArm2DState(env, lambda picture: model.keypoints(picture)[0])
