"""A follower's model of its own motion, by the env's own kinematics (eq. 1).

The policies that carry a point through the follower's own motion (the last-seen point of
:mod:`baselines.last_seen`; the estimate and the odometry of :mod:`baselines.filtered_ppc`)
move it by the env's exact unicycle arc (:func:`platoon_env.dynamics.unicycle.unicycle_arc`),
so that the model and the simulated robot integrate a velocity alike. Two compiled helpers:

* :func:`body_arc`: the motion ``(dx, dy, a)`` of holding ``(u, omega)`` for ``h`` seconds, in
  the body frame at its start (the arc from the origin): the robot ends at ``(dx, dy)``,
  turned by ``a = omega h``;
* :func:`in_frame`: a point's coordinates in a frame at ``(x_o, y_o)`` turned by ``theta_o``,
  ``R(-theta_o) ((x, y) - (x_o, y_o))``. A point fixed in the world at ``(x, y)`` in the old body
  frame is at ``in_frame(x, y, *body_arc(u, omega, h))`` in the new one.
"""

from __future__ import annotations

import math

from numba import njit

from platoon_env.dynamics.unicycle import unicycle_arc

__all__ = ["body_arc", "in_frame"]


@njit(cache=True)
def body_arc(u: float, omega: float, h: float) -> tuple[float, float, float]:
    """``(dx, dy, a)``: the pose after holding ``(u, omega)`` for ``h`` seconds, in the body
    frame at the start (eq. 1's exact arc from the origin, the env's rule)."""
    return unicycle_arc(0.0, 0.0, 0.0, u, omega, h)


@njit(cache=True)
def in_frame(x: float, y: float, x_o: float, y_o: float, theta_o: float) -> tuple[float, float]:
    """The point ``(x, y)`` in the frame at ``(x_o, y_o)`` turned by ``theta_o`` (all in one
    frame): ``R(-theta_o) ((x, y) - (x_o, y_o))``."""
    c, s = math.cos(theta_o), math.sin(theta_o)
    ex, ey = x - x_o, y - y_o
    return c * ex + s * ey, -s * ex + c * ey
