"""A binpick env as a ROS action server (thesis §6.1.1): goals are ``reset`` or ``step`` commands,
results carry the observation, reward and episode end, feedback says what the server is doing.

``actionlib.ActionServer`` answers in about a millisecond; ``SimpleActionServer`` would add a
~100 ms tail (its execute loop waits 0.1 s between goals). The spaces, the success distance and the
episode limit are published on the parameter server under the namespace for the client env.
"""

from __future__ import annotations

import json
from typing import Any

import gymnasium as gym
import numpy as np

from binpick.envs.spaces import describe_space
from binpick.integrations.ros1 import init_node_within, master_uri, require_ros, wait_for_master
from binpick.integrations.ros1.messages import env_action_types


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value if isinstance(value, (str, int, float, bool)) or value is None else str(value)


class EnvActionServer:
    """Serves ``env`` at ``namespace`` (e.g. ``/binpick/fetch_reach``). Call from a node."""

    def __init__(self, env: gym.Env, namespace: str) -> None:
        require_ros()
        import actionlib
        import rospy

        self.env, self.namespace = env, namespace.rstrip("/")
        self.types = env_action_types()
        description = {"observation_space": describe_space(env.observation_space), "action_space": describe_space(env.action_space),
                       "distance_threshold": getattr(env.unwrapped, "distance_threshold", None),
                       "max_episode_steps": env.spec.max_episode_steps if env.spec else None,
                       "env_id": env.spec.id if env.spec else type(env.unwrapped).__name__}
        rospy.set_param(f"{self.namespace}/description", json.dumps(description))
        self.server = actionlib.ActionServer(self.namespace, self.types["EnvAction"], self._on_goal, auto_start=False)
        self.server.start()
        self.goals = 0
        self.stopped = False
        rospy.on_shutdown(self.stop)  # rospy's first step when it shuts down, before it closes the topics

    def _result(self, observation, reward: float, terminated: bool, truncated: bool, info: dict):
        result = self.types["EnvResult"]()
        if isinstance(observation, dict):
            result.observation = np.asarray(observation["observation"], dtype=np.float64).ravel().tolist()
            result.achieved_goal = np.asarray(observation["achieved_goal"], dtype=np.float64).ravel().tolist()
            result.desired_goal = np.asarray(observation["desired_goal"], dtype=np.float64).ravel().tolist()
        else:
            result.observation = np.asarray(observation, dtype=np.float64).ravel().tolist()
        result.reward, result.terminated, result.truncated = float(reward), bool(terminated), bool(truncated)
        result.info_json = json.dumps(_jsonable(info))
        return result

    def _on_goal(self, handle) -> None:
        goal = handle.get_goal()
        handle.set_accepted()
        self.goals += 1
        try:
            if goal.command == "reset":
                handle.publish_feedback(self.types["EnvFeedback"](state="resetting"))
                observation, info = self.env.reset(seed=None if goal.seed < 0 else int(goal.seed))
                handle.set_succeeded(self._result(observation, 0.0, False, False, info))
            elif goal.command == "step":
                handle.publish_feedback(self.types["EnvFeedback"](state="stepping"))
                action = np.asarray(goal.action, dtype=np.float32)
                if action.shape != self.env.action_space.shape:
                    handle.set_aborted(text=f"action has shape {action.shape}, the env takes {self.env.action_space.shape}")
                    return
                handle.set_succeeded(self._result(*self.env.step(action)))
            else:
                handle.set_aborted(text=f"unknown command {goal.command!r}: reset or step")
        except Exception as error:  # noqa: BLE001 - the client gets the reason instead of a timeout
            handle.set_aborted(text=f"{type(error).__name__}: {error}")

    def stop(self) -> None:
        """Stop the action server once, before rospy closes its topics (its status timer published into
        a closed topic and died in its thread otherwise)."""
        if not self.stopped:
            self.stopped = True
            self.server.stop()


def serve(env_id: str, namespace: str, node_name: str = "binpick_env_server", master_timeout: float = 10.0,
          **env_kwargs) -> None:
    """Run a server node until ROS shuts down (Ctrl-C or SIGTERM); fails in one line when no master
    answers within ``master_timeout`` seconds."""
    require_ros()
    import rospy

    from binpick.envs import make

    wait_for_master(master_uri(), master_timeout)
    env = make(env_id, **env_kwargs)
    init_node_within(node_name, master_timeout)
    server = EnvActionServer(env, namespace)
    rospy.loginfo("binpick: serving %s at %s", env_id, namespace)
    try:
        rospy.spin()
    finally:
        server.stop()
        env.close()
