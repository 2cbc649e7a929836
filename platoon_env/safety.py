"""Safety rules (eqs. 4-5, DESIGN §3): which constraint a follower violates, checked after every
physics sub-step.

A violation of follower ``i`` has a cause (bit ``k`` of a mask is ``VIOLATION_CAUSES[k]``):

* ``collision_robot``: ``d_i <= d_col``, or any two robots' disks touch (``|p_j - p_k| <= 2r``);
* ``collision_obstacle``: clearance to ``∂W_f`` ``<= r`` (eq. 4), or the robot's motion over the
  sub-step crossed the boundary (so a fast robot cannot tunnel through a thin wall unnoticed);
* ``occluded``: ``L_i`` touches ``∂W_f`` (eq. 5, ``d_l, d_r > 0``);
* ``out_of_range``: ``d_i >= d_con``; ``out_of_fov``: ``|beta_i| >= beta_con`` (eq. 5).

The primitives are those of :mod:`platoon_env.geometry.sensing`, so sensing and collision checks
agree on where the walls are. Distances are compared squared (``clearance² <= r²``), exactly as
the sensing kernel reports them, so that the sub-step checks and the final sensing agree. In the
last sub-step of a control period the simulator derives the mask from the sensing it computes
anyway (:func:`sensed_violation`), instead of testing the same edges twice.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from platoon_env.geometry.grid import grid_candidates
from platoon_env.geometry.primitives import (
    box_distance2,
    point_segment_distance2,
    segments_intersect,
    wrap_angle,
)
from platoon_env.geometry.sensing import (
    SENSE_CLEARANCE,
    SENSE_D_SIGHT_LEFT,
    SENSE_D_SIGHT_RIGHT,
    SENSE_OCCLUDED,
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


#: Cause names of every possible mask, in reporting priority order (a lookup table: masks are
#: read every step; ``CAUSES_OF_MASK[m]`` is :func:`mask_to_causes` without the call).
CAUSES_OF_MASK: tuple[tuple[str, ...], ...] = tuple(
    _causes(m) for m in range(1 << len(VIOLATION_CAUSES))
)


def mask_to_causes(mask: int) -> tuple[str, ...]:
    """Cause names set in ``mask``, in reporting priority order."""
    return CAUSES_OF_MASK[mask]


def first_cause(mask: int) -> str | None:
    """The highest-priority cause in ``mask`` (the one reported in ``info['violation']``)."""
    for k, cause in enumerate(VIOLATION_CAUSES):
        if mask & (1 << k):
            return cause
    return None


@njit(cache=True)
def near_boundary(px: float, py: float, limit: float, edges: np.ndarray, boxes: np.ndarray) -> bool:
    """True when some boundary point lies within ``limit`` of ``p`` (clearance ``<= limit``)."""
    limit2 = limit * limit
    for e in range(edges.shape[0]):
        if (
            box_distance2(px, py, px, py, boxes[e, 0], boxes[e, 1], boxes[e, 2], boxes[e, 3])
            > limit2
        ):
            continue
        if (
            point_segment_distance2(px, py, edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3])
            <= limit2
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


@njit(cache=True, inline="always")
def distance_bearing_causes(
    d: float, beta: float, d_col: float, d_con: float, beta_con: float
) -> int:
    """The causes read off ``d_i`` and ``beta_i`` alone: ``d_i <= d_col`` (eq. 4),
    ``d_i >= d_con`` and ``|beta_i| >= beta_con`` (eq. 5)."""
    mask = 0
    if d <= d_col:
        mask |= COLLISION_ROBOT
    if d >= d_con:
        mask |= OUT_OF_RANGE
    if abs(beta) >= beta_con:
        mask |= OUT_OF_FOV
    return mask


@njit(cache=True)
def pose_violation(
    px: float,
    py: float,
    theta: float,
    qx: float,
    qy: float,
    d_col: float,
    d_con: float,
    beta_con: float,
) -> int:
    """The causes that depend on the pair of poses only: ``d_i`` and ``beta_i`` (eqs. 2-5)."""
    dx = qx - px
    dy = qy - py
    d = math.sqrt(dx * dx + dy * dy)  # as in sensing.sense_candidates
    beta = wrap_angle(math.atan2(dy, dx) - theta)
    return distance_bearing_causes(d, beta, d_col, d_con, beta_con)


@njit(cache=True)
def follower_violation(
    px: float,
    py: float,
    theta: float,
    qx: float,
    qy: float,
    ox: float,
    oy: float,
    edges: np.ndarray,
    boxes: np.ndarray,
    cand: np.ndarray,
    n_cand: int,
    radius: float,
    d_col: float,
    d_con: float,
    beta_con: float,
) -> int:
    """Violation mask of the follower at ``p`` (previously at ``o``) behind a robot at ``q``.

    Visits the edges ``cand[:n_cand]``, which must include every edge whose bounding box lies
    within ``radius`` of ``p`` or overlaps the boxes of ``[o, p]`` and ``L_i = [p, q]``. Robot
    contacts other than with the predecessor are added by :func:`robot_contacts`.
    """
    mask = pose_violation(px, py, theta, qx, qy, d_col, d_con, beta_con)
    r2 = radius * radius
    mx0, mx1 = min(ox, px), max(ox, px)
    my0, my1 = min(oy, py), max(oy, py)
    sx0, sx1 = min(px, qx), max(px, qx)
    sy0, sy1 = min(py, qy), max(py, qy)
    obstacle = False
    occluded = False
    for k in range(n_cand):
        e = cand[k]
        bx0, by0, bx1, by1 = boxes[e, 0], boxes[e, 1], boxes[e, 2], boxes[e, 3]
        ax, ay, bx, by = edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3]
        if not obstacle:
            if box_distance2(px, py, px, py, bx0, by0, bx1, by1) <= r2 and (
                point_segment_distance2(px, py, ax, ay, bx, by) <= r2
            ):
                obstacle = True
            elif (
                bx0 <= mx1
                and bx1 >= mx0
                and by0 <= my1
                and by1 >= my0
                and segments_intersect(ox, oy, px, py, ax, ay, bx, by)
            ):
                obstacle = True
        if (
            not occluded
            and bx0 <= sx1
            and bx1 >= sx0
            and by0 <= sy1
            and by1 >= sy0
            and segments_intersect(px, py, qx, qy, ax, ay, bx, by)
        ):
            occluded = True
        if obstacle and occluded:
            break
    if obstacle:
        mask |= COLLISION_OBSTACLE
    if occluded:
        mask |= OCCLUDED
    return mask


@njit(cache=True)
def sensed_violation(
    d: float,
    beta: float,
    clearance2: float,
    occluded: bool,
    motion_hit: bool,
    radius: float,
    d_col: float,
    d_con: float,
    beta_con: float,
) -> int:
    """The violation mask from a follower's sensing (``d``, ``beta``, squared clearance,
    occlusion) and the tunnelling check; same rules as :func:`follower_violation`."""
    mask = distance_bearing_causes(d, beta, d_col, d_con, beta_con)
    if clearance2 <= radius * radius or motion_hit:
        mask |= COLLISION_OBSTACLE
    if occluded:
        mask |= OCCLUDED
    return mask


@njit(cache=True)
def robot_contacts(poses: np.ndarray, radius: float, out: np.ndarray) -> None:
    """OR ``COLLISION_ROBOT`` into ``out`` (N,) for every follower whose disk touches another's.

    Any two robots count (non-consecutive ones, and the leader), ``|p_j - p_k| <= 2r``.
    """
    touch2 = 4.0 * radius * radius
    n_robots = poses.shape[0]
    for j in range(n_robots):
        xj, yj = poses[j, 0], poses[j, 1]
        for k in range(j + 1, n_robots):
            gx = poses[k, 0] - xj
            gy = poses[k, 1] - yj
            if gx * gx + gy * gy <= touch2:
                if j >= 1:
                    out[j - 1] |= COLLISION_ROBOT
                out[k - 1] |= COLLISION_ROBOT


@njit(cache=True)
def violation_masks_grid(
    poses: np.ndarray,
    prev_poses: np.ndarray,
    edges: np.ndarray,
    boxes: np.ndarray,
    grid_params: np.ndarray,
    cell_start: np.ndarray,
    cell_edges: np.ndarray,
    edge_cell: np.ndarray,
    cand: np.ndarray,
    radius: float,
    d_col: float,
    d_con: float,
    beta_con: float,
    out: np.ndarray,
    start_sensed: np.ndarray,
    travel: np.ndarray,
) -> None:
    """:func:`violation_masks` visiting only the edges the grid lists near each follower.

    ``cand`` is scratch space for at least ``E`` edge indices.

    When ``start_sensed`` (N, SENSE_SIZE) holds the sensing of earlier poses and ``travel``
    (N+1,) bounds how far each robot has moved since, a follower whose clearance then exceeded
    ``r`` plus its travel, and whose line of sight then kept farther from ``∂W_f`` than either
    end has moved, cannot have touched an obstacle, crossed one or lost its line of sight: its
    edge tests are skipped (the result is the same, only cheaper). Pass an empty
    ``start_sensed`` (0 rows) to test every follower.
    """
    reach = radius * (1.0 + 1e-9) + 1e-9
    bounded = start_sensed.shape[0] > 0
    for i in range(1, poses.shape[0]):
        px, py = poses[i, 0], poses[i, 1]
        qx, qy = poses[i - 1, 0], poses[i - 1, 1]
        if bounded:
            # Margins far above the rounding error of the distances involved.
            moved = travel[i] * (1.0 + 1e-9) + 1e-9
            moved_sight = max(travel[i], travel[i - 1]) * (1.0 + 1e-9) + 1e-9
            row = start_sensed[i - 1]
            if (
                row[SENSE_CLEARANCE] > radius + moved
                and row[SENSE_OCCLUDED] == 0.0
                and min(row[SENSE_D_SIGHT_LEFT], row[SENSE_D_SIGHT_RIGHT]) > moved_sight
            ):
                out[i - 1] = pose_violation(px, py, poses[i, 2], qx, qy, d_col, d_con, beta_con)
                continue
        ox, oy = prev_poses[i, 0], prev_poses[i, 1]
        n = grid_candidates(
            grid_params,
            cell_start,
            cell_edges,
            edge_cell,
            min(min(px, qx), ox) - reach,
            min(min(py, qy), oy) - reach,
            max(max(px, qx), ox) + reach,
            max(max(py, qy), oy) + reach,
            cand,
        )
        out[i - 1] = follower_violation(
            px,
            py,
            poses[i, 2],
            qx,
            qy,
            ox,
            oy,
            edges,
            boxes,
            cand,
            n,
            radius,
            d_col,
            d_con,
            beta_con,
        )
    robot_contacts(poses, radius, out)


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

    ``prev_poses`` are the poses before the sub-step (for the tunnelling check). Brute force
    over every edge; the simulator uses the grid (:func:`violation_masks_grid`).
    """
    cand = np.arange(edges.shape[0])
    for i in range(1, poses.shape[0]):
        out[i - 1] = follower_violation(
            poses[i, 0],
            poses[i, 1],
            poses[i, 2],
            poses[i - 1, 0],
            poses[i - 1, 1],
            prev_poses[i, 0],
            prev_poses[i, 1],
            edges,
            boxes,
            cand,
            cand.shape[0],
            radius,
            d_col,
            d_con,
            beta_con,
        )
    robot_contacts(poses, radius, out)
