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
signal only; the benchmark's metrics (``docs/metrics.md``) are computed from ground truth
separately.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from platoon_env.geometry.sensing import SENSE_BETA, SENSE_CLEARANCE, SENSE_D
from platoon_env.records import PARAMS_DTYPE

REWARD_TERMS: tuple[str, ...] = ("distance", "bearing", "effort", "alive", "violation", "wall")
R_DISTANCE, R_BEARING, R_EFFORT, R_ALIVE, R_VIOLATION, R_WALL = range(6)


# The kernel reads each weight by name from the params record: "w_" + the term's name.
_missing = [t for t in REWARD_TERMS if f"w_{t}" not in (PARAMS_DTYPE.names or ())]
if _missing:  # pragma: no cover - guards a refactoring mistake
    raise ImportError(f"records.PARAMS_DTYPE lacks the weights of reward terms {_missing}")


@njit(cache=True)
def reward_terms_into(
    sensed: np.ndarray, actions: np.ndarray, violations: np.ndarray, p: np.record, out: np.ndarray
) -> None:
    """Each term (columns of :data:`REWARD_TERMS`) for every follower into ``out`` (N, 6).

    ``sensed`` holds the ground-truth sensing (``SENSE_*`` columns) after the step, ``actions``
    the applied ``[u, omega]`` and ``violations`` the step's masks; ``p`` is a
    :data:`~platoon_env.records.PARAMS_DTYPE` record: the weights ``w_<term>``, ``d_des``, the
    scales ``reward_d_scale`` (``d_con - d_des``) and ``beta_con``, the robot radius ``r`` and
    the margin ``m = wall_margin`` of the ``wall`` term.
    """
    if out.shape[1] != len(REWARD_TERMS) or out.shape[0] != sensed.shape[0]:
        # Compiled code does not check bounds: a short buffer would be overwritten silently.
        raise ValueError("out must have shape (N, len(REWARD_TERMS))")
    for i in range(out.shape[0]):
        ed = min(2.0, max(-2.0, (sensed[i, SENSE_D] - p.d_des) / p.reward_d_scale))
        eb = min(2.0, max(-2.0, sensed[i, SENSE_BETA] / p.beta_con))
        out[i, R_DISTANCE] = -p.w_distance * ed * ed
        out[i, R_BEARING] = -p.w_bearing * eb * eb
        out[i, R_EFFORT] = -p.w_effort * (
            actions[i, 0] * actions[i, 0] + actions[i, 1] * actions[i, 1]
        )
        violated = violations[i] != 0
        out[i, R_ALIVE] = 0.0 if violated else p.w_alive
        out[i, R_VIOLATION] = -p.w_violation if violated else 0.0
        near = 1.0 - (sensed[i, SENSE_CLEARANCE] - p.radius) / p.wall_margin
        near = min(1.0, max(0.0, near))
        out[i, R_WALL] = -p.w_wall * near * near
