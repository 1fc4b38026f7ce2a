"""Any robot of conf/robot/ reaching goals among the obstacles of a scene of conf/scene/, in pybullet (paper §4.2,
App. D.2; the same environment for every robot).

Two ways to run a policy q̈ = π(q, q̇, aux):
- ``torque`` (``torque.py``): each rollout has its own pybullet world; the tree's acceleration becomes joint
  torques by computed-torque control (pybullet's inverse dynamics, default velocity motors disabled), so the
  simulated robot is the paper's feedback-linearised system, integrated by pybullet itself;
- ``kinematic`` (``kinematic.py``): the same closed loop integrated in torch for the whole batch at once (data
  collection).
Collision means some robot link is at distance ≤ 0 from an obstacle (or, for the links the joints move, from the
ground plane) by pybullet's closest points, in both modes (kinematic rollouts are checked at every integration step
after the fact, the simulator asked where the robot's spheres cannot clear the step; ``collisions.py``). Moving obstacles move in both modes along the paths of the scene.

The environment (``env.py``) serves the pipeline's ``Env`` protocol and its capabilities: demonstrations of 5–10 s
(``demonstrations.py``), task metrics and ratios to the expert (``metrics.py``), rendering (``render.py``), and
time-varying aux state for moving obstacles (``aux_at``).
"""

from .env import Manipulator  # importing it registers "manipulator" in rmpfusion.registry.ENVS
from .params import ManipulatorParams

__all__ = ["Manipulator", "ManipulatorParams"]
