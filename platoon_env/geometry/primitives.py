"""Compiled 2D primitives: point/segment distances and segment intersection.

All functions are numba ``njit`` scalar kernels used inside the per-step loops; they take plain
floats so that no array is allocated in the hot path. Tests check them against shapely. The
``*_distance2`` variants return squared distances: the per-step kernels compare and minimise
those and take one square root at the end.
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, inline="always")
def cross(ax: float, ay: float, bx: float, by: float) -> float:
    """z-component of the cross product ``a x b``."""
    return ax * by - ay * bx


@njit(cache=True)
def point_segment_distance(
    px: float, py: float, ax: float, ay: float, bx: float, by: float
) -> float:
    """Euclidean distance from point ``p`` to the closed segment ``[a, b]``."""
    dx = bx - ax
    dy = by - ay
    len2 = dx * dx + dy * dy
    if len2 <= 0.0:
        return math.hypot(px - ax, py - ay)
    t = ((px - ax) * dx + (py - ay) * dy) / len2
    if t < 0.0:
        t = 0.0
    elif t > 1.0:
        t = 1.0
    return math.hypot(px - (ax + t * dx), py - (ay + t * dy))


@njit(cache=True)
def point_segment_distance2(
    px: float, py: float, ax: float, ay: float, bx: float, by: float
) -> float:
    """Squared Euclidean distance from point ``p`` to the closed segment ``[a, b]``."""
    dx = bx - ax
    dy = by - ay
    len2 = dx * dx + dy * dy
    ex = px - ax
    ey = py - ay
    if len2 <= 0.0:
        return ex * ex + ey * ey
    t = (ex * dx + ey * dy) / len2
    if t < 0.0:
        t = 0.0
    elif t > 1.0:
        t = 1.0
    ex -= t * dx
    ey -= t * dy
    return ex * ex + ey * ey


@njit(cache=True)
def _on_segment(px: float, py: float, ax: float, ay: float, bx: float, by: float) -> bool:
    # p is known to be collinear with [a, b]; is it inside the bounding box?
    return min(ax, bx) <= px <= max(ax, bx) and min(ay, by) <= py <= max(ay, by)


@njit(cache=True)
def segments_intersect(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float, dx: float, dy: float
) -> bool:
    """True when the closed segments ``[a, b]`` and ``[c, d]`` share a point (touching counts)."""
    d1 = cross(bx - ax, by - ay, cx - ax, cy - ay)
    d2 = cross(bx - ax, by - ay, dx - ax, dy - ay)
    d3 = cross(dx - cx, dy - cy, ax - cx, ay - cy)
    d4 = cross(dx - cx, dy - cy, bx - cx, by - cy)
    if ((d1 > 0.0 and d2 < 0.0) or (d1 < 0.0 and d2 > 0.0)) and (
        (d3 > 0.0 and d4 < 0.0) or (d3 < 0.0 and d4 > 0.0)
    ):
        return True
    if d1 == 0.0 and _on_segment(cx, cy, ax, ay, bx, by):
        return True
    if d2 == 0.0 and _on_segment(dx, dy, ax, ay, bx, by):
        return True
    if d3 == 0.0 and _on_segment(ax, ay, cx, cy, dx, dy):
        return True
    if d4 == 0.0 and _on_segment(bx, by, cx, cy, dx, dy):
        return True
    return False


@njit(cache=True)
def segment_segment_distance(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float, dx: float, dy: float
) -> float:
    """Distance between the closed segments ``[a, b]`` and ``[c, d]`` (0 if they touch)."""
    if segments_intersect(ax, ay, bx, by, cx, cy, dx, dy):
        return 0.0
    return min(
        point_segment_distance(ax, ay, cx, cy, dx, dy),
        point_segment_distance(bx, by, cx, cy, dx, dy),
        point_segment_distance(cx, cy, ax, ay, bx, by),
        point_segment_distance(dx, dy, ax, ay, bx, by),
    )


@njit(cache=True, inline="always")
def box_distance(
    ax0: float, ay0: float, ax1: float, ay1: float, bx0: float, by0: float, bx1: float, by1: float
) -> float:
    """Distance between two axis-aligned boxes ``[x0, x1] x [y0, y1]`` (0 if they overlap).

    A lower bound of the distance between any geometry inside them, used to skip edges.
    """
    gx = max(0.0, max(ax0, bx0) - min(ax1, bx1))
    gy = max(0.0, max(ay0, by0) - min(ay1, by1))
    return math.hypot(gx, gy)


@njit(cache=True, inline="always")
def box_distance2(
    ax0: float, ay0: float, ax1: float, ay1: float, bx0: float, by0: float, bx1: float, by1: float
) -> float:
    """Squared :func:`box_distance` (no square root: used to skip edges cheaply)."""
    gx = max(0.0, max(ax0, bx0) - min(ax1, bx1))
    gy = max(0.0, max(ay0, by0) - min(ay1, by1))
    return gx * gx + gy * gy


@njit(cache=True, inline="always")
def wrap_angle(a: float) -> float:
    """Wrap an angle into ``(-pi, pi]``."""
    two_pi = 2.0 * math.pi
    a = a - two_pi * math.floor((a + math.pi) / two_pi)  # now in [-pi, pi)
    if a <= -math.pi:
        a += two_pi
    return a
