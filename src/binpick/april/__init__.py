"""APRiL (thesis ch. 4): train the policy on state, deploy it on pixels."""

from binpick.april.config import AprilConfig
from binpick.april.pipeline import AprilRun
from binpick.april.policy import AprilPolicy

__all__ = ["AprilConfig", "AprilRun", "AprilPolicy"]
