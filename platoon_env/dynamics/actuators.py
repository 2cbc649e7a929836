"""Actuator dynamics: from the commanded ``[u, omega]`` to the velocities the wheels apply.

Per control period of ``dt`` seconds and per follower (``docs/realism.md``), the command
(already clipped to the action box) passes through

1. a first-order lag of time constant ``robot.lag``: ``v += (command - v) (1 - exp(-dt / lag))``;
2. rate limits: the applied ``u`` changes by at most ``accel_max * dt``, ``omega`` by at most
   ``alpha_max * dt``.

The applied velocity is held over the period's physics sub-steps, so the unicycle arcs of eq. 1
stay exact. Without any of the three the command is applied as it is (bit for bit). The robots
stand still at a reset.

:func:`follow` is the rule for one velocity and :func:`lag_gain` its gain; the env applies them
to every follower (:func:`actuate`), and a policy that models its own drive calls the same two.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from platoon_env.observation import ACT_OMEGA, ACT_U


def lag_gain(lag: float, dt: float) -> float:
    """The lag's gain per period, ``1 - exp(-dt / lag)``; 1 without a lag (``lag = 0``)."""
    return 1.0 if lag == 0 else -math.expm1(-dt / lag)


@njit(cache=True, inline="always")
def follow(applied: float, command: float, gain: float, max_change: float) -> float:
    """One velocity after one period: the lag of gain ``gain`` (:func:`lag_gain`; ``>= 1``: none)
    towards ``command``, then the rate limit ``|change| <= max_change`` (``inf``: none)."""
    target = command if gain >= 1.0 else applied + (command - applied) * gain
    return min(applied + max_change, max(applied - max_change, target))


@njit(cache=True)
def actuate(actions: np.ndarray, applied: np.ndarray, p: np.record) -> None:
    """Update the applied velocities ``applied`` (N, 2) towards the commands ``actions`` (N, 2)
    by the lag and rate limits of params record ``p``; a copy when ``p.actuate`` is off."""
    if not p.actuate:
        for i in range(actions.shape[0]):
            applied[i, ACT_U] = actions[i, ACT_U]
            applied[i, ACT_OMEGA] = actions[i, ACT_OMEGA]
        return
    du = p.accel_max * p.control_period
    dw = p.alpha_max * p.control_period
    for i in range(actions.shape[0]):
        applied[i, ACT_U] = follow(applied[i, ACT_U], actions[i, ACT_U], p.lag_gain, du)
        applied[i, ACT_OMEGA] = follow(applied[i, ACT_OMEGA], actions[i, ACT_OMEGA], p.lag_gain, dw)
