"""Unicycle kinematics (eq. 1), integrated exactly for a constant command over a sub-step.

``p_dot = n(theta) u``, ``theta_dot = omega`` with ``n(theta) = [cos theta, sin theta]``. For a
constant ``(u, omega)`` held for ``h`` seconds the robot moves on an arc of a circle of radius
``u / omega`` (a straight line when ``omega ≈ 0``), so the integration is exact, not Euler.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Below this |omega * h| the arc formula is replaced by its Taylor expansion (straight line
#: plus the first-order bend), which is exact to machine precision there.
_SMALL_TURN = 1e-6


@njit(cache=True)
def unicycle_arc(
    x: float, y: float, theta: float, u: float, omega: float, h: float
) -> tuple[float, float, float]:
    """Pose after holding ``(u, omega)`` for ``h`` seconds from ``(x, y, theta)`` (eq. 1).

    ``theta`` is not wrapped, so that headings stay continuous for plots.
    """
    dtheta = omega * h
    theta_new = theta + dtheta
    if abs(dtheta) < _SMALL_TURN:
        # sin(t+a)-sin(t) ≈ a cos(t) - a²/2 sin(t); error O(a³) < 1e-18 here.
        half = 0.5 * dtheta
        x_new = x + u * h * (math.cos(theta) - half * math.sin(theta))
        y_new = y + u * h * (math.sin(theta) + half * math.cos(theta))
    else:
        radius = u / omega
        x_new = x + radius * (math.sin(theta_new) - math.sin(theta))
        y_new = y - radius * (math.cos(theta_new) - math.cos(theta))
    return x_new, y_new, theta_new


def integrate(pose: np.ndarray, u: float, omega: float, h: float) -> np.ndarray:
    """Python convenience wrapper of :func:`unicycle_arc` for one ``[x, y, theta]`` pose."""
    x, y, th = unicycle_arc(float(pose[0]), float(pose[1]), float(pose[2]), u, omega, h)
    return np.array([x, y, th])
