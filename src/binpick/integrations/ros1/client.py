"""``binpick/Ros-v0``: a Gymnasium env whose every reset and step is a goal sent to a binpick
action server over ROS — a simulator on another machine, or a real robot behind the same interface.

    env = gymnasium.make("binpick/Ros-v0", namespace="/binpick/fetch_reach")

The spaces, success distance and episode limit come from the server's parameters, so a policy
trained on the simulated env runs unchanged. Goal envs get ``compute_reward`` (the Fetch rule:
0 within the success distance, -1 outside), so HER works through the bridge too.
"""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import gymnasium as gym
import numpy as np

from binpick.envs.spaces import build_space
from binpick.core.errors import BinpickError
from binpick.integrations.ros1 import init_node_within, master_uri, require_ros, wait_for_master
from binpick.integrations.ros1.messages import env_action_types


def init_node_once(name: str = "binpick_client", timeout: float = 10.0) -> None:
    """rospy allows one node per process: start it the first time a client needs it, once the master
    answers (rospy alone would wait for an absent master forever)."""
    import rospy

    if not rospy.core.is_initialized():
        wait_for_master(master_uri(), timeout)
        init_node_within(name, timeout, signals=False)


class RosEnv(gym.Env):
    metadata = {"render_modes": []}

    def __init__(self, namespace: str = "/binpick/env", timeout: float = 10.0) -> None:
        require_ros()
        import actionlib
        import rospy

        init_node_once(timeout=timeout)
        self.namespace, self.timeout = namespace.rstrip("/"), timeout
        deadline = time.monotonic() + timeout
        while not rospy.has_param(f"{self.namespace}/description"):
            if time.monotonic() > deadline:
                raise BinpickError(f"no binpick env server at {self.namespace} (parameter {self.namespace}/description "
                                   f"not set within {timeout:.0f} s): start one with `binpick ros serve`")
            time.sleep(0.05)
        self.description = json.loads(rospy.get_param(f"{self.namespace}/description"))
        self.observation_space = build_space(self.description["observation_space"])
        self.action_space = build_space(self.description["action_space"])
        self.distance_threshold = self.description.get("distance_threshold")
        self.types = env_action_types()
        # the plain ActionClient: SimpleActionClient logs an error for every late status message of a
        # goal it stopped tracking, which happens on every step
        self.client = actionlib.ActionClient(self.namespace, self.types["EnvAction"])
        if not self.client.wait_for_server(rospy.Duration(timeout)):
            raise BinpickError(f"the action server at {self.namespace} did not connect within {timeout:.0f} s")
        self.round_trips_ms: list[float] = []

    def _call(self, command: str, seed: int = -1, action=()) -> Any:
        import actionlib

        done = threading.Event()

        def on_transition(handle) -> None:
            if handle.get_comm_state() == actionlib.CommState.DONE:
                done.set()

        started = time.perf_counter()
        goal = self.types["EnvGoal"](command=command, seed=seed, action=list(map(float, action)))
        handle = self.client.send_goal(goal, transition_cb=on_transition)
        if not done.wait(self.timeout):
            handle.cancel()
            raise BinpickError(f"{command} at {self.namespace}: no result within {self.timeout:.0f} s")
        if handle.get_goal_status() != actionlib.GoalStatus.SUCCEEDED:
            raise BinpickError(f"{command} at {self.namespace} failed: {handle.get_goal_status_text()}")
        self.round_trips_ms.append(1000 * (time.perf_counter() - started))
        return handle.get_result()

    def _observation(self, result) -> Any:
        if isinstance(self.observation_space, gym.spaces.Dict):
            return {"observation": np.array(result.observation), "achieved_goal": np.array(result.achieved_goal),
                    "desired_goal": np.array(result.desired_goal)}
        return np.array(result.observation).reshape(self.observation_space.shape)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        result = self._call("reset", seed=-1 if seed is None else int(seed))
        return self._observation(result), json.loads(result.info_json or "{}")

    def step(self, action):
        result = self._call("step", action=np.asarray(action, dtype=np.float32).ravel())
        return (self._observation(result), float(result.reward), bool(result.terminated), bool(result.truncated),
                json.loads(result.info_json or "{}"))

    def compute_reward(self, achieved_goal, desired_goal, info) -> np.ndarray:
        if self.distance_threshold is None:
            raise BinpickError(f"the env at {self.namespace} is not goal-conditioned (no distance_threshold)")
        distance = np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1)
        return -(distance > self.distance_threshold).astype(np.float32)
