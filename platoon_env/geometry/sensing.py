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

Cost: each follower only visits the edges that a static grid (:mod:`platoon_env.geometry.grid`)
lists near its line of sight (within the proximity range), and skips those whose bounding box
cannot improve a current minimum; distances are compared squared, with one square root per
output. The uncapped clearance falls back to a widening grid search when no edge lies within
the proximity range. The brute-force entry points (:func:`sense_into`, :func:`sense` without a
grid) visit every edge and give the same results.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from platoon_env.geometry.grid import (
    EdgeGrid,
    covers_grid,
    edge_boxes,
    grid_candidates,
    nearest_edge_distance2,
)
from platoon_env.geometry.primitives import (
    box_distance2,
    cross,
    point_segment_distance2,
    segments_intersect,
    wrap_angle,
)

__all__ = [
    "SENSE_BETA",
    "SENSE_CLEARANCE",
    "SENSE_D",
    "SENSE_D_SIGHT_LEFT",
    "SENSE_D_SIGHT_RIGHT",
    "SENSE_D_WALL_LEFT",
    "SENSE_D_WALL_RIGHT",
    "SENSE_NAMES",
    "SENSE_OCCLUDED",
    "SENSE_SIZE",
    "SENSE_VISIBLE",
    "edge_boxes",
    "sense",
    "sense_candidates",
    "sense_follower",
    "sense_follower_grid",
    "sense_into",
    "sense_into_grid",
]

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


#: Relative and absolute padding of query boxes, so that rounding never culls an edge that lies
#: exactly at the proximity range.
_PAD_REL = 1e-9
_PAD_ABS = 1e-9


