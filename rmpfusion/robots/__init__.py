"""Robot descriptions (conf/robot/) and the robots built from them; importing registers the ``urdf`` kind."""

from .description import ControlPoint, EndEffector, RobotDescription
from .robot import RobotField, URDFRobot, build_robot  # importing it registers the ``urdf`` kind

__all__ = ["ControlPoint", "EndEffector", "RobotDescription", "RobotField", "URDFRobot", "build_robot"]
