"""The per-follower observation vector and the per-follower action (``docs/sensing.md``).

Everything a policy may use is here, derived from the follower's own sensors only: the
camera's body-frame measurement of its predecessor and the proximity sensor's four clearances.
No global positions, no leader speed.

======  ===========  =============================================  ==================
index   name         meaning                                        range
======  ===========  =============================================  ==================
0       visible      1 if the predecessor is visible, else 0        {0, 1}
1       x_rel        ``x~ = d cos(beta)`` (0 when not visible)      [0, d_con]
2       y_rel        ``y~ = d sin(beta)`` (0 when not visible)      [-d_con, d_con]
3       d_W_l        clearance of the robot, left of ``L_i``        [0, proximity range]
4       d_W_r        clearance of the robot, right of ``L_i``       [0, proximity range]
5       d_l          clearance of the line of sight ``L_i``, left   [0, proximity range]
6       d_r          clearance of the line of sight ``L_i``, right  [0, proximity range]
======  ===========  =============================================  ==================

Distances in metres. ``beta`` is the angle of view (eq. 3), ``d`` the distance (eq. 2).
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from platoon_env.scenarios.schema import ScenarioConfig

OBS_VISIBLE = 0
OBS_X_REL = 1
OBS_Y_REL = 2
OBS_D_WALL_LEFT = 3
OBS_D_WALL_RIGHT = 4
OBS_D_SIGHT_LEFT = 5
OBS_D_SIGHT_RIGHT = 6
OBS_SIZE = 7
OBS_NAMES: tuple[str, ...] = ("visible", "x_rel", "y_rel", "d_W_l", "d_W_r", "d_l", "d_r")

ACT_U = 0
ACT_OMEGA = 1
ACT_SIZE = 2


def observation_space(cfg: ScenarioConfig) -> spaces.Box:
    """The bounded float32 Box of one follower's observation."""
    d_con = cfg.camera.range
    prox = cfg.proximity_range
    low = np.array([0.0, 0.0, -d_con, 0.0, 0.0, 0.0, 0.0], dtype=np.float32)
    high = np.array([1.0, d_con, d_con, prox, prox, prox, prox], dtype=np.float32)
    return spaces.Box(low=low, high=high, dtype=np.float32)


def action_space(cfg: ScenarioConfig) -> spaces.Box:
    """The float32 Box of one follower's action ``[u, omega]`` in m/s and rad/s.

    Its bounds are the actuator limits ``robot.u_max`` and ``robot.omega_max``; actions outside
    are clipped by the env.
    """
    high = np.array([cfg.robot.u_max, cfg.robot.omega_max], dtype=np.float32)
    return spaces.Box(low=-high, high=high, dtype=np.float32)