@njit(cache=True)
def sense_candidates(
    px: float,
    py: float,
    theta: float,
    qx: float,
    qy: float,
    ox: float,
    oy: float,
    check_motion: bool,
    edges: np.ndarray,
    boxes: np.ndarray,
    cand: np.ndarray,
    n_cand: int,
    d_con: float,
    beta_con: float,
    proximity_range: float,
    out: np.ndarray,
) -> tuple[float, bool]:
    """Sense one follower at ``(px, py, theta)`` with predecessor at ``(qx, qy)`` (eqs. 2-3).

    Visits the edges ``cand[:n_cand]`` only (they must include every edge within the proximity
    range of ``L_i`` and every edge whose box overlaps ``L_i``'s); writes the ``SENSE_*``
    columns into ``out``. Returns ``(clearance², motion_hit)``: the squared clearance over the
    visited edges (exact whenever it is ``<= proximity_range²`` or every edge was visited) and,
    when ``check_motion``, whether the motion segment ``[o, p]`` of the last sub-step touches an
    edge (the tunnelling check of :mod:`platoon_env.safety`).
    """
    dx = qx - px
    dy = qy - py
    d = math.sqrt(dx * dx + dy * dy)  # as in safety.pose_violation
    beta = wrap_angle(math.atan2(dy, dx) - theta)
    # Direction that defines left/right; degenerate only when the robots coincide.
    lx, ly = dx, dy
    if d == 0.0:
        lx, ly = math.cos(theta), math.sin(theta)
    inv_d2 = 1.0 / (dx * dx + dy * dy) if d > 0.0 else 0.0
    sx0, sx1 = min(px, qx), max(px, qx)
    sy0, sy1 = min(py, qy), max(py, qy)
    mx0, mx1 = min(px, ox), max(px, ox)
    my0, my1 = min(py, oy), max(py, oy)
    cap2 = proximity_range * proximity_range
    wall_l = cap2
    wall_r = cap2
    sight_l = cap2
    sight_r = cap2
    clear2 = math.inf
    occluded = False
    motion_hit = False
    for k in range(n_cand):
        e = cand[k]
        bx0, by0, bx1, by1 = boxes[e, 0], boxes[e, 1], boxes[e, 2], boxes[e, 3]
        ax, ay, bx, by = edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3]
        lb_point = box_distance2(px, py, px, py, bx0, by0, bx1, by1)
        if lb_point < clear2:
            clear2 = min(clear2, point_segment_distance2(px, py, ax, ay, bx, by))
        if (
            check_motion
            and not motion_hit
            and bx0 <= mx1
            and bx1 >= mx0
            and by0 <= my1
            and by1 >= my0
            and segments_intersect(ox, oy, px, py, ax, ay, bx, by)
        ):
            motion_hit = True
        sight_box = bx0 <= sx1 and bx1 >= sx0 and by0 <= sy1 and by1 >= sy0
        if sight_box and not occluded and segments_intersect(px, py, qx, qy, ax, ay, bx, by):
            occluded = True
        # Once occluded, d_l = d_r = 0: only the wall clearances remain to be found.
        lb_sight = 0.0
        need_sight = False
        if not occluded:
            if not sight_box:
                lb_sight = box_distance2(sx0, sy0, sx1, sy1, bx0, by0, bx1, by1)
            need_sight = lb_sight < max(sight_l, sight_r)
        if not (need_sight or lb_point < max(wall_l, wall_r)):
            continue
        sa = cross(lx, ly, ax - px, ay - py)
        sb = cross(lx, ly, bx - px, by - py)
        # Split point on the line through L_i (only used when the edge straddles it).
        smx, smy = ax, ay
        if (sa > 0.0 and sb < 0.0) or (sa < 0.0 and sb > 0.0):
            t = sa / (sa - sb)
            smx = ax + t * (bx - ax)
            smy = ay + t * (by - ay)
        # Left part: the edge's points in the closed half-plane cross >= 0.
        has_left = True
        if sa >= 0.0 and sb >= 0.0:
            cx, cy, ex, ey = ax, ay, bx, by
        elif sa > 0.0:  # sb < 0: straddles
            cx, cy, ex, ey = ax, ay, smx, smy
        elif sb > 0.0:  # sa < 0: straddles
            cx, cy, ex, ey = smx, smy, bx, by
        elif sa == 0.0:  # sb < 0: only the endpoint a lies on the line
            cx, cy, ex, ey = ax, ay, ax, ay
        elif sb == 0.0:  # sa < 0: only b
            cx, cy, ex, ey = bx, by, bx, by
        else:
            has_left = False
        if has_left and (lb_point < wall_l or (need_sight and lb_sight < sight_l)):
            near, sight = _part_distances2(
                px, py, qx, qy, dx, dy, inv_d2, cx, cy, ex, ey, need_sight and lb_sight < sight_l
            )
            wall_l = min(wall_l, near)
            sight_l = min(sight_l, sight)
        # Right part: the closed half-plane cross <= 0.
        has_right = True
        if sa <= 0.0 and sb <= 0.0:
            cx, cy, ex, ey = ax, ay, bx, by
        elif sa < 0.0:  # sb > 0: straddles
            cx, cy, ex, ey = ax, ay, smx, smy
        elif sb < 0.0:  # sa > 0: straddles
            cx, cy, ex, ey = smx, smy, bx, by
        elif sa == 0.0:  # sb > 0
            cx, cy, ex, ey = ax, ay, ax, ay
        elif sb == 0.0:  # sa > 0
            cx, cy, ex, ey = bx, by, bx, by
        else:
            has_right = False
        if has_right and (lb_point < wall_r or (need_sight and lb_sight < sight_r)):
            near, sight = _part_distances2(
                px, py, qx, qy, dx, dy, inv_d2, cx, cy, ex, ey, need_sight and lb_sight < sight_r
            )
            wall_r = min(wall_r, near)
            sight_r = min(sight_r, sight)
    out[SENSE_D] = d
    out[SENSE_BETA] = beta
    out[SENSE_OCCLUDED] = 1.0 if occluded else 0.0
    out[SENSE_VISIBLE] = 1.0 if (d < d_con and abs(beta) < beta_con and not occluded) else 0.0
    out[SENSE_D_WALL_LEFT] = _capped(wall_l, cap2, proximity_range)
    out[SENSE_D_WALL_RIGHT] = _capped(wall_r, cap2, proximity_range)
    out[SENSE_D_SIGHT_LEFT] = 0.0 if occluded else _capped(sight_l, cap2, proximity_range)
    out[SENSE_D_SIGHT_RIGHT] = 0.0 if occluded else _capped(sight_r, cap2, proximity_range)
    out[SENSE_CLEARANCE] = math.sqrt(clear2)
    return clear2, motion_hit


