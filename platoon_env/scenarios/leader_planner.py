"""A navigation-stack-like local planner for the leader ``R_0``: a timed trajectory that stops
and turns in place at sharp vertices (Remark 2: any planner may dictate the leader's motion).

The paper's study B (section 4.2) drove its leader with the ROS Navigation Stack. Two users
share the local layer here: ``scripts/plan_leader_trajectory.py`` (study B's global plan on an
occupancy grid, then :func:`follow`, written as ``data/trajectories/study_b_trajectory.yaml``)
and the procedural rooms layouts of the ``paper`` tier
(:mod:`~platoon_env.scenarios.sharp_layouts`), whose leader drives a generated polyline the
same way. The samples ``[t, x, y, theta]`` are what ``leader.trajectory`` replays.

:func:`follow` is a regulated pure pursuit (after Nav2's ``RegulatedPurePursuitController``) at
:attr:`PlannerParams.period`: pure pursuit with lookahead :attr:`PlannerParams.lookahead`;
linear speed regulated by curvature below :attr:`PlannerParams.regulated_radius` and capped so
that the robot can stop at the next *sharp* vertex (turn above :attr:`PlannerParams.sharp_turn`)
and at the goal; there it stops and **turns in place** to the next segment's heading (and at
the goal to the goal heading). Every command obeys ``0 <= u <= Limits.speed``,
``|omega| <= Limits.turn_rate``, ``|du/dt| <= Limits.accel`` and ``|domega/dt| <=
Limits.alpha``; the pose is integrated exactly (unicycle arcs, eq. 1) over each period. Nothing
is random: the same inputs give the same samples.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from platoon_env.geometry.workspace import LEADER_PATH_MARGIN

FloatArray = NDArray[np.float64]

__all__ = [
    "Limits",
    "PlannerParams",
    "follow",
    "sharp_vertices",
    "stopping_speed",
    "unicycle",
    "wrap",
]


@dataclass(frozen=True)
class PlannerParams:
    """Every setting of the planner (SI units); the defaults made study B's trajectory. The
    global planner's settings (``safety_margin`` to ``simplify_tolerance``) are read by
    ``scripts/plan_leader_trajectory.py`` only."""

    speed: float = 0.2  # [m/s] top linear speed of the leader (study B's leader speed)
    turn_rate: float = 1.0  # [rad/s] top |omega| of the leader
    safety_margin: float = 0.1  # [m] obstacle inflation beyond the robot radius (paper §4.2)
    #: [m] and the margin the env demands of a leader's path beyond that (r + m + this)
    path_margin: float = LEADER_PATH_MARGIN
    resolution: float = 0.05  # [m] occupancy-grid cell size
    cost_weight: float = 5.0  # inflation-layer cost at the lethal boundary, above 1
    cost_scaling: float = 10.0  # [1/m] decay of the inflation-layer cost with clearance
    simplify_tolerance: float = 0.1  # [m] Douglas-Peucker tolerance on the grid path
    period: float = 0.1  # [s] local-planner period = sampling period of the trajectory
    lookahead: float = 0.3  # [m] pure-pursuit lookahead
    sharp_turn: float = math.radians(30.0)  # [rad] vertex turn above which it stops and turns
    regulated_radius: float = 0.9  # [m] below this turning radius the speed scales down
    min_speed: float = 0.03  # [m/s] floor of the curvature regulation
    accel_max: float = 0.3  # [m/s^2] bound on |du/dt|
    alpha_max: float = 1.0  # [rad/s^2] bound on |domega/dt|
    stop_tolerance: float = 0.005  # [m] distance to a stop point counted as arrived
    heading_tolerance: float = 0.005  # [rad] heading error at which a turn in place ends
    max_time: float = 600.0  # [s] give up (an error) if the goal is not reached by then


@dataclass(frozen=True)
class Limits:
    """The robot's limits: from the scenario's ``leader`` block and the planner's settings."""

    speed: float  # [m/s] top speed (PlannerParams.speed)
    turn_rate: float  # [rad/s] top turn rate (PlannerParams.turn_rate)
    accel: float  # [m/s^2]
    alpha: float  # [rad/s^2]


def wrap(a: float) -> float:
    """The angle ``a`` in ``(-pi, pi]``."""
    return math.atan2(math.sin(a), math.cos(a))


def unicycle(x: float, y: float, th: float, u: float, w: float, h: float) -> tuple[float, ...]:
    """Exact unicycle motion (eq. 1) for ``h`` seconds at constant ``(u, omega)``."""
    if abs(w) < 1e-9:
        return x + u * h * math.cos(th), y + u * h * math.sin(th), th
    th2 = th + w * h
    return (
        x + u / w * (math.sin(th2) - math.sin(th)),
        y - u / w * (math.cos(th2) - math.cos(th)),
        th2,
    )


def stopping_speed(distance: float, accel: float, h: float) -> float:
    """The largest speed from which steps of ``accel h`` less per period stop within
    ``distance``: ``v^2 / (2 a) + v h / 2 <= distance``."""
    half = 0.5 * accel * h
    return max(0.0, -half + math.sqrt(half * half + 2.0 * accel * max(distance, 0.0)))


def sharp_vertices(path: FloatArray, sharp_turn: float) -> list[int]:
    """Indices of the interior vertices where the path turns by more than ``sharp_turn``."""
    seg = np.diff(path, axis=0)
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    turn = np.abs([wrap(b - a) for a, b in itertools.pairwise(heading)])
    return [int(k) + 1 for k in np.flatnonzero(turn > sharp_turn)]


