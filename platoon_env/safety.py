"""Safety rules (eqs. 4-5, ``docs/safety.md``): which constraint a follower violates, checked
after every physics sub-step.

A violation of follower ``i`` has a cause (bit ``k`` of a mask is ``VIOLATION_CAUSES[k]``):

* ``collision_robot``: ``d_i <= d_col``, or any two robots' disks touch (``|p_j - p_k| <= 2r``);
* ``collision_obstacle``: clearance to ``∂W_f`` ``<= r`` (eq. 4), or the robot's motion over the
  sub-step crossed the boundary (so a fast robot cannot tunnel through a thin wall unnoticed).
  With an obstacle inflation ``m`` (``safety.inflation``, the paper's study B "augmented the
  obstacles' boundary by 0.1 m", §4.2) the clearance is to the inflated outline: a collision is
  ``true clearance <= r + m`` (:func:`obstacle_contact`); the walls the robot cannot pass are
  still the true ones;
* ``occluded``: ``L_i`` touches ``∂W_f`` (eq. 5, ``d_l, d_r > 0``);
* ``out_of_range``: ``d_i >= d_con``; ``out_of_fov``: ``|beta_i| >= beta_con`` (eq. 5).

The primitives are those of :mod:`platoon_env.geometry.sensing`, so sensing and collision checks
agree on where the walls are. Distances are compared squared (``clearance² <= r²``), exactly as
the sensing kernel reports them, so that the sub-step checks and the final sensing agree. In the
last sub-step of a control period the simulator derives the mask from the sensing it computes
anyway (:func:`sensed_violation`), instead of testing the same edges twice;
:func:`configuration_masks` applies those same rules to a configuration at rest (the initial
one, a scenario's), and :func:`describe_masks` words its violations.

As in :mod:`platoon_env.geometry.sensing`, the kernels take poses as ``(x, y, theta)`` and points
as ``(x, y)`` tuples, the workspace as a :class:`~platoon_env.records.Walls` and the parameters
as one :data:`~platoon_env.records.PARAMS_DTYPE` record ``p``, read by name: ``p.radius`` (r),
``p.d_col`` (eq. 4), ``p.inflation`` (m), ``p.d_con`` and ``p.beta_con`` (eq. 5).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from platoon_env.geometry.grid import grid_candidates
from platoon_env.geometry.primitives import (
    Point,
    boxes_overlap,
    padded_box,
    point_box_distance2,
    point_segment_distance2,
    segments_intersect,
    wrap_angle,
)
from platoon_env.geometry.sensing import (
    SENSE_BETA,
    SENSE_CLEARANCE,
    SENSE_D,
    SENSE_D_SIGHT_LEFT,
    SENSE_D_SIGHT_RIGHT,
    SENSE_OCCLUDED,
    SENSE_SIZE,
    Pose,
    sense_follower_grid,
)
from platoon_env.records import Walls
from platoon_env.violations import (
    CAUSES_OF_MASK,
    COLLISION_OBSTACLE,
    COLLISION_ROBOT,
    OCCLUDED,
    OUT_OF_FOV,
    OUT_OF_RANGE,
    VIOLATION_CAUSES,
    causes_to_mask,
    first_cause,
    mask_to_causes,
)

__all__ = [
    "CAUSES_OF_MASK",
    "COLLISION_OBSTACLE",
    "COLLISION_ROBOT",
    "OCCLUDED",
    "OUT_OF_FOV",
    "OUT_OF_RANGE",
    "VIOLATION_CAUSES",
    "causes_to_mask",
    "configuration_masks",
    "configuration_problems",
    "describe_masks",
    "first_cause",
    "mask_to_causes",
    "motion_crosses_wall",
    "obstacle_contact",
    "obstacle_reach",
    "robot_contacts",
    "sensed_violation",
    "stop_at_walls",
    "violation_masks",
    "violation_masks_grid",
]


@njit(cache=True, inline="always")
def obstacle_reach(p: np.record) -> float:
    """``r + m``: how close [m] a robot's centre may come to the true boundary ``∂W_f`` before
    it collides with the obstacles inflated by ``m = p.inflation`` (eq. 4 on the inflated
    outline: ``d_W > r``)."""
    return p.radius + p.inflation


@njit(cache=True, inline="always")
def obstacle_contact(clearance2: float, p: np.record) -> bool:
    """``collision_obstacle`` by distance (eq. 4): the squared true clearance ``clearance2`` is
    ``<= (r + m)²`` — the robot's disk touches the obstacles inflated by ``m`` (``m = 0``:
    ``clearance² <= r²``). The one rule of every obstacle-collision check."""
    reach = obstacle_reach(p)
    return clearance2 <= reach * reach


@njit(cache=True, inline="always")
def distance_bearing_causes(d: float, beta: float, p: np.record) -> int:
    """The causes read off ``d_i`` and ``beta_i`` alone: ``d_i <= d_col`` (eq. 4),
    ``d_i >= d_con`` and ``|beta_i| >= beta_con`` (eq. 5)."""
    mask = 0
    if d <= p.d_col:
        mask |= COLLISION_ROBOT
    if d >= p.d_con:
        mask |= OUT_OF_RANGE
    if abs(beta) >= p.beta_con:
        mask |= OUT_OF_FOV
    return mask


@njit(cache=True)
def pose_violation(pose: Pose, pred: Point, p: np.record) -> int:
    """The causes that depend on the pair of poses only: ``d_i`` and ``beta_i`` (eqs. 2-5) of
    the follower at ``pose = (x, y, theta)`` behind the robot at ``pred``."""
    dx = pred[0] - pose[0]
    dy = pred[1] - pose[1]
    d = math.sqrt(dx * dx + dy * dy)  # as in sensing.sense_candidates
    beta = wrap_angle(math.atan2(dy, dx) - pose[2])
    return distance_bearing_causes(d, beta, p)


# Inlined, as sensing.sense_candidates, so that no call copies the Walls for every follower.
@njit(cache=True, inline="always")
def follower_violation(
    pose: Pose, pred: Point, prev: Point, walls: Walls, cand: np.ndarray, p: np.record
) -> int:
    """Violation mask of the follower at ``pose`` (previously at ``prev``) behind a robot at
    ``pred``.

    Visits the edges ``cand`` of ``walls``, which must include every edge whose bounding box
    lies within ``r + m`` (:func:`obstacle_reach`) of ``p_i`` or overlaps the boxes of
    ``[prev, p_i]`` and ``L_i = [p_i, pred]``. Robot contacts other than with the predecessor
    are added by :func:`robot_contacts`.
    """
    edges, boxes = walls.edges, walls.boxes
    mask = pose_violation(pose, pred, p)
    px, py = pose[0], pose[1]
    pt = (px, py)
    reach = obstacle_reach(p)
    r2 = reach * reach
    motion_bounds = (min(prev[0], px), min(prev[1], py), max(prev[0], px), max(prev[1], py))
    sight_bounds = (min(px, pred[0]), min(py, pred[1]), max(px, pred[0]), max(py, pred[1]))
    obstacle = False
    occluded = False
    for k in range(cand.shape[0]):
        e = cand[k]
        ebox = (boxes[e, 0], boxes[e, 1], boxes[e, 2], boxes[e, 3])
        a = (edges[e, 0], edges[e, 1])
        b = (edges[e, 2], edges[e, 3])
        if not obstacle:
            if point_box_distance2(pt, ebox) <= r2 and obstacle_contact(
                point_segment_distance2(pt, a, b), p
            ):
                obstacle = True
            elif boxes_overlap(motion_bounds, ebox) and segments_intersect(prev, pt, a, b):
                obstacle = True
        if (
            not occluded
            and boxes_overlap(sight_bounds, ebox)
            and segments_intersect(pt, pred, a, b)
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
def sensed_violation(row: np.ndarray, clearance2: float, motion_hit: bool, p: np.record) -> int:
    """The violation mask from a follower's sensing ``row`` (``SENSE_D``, ``SENSE_BETA``,
    ``SENSE_OCCLUDED``), its squared clearance and the tunnelling check (``motion_hit``); the
    same rules as :func:`follower_violation`."""
    mask = distance_bearing_causes(row[SENSE_D], row[SENSE_BETA], p)
    if obstacle_contact(clearance2, p) or motion_hit:
        mask |= COLLISION_OBSTACLE
    if row[SENSE_OCCLUDED] > 0.0:
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
    walls: Walls,
    cand: np.ndarray,
    p: np.record,
    out: np.ndarray,
    start_sensed: np.ndarray,
    travel: np.ndarray,
) -> None:
    """:func:`violation_masks` visiting only the edges the grid lists near each follower.

    ``cand`` is scratch space for at least ``E`` edge indices.

    When ``start_sensed`` (N, SENSE_SIZE) holds the sensing of earlier poses and ``travel``
    (N+1,) bounds how far each robot has moved since, a follower whose clearance (to the
    inflated outline) then exceeded ``r`` plus its travel, and whose line of sight then kept
    farther from ``∂W_f`` than either end has moved, cannot have touched an obstacle, crossed
    one or lost its line of sight: its edge tests are skipped (the result is the same, only
    cheaper). ``d_l``, ``d_r`` bound the line of sight's distance to every wall only when all
    of ``L_i`` and that margin lie within the sensed range ``R_p + m`` of ``p_i`` (they see only
    the boundary there), so that is required too. Pass an empty ``start_sensed`` (0 rows) to
    test every follower.
    """
    radius = p.radius
    reach = obstacle_reach(p) * (1.0 + 1e-9) + 1e-9
    sensed_range = p.proximity_range + p.inflation
    bounded = start_sensed.shape[0] > 0
    for i in range(1, poses.shape[0]):
        pose = (poses[i, 0], poses[i, 1], poses[i, 2])
        px, py = pose[0], pose[1]
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
                and row[SENSE_D] + moved_sight < sensed_range
            ):
                out[i - 1] = pose_violation(pose, (qx, qy), p)
                continue
        ox, oy = prev_poses[i, 0], prev_poses[i, 1]
        query = padded_box((px, py), (qx, qy), (ox, oy), reach)
        n = grid_candidates(walls, query, cand)
        out[i - 1] = follower_violation(pose, (qx, qy), (ox, oy), walls, cand[:n], p)
    robot_contacts(poses, radius, out)


@njit(cache=True)
def violation_masks(
    poses: np.ndarray, prev_poses: np.ndarray, walls: Walls, p: np.record, out: np.ndarray
) -> None:
    """Violation bit mask of every follower after a sub-step, written to ``out`` (N,) int64.

    ``prev_poses`` are the poses before the sub-step (for the tunnelling check). Brute force
    over every edge of ``walls`` (its grid is not read); the simulator uses the grid
    (:func:`violation_masks_grid`).
    """
    cand = np.arange(walls.edges.shape[0])
    for i in range(1, poses.shape[0]):
        out[i - 1] = follower_violation(
            (poses[i, 0], poses[i, 1], poses[i, 2]),
            (poses[i - 1, 0], poses[i - 1, 1]),
            (prev_poses[i, 0], prev_poses[i, 1]),
            walls,
            cand,
            p,
        )
    robot_contacts(poses, p.radius, out)


@njit(cache=True)
def motion_crosses_wall(walls: Walls, start: Point, end: Point, cand: np.ndarray) -> bool:
    """Whether the straight motion ``[start, end]`` of a robot's centre touches ``∂W_f``.

    A sub-step's motion is an arc whose chord this is; a crossing of a wall between the two
    poses is a crossing of the chord or of the arc's cap, and the cap stays within the disk the
    clearance test covers. ``cand`` is scratch space for ``E`` edge indices.
    """
    box = (
        min(start[0], end[0]),
        min(start[1], end[1]),
        max(start[0], end[0]),
        max(start[1], end[1]),
    )
    n = grid_candidates(walls, box, cand)
    for k in range(n):
        e = cand[k]
        edge = walls.edges[e]
        if boxes_overlap(
            box, (walls.boxes[e, 0], walls.boxes[e, 1], walls.boxes[e, 2], walls.boxes[e, 3])
        ):
            if segments_intersect(start, end, (edge[0], edge[1]), (edge[2], edge[3])):
                return True
    return False


@njit(cache=True)
def stop_at_walls(
    poses: np.ndarray, prev: np.ndarray, walls: Walls, cand: np.ndarray, masks: np.ndarray
) -> bool:
    """Walls are solid: a follower whose sub-step motion (from ``prev`` to ``poses``) crossed
    the boundary goes back to its pose before the sub-step. Only followers with
    ``COLLISION_OBSTACLE`` in ``masks`` are tested (a crossing always sets it). Returns whether
    any follower was stopped; the collision stays reported."""
    stopped = False
    for i in range(masks.shape[0]):
        if not masks[i] & COLLISION_OBSTACLE:
            continue
        r = i + 1
        if motion_crosses_wall(walls, (prev[r, 0], prev[r, 1]), (poses[r, 0], poses[r, 1]), cand):
            poses[r, 0], poses[r, 1], poses[r, 2] = prev[r, 0], prev[r, 1], prev[r, 2]
            stopped = True
    return stopped


@njit(cache=True)
def configuration_masks(
    poses: np.ndarray, walls: Walls, p: np.record, sensed: np.ndarray, out: np.ndarray
) -> None:
    """The constraints of a configuration at rest: the one source of truth of its rules.

    Senses every follower of ``poses`` (N+1, 3) into ``sensed`` (N, SENSE_SIZE) without motion
    and writes each follower's violation bit mask into ``out`` (N,) int64, by the rules of the
    last sub-step of a step (:func:`sensed_violation`, then :func:`robot_contacts`):
    ``d_i <= d_col`` or a robot contact, ``clearance² <= (r + m)²`` (:func:`obstacle_contact`,
    the obstacles inflated by ``m``), an occluded ``L_i``,
    ``d_i >= d_con``, ``|beta_i| >= beta_con``. The leader's own clearance is not checked.
    """
    cand = np.empty(walls.edges.shape[0], dtype=np.int64)
    for i in range(1, poses.shape[0]):
        pose = (poses[i, 0], poses[i, 1], poses[i, 2])
        clear2, hit = sense_follower_grid(
            pose,
            (poses[i - 1, 0], poses[i - 1, 1]),
            (pose[0], pose[1]),
            False,
            walls,
            cand,
            p,
            sensed[i - 1],
        )
        out[i - 1] = sensed_violation(sensed[i - 1], clear2, hit, p)
    robot_contacts(poses, p.radius, out)


def _field(p: np.void | np.ndarray, name: str) -> float:
    """Field ``name`` of a params record (a record, or a ``(1,)`` array of one)."""
    value = np.asarray(p[name]).reshape(-1)
    return float(value[0])


def describe_masks(
    masks: np.ndarray,
    sensed: np.ndarray,
    p: np.void | np.ndarray,
    poses: np.ndarray | None = None,
) -> list[str]:
    """One readable message per violated constraint in ``masks``, naming the follower.

    ``masks`` (N,) and ``sensed`` (N, SENSE_SIZE) as :func:`configuration_masks` (or a step)
    wrote them, ``p`` the params record (or a ``(1,)`` array of one); e.g.
    ``follower_2: d_2 = 0.301 must exceed d_col = 0.3``. Empty when every mask is 0. With
    ``poses`` (N+1, 3) robot contacts are reported as ``robots j and k overlap`` (every pair
    with ``|p_j - p_k| <= 2r``, as :func:`robot_contacts` tests), otherwise per follower.
    """
    r, d_col, m = _field(p, "radius"), _field(p, "d_col"), _field(p, "inflation")
    d_con, b_con = _field(p, "d_con"), _field(p, "beta_con")
    problems: list[str] = []
    for i in range(1, len(masks) + 1):
        mask, row, name = int(masks[i - 1]), sensed[i - 1], f"follower_{i}"
        d, beta, clearance = row[SENSE_D], row[SENSE_BETA], row[SENSE_CLEARANCE]
        if mask & COLLISION_ROBOT:
            if d <= d_col:
                problems.append(f"{name}: d_{i} = {d:.3f} must exceed d_col = {d_col}")
            elif poses is None:
                problems.append(f"{name}: its disk touches another robot's")
        if mask & OUT_OF_RANGE:
            problems.append(f"{name}: d_{i} = {d:.3f} must be below d_con = {d_con}")
        if mask & OUT_OF_FOV:
            problems.append(
                f"{name}: |beta_{i}| = {abs(beta):.3f} must be below beta_con = {b_con}"
            )
        if mask & COLLISION_OBSTACLE:
            # The mask compares the squared true clearance; its square root may round up past
            # r + m. (The reported clearance is to the inflated outline: true less m.)
            true_clearance = clearance + m
            if clearance > r and true_clearance * true_clearance > (r + m) * (r + m):
                problems.append(f"{name}: its motion over the sub-step crossed an obstacle")
            elif m > 0:
                problems.append(
                    f"{name}: clearance {clearance:.3f} to the obstacles inflated by "
                    f"safety.inflation = {m} must exceed r = {r}"
                )
            else:
                problems.append(
                    f"{name}: clearance {clearance:.3f} to the obstacles must exceed r = {r}"
                )
        if mask & OCCLUDED:
            problems.append(f"{name}: the line of sight to robot {i - 1} crosses an obstacle")
    if poses is not None and np.any(np.asarray(masks) & COLLISION_ROBOT):
        xy = np.asarray(poses, dtype=np.float64)[:, :2]
        touch2 = 4.0 * r * r
        for j in range(xy.shape[0]):
            for k in range(j + 1, xy.shape[0]):
                gx, gy = xy[k, 0] - xy[j, 0], xy[k, 1] - xy[j, 1]
                if gx * gx + gy * gy <= touch2:
                    problems.append(f"robots {j} and {k} overlap")
    return problems


def configuration_problems(poses: np.ndarray, walls: Walls, p: np.void | np.ndarray) -> list[str]:
    """The messages of :func:`describe_masks` for the configuration ``poses`` (N+1, 3) at rest
    (:func:`configuration_masks`); empty when it satisfies every constraint of its followers."""
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    record: Any = p[0] if isinstance(p, np.ndarray) and p.ndim == 1 else p
    n = poses.shape[0] - 1
    sensed = np.empty((n, SENSE_SIZE))
    masks = np.zeros(n, dtype=np.int64)
    configuration_masks(poses, walls, record, sensed, masks)
    return describe_masks(masks, sensed, record, poses)