@njit(cache=True, inline="always")
def _part_distances2(
    px: float,
    py: float,
    qx: float,
    qy: float,
    dx: float,
    dy: float,
    inv_d2: float,
    cx: float,
    cy: float,
    ex: float,
    ey: float,
    with_sight: bool,
) -> tuple[float, float]:
    """Squared distances from ``p`` and (if ``with_sight``) from ``L_i = [p, q]`` to ``[c, e]``.

    ``(dx, dy) = q - p`` and ``inv_d2 = 1 / |q - p|²`` (0 when ``p = q``). The segments are known
    not to cross when the second distance matters (a crossing means occluded, and then
    ``d_l = d_r = 0`` anyway), so it is attained at one of the four endpoints. Returns
    ``(near², sight²)``, ``sight² = inf`` without ``with_sight``.
    """
    ux = ex - cx
    uy = ey - cy
    lu = ux * ux + uy * uy
    inv_u = 1.0 / lu if lu > 0.0 else 0.0
    wx = px - cx
    wy = py - cy
    t = min(1.0, max(0.0, (wx * ux + wy * uy) * inv_u))
    wx -= t * ux
    wy -= t * uy
    near = wx * wx + wy * wy
    if not with_sight:
        return near, math.inf
    best = near
    # q to the part.
    wx = qx - cx
    wy = qy - cy
    t = min(1.0, max(0.0, (wx * ux + wy * uy) * inv_u))
    wx -= t * ux
    wy -= t * uy
    best = min(best, wx * wx + wy * wy)
    # The part's endpoints to L_i.
    wx = cx - px
    wy = cy - py
    t = min(1.0, max(0.0, (wx * dx + wy * dy) * inv_d2))
    wx -= t * dx
    wy -= t * dy
    best = min(best, wx * wx + wy * wy)
    wx = ex - px
    wy = ey - py
    t = min(1.0, max(0.0, (wx * dx + wy * dy) * inv_d2))
    wx -= t * dx
    wy -= t * dy
    return near, min(best, wx * wx + wy * wy)


@njit(cache=True, inline="always")
def _capped(value2: float, cap2: float, cap: float) -> float:
    """``sqrt(value2)``, or exactly ``cap`` when the squared value reached the cap."""
    return cap if value2 >= cap2 else math.sqrt(value2)


