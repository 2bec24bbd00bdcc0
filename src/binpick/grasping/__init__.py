"""Grasps from depth (no simulator): candidates for a detection, a learnt grasp-quality model and the
planner that chooses one (Dex-Net 2.0 / GG-CNN's setting; thesis §5.4.4 and §6.3)."""

from binpick.grasping.camera import PinholeCamera
from binpick.grasping.candidates import GraspCandidate, JawGripper, grasp_candidates
from binpick.grasping.frame import DepthFrame
from binpick.grasping.planner import GraspChoice, GraspPlanner, GraspPolicyName

__all__ = ["DepthFrame", "GraspCandidate", "GraspChoice", "GraspPlanner", "GraspPolicyName", "JawGripper", "PinholeCamera", "grasp_candidates"]
