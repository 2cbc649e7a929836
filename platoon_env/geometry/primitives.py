"""Compiled 2D primitives: point/segment and box distances, segment intersection.

All functions are numba ``njit`` scalar kernels used inside the per-step loops. Points and
vectors are ``(x, y)`` tuples and axis-aligned boxes ``(x0, y0, x1, y1)`` tuples of floats:
numba keeps them in registers, so no array is allocated in the hot path. The ``*_distance2``
variants return squared distances: the per-step kernels compare and minimise those and take one
square root at the end.
"""

from __future__ import annotations

import math

from numba import njit

#: A point or vector ``(x, y)`` [m].
Point = tuple[float, float]
#: An axis-aligned box ``(x0, y0, x1, y1)`` [m], ``x0 <= x1``, ``y0 <= y1``.
Box = tuple[float, float, float, float]


@njit(cache=True, inline="always")
def cross(a: Point, b: Point) -> float:
    """z-component of the cross product ``a x b``."""
    return a[0] * b[1] - a[1] * b[0]


@njit(cache=True)
def point_segment_distance2(p: Point, a: Point, b: Point) -> float:
    """Squared Euclidean distance from point ``p`` to the closed segment ``[a, b]``."""
    ax, ay = a
    dx = b[0] - ax
    dy = b[1] - ay
    len2 = dx * dx + dy * dy
    ex = p[0] - ax
    ey = p[1] - ay
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
def _on_segment(p: Point, a: Point, b: Point) -> bool:
    # p is known to be collinear with [a, b]; is it inside the bounding box?
    return min(a[0], b[0]) <= p[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= p[1] <= max(a[1], b[1])


@njit(cache=True)
def segments_intersect(a: Point, b: Point, c: Point, d: Point) -> bool:
    """True when the closed segments ``[a, b]`` and ``[c, d]`` share a point (touching counts)."""
    ab = (b[0] - a[0], b[1] - a[1])
    cd = (d[0] - c[0], d[1] - c[1])
    d1 = cross(ab, (c[0] - a[0], c[1] - a[1]))
    d2 = cross(ab, (d[0] - a[0], d[1] - a[1]))
    d3 = cross(cd, (a[0] - c[0], a[1] - c[1]))
    d4 = cross(cd, (b[0] - c[0], b[1] - c[1]))
    if ((d1 > 0.0 and d2 < 0.0) or (d1 < 0.0 and d2 > 0.0)) and (
        (d3 > 0.0 and d4 < 0.0) or (d3 < 0.0 and d4 > 0.0)
    ):
        return True
    if d1 == 0.0 and _on_segment(c, a, b):
        return True
    if d2 == 0.0 and _on_segment(d, a, b):
        return True
    if d3 == 0.0 and _on_segment(a, c, d):
        return True
    if d4 == 0.0 and _on_segment(b, c, d):
        return True
    return False


@njit(cache=True, inline="always")
def box_distance2(a: Box, b: Box) -> float:
    """Squared distance between two axis-aligned boxes ``(x0, y0, x1, y1)`` (0 if they overlap).

    A lower bound of the squared distance between any geometry inside them, used to skip edges
    cheaply (no square root).
    """
    gx = max(0.0, max(a[0], b[0]) - min(a[2], b[2]))
    gy = max(0.0, max(a[1], b[1]) - min(a[3], b[3]))
    return gx * gx + gy * gy


@njit(cache=True, inline="always")
def point_box_distance2(p: Point, b: Box) -> float:
    """Squared distance from point ``p`` to the box ``b`` (:func:`box_distance2` of the
    degenerate box ``(p, p)``, the same operations)."""
    return box_distance2((p[0], p[1], p[0], p[1]), b)


@njit(cache=True, inline="always")
def boxes_overlap(a: Box, b: Box) -> bool:
    """Whether the closed boxes ``a`` and ``b`` share a point."""
    return b[0] <= a[2] and b[2] >= a[0] and b[1] <= a[3] and b[3] >= a[1]


@njit(cache=True, inline="always")
def wrap_angle(a: float) -> float:
    """Wrap an angle into ``(-pi, pi]``."""
    two_pi = 2.0 * math.pi
    a = a - two_pi * math.floor((a + math.pi) / two_pi)  # now in [-pi, pi)
    if a <= -math.pi:
        a += two_pi
    return a


@njit(cache=True, inline="always")
def padded_box(a: Point, b: Point, c: Point, pad: float) -> Box:
    """The bounding box of the points ``a``, ``b``, ``c``, grown by ``pad`` on every side (the
    grid query of a follower, its predecessor and its position before a sub-step)."""
    return (
        min(min(a[0], b[0]), c[0]) - pad,
        min(min(a[1], b[1]), c[1]) - pad,
        max(max(a[0], b[0]), c[0]) + pad,
        max(max(a[1], b[1]), c[1]) + pad,
    )
