"""Safety rules (eqs. 4-5, DESIGN §3): which constraint a follower violates, checked after every
physics sub-step.

A violation of follower ``i`` has a cause (bit ``k`` of a mask is ``VIOLATION_CAUSES[k]``):

* ``collision_robot``: ``d_i <= d_col``, or any two robots' disks touch (``|p_j - p_k| <= 2r``);
* ``collision_obstacle``: clearance to ``∂W_f`` ``<= r`` (eq. 4), or the robot's motion over the
  sub-step crossed the boundary (so a fast robot cannot tunnel through a thin wall unnoticed);
* ``occluded``: ``L_i`` touches ``∂W_f`` (eq. 5, ``d_l, d_r > 0``);
* ``out_of_range``: ``d_i >= d_con``; ``out_of_fov``: ``|beta_i| >= beta_con`` (eq. 5).

The primitives are those of :mod:`platoon_env.geometry.sensing`, so sensing and collision checks
agree on where the walls are.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from platoon_env.geometry.primitives import (
    box_distance,
    point_segment_distance,
    segments_intersect,
    wrap_angle,
)
from platoon_env.scenarios.schema import VIOLATION_CAUSES

COLLISION_ROBOT = 1 << VIOLATION_CAUSES.index("collision_robot")
COLLISION_OBSTACLE = 1 << VIOLATION_CAUSES.index("collision_obstacle")
OCCLUDED = 1 << VIOLATION_CAUSES.index("occluded")
OUT_OF_RANGE = 1 << VIOLATION_CAUSES.index("out_of_range")
OUT_OF_FOV = 1 << VIOLATION_CAUSES.index("out_of_fov")


def causes_to_mask(causes: tuple[str, ...] | list[str] | set[str] | frozenset[str]) -> int:
    """Bit mask of a set of cause names (unknown names raise ``ValueError``)."""
    mask = 0
    for cause in causes:
        if cause not in VIOLATION_CAUSES:
            raise ValueError(
                f"unknown violation cause {cause!r}; expected some of {', '.join(VIOLATION_CAUSES)}"
            )
        mask |= 1 << VIOLATION_CAUSES.index(cause)
    return mask


def _causes(mask: int) -> tuple[str, ...]:
    return tuple(c for k, c in enumerate(VIOLATION_CAUSES) if mask & (1 << k))


#: Cause names of every possible mask (a lookup table: masks are read every step).
_CAUSES_OF_MASK: tuple[tuple[str, ...], ...] = tuple(
    _causes(m) for m in range(1 << len(VIOLATION_CAUSES))
)


def mask_to_causes(mask: int) -> tuple[str, ...]:
    """Cause names set in ``mask``, in reporting priority order."""
    return _CAUSES_OF_MASK[mask]


def first_cause(mask: int) -> str | None:
    """The highest-priority cause in ``mask`` (the one reported in ``info['violation']``)."""
    for k, cause in enumerate(VIOLATION_CAUSES):
        if mask & (1 << k):
            return cause
    return None


@njit(cache=True)
def near_boundary(px: float, py: float, limit: float, edges: np.ndarray, boxes: np.ndarray) -> bool:
    """True when some boundary point lies within ``limit`` of ``p`` (clearance ``<= limit``)."""
    for e in range(edges.shape[0]):
        if box_distance(px, py, px, py, boxes[e, 0], boxes[e, 1], boxes[e, 2], boxes[e, 3]) > limit:
            continue
        if (
            point_segment_distance(px, py, edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3])
            <= limit
        ):
            return True
    return False


@njit(cache=True)
def segment_hits_boundary(
    ax: float, ay: float, bx: float, by: float, edges: np.ndarray, boxes: np.ndarray
) -> bool:
    """True when the closed segment ``[a, b]`` touches any boundary edge."""
    x0, x1 = min(ax, bx), max(ax, bx)
    y0, y1 = min(ay, by), max(ay, by)
    for e in range(edges.shape[0]):
        if boxes[e, 0] > x1 or boxes[e, 2] < x0 or boxes[e, 1] > y1 or boxes[e, 3] < y0:
            continue
        if segments_intersect(ax, ay, bx, by, edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3]):
            return True
    return False


@njit(cache=True)
def violation_masks(
    poses: np.ndarray,
    prev_poses: np.ndarray,
    edges: np.ndarray,
    boxes: np.ndarray,
    radius: float,
    d_col: float,
    d_con: float,
    beta_con: float,
    out: np.ndarray,
) -> None:
    """Violation bit mask of every follower after a sub-step, written to ``out`` (N,) int64.

    ``prev_poses`` are the poses before the sub-step (for the tunnelling check).
    """
    n_robots = poses.shape[0]
    for i in range(1, n_robots):
        mask = 0
        px, py = poses[i, 0], poses[i, 1]
        qx, qy = poses[i - 1, 0], poses[i - 1, 1]
        d = math.hypot(qx - px, qy - py)
        beta = wrap_angle(math.atan2(qy - py, qx - px) - poses[i, 2])
        if d <= d_col:
            mask |= COLLISION_ROBOT
        if near_boundary(px, py, radius, edges, boxes) or segment_hits_boundary(
            prev_poses[i, 0], prev_poses[i, 1], px, py, edges, boxes
        ):
            mask |= COLLISION_OBSTACLE
        if segment_hits_boundary(px, py, qx, qy, edges, boxes):
            mask |= OCCLUDED
        if d >= d_con:
            mask |= OUT_OF_RANGE
        if abs(beta) >= beta_con:
            mask |= OUT_OF_FOV
        out[i - 1] = mask
    # Any two disks touching (non-consecutive robots included).
    touch = 2.0 * radius
    for j in range(n_robots):
        for k in range(j + 1, n_robots):
            if math.hypot(poses[j, 0] - poses[k, 0], poses[j, 1] - poses[k, 1]) <= touch:
                if j >= 1:
                    out[j - 1] |= COLLISION_ROBOT
                out[k - 1] |= COLLISION_ROBOT
