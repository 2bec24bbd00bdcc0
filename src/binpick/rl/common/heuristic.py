"""A scripted pick-and-place policy (thesis §4.5.3: "a simple hand-crafted heuristic policy").

It decides from what the learnt policy sees too, s̄ = (gripper, object, goal) — not the finger
opening — so that behaviour cloning can imitate it: a policy cannot copy a decision made on an input
it does not have. It works in phases decided afresh at every step, so it recovers when the object
slips: over the object with the jaws open, down around it, close while rising slowly (the object
comes up only if the jaws hold it), then carry it to the goal. Its episodes are the demonstrations
that pretrain the actor by behaviour cloning, and its noisy runs give perception its images.
"""

from __future__ import annotations

import numpy as np

REST_HEIGHT = 0.4249  # the object's centre when it lies on Fetch's table (gymnasium-robotics height_offset)


class PickAndPlaceHeuristic:
    """Callable policy: Fetch pick-and-place dict observation -> action (Δx, Δy, Δz, gripper)."""

    def __init__(self, gain: float = 10.0, hover: float = 0.05, rise: float = 0.1, noise: float = 0.0,
                 seed: int | None = None, rest_height: float = REST_HEIGHT) -> None:
        self.gain, self.hover, self.rise, self.noise, self.rest_height = gain, hover, rise, noise, rest_height
        self.rng = np.random.default_rng(seed)

    def __call__(self, observation: dict) -> np.ndarray:
        gripper = observation["observation"][:3]
        target, obj = observation["desired_goal"], observation["achieved_goal"]
        offset = obj - gripper
        horizontal = np.linalg.norm(offset[:2])
        in_hand = horizontal < 0.02 and abs(offset[2]) < 0.03
        if in_hand and obj[2] > self.rest_height + 0.01:  # it came up with the gripper: carry it
            move, grip = (target - obj) * self.gain, -1.0
        elif horizontal > 0.015:  # line up above the object, jaws open
            move, grip = np.array([offset[0], offset[1], obj[2] + self.hover - gripper[2]]) * self.gain, 1.0
        elif offset[2] < -0.025:  # lower round it, jaws open
            move, grip = offset * self.gain, 1.0
        else:  # around it: close while rising slowly
            move, grip = np.array([offset[0] * self.gain, offset[1] * self.gain, self.rise]), -1.0
        action = np.clip(np.append(move, grip), -1.0, 1.0)
        if self.noise:
            action[:3] = np.clip(action[:3] + self.rng.normal(0, self.noise, 3), -1.0, 1.0)
        return action.astype(np.float32)


class ReachController:
    """A P-controller to the goal for Fetch reach envs, gripper still: ``clip(gain · (g − z), −1, 1)``
    (FACTS: 100% success in 3.1 actions on Fetch Reach). The reference that `binpick ros bench` drives
    a served env with, and a sanity check for any new reach env."""

    def __init__(self, action_dim: int = 4, gain: float = 10.0) -> None:
        self.action_dim, self.gain = action_dim, gain

    def __call__(self, observation: dict) -> np.ndarray:
        action = np.zeros(self.action_dim, dtype=np.float32)
        action[:3] = np.clip(self.gain * (observation["desired_goal"] - observation["achieved_goal"]), -1, 1)
        return action


def box_clearance(start: np.ndarray, end: np.ndarray, centre: np.ndarray, half_size: float, samples: int = 200) -> float:
    """How far the straight segment start -> end passes from a cube's faces (max-norm; negative:
    through it), on ``samples`` points: whether the obstacle is in the way of a straight reach."""
    line = np.asarray(start) + np.linspace(0.0, 1.0, samples)[:, None] * (np.asarray(end) - np.asarray(start))
    return float(np.max(np.abs(line - centre) - half_size, axis=1).min())


class ObstacleDetour:
    """A scripted teacher for FetchReachObstacle that knows where the box is: straight at the goal
    when the line there is clear, else up over the box, across above the goal, and down (on the
    default seeds 20000+ of ``obstacle_on_path: 1.0`` worlds: 97% in 6.86 actions, 75% driving straight).

    It reads the state a :class:`SemanticState` with ``privileged=["obstacle_position"]`` gives,
    ``observation`` = (z, box centre), and has ``predict`` like a policy, so APRiL's distillation can
    use it wherever a state policy that read the box would go (``policy.teacher: detour``). Stateless:
    every step decides from the geometry alone, so DAgger may ask it about any state.
    """

    def __init__(self, half_size: float, clearance: float = 0.03, rise: float = 0.05, gain: float = 20.0) -> None:
        self.half_size, self.clearance, self.rise, self.gain = half_size, clearance, rise, gain

    def _blocked(self, start: np.ndarray, end: np.ndarray, box: np.ndarray) -> bool:
        return box_clearance(start, end, box, self.half_size, samples=50) < self.clearance

    def __call__(self, observation: dict) -> np.ndarray:
        gripper, box = observation["observation"][:3], observation["observation"][3:6]
        goal = observation["desired_goal"]
        target = goal
        above_it = np.linalg.norm(gripper[:2] - goal[:2]) < 0.015  # over the goal: down, whatever the margin says
        if not above_it and self._blocked(gripper, goal, box):
            top = box[2] + self.half_size + self.rise
            above_goal = np.array([goal[0], goal[1], max(top, goal[2])])
            target = np.array([gripper[0], gripper[1], top]) if gripper[2] < top - 0.01 else above_goal
        action = np.zeros(4, dtype=np.float32)
        action[:3] = np.clip(self.gain * (target - gripper), -1.0, 1.0)
        return action

    def predict(self, observation: dict, deterministic: bool = True) -> tuple[np.ndarray, None]:
        return self(observation), None
