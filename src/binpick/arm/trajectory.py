"""Time-optimal, jerk-limited joint trajectories with Ruckig (community version, offline, state to state).

Two kinds of segment, both starting and ending at rest:

- :func:`joint_move`: all seven joints from one posture to another, time-synchronised, each within its
  velocity, acceleration and jerk limit (the arm's free moves: to the bin, to the order tote, home);
- :func:`path_move`: along a path of postures the inverse kinematics gave for points on a straight line
  of the gripper (descend, lift, lower), joined by a cubic spline in the path parameter s in [0, 1] (a
  smooth joint path: straight pieces between the postures would jump in velocity at every one). Ruckig
  times s; its limits come from the joints': with q' = dq/ds and q'' = d²q/ds², a joint's velocity is
  q'·ṡ and its acceleration q'·s̈ + q''·ṡ², so ṡ is held to vmax/|q'| and to a speed where the
  curvature term takes at most half of amax, s̈ to what is left of amax over |q'|, and the jerk of s
  to jmax/|q'| (the smaller terms of the joints' jerk are neglected; the tests measure all three).

A segment is sampled at the controller's period into joint targets and velocities.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Trajectory

from binpick.core.errors import ConfigError
from binpick.sim.robot_arm import JointLimits


@dataclass
class Segment:
    """One motion: joint targets ``q`` and velocities ``qd`` every ``period`` seconds (rows), at rest at both ends."""

    name: str
    q: np.ndarray  # (steps, joints)
    qd: np.ndarray  # (steps, joints)
    period: float
    closed: bool = False  # the fingers: closed on a product (True) or open

    @property
    def duration(self) -> float:
        return len(self.q) * self.period

    @staticmethod
    def dwell(name: str, q, seconds: float, period: float, closed: bool = False) -> Segment:
        """Standing still at ``q`` (the gripper closing or opening)."""
        steps = max(1, int(round(seconds / period)))
        return Segment(name, np.tile(np.asarray(q, dtype=float), (steps, 1)), np.zeros((steps, len(q))), period, closed)


def _timed(dofs: int, start, end, velocity, acceleration, jerk) -> Trajectory:
    generator = Ruckig(dofs)
    request = InputParameter(dofs)
    request.current_position, request.target_position = list(map(float, start)), list(map(float, end))
    request.current_velocity = request.current_acceleration = [0.0] * dofs
    request.target_velocity = request.target_acceleration = [0.0] * dofs
    request.max_velocity, request.max_acceleration, request.max_jerk = (list(map(float, v)) for v in (velocity, acceleration, jerk))
    trajectory = Trajectory(dofs)
    result = generator.calculate(request, trajectory)
    if result not in (Result.Working, Result.Finished):
        raise ConfigError(f"ruckig found no trajectory ({result}) between {np.round(start, 3)} and {np.round(end, 3)}")
    return trajectory


def _sample(trajectory: Trajectory, period: float) -> tuple[np.ndarray, np.ndarray]:
    steps = max(1, int(np.ceil(trajectory.duration / period)))
    times = np.minimum(np.arange(1, steps + 1) * period, trajectory.duration)
    states = [trajectory.at_time(float(t)) for t in times]
    return np.array([s[0] for s in states], dtype=float), np.array([s[1] for s in states], dtype=float)


def joint_move(name: str, start, end, limits: JointLimits, period: float, closed: bool = False) -> Segment:
    """From posture ``start`` to ``end`` (rest to rest), time-synchronised within the joint limits."""
    trajectory = _timed(len(start), start, end, limits.velocity, limits.acceleration, limits.jerk)
    q, qd = _sample(trajectory, period)
    return Segment(name, q, qd, period, closed)


def path_move(name: str, path: np.ndarray, limits: JointLimits, period: float, closed: bool = False) -> Segment:
    """Along ``path`` (postures at evenly spaced points s = 0 … 1 of a straight gripper line)."""
    from scipy.interpolate import CubicSpline

    path = np.asarray(path, dtype=float)
    if len(path) < 2:
        return Segment.dwell(name, path[0], period, period, closed)
    spline = CubicSpline(np.linspace(0.0, 1.0, len(path)), path, axis=0, bc_type="natural")
    fine = np.linspace(0.0, 1.0, 200)
    slope = np.maximum(np.abs(spline(fine, 1)).max(axis=0), 1e-6)  # the largest |q'| of each joint
    bend = np.abs(spline(fine, 2)).max(axis=0)  # and |q''|
    velocity, acceleration, jerk = (np.asarray(v, dtype=float) for v in (limits.velocity, limits.acceleration, limits.jerk))
    speed = float(np.min(np.minimum(velocity / slope, np.sqrt(0.5 * acceleration / np.maximum(bend, 1e-9)))))
    push = float(np.min((acceleration - bend * speed ** 2) / slope))
    trajectory = _timed(1, [0.0], [1.0], [speed], [push], [float(np.min(jerk / slope))])
    s, sd = _sample(trajectory, period)
    s, sd = np.clip(s[:, 0], 0.0, 1.0), sd[:, 0]
    return Segment(name, spline(s), spline(s, 1) * sd[:, None], period, closed)
