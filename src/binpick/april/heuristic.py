"""A scripted pick-and-place policy (thesis §4.5.3: "a simple hand-crafted heuristic policy").

It reads the Fetch observation (gripper position, object position, finger opening) and works in
phases decided afresh at every step, so it recovers when the object slips: over the object with the
jaws open, down around it, close, then carry it to the goal. Its episodes are the demonstrations
that pretrain the actor by behaviour cloning.
"""

from __future__ import annotations

import numpy as np


class PickAndPlaceHeuristic:
    """Callable policy: Fetch pick-and-place dict observation -> action (Δx, Δy, Δz, gripper)."""

    def __init__(self, gain: float = 10.0, hover: float = 0.05, grasp_height: float = 0.01, noise: float = 0.0,
                 seed: int | None = None) -> None:
        self.gain, self.hover, self.grasp_height, self.noise = gain, hover, grasp_height, noise
        self.rng = np.random.default_rng(seed)

    def __call__(self, observation: dict) -> np.ndarray:
        state = observation["observation"]
        gripper, target = state[:3], observation["desired_goal"]
        obj = observation["achieved_goal"]
        fingers = state[9] + state[10]  # total jaw opening, metres
        offset = obj - gripper
        horizontal = np.linalg.norm(offset[:2])
        holding = horizontal < 0.02 and abs(offset[2]) < 0.03 and fingers < 0.06
        if holding:  # carry it to the goal, jaws closed
            move, grip = target - obj, -1.0
        elif horizontal > 0.015:  # line up above the object, jaws open
            move, grip = np.array([offset[0], offset[1], obj[2] + self.hover - gripper[2]]), 1.0
        elif offset[2] < -self.grasp_height:  # lower round it
            move, grip = np.array([offset[0], offset[1], offset[2]]), 1.0
        else:  # close on it
            move, grip = np.zeros(3), -1.0
        action = np.clip(np.append(move * self.gain, grip), -1.0, 1.0)
        if self.noise:
            action[:3] = np.clip(action[:3] + self.rng.normal(0, self.noise, 3), -1.0, 1.0)
        return action.astype(np.float32)
