"""Per-follower reward as named, weighted terms (weights from the scenario's ``reward`` block).

====================  =========================================================
term                  value per step
====================  =========================================================
``distance``          ``-w_distance * (e_d / (d_con - d_des))**2``
``bearing``           ``-w_bearing * (e_beta / beta_con)**2``
``effort``            ``-w_effort * (u**2 + omega**2)``
``alive``             ``+w_alive`` when the follower has no violation this step
``violation``         ``-w_violation`` when it has one (any cause)
``wall``              ``-w_wall * (1 - (c - r) / m)**2`` when the follower's
                      clearance to the obstacle boundary ``c`` is within the
                      margin ``m = wall_margin`` of a collision (``c - r < m``),
                      else 0 (clipped to ``-w_wall`` at contact)
====================  =========================================================

``e_d = d - d_des`` and ``e_beta = beta`` are the errors of eq. 7 (normalised errors are clipped
to ±2 so that one step after a violation cannot dominate). ``wall`` warns a learner of a
collision before it happens: without it the only signal near a wall is the violation itself
(``c`` and ``r`` are the quantities of ``collision_obstacle``, eq. 4). The reward is a training
signal only; the benchmark's metrics (DESIGN §7) are computed from ground truth separately.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from platoon_env.geometry.sensing import SENSE_BETA, SENSE_CLEARANCE, SENSE_D
from platoon_env.scenarios.schema import ScenarioConfig

REWARD_TERMS: tuple[str, ...] = ("distance", "bearing", "effort", "alive", "violation", "wall")
R_DISTANCE, R_BEARING, R_EFFORT, R_ALIVE, R_VIOLATION, R_WALL = range(6)


def reward_weights(cfg: ScenarioConfig) -> np.ndarray:
    """The weights of :data:`REWARD_TERMS` as a float64 vector."""
    w = cfg.reward
    return np.array(
        [w.distance, w.bearing, w.effort, w.alive, w.violation, w.wall], dtype=np.float64
    )


@njit(cache=True)
def reward_terms_into(
    sensed: np.ndarray,
    d_des: float,
    actions: np.ndarray,
    violations: np.ndarray,
    weights: np.ndarray,
    d_scale: float,
    beta_scale: float,
    radius: float,
    wall_margin: float,
    out: np.ndarray,
) -> None:
    """Each term (columns of :data:`REWARD_TERMS`) for every follower into ``out`` (N, 6).

    ``sensed`` holds the ground-truth sensing (``SENSE_*`` columns) after the step; ``radius``
    is the robot radius ``r`` and ``wall_margin`` the margin ``m`` of the ``wall`` term.
    """
    if out.shape[1] != len(REWARD_TERMS) or out.shape[0] != sensed.shape[0]:
        # Compiled code does not check bounds: a short buffer would be overwritten silently.
        raise ValueError("out must have shape (N, len(REWARD_TERMS))")
    for i in range(out.shape[0]):
        ed = min(2.0, max(-2.0, (sensed[i, SENSE_D] - d_des) / d_scale))
        eb = min(2.0, max(-2.0, sensed[i, SENSE_BETA] / beta_scale))
        out[i, R_DISTANCE] = -weights[R_DISTANCE] * ed * ed
        out[i, R_BEARING] = -weights[R_BEARING] * eb * eb
        out[i, R_EFFORT] = -weights[R_EFFORT] * (
            actions[i, 0] * actions[i, 0] + actions[i, 1] * actions[i, 1]
        )
        violated = violations[i] != 0
        out[i, R_ALIVE] = 0.0 if violated else weights[R_ALIVE]
        out[i, R_VIOLATION] = -weights[R_VIOLATION] if violated else 0.0
        near = 1.0 - (sensed[i, SENSE_CLEARANCE] - radius) / wall_margin
        near = min(1.0, max(0.0, near))
        out[i, R_WALL] = -weights[R_WALL] * near * near
