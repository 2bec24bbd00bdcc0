"""binpick's bridges to other systems: ROS 1 (``ros1``), ROS 2 (``ros2``) and Ray (``ray``, simulators and
learners spread over machines)."""
