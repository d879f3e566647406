"""Crowds: social-force humans with HuNavSim behaviours, reacting to a robot that replays its path.

``social_force`` holds the crowd's state, the forces and the integrator (``step``); ``rollout``
runs it over a replayed robot and records every tick; ``state`` the robot as the crowd sees it
(``RobotState``); ``behaviours`` the reactions to the robot; ``neighbours`` the KD-tree / grid
searches; ``gait`` the walk-cycle phase; ``metrics`` the HuNavSim evaluation metrics.
"""

from nsim.crowd.behaviours import Behaviour, BehaviourParams, behaviour_codes
from nsim.crowd.metrics import CrowdMetrics, crowd_metrics
from nsim.crowd.neighbours import segments_from_polygons
from nsim.crowd.rollout import CrowdTrajectory, RobotTrack, rollout
from nsim.crowd.social_force import CrowdState, ForceParams, make_walls, step
from nsim.crowd.state import RobotState

__all__ = [
    "Behaviour",
    "BehaviourParams",
    "CrowdMetrics",
    "CrowdState",
    "CrowdTrajectory",
    "ForceParams",
    "RobotState",
    "RobotTrack",
    "behaviour_codes",
    "crowd_metrics",
    "make_walls",
    "rollout",
    "segments_from_polygons",
    "step",
]