@njit(cache=True)
def sense_follower_grid(
    px: float,
    py: float,
    theta: float,
    qx: float,
    qy: float,
    ox: float,
    oy: float,
    check_motion: bool,
    edges: np.ndarray,
    boxes: np.ndarray,
    grid_params: np.ndarray,
    cell_start: np.ndarray,
    cell_edges: np.ndarray,
    edge_cell: np.ndarray,
    cand: np.ndarray,
    d_con: float,
    beta_con: float,
    proximity_range: float,
    out: np.ndarray,
) -> tuple[float, bool]:
    """:func:`sense_candidates` over the edges the grid lists near ``L_i`` (and ``[o, p]``).

    ``cand`` is scratch space for at least ``E`` edge indices. The clearance is exact: when no
    edge lies within the proximity range, a widening grid search finds the nearest one.
    """
    reach = proximity_range * (1.0 + _PAD_REL) + _PAD_ABS
    x0 = min(min(px, qx), ox) - reach
    y0 = min(min(py, qy), oy) - reach
    x1 = max(max(px, qx), ox) + reach
    y1 = max(max(py, qy), oy) + reach
    n = grid_candidates(grid_params, cell_start, cell_edges, edge_cell, x0, y0, x1, y1, cand)
    clear2, hit = sense_candidates(
        px,
        py,
        theta,
        qx,
        qy,
        ox,
        oy,
        check_motion,
        edges,
        boxes,
        cand,
        n,
        d_con,
        beta_con,
        proximity_range,
        out,
    )
    if clear2 > proximity_range * proximity_range and not covers_grid(grid_params, x0, y0, x1, y1):
        clear2 = nearest_edge_distance2(
            grid_params, cell_start, cell_edges, edge_cell, edges, boxes, px, py, reach, cand
        )
        out[SENSE_CLEARANCE] = math.sqrt(clear2)
    return clear2, hit


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
    """Sense one follower against every edge (brute force); see :func:`sense_candidates`."""
    cand = np.arange(edges.shape[0])
    sense_candidates(
        px,
        py,
        theta,
        qx,
        qy,
        px,
        py,
        False,
        edges,
        boxes,
        cand,
        cand.shape[0],
        d_con,
        beta_con,
        proximity_range,
        out,
    )


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
    """Sense every follower ``i = 1..N`` of ``poses`` ((N+1) x 3) into ``out`` (N x SENSE_SIZE).

    Brute force over every edge (no grid); :func:`sense_into_grid` culls.
    """
    cand = np.arange(edges.shape[0])
    for i in range(1, poses.shape[0]):
        sense_candidates(
            poses[i, 0],
            poses[i, 1],
            poses[i, 2],
            poses[i - 1, 0],
            poses[i - 1, 1],
            poses[i, 0],
            poses[i, 1],
            False,
            edges,
            boxes,
            cand,
            cand.shape[0],
            d_con,
            beta_con,
            proximity_range,
            out[i - 1],
        )


@njit(cache=True)
def sense_into_grid(
    poses: np.ndarray,
    edges: np.ndarray,
    boxes: np.ndarray,
    grid_params: np.ndarray,
    cell_start: np.ndarray,
    cell_edges: np.ndarray,
    edge_cell: np.ndarray,
    d_con: float,
    beta_con: float,
    proximity_range: float,
    out: np.ndarray,
) -> None:
    """:func:`sense_into` with grid culling (same results)."""
    cand = np.empty(edges.shape[0], dtype=np.int64)
    for i in range(1, poses.shape[0]):
        sense_follower_grid(
            poses[i, 0],
            poses[i, 1],
            poses[i, 2],
            poses[i - 1, 0],
            poses[i - 1, 1],
            poses[i, 0],
            poses[i, 1],
            False,
            edges,
            boxes,
            grid_params,
            cell_start,
            cell_edges,
            edge_cell,
            cand,
            d_con,
            beta_con,
            proximity_range,
            out[i - 1],
        )


def sense(
    poses: np.ndarray,
    edges: np.ndarray,
    d_con: float,
    beta_con: float,
    proximity_range: float,
    grid: EdgeGrid | None = None,
) -> np.ndarray:
    """Sense all followers; returns an ``(N, SENSE_SIZE)`` float64 array of ``SENSE_*`` columns.

    Convenience entry point for tests and plots; the env calls the compiled kernel directly.
    ``grid`` (built over the same ``edges``) culls distant edges; without it every edge is
    visited. Both give the same result.
    """
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    edges = np.ascontiguousarray(edges, dtype=np.float64).reshape(-1, 4)
    if poses.ndim != 2 or poses.shape[1] != 3 or poses.shape[0] < 2:
        raise ValueError(f"poses must have shape (N+1, 3) with N >= 1, got {poses.shape}")
    out = np.empty((poses.shape[0] - 1, SENSE_SIZE), dtype=np.float64)
    boxes = edge_boxes(edges)
    if grid is None:
        sense_into(poses, edges, boxes, d_con, beta_con, proximity_range, out)
    else:
        if grid.n_edges != edges.shape[0]:
            raise ValueError(f"grid indexes {grid.n_edges} edges, got {edges.shape[0]}")
        sense_into_grid(poses, *grid.arrays, d_con, beta_con, proximity_range, out)
    return out
