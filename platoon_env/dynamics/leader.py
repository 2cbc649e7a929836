"""The scripted leader ``R_0``: pure pursuit along a polyline path at constant speed.

The leader tracks its arc-length progress ``s`` along the path (monotone: it never goes back),
steers towards the point ``lookahead`` metres further along with the pure-pursuit curvature
``kappa = 2 sin(alpha) / L`` (``alpha`` the bearing of that point, ``L`` its distance), bounds
its turn rate, and stops for good when it reaches the path's end.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from platoon_env.geometry.primitives import wrap_angle

#: Distance to the path's end at which the leader counts as arrived [m].
ARRIVAL_TOLERANCE = 1e-3


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
    route: tuple[np.ndarray, np.ndarray],
    pose: tuple[float, float, float],
    s: float,
    p: np.record,
) -> tuple[float, float, float, bool]:
    """Pure-pursuit command ``(u, omega)`` for one sub-step of ``h = p.substep`` seconds.

    ``route`` is the path ``(M, 2)`` and its cumulative arc length; ``pose`` the leader's
    ``(x, y, theta)``; ``s`` its progress; ``p`` a :data:`~platoon_env.records.PARAMS_DTYPE`
    record (``leader_speed``, ``lookahead``, ``leader_turn_rate``, ``substep``). Returns
    ``(u, omega, s_new, arrived)``: the updated progress and whether the leader has reached the
    end (then ``u = omega = 0``).
    """
    path, cum = route
    x, y, theta = pose
    speed, lookahead, h = p.leader_speed, p.lookahead, p.substep
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
    if total - s_new < lookahead:
        # Final approach: arrive at the end point without overshooting it.
        u = min(speed, to_end / h)
        if abs(alpha) > 0.5 * math.pi:
            return 0.0, 0.0, s_new, True
    omega = 2.0 * u * math.sin(alpha) / max(dist, 1e-9)
    omega = min(max_turn_rate, max(-max_turn_rate, omega))
    return u, omega, s_new, False
