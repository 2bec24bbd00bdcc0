"""Sample data that ships with binpick, so its commands run straight after install.

``SAMPLE_FRAME`` is one bin as a real RGB-D camera over it gives it (made by binpick's own generator
with the ``realistic`` sensor: ``tools/make_sample_frame.py``): ``rgb.png`` (640x480), ``depth.png``
(320x240, 16-bit millimetres, 0 where the sensor read nothing), ``camera.yaml`` (ROS camera_info
and the camera's tilted pose in the base frame), ``photo.png`` (the ordered product's shop photo) and
``truth.json`` (what the simulator knew; the planner never reads it).
"""

from pathlib import Path

SAMPLE_FRAME = Path(__file__).resolve().parent / "bin_frame"
