"""The sensing model (DESIGN §2, paper §2): camera and proximity sensor of every follower.

One compiled kernel computes, for all followers at once, from the ground-truth poses and the
obstacle-boundary edges ``∂W_f``:

* ``d_i = |p_{i-1} - p_i|`` (eq. 2) and ``beta_i = wrap(atan2(y~, x~) - theta_i)`` (eq. 3);
* ``occluded``: the line of sight ``L_i = [p_i, p_{i-1}]`` touches ``∂W_f``;
* ``visible``: ``d_i < d_con``, ``|beta_i| < beta_con`` and not occluded;
* ``d_W_l,i``, ``d_W_r,i``: distance from ``p_i`` to the nearest boundary point left / right of
  ``L_i``; ``d_l,i``, ``d_r,i``: distance from the segment ``L_i`` to the nearest boundary point
  left / right. A point ``b`` is left when ``cross(p_{i-1} - p_i, b - p_i) > 0``; edges that cross
  the line through ``L_i`` are split at it; points on the line count for both sides. All four
  are capped at the proximity range. Hence occluded ⇔ ``d_l = d_r = 0``.
* ``clearance``: distance from ``p_i`` to ``∂W_f``, uncapped (collision iff ``clearance <= r``).

The same edge arrays and primitives serve the collision checks in :mod:`platoon_env.safety`, so
no sensor sees a wall the robot could drive through. Tests compare against a shapely oracle.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from platoon_env.geometry.primitives import (
    box_distance,
    cross,
    point_segment_distance,
    segment_segment_distance,
    segments_intersect,
    wrap_angle,
)

SENSE_D = 0
SENSE_BETA = 1
SENSE_VISIBLE = 2
SENSE_OCCLUDED = 3
SENSE_D_WALL_LEFT = 4
SENSE_D_WALL_RIGHT = 5
SENSE_D_SIGHT_LEFT = 6
SENSE_D_SIGHT_RIGHT = 7
SENSE_CLEARANCE = 8
SENSE_SIZE = 9
SENSE_NAMES: tuple[str, ...] = (
    "d",
    "beta",
    "visible",
    "occluded",
    "d_W_l",
    "d_W_r",
    "d_l",
    "d_r",
    "clearance",
)


@njit(cache=True)
def sense_follower(
    px: float,
    py: float,
    theta: float,
    qx: float,
    qy: float,
    edges: np.ndarray,
    boxes: np.ndarray,
    d_con: float,
    beta_con: float,
    proximity_range: float,
    out: np.ndarray,
) -> None:
    """Sense one follower at ``(px, py, theta)`` whose predecessor is at ``(qx, qy)``.

    Writes the ``SENSE_*`` columns into ``out`` (length ``SENSE_SIZE``). ``boxes`` holds each
    edge's bounding box ``[xmin, ymin, xmax, ymax]``; it lets edges that cannot improve any
    current minimum be skipped.
    """
    dx = qx - px
    dy = qy - py
    d = math.hypot(dx, dy)
    beta = wrap_angle(math.atan2(dy, dx) - theta)
    # Direction that defines left/right; degenerate only when the robots coincide.
    lx, ly = dx, dy
    if d == 0.0:
        lx, ly = math.cos(theta), math.sin(theta)
    sx0, sx1 = min(px, qx), max(px, qx)
    sy0, sy1 = min(py, qy), max(py, qy)
    wall_l = proximity_range
    wall_r = proximity_range
    sight_l = proximity_range
    sight_r = proximity_range
    clearance = math.inf
    occluded = False
    for e in range(edges.shape[0]):
        bx0, by0, bx1, by1 = boxes[e, 0], boxes[e, 1], boxes[e, 2], boxes[e, 3]
        lb_point = box_distance(px, py, px, py, bx0, by0, bx1, by1)
        lb_sight = box_distance(sx0, sy0, sx1, sy1, bx0, by0, bx1, by1)
        need_side = lb_sight < max(max(wall_l, wall_r), max(sight_l, sight_r))
        if lb_point >= clearance and not need_side:
            continue
        ax, ay, bx, by = edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3]
        if lb_point < clearance:
            clearance = min(clearance, point_segment_distance(px, py, ax, ay, bx, by))
        if not need_side:
            continue
        if not occluded and segments_intersect(px, py, qx, qy, ax, ay, bx, by):
            occluded = True
        sa = cross(lx, ly, ax - px, ay - py)
        sb = cross(lx, ly, bx - px, by - py)
        # Split point on the line through L_i (only used when the edge straddles it).
        mx, my = ax, ay
        if (sa > 0.0 and sb < 0.0) or (sa < 0.0 and sb > 0.0):
            t = sa / (sa - sb)
            mx = ax + t * (bx - ax)
            my = ay + t * (by - ay)
        # Left part: the edge's points in the closed half-plane cross >= 0.
        has_left = True
        if sa >= 0.0 and sb >= 0.0:
            cx, cy, ex, ey = ax, ay, bx, by
        elif sa > 0.0:  # sb < 0: straddles
            cx, cy, ex, ey = ax, ay, mx, my
        elif sb > 0.0:  # sa < 0: straddles
            cx, cy, ex, ey = mx, my, bx, by
        elif sa == 0.0:  # sb < 0: only the endpoint a lies on the line
            cx, cy, ex, ey = ax, ay, ax, ay
        elif sb == 0.0:  # sa < 0: only b
            cx, cy, ex, ey = bx, by, bx, by
        else:
            has_left = False
        if has_left:
            wall_l = min(wall_l, point_segment_distance(px, py, cx, cy, ex, ey))
            sight_l = min(sight_l, segment_segment_distance(px, py, qx, qy, cx, cy, ex, ey))
        # Right part: the closed half-plane cross <= 0.
        has_right = True
        if sa <= 0.0 and sb <= 0.0:
            cx, cy, ex, ey = ax, ay, bx, by
        elif sa < 0.0:  # sb > 0: straddles
            cx, cy, ex, ey = ax, ay, mx, my
        elif sb < 0.0:  # sa > 0: straddles
            cx, cy, ex, ey = mx, my, bx, by
        elif sa == 0.0:  # sb > 0
            cx, cy, ex, ey = ax, ay, ax, ay
        elif sb == 0.0:  # sa > 0
            cx, cy, ex, ey = bx, by, bx, by
        else:
            has_right = False
        if has_right:
            wall_r = min(wall_r, point_segment_distance(px, py, cx, cy, ex, ey))
            sight_r = min(sight_r, segment_segment_distance(px, py, qx, qy, cx, cy, ex, ey))
    if occluded:
        sight_l = 0.0
        sight_r = 0.0
    out[SENSE_D] = d
    out[SENSE_BETA] = beta
    out[SENSE_OCCLUDED] = 1.0 if occluded else 0.0
    out[SENSE_VISIBLE] = 1.0 if (d < d_con and abs(beta) < beta_con and not occluded) else 0.0
    out[SENSE_D_WALL_LEFT] = wall_l
    out[SENSE_D_WALL_RIGHT] = wall_r
    out[SENSE_D_SIGHT_LEFT] = sight_l
    out[SENSE_D_SIGHT_RIGHT] = sight_r
    out[SENSE_CLEARANCE] = clearance


@njit(cache=True)
def sense_into(
    poses: np.ndarray,
    edges: np.ndarray,
    boxes: np.ndarray,
    d_con: float,
    beta_con: float,
    proximity_range: float,
    out: np.ndarray,
) -> None:
    """Sense every follower ``i = 1..N`` of ``poses`` ((N+1) x 3) into ``out`` (N x SENSE_SIZE)."""
    for i in range(1, poses.shape[0]):
        sense_follower(
            poses[i, 0],
            poses[i, 1],
            poses[i, 2],
            poses[i - 1, 0],
            poses[i - 1, 1],
            edges,
            boxes,
            d_con,
            beta_con,
            proximity_range,
            out[i - 1],
        )


def edge_boxes(edges: np.ndarray) -> np.ndarray:
    """Bounding box ``[xmin, ymin, xmax, ymax]`` of every edge ``[ax, ay, bx, by]``."""
    edges = np.asarray(edges, dtype=np.float64).reshape(-1, 4)
    return np.ascontiguousarray(
        np.stack(
            [
                np.minimum(edges[:, 0], edges[:, 2]),
                np.minimum(edges[:, 1], edges[:, 3]),
                np.maximum(edges[:, 0], edges[:, 2]),
                np.maximum(edges[:, 1], edges[:, 3]),
            ],
            axis=1,
        )
    )


def sense(
    poses: np.ndarray,
    edges: np.ndarray,
    d_con: float,
    beta_con: float,
    proximity_range: float,
) -> np.ndarray:
    """Sense all followers; returns an ``(N, SENSE_SIZE)`` float64 array of ``SENSE_*`` columns.

    Convenience entry point for tests and plots; the env calls the compiled kernel directly.
    """
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    edges = np.ascontiguousarray(edges, dtype=np.float64).reshape(-1, 4)
    if poses.ndim != 2 or poses.shape[1] != 3 or poses.shape[0] < 2:
        raise ValueError(f"poses must have shape (N+1, 3) with N >= 1, got {poses.shape}")
    out = np.empty((poses.shape[0] - 1, SENSE_SIZE), dtype=np.float64)
    sense_into(poses, edges, edge_boxes(edges), d_con, beta_con, proximity_range, out)
    return out
