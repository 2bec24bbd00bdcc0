"""Pick planning from a real camera's frames, no simulator inside: ``Picker`` turns an RGB-D
frame, its calibration and the shop photo into grasp poses in the robot's base frame."""

from binpick.picking.camera_info import CameraInfo, read_camera_info, write_camera_info
from binpick.picking.picker import GraspPlan, Picker, Plans

__all__ = ["CameraInfo", "GraspPlan", "Picker", "Plans", "read_camera_info", "write_camera_info"]
