"""The maths and the rules of a timed leader trajectory (``leader.trajectory``).

A trajectory is its samples ``(t_k, x_k, y_k, theta_k)`` (``docs/scenarios.md``), replayed by
:func:`platoon_env.dynamics.leader.replay_leader`. This module gives what is derived from them
(:func:`trajectory_route`, the compiled leader's form; :func:`trajectory_length`;
:func:`trajectory_mean_speed`) and the rules a trajectory must keep: its sample times
(:func:`check_trajectory_times`) and its feasibility for the leader, a unicycle robot of the
platoon (:func:`check_trajectory_motion`).
"""

from __future__ import annotations

import math

import numpy as np

from platoon_env.config import ScenarioConfig, TrajectorySample, field_error, require
from platoon_env.dynamics.leader import trajectory_velocities
from platoon_env.records import PATH_T, PATH_THETA, PATH_X, PATH_Y, Route

#: Most samples of ``leader.trajectory`` (the core keeps them in its map bank, like a path).
MAX_TRAJECTORY_SAMPLES: int = 100_000
#: [s] Shortest interval between two samples of ``leader.trajectory``, and longest trajectory
#: (its last sample's time): together they keep every sample time apart from the next by far
#: more than the replay's clock tolerance
#: (:data:`~platoon_env.dynamics.leader.TRAJECTORY_TIME_TOLERANCE`).
MIN_TRAJECTORY_INTERVAL: float = 1e-6
MAX_TRAJECTORY_DURATION: float = 1e6
#: Relative tolerance of the trajectory's feasibility rule (``|u| <= u_max``, ``|omega| <=
#: max_turn_rate``): a log written with its values rounded passes (a heading rounded to 0.1 mrad
#: at samples 0.1 s apart changes a turn rate by up to 1e-3 rad/s); 1 % beyond a limit fails.
TRAJECTORY_LIMIT_TOLERANCE: float = 1e-2
#: [rad] How far a segment's direction of travel may lie outside the headings the leader held
#: on it (the heading rule of :func:`check_trajectory_motion`): 0.05 rad, about 3 degrees. It
#: covers a turn rate that changes within a sample period (which bends the chord away from the
#: mean heading by a small fraction of the segment's turn) and headings rounded to 0.1 mrad; a
#: leader that slides sideways, or whose heading lags its motion, exceeds it at once.
TRAJECTORY_HEADING_TOLERANCE: float = 0.05
#: [m] Sideways displacement per segment that the heading rule always allows: positions rounded
#: to 0.1 mm (each coordinate off by up to 0.05 mm at both ends) move a short segment's chord
#: sideways by up to about 0.14 mm, whatever its direction.
TRAJECTORY_POSITION_TOLERANCE: float = 2e-4


def trajectory_route(samples: tuple[TrajectorySample, ...]) -> Route:
    """A trajectory's samples as the compiled leader reads them (a
    :data:`~platoon_env.records.Route`): the path ``(M, 4)`` with columns ``x, y, t, theta``
    (:data:`~platoon_env.records.PATH_X` ...) and the cumulative arc length ``(M,)`` of its
    positions."""
    arr = np.asarray(samples, dtype=np.float64).reshape(-1, 4)
    path = np.empty_like(arr)
    path[:, [PATH_T, PATH_X, PATH_Y, PATH_THETA]] = arr  # the samples' order: t, x, y, theta
    seg = np.hypot(np.diff(path[:, PATH_X]), np.diff(path[:, PATH_Y]))
    return path, np.concatenate([[0.0], np.cumsum(seg)])


def polyline_length(xy: np.ndarray) -> float:
    """Length [m] of the polyline ``xy`` ``(M, 2)``."""
    return float(np.sum(np.hypot(np.diff(xy[:, 0]), np.diff(xy[:, 1]))))


def trajectory_length(samples: tuple[TrajectorySample, ...]) -> float:
    """Length [m] of the polyline of the samples' positions (the leader's path)."""
    return polyline_length(np.asarray([(x, y) for _, x, y, _ in samples], dtype=np.float64))


def trajectory_mean_speed(samples: tuple[TrajectorySample, ...]) -> float:
    """A trajectory's mean speed [m/s]: its length over its duration (``leader.speed`` of the
    trajectory mode). The samples must pass :func:`check_trajectory_times`."""
    return trajectory_length(samples) / samples[-1][0]


def check_trajectory_times(samples: tuple[TrajectorySample, ...], where: str) -> None:
    """The samples of a timed leader trajectory: at least two, at most
    :data:`MAX_TRAJECTORY_SAMPLES`; ``t`` starts at 0, increases by at least
    :data:`MIN_TRAJECTORY_INTERVAL` per sample and ends by :data:`MAX_TRAJECTORY_DURATION`; the
    leader moves (a length > 0). ``ScenarioError`` naming ``where`` (and the sample) otherwise.
    """
    n = len(samples)
    require(n >= 2, where, f"needs at least two samples [t, x, y, theta], got {n}")
    require(
        n <= MAX_TRAJECTORY_SAMPLES,
        where,
        f"must have at most {MAX_TRAJECTORY_SAMPLES} samples (MAX_TRAJECTORY_SAMPLES), got {n}",
    )
    t0 = samples[0][0]
    require(t0 == 0.0, f"{where}[0]", f"the first sample's time t must be 0, got {t0!r}")
    for k in range(1, n):
        dt = samples[k][0] - samples[k - 1][0]
        require(
            dt >= MIN_TRAJECTORY_INTERVAL,
            f"{where}[{k}]",
            f"sample times must increase by at least {MIN_TRAJECTORY_INTERVAL:g} s "
            f"(MIN_TRAJECTORY_INTERVAL), got t = {samples[k][0]!r} after {samples[k - 1][0]!r}",
        )
    end = samples[-1][0]
    require(
        end <= MAX_TRAJECTORY_DURATION,
        f"{where}[{n - 1}]",
        f"the last sample's time must be at most {MAX_TRAJECTORY_DURATION:g} s "
        f"(MAX_TRAJECTORY_DURATION), got {end!r}",
    )
    length = trajectory_length(samples)
    require(length > 0.0, where, "the leader never moves: every sample is at the same position")


