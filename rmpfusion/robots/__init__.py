"""Robot descriptions (conf/robot/) and the robots built from them; importing registers the ``urdf`` kind."""

from .description import ControlPoint, EndEffector, RobotDescription  # noqa: F401
from .robot import RobotField, URDFRobot, build_robot  # noqa: F401