class _Polyline:
    """Projection onto and interpolation along a short polyline (a leg of the path), in plain
    floats: the local planner calls both once per period, and a leg has a few segments."""

    def __init__(self, points: FloatArray) -> None:
        self.xy = [(float(x), float(y)) for x, y in points]
        self.cum = [0.0]
        for (ax, ay), (bx, by) in itertools.pairwise(self.xy):
            self.cum.append(self.cum[-1] + math.hypot(bx - ax, by - ay))

    def project(self, x: float, y: float) -> float:
        """Arc length of the polyline's point nearest to ``(x, y)`` (the first, on ties)."""
        best_d, best_s = math.inf, 0.0
        for k, ((ax, ay), (bx, by)) in enumerate(itertools.pairwise(self.xy)):
            dx, dy = bx - ax, by - ay
            len2 = dx * dx + dy * dy
            t = 0.0 if len2 <= 0.0 else min(1.0, max(0.0, ((x - ax) * dx + (y - ay) * dy) / len2))
            d = math.hypot(x - ax - t * dx, y - ay - t * dy)
            if d < best_d:
                best_d, best_s = d, self.cum[k] + t * (self.cum[k + 1] - self.cum[k])
        return best_s

    def interpolate(self, s: float) -> tuple[float, float]:
        """The point at arc length ``s`` (clamped to the polyline)."""
        for k in range(len(self.xy) - 1):
            if s <= self.cum[k + 1] or k == len(self.xy) - 2:
                seg = self.cum[k + 1] - self.cum[k]
                t = 0.0 if seg <= 0.0 else min(1.0, max(0.0, (s - self.cum[k]) / seg))
                (ax, ay), (bx, by) = self.xy[k], self.xy[k + 1]
                return ax + t * (bx - ax), ay + t * (by - ay)
        return self.xy[-1]


def follow(
    path: FloatArray, start_heading: float, goal_heading: float, lim: Limits, p: PlannerParams
) -> FloatArray:
    """Drive ``path`` from rest at its first point; the samples ``(T, 4)``: ``[t, x, y, theta]``.

    The path is cut into *legs* at its sharp vertices; the robot turns in place to each leg's
    heading, follows the leg by pure pursuit (its carrot runs on along the leg's last segment,
    extended, so that the robot ends on the leg's line), stops at the leg's end, and at the goal
    turns in place to ``goal_heading``. ``RuntimeError`` if the goal is not reached within
    :attr:`PlannerParams.max_time`.
    """
    h = p.period
    cuts = [0, *sharp_vertices(path, p.sharp_turn), len(path) - 1]
    legs = [path[a : b + 1] for a, b in itertools.pairwise(cuts)]
    x, y = float(path[0, 0]), float(path[0, 1])
    th = start_heading
    u = w = 0.0
    samples = [(0.0, x, y, th)]

    def step(u_target: float, w_target: float) -> None:
        nonlocal x, y, th, u, w
        u = min(max(u_target, u - lim.accel * h, 0.0), u + lim.accel * h, lim.speed)
        w = min(max(w_target, w - lim.alpha * h, -lim.turn_rate), w + lim.alpha * h, lim.turn_rate)
        x, y, th = unicycle(x, y, th, u, w, h)
        samples.append((len(samples) * h, x, y, th))
        if samples[-1][0] > p.max_time:
            raise RuntimeError(f"the goal was not reached within {p.max_time} s")

    def turn_to(heading: float) -> None:
        # brake u first, then turn with a braking profile so that the turn ends at rest
        while u > 0.0:
            step(0.0, 0.0)
        while True:
            err = wrap(heading - th)
            if abs(err) <= p.heading_tolerance and abs(w) <= lim.alpha * h:
                break
            target = math.copysign(stopping_speed(abs(err), lim.alpha, h), err)
            step(0.0, min(max(target, -lim.turn_rate), lim.turn_rate))
        while w != 0.0:
            step(0.0, 0.0)

    for leg in legs:
        line = _Polyline(leg)
        total = line.cum[-1]
        ex, ey = line.xy[-1]
        last = leg[-1] - leg[-2]
        lx, ly = float(last[0]), float(last[1])
        norm = math.hypot(lx, ly)
        lx, ly = lx / norm, ly / norm
        first = leg[1] - leg[0]
        if abs(wrap(math.atan2(first[1], first[0]) - th)) > p.sharp_turn:
            turn_to(math.atan2(first[1], first[0]))
        while True:
            along_end = (ex - x) * lx + (ey - y) * ly  # signed, on the last segment
            s_near = line.project(x, y)
            remaining = max(total - s_near, along_end) if s_near < total else along_end
            if remaining <= p.stop_tolerance:
                break
            s_carrot = s_near + p.lookahead
            if s_carrot <= total:
                cx, cy = line.interpolate(s_carrot)
            else:  # the carrot runs on along the last segment's extension
                cx, cy = ex + (s_carrot - total) * lx, ey + (s_carrot - total) * ly
            dist = math.hypot(cx - x, cy - y)
            alpha = wrap(math.atan2(cy - y, cx - x) - th)
            kappa = 2.0 * math.sin(alpha) / max(dist, 1e-9)
            v = lim.speed
            if abs(kappa) * p.regulated_radius > 1.0:  # curvature regulation (RPP)
                v = max(lim.speed / (abs(kappa) * p.regulated_radius), p.min_speed)
            v = min(v, stopping_speed(remaining, lim.accel, h))
            if abs(kappa) > 1e-12:
                v = min(v, lim.turn_rate / abs(kappa))
            v = max(v, min(p.min_speed, remaining / h))  # never stall short of the stop point
            step(v, v * kappa)
        while u > 0.0 or w != 0.0:
            step(0.0, 0.0)
    turn_to(goal_heading)
    return np.asarray(samples, dtype=np.float64)
