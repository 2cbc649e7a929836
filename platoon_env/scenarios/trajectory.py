"""The maths and the rules of a timed leader trajectory (``leader.trajectory``).

A trajectory is its samples ``(t_k, x_k, y_k, theta_k)`` (``docs/scenarios.md``), replayed by
:func:`platoon_env.dynamics.leader.replay_leader`. This module gives what is derived from them
(:func:`trajectory_route`, the compiled leader's form; :func:`trajectory_length`;
:func:`trajectory_mean_speed`) and the rules a trajectory must keep: its sample times
(:func:`check_trajectory_times`) and its feasibility for the leader, a unicycle robot of the
platoon (:func:`check_trajectory_motion`).
"""

from __future__ import annotations

import dataclasses
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


# --------------------------------------------------------------------------------------------
# The leader is one of the robots: its motion within the robots' drive (``leader.drive``).
# --------------------------------------------------------------------------------------------

#: The values of ``leader.drive`` (:class:`~platoon_env.config.LeaderConfig`).
LEADER_DRIVE_MODES: tuple[str, ...] = ("free", "check", "retime")


def trajectory_rates(
    samples: tuple[TrajectorySample, ...],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A trajectory's segment velocities ``u``, ``omega`` ``(M - 1,)`` (the interpolation's,
    :func:`~platoon_env.dynamics.leader.trajectory_velocities`) and its accelerations
    ``a``, ``alpha`` ``(M,)``: each change of velocity (from rest at the first sample, between
    consecutive segments, to rest at the last) over the time between the segments' midpoints
    (half a segment at either end). At speed factor 1; a factor ``f`` scales the velocities by
    ``f`` and the accelerations by ``f^2``."""
    route = trajectory_route(samples)
    u, omega = trajectory_velocities(route)
    t = route[0][:, PATH_T]
    mid = 0.5 * (t[1:] + t[:-1])
    at = np.concatenate([[t[0]], mid, [t[-1]]])
    dt = np.diff(at)
    a = np.diff(np.concatenate([[0.0], u, [0.0]])) / dt
    alpha = np.diff(np.concatenate([[0.0], omega, [0.0]])) / dt
    return u, omega, a, alpha


def _drive_limits(cfg: ScenarioConfig) -> list[tuple[str, float, str, int]]:
    """``(quantity, limit, field, power)`` of the robots' drive that are set: a velocity bound
    scales with the speed factor (power 1), an acceleration bound with its square (2)."""
    rob = cfg.robot
    out = [
        ("speed", rob.u_max, "robot.u_max", 1),
        ("turn rate", rob.omega_max, "robot.omega_max", 1),
    ]
    if rob.accel_max is not None:
        out.append(("acceleration", rob.accel_max, "robot.accel_max", 2))
    if rob.alpha_max is not None:
        out.append(("angular acceleration", rob.alpha_max, "robot.alpha_max", 2))
    return out


def _trajectory_peaks(cfg: ScenarioConfig) -> dict[str, tuple[float, int]]:
    """The fastest leader's (speed factor ``1 + speed_variation``) largest ``|u|``,
    ``|omega|``, ``|a|``, ``|alpha|`` on its trajectory, each with the sample that ends the
    segment (or the change) where it occurs."""
    f = 1.0 + cfg.leader.speed_variation
    u, omega, a, alpha = trajectory_rates(cfg.leader.trajectory)
    peaks = {}
    for name, values, power, shift in (
        ("speed", u, 1, 1),
        ("turn rate", omega, 1, 1),
        ("acceleration", a, 2, 0),
        ("angular acceleration", alpha, 2, 0),
    ):
        k = int(np.argmax(np.abs(values)))
        peaks[name] = (float(abs(values[k])) * f**power, min(k + shift, len(values)))
    return peaks


def leader_drive_excess(cfg: ScenarioConfig) -> list[tuple[str, float, float, str, str]]:
    """Where the leader exceeds the robots' drive (an empty list: nowhere): ``(quantity,
    value, limit, field, where)`` for each bound exceeded, ``where`` the leader's field that
    does. A timed trajectory: its peaks (:func:`trajectory_rates`) at the fastest speed factor
    against every bound set. A path (pure pursuit): ``speed * (1 + speed_variation)`` against
    ``u_max`` and ``max_turn_rate`` against ``omega_max``; its accelerations keep the bounds by
    construction (with ``leader.drive`` set, the pure pursuit itself is rate-limited and brakes
    in time, :func:`platoon_env.dynamics.leader.limit_leader_rates`)."""
    lead = cfg.leader
    out = []
    if lead.trajectory:
        peaks = _trajectory_peaks(cfg)
        for name, limit, field, _ in _drive_limits(cfg):
            value, k = peaks[name]
            if value > limit * (1.0 + TRAJECTORY_LIMIT_TOLERANCE):
                out.append((name, value, limit, field, f"leader.trajectory[{k}]"))
        return out
    fastest = lead.speed * (1.0 + lead.speed_variation)
    for name, limit, field, _ in _drive_limits(cfg):
        if name == "speed" and fastest > limit:
            out.append((name, fastest, limit, field, "leader.speed"))
        elif name == "turn rate" and lead.max_turn_rate > limit:
            out.append((name, lead.max_turn_rate, limit, field, "leader.max_turn_rate"))
    return out


def fit_leader_to_drive(cfg: ScenarioConfig) -> ScenarioConfig:
    """``cfg`` with its leader slowed to the robots' drive when ``leader.drive`` is
    ``"retime"`` (else ``cfg`` itself), the smallest change that fits:

    * a timed trajectory: every sample time multiplied by one factor ``s >= 1``, the largest of
      ``value / limit`` over the velocity bounds and ``sqrt(value / limit)`` over the
      acceleration bounds (velocities scale by ``1 / s``, accelerations by ``1 / s^2``), its
      ``speed`` the new mean speed; the path driven is the same, only slower;
    * a path: ``speed`` lowered to ``u_max / (1 + speed_variation)`` and ``max_turn_rate`` to
      ``omega_max`` where they exceed them (the rate-limited pure pursuit keeps the acceleration
      bounds by construction).

    Idempotent: a fitted leader is returned unchanged.
    """
    lead = cfg.leader
    if lead.drive != "retime":
        return cfg
    if lead.trajectory:
        peaks = _trajectory_peaks(cfg)
        stretch = 1.0
        for name, limit, _, power in _drive_limits(cfg):
            ratio = peaks[name][0] / limit
            stretch = max(stretch, ratio ** (1.0 / power))
        if stretch <= 1.0:
            return cfg
        # A hair beyond the ratio, so that rounding never leaves a peak above its bound.
        stretch *= 1.0 + 1e-9
        t0 = lead.trajectory[0][0]
        samples = tuple(
            (t0 + (t - t0) * stretch, x, y, theta) for t, x, y, theta in lead.trajectory
        )
        new = dataclasses.replace(lead, trajectory=samples, speed=trajectory_mean_speed(samples))
        return dataclasses.replace(cfg, leader=new)
    speed = min(lead.speed, cfg.robot.u_max / (1.0 + lead.speed_variation))
    turn = min(lead.max_turn_rate, cfg.robot.omega_max)
    if speed == lead.speed and turn == lead.max_turn_rate:
        return cfg
    return dataclasses.replace(
        cfg, leader=dataclasses.replace(lead, speed=speed, max_turn_rate=turn)
    )


def check_leader_drive(cfg: ScenarioConfig, path: str) -> None:
    """With ``leader.drive`` ``"check"`` or ``"retime"`` (after :func:`fit_leader_to_drive`),
    the leader keeps the robots' drive (:func:`leader_drive_excess`); ``ScenarioError`` naming
    the leader's field and the bound otherwise. ``"free"``: nothing checked here."""
    lead = cfg.leader
    require(
        lead.drive in LEADER_DRIVE_MODES,
        f"{path}.leader.drive",
        f"must be one of {', '.join(LEADER_DRIVE_MODES)}, got {lead.drive!r}",
    )
    if lead.drive == "free":
        return
    excess = leader_drive_excess(cfg)
    if not excess:
        return
    name, value, limit, field, where = excess[0]
    fastest = (
        " at the fastest speed factor 1 + leader.speed_variation" if lead.speed_variation else ""
    )
    raise field_error(
        f"{path}.{where}",
        f"the leader's {name}{fastest} reaches {value:.6g}, above {field} = {limit:g} (the "
        f"leader is one of the robots; leader.drive = {lead.drive!r}): set leader.drive: "
        "retime to slow it down, or raise the bound",
    )