def sideways_slip(route: Route, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per segment ``k`` of ``route``, the displacement across the segment's mean heading
    ``theta_k + wrap(theta_{k+1} - theta_k) / 2`` (the heading :func:`segment_velocity
    <platoon_env.dynamics.leader.segment_velocity>` drives along) and the most the heading rule
    allows there [m], each ``(M - 1,)``; ``omega`` is the segments' turn rate
    (:func:`~platoon_env.dynamics.leader.trajectory_velocities`).

    A unicycle moves along its heading (eq. 1), forwards or backwards: between two samples its
    chord lies among the headings it held, within ``|turn| / 2`` of the mean heading when it
    turns one way. The rule allows a chord of length ``L`` a sideways displacement of
    ``L sin(min(|turn| / 2 + TRAJECTORY_HEADING_TOLERANCE, pi / 2)) +
    TRAJECTORY_POSITION_TOLERANCE``; a leader that turns in place (``L = 0``) always passes.
    """
    path = route[0]
    dt = np.diff(path[:, PATH_T])
    dx, dy = np.diff(path[:, PATH_X]), np.diff(path[:, PATH_Y])
    half_turn = 0.5 * omega * dt
    mid = path[:-1, PATH_THETA] + half_turn
    sideways = np.abs(dx * np.sin(mid) - dy * np.cos(mid))
    spread = np.minimum(np.abs(half_turn) + TRAJECTORY_HEADING_TOLERANCE, 0.5 * math.pi)
    allowed = np.hypot(dx, dy) * np.sin(spread) + TRAJECTORY_POSITION_TOLERANCE
    return sideways, allowed


def check_trajectory_motion(cfg: ScenarioConfig, path: str) -> None:
    """The trajectory of ``cfg.leader`` is one the leader can drive (Problem 1 asks for a
    leader with bounded velocities; the leader is a unicycle robot of the platoon, eq. 1).

    * Velocity limits: on every segment the velocity the interpolation implies
      (:func:`platoon_env.dynamics.leader.segment_velocity`), times the fastest speed factor
      ``1 + speed_variation``, keeps ``|u| <= robot.u_max`` and ``|omega| <=
      leader.max_turn_rate``, up to :data:`TRAJECTORY_LIMIT_TOLERANCE`.
    * Heading: on every segment where it moves, the direction of travel matches the heading
      (forwards or backwards) within :data:`TRAJECTORY_HEADING_TOLERANCE` of the headings held
      (:func:`sideways_slip`): no sliding sideways.

    The samples must pass :func:`check_trajectory_times`. ``ScenarioError`` naming the sample
    that ends the offending segment (``{path}.leader.trajectory[k]``) otherwise: for a limit
    the segment that exceeds it most, for the heading the first that slides.
    """
    lead = cfg.leader
    where = f"{path}.leader.trajectory"
    route = trajectory_route(lead.trajectory)
    u, omega = trajectory_velocities(route)
    fastest = 1.0 + lead.speed_variation
    scaled = " times 1 + leader.speed_variation" if lead.speed_variation > 0 else ""
    limits = (
        (np.abs(u) * fastest, cfg.robot.u_max, "speed", "m/s", "robot.u_max"),
        (np.abs(omega) * fastest, lead.max_turn_rate, "turn rate", "rad/s", "leader.max_turn_rate"),
    )
    for values, limit, what, unit, name in limits:
        worst = int(np.argmax(values))
        require(
            values[worst] <= limit * (1.0 + TRAJECTORY_LIMIT_TOLERANCE),
            f"{where}[{worst + 1}]",
            f"infeasible: from sample {worst} to {worst + 1} the leader's {what}{scaled} would "
            f"be {values[worst]:.6g} {unit}, above {name} = {limit:g} {unit}",
        )
    sideways, allowed = sideways_slip(route, omega)
    sliding = np.flatnonzero(sideways > allowed)
    if sliding.size:  # the first one: where the samples' headings first part from the motion
        k = int(sliding[0])
        raise field_error(
            f"{where}[{k + 1}]",
            f"the heading does not match the motion: from sample {k} to {k + 1} the leader "
            f"moves {sideways[k]:.6g} m sideways of its heading (theta = "
            f"{lead.trajectory[k][3]:g} to {lead.trajectory[k + 1][3]:g} rad), more than the "
            f"{allowed[k]:.6g} m a unicycle can (TRAJECTORY_HEADING_TOLERANCE = "
            f"{TRAJECTORY_HEADING_TOLERANCE:g} rad beyond the headings it held): give each "
            "sample the heading of its motion",
        )
