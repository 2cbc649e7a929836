"""The scripted leader ``R_0`` (eq. 1, Problem 1: "a feasible path ... with bounded linear and
angular velocity"; Remark 2: any planner may dictate its motion). Two modes:

* **pure pursuit** (``leader.path``, :func:`leader_command`): the leader tracks its arc-length
  progress ``s`` along the path (monotone: it never goes back), steers towards the point
  ``lookahead`` metres further along with the pure-pursuit curvature ``kappa = 2 sin(alpha) / L``
  (``alpha`` the bearing of that point, ``L`` its distance) at ``leader.speed``, bounds its turn
  rate, and stops for good when it reaches the path's end.
* **timed trajectory** (``leader.trajectory``, :func:`replay_leader`): samples ``(t_k, x_k, y_k,
  theta_k)`` replayed exactly. At trajectory time ``tau`` the pose is the sample's when ``tau`` is
  a sample time (float-exact: within :data:`TRAJECTORY_TIME_TOLERANCE`), else the interpolation
  between the samples around it: linear in ``x``, ``y`` and along the shorter way round in
  ``theta``, ``theta_k + s wrap(theta_{k+1} - theta_k)``, ``s = (tau - t_k) / (t_{k+1} - t_k)``.
  Its velocity on that segment is the one the interpolation implies
  (:func:`segment_velocity`): ``u = ±|p_{k+1} - p_k| / (t_{k+1} - t_k)`` (negative when the
  displacement points backwards from the segment's mean heading), ``omega = wrap(theta_{k+1} -
  theta_k) / (t_{k+1} - t_k)``. At the last sample's time the leader has arrived and stays.

Both modes take the episode's speed factor ``f`` (``leader.speed_variation``, drawn at reset):
pure pursuit drives at ``f * leader.speed``; a trajectory is replayed ``f`` times as fast (the
leader is at sample ``k`` at time ``t_k / f``, with velocities ``f (u, omega)``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from platoon_env.geometry.primitives import wrap_angle
from platoon_env.records import PATH_T, PATH_THETA, PATH_X, PATH_Y, Route

#: Distance to the path's end at which the leader counts as arrived [m].
ARRIVAL_TOLERANCE = 1e-3
#: Relative tolerance (of ``max(1 s, t_k)``) within which the replay's clock is at the time
#: ``t_k`` of a sample, and the leader exactly at that sample's pose: the clock ``n h f`` (``n``
#: sub-steps of ``h``) rounds, and a sample time written in decimal (``0.3``) is not a binary
#: number. Far above rounding (a few 1e-16), far below the shortest sample interval the schema
#: allows (:data:`~platoon_env.scenarios.schema.MIN_TRAJECTORY_INTERVAL` over
#: :data:`~platoon_env.scenarios.schema.MAX_TRAJECTORY_DURATION`).
TRAJECTORY_TIME_TOLERANCE = 1e-13


def path_arclength(path: np.ndarray) -> np.ndarray:
    """Cumulative arc length at each vertex of a polyline ``(M, 2)``; starts at 0."""
    seg = np.hypot(np.diff(path[:, 0]), np.diff(path[:, 1]))
    return np.concatenate([[0.0], np.cumsum(seg)])


@njit(cache=True)
def point_at(path: np.ndarray, cum: np.ndarray, s: float) -> tuple[float, float]:
    """The point at arc length ``s`` (clamped to the path)."""
    m = path.shape[0]
    if s <= 0.0:
        return path[0, 0], path[0, 1]
    if s >= cum[m - 1]:
        return path[m - 1, 0], path[m - 1, 1]
    k = int(np.searchsorted(cum, s)) - 1
    k = max(0, min(k, m - 2))
    seg = cum[k + 1] - cum[k]
    t = 0.0 if seg <= 0.0 else (s - cum[k]) / seg
    return (
        path[k, 0] + t * (path[k + 1, 0] - path[k, 0]),
        path[k, 1] + t * (path[k + 1, 1] - path[k, 1]),
    )


@njit(cache=True)
def project_progress(
    path: np.ndarray, cum: np.ndarray, point: tuple[float, float], s_prev: float, window: float
) -> float:
    """Arc length of the path point nearest to ``point`` in ``[s_prev, s_prev + window]``.

    Searching only forward in a window keeps the progress monotone and unambiguous on paths
    that pass near themselves.
    """
    x, y = point
    m = path.shape[0]
    best_d = math.inf
    best_s = s_prev
    # Segments ending before s_prev are skipped by a binary search; the loop stops past the window.
    first = max(0, int(np.searchsorted(cum, s_prev)) - 1)
    for k in range(first, m - 1):
        if cum[k] > s_prev + window:
            break
        if cum[k + 1] < s_prev:
            continue
        ax, ay = path[k, 0], path[k, 1]
        dx, dy = path[k + 1, 0] - ax, path[k + 1, 1] - ay
        len2 = dx * dx + dy * dy
        t = 0.0 if len2 <= 0.0 else ((x - ax) * dx + (y - ay) * dy) / len2
        t = min(1.0, max(0.0, t))
        s = cum[k] + t * (cum[k + 1] - cum[k])
        if s < s_prev:
            s = s_prev
            px, py = point_at(path, cum, s)
        else:
            px, py = ax + t * dx, ay + t * dy
        d = math.hypot(x - px, y - py)
        if d < best_d:
            best_d = d
            best_s = s
    return best_s


@njit(cache=True)
def leader_command(
    route: Route,
    pose: tuple[float, float, float],
    s: float,
    p: np.record,
    speed_factor: float = 1.0,
) -> tuple[float, float, float, bool]:
    """Pure-pursuit command ``(u, omega)`` for one sub-step of ``h = p.substep`` seconds.

    ``route`` is the path ``(M, 2)`` (or a :data:`~platoon_env.records.Route`'s ``(M, 4)``:
    its first two columns) and its cumulative arc length; ``pose`` the leader's
    ``(x, y, theta)``; ``s`` its progress; ``p`` a :data:`~platoon_env.records.PARAMS_DTYPE`
    record (``leader_speed``, ``lookahead``, ``leader_turn_rate``, ``substep``; with
    ``leader_rate_limited`` it brakes in time to stop at the end within ``leader_accel``);
    ``speed_factor`` the episode's ``f`` (the leader drives at ``f * leader_speed``). Returns
    ``(u, omega, s_new, arrived)``: the updated progress and whether the leader has reached the
    end (then ``u = omega = 0``).
    """
    path, cum = route
    x, y, theta = pose
    speed, lookahead, h = p.leader_speed * speed_factor, p.lookahead, p.substep
    max_turn_rate = p.leader_turn_rate
    total = cum[cum.shape[0] - 1]
    s_new = project_progress(path, cum, (x, y), s, 2.0 * lookahead + speed * h + 1.0)
    ex, ey = path[path.shape[0] - 1, 0], path[path.shape[0] - 1, 1]
    to_end = math.hypot(ex - x, ey - y)
    if total - s_new <= ARRIVAL_TOLERANCE or to_end <= ARRIVAL_TOLERANCE:
        return 0.0, 0.0, s_new, True
    tx, ty = point_at(path, cum, s_new + lookahead)
    dist = math.hypot(tx - x, ty - y)
    alpha = wrap_angle(math.atan2(ty - y, tx - x) - theta)
    u = speed
    if p.leader_rate_limited:
        # Brake in time: within the acceleration bound the leader stops at the path's end.
        u = min(u, math.sqrt(2.0 * p.leader_accel * max(total - s_new, 0.0)))
    if total - s_new < lookahead:
        # Final approach: arrive at the end point without overshooting it.
        u = min(speed, to_end / h)
        if abs(alpha) > 0.5 * math.pi:
            return 0.0, 0.0, s_new, True
    omega = 2.0 * u * math.sin(alpha) / max(dist, 1e-9)
    omega = min(max_turn_rate, max(-max_turn_rate, omega))
    return u, omega, s_new, False


@njit(cache=True)
def limit_leader_rates(
    u: float, omega: float, u_prev: float, omega_prev: float, p: np.record
) -> tuple[float, float]:
    """A pure-pursuit leader's command ``(u, omega)`` for one sub-step of ``h = p.substep``
    within the robots' rate limits (``leader.drive`` ``check``/``retime``, ``p.leader_accel``,
    ``p.leader_alpha``): each moves from the last sub-step's ``(u_prev, omega_prev)`` by at most
    ``accel h`` and ``alpha h``. After arriving (a command of zero) the leader so coasts to a
    stop within the bound."""
    du = p.leader_accel * p.substep
    dw = p.leader_alpha * p.substep
    return (
        min(u_prev + du, max(u_prev - du, u)),
        min(omega_prev + dw, max(omega_prev - dw, omega)),
    )


@njit(cache=True)
def segment_velocity(route: Route, k: int) -> tuple[float, float]:
    """The velocity ``(u, omega)`` that the interpolation implies on segment ``k`` (from sample
    ``k`` to ``k + 1``) of a timed trajectory ``route`` (module docstring), at speed factor 1.

    ``|u| = |p_{k+1} - p_k| / (t_{k+1} - t_k)``, negative when the displacement points backwards
    from the segment's mean heading ``theta_k + wrap(theta_{k+1} - theta_k) / 2``;
    ``omega = wrap(theta_{k+1} - theta_k) / (t_{k+1} - t_k)``. The schema's feasibility rule
    bounds these (:func:`platoon_env.scenarios.schema.check_ranges`).
    """
    path = route[0]
    dt = path[k + 1, PATH_T] - path[k, PATH_T]
    dx = path[k + 1, PATH_X] - path[k, PATH_X]
    dy = path[k + 1, PATH_Y] - path[k, PATH_Y]
    turn = wrap_angle(path[k + 1, PATH_THETA] - path[k, PATH_THETA])
    u = math.hypot(dx, dy) / dt
    mid = path[k, PATH_THETA] + 0.5 * turn
    if dx * math.cos(mid) + dy * math.sin(mid) < 0.0:
        u = -u
    return u, turn / dt


@njit(cache=True)
def trajectory_velocities(route: Route) -> tuple[np.ndarray, np.ndarray]:
    """:func:`segment_velocity` of every segment of ``route``: ``(u, omega)``, each ``(M - 1,)``."""
    m = route[0].shape[0]
    u = np.empty(m - 1)
    omega = np.empty(m - 1)
    for k in range(m - 1):
        u[k], omega[k] = segment_velocity(route, k)
    return u, omega


@njit(cache=True, inline="always")
def _at_time(tau: float, t: float) -> bool:
    """Whether the clock ``tau`` is at the sample time ``t`` (:data:`TRAJECTORY_TIME_TOLERANCE`)."""
    return abs(tau - t) <= TRAJECTORY_TIME_TOLERANCE * max(1.0, abs(t))


@njit(cache=True, inline="always")
def _segment_at(path: np.ndarray, tau: float) -> int:
    """The segment ``k`` with ``t_k <= tau < t_{k+1}`` (clamped to ``[0, M - 2]``): a binary
    search over the sample times (column :data:`~platoon_env.records.PATH_T`)."""
    lo, hi = 0, path.shape[0] - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if path[mid, PATH_T] <= tau:
            lo = mid
        else:
            hi = mid
    return lo


@njit(cache=True)
def replay_leader(
    route: Route, tau: float
) -> tuple[float, float, float, float, float, float, bool]:
    """The leader of a timed trajectory ``route`` at trajectory time ``tau > 0`` [s].

    Returns ``(x, y, theta, s, u, omega, arrived)``: the pose (a sample's own, bit for bit, when
    ``tau`` is its time; else the interpolation of the module docstring), the arc length ``s``
    along the samples' polyline, the velocity of the motion just before ``tau`` at speed factor
    1 (:func:`segment_velocity` of the segment that ends at or contains ``tau``), and whether
    ``tau`` reached the last sample's time (then the pose is the last sample's).
    """
    path, cum = route
    last = path.shape[0] - 1
    t_last = path[last, PATH_T]
    if tau >= t_last or _at_time(tau, t_last):
        u, omega = segment_velocity(route, last - 1)
        return (
            path[last, PATH_X],
            path[last, PATH_Y],
            path[last, PATH_THETA],
            cum[last],
            u,
            omega,
            True,
        )
    k = _segment_at(path, tau)
    if _at_time(tau, path[k + 1, PATH_T]):
        u, omega = segment_velocity(route, k)
        j = k + 1
        return path[j, PATH_X], path[j, PATH_Y], path[j, PATH_THETA], cum[j], u, omega, False
    if _at_time(tau, path[k, PATH_T]) and k > 0:
        u, omega = segment_velocity(route, k - 1)
        return path[k, PATH_X], path[k, PATH_Y], path[k, PATH_THETA], cum[k], u, omega, False
    u, omega = segment_velocity(route, k)
    a, b = path[k], path[k + 1]
    frac = (tau - a[PATH_T]) / (b[PATH_T] - a[PATH_T])
    x = a[PATH_X] + frac * (b[PATH_X] - a[PATH_X])
    y = a[PATH_Y] + frac * (b[PATH_Y] - a[PATH_Y])
    theta = a[PATH_THETA] + frac * wrap_angle(b[PATH_THETA] - a[PATH_THETA])
    s = cum[k] + frac * (cum[k + 1] - cum[k])
    return x, y, theta, s, u, omega, False
